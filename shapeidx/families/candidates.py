"""The candidate step now lives in :mod:`shapeidx.store.candidates` (one module for the query,
duplicates and cluster); these names stay importable from here."""

from ..store.candidates import (  # noqa: F401
    COARSE_BINS,
    EXACT_LIMIT,
    FINE_PER_COARSE,
    HNSW_EF_CONSTRUCTION,
    HNSW_EF_SEARCH,
    HNSW_M,
    OVERFETCH,
    CandidateIndex,
    candidate_pairs,
    embed,
)
