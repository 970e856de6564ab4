"""scripts/make_store.py: synthetic stores of real signatures, for the benchmarks and tests."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from clitools import run_shapeidx
from storetools import REPO, build, load_script, small_kicad

from shapeidx.search import Searcher
from shapeidx.search.distances import distances
from shapeidx.signing.parameters import BIN_DIVISOR, CLASS_NAMES, HISTOGRAMS
from shapeidx.store import STATUS_OK, open_store

MADE = 64


@pytest.fixture(scope="module")
def stores(data_dir, tmp_path_factory):
    """A real store of 20 kicad6 parts and a synthetic one of MADE entries made from it."""
    tmp = tmp_path_factory.mktemp("make_store")
    tree = small_kicad(data_dir, tmp, ["Diode_SMD", "Relay_THT"])
    source = tmp / "source.h5"
    assert build(tree, source).exit_code == 0
    made = tmp / "made.h5"
    run = subprocess.run([sys.executable, str(REPO / "scripts" / "make_store.py"), str(source), str(MADE), str(made)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return source, made


def source_of(path: str) -> str:
    """The real entry a synthetic one was made from (its path says so)."""
    return path.split("/", 1)[1].split("-", 1)[1]


def test_a_made_store_opens_with_n_distinct_entries(stores):
    source, made = stores
    stats = json.loads(run_shapeidx("stats", "--store", made, "--json").stdout)
    assert stats["entries"] == MADE and stats["journal_batches"] == 0
    with open_store(made) as reader, open_store(source) as real:
        assert reader.params == real.params
        assert len(set(reader.paths)) == MADE
        assert np.all(reader.column("entries/status") == STATUS_OK)
        assert {source_of(p) for p in reader.paths} <= set(real.paths)
        assert len({source_of(p) for p in reader.paths}) < MADE  # real signatures are reused ...
        signatures = [reader.signature(i) for i in range(MADE)]
    # ... yet no two entries are alike
    keys = {tuple(np.concatenate([s.histograms[h].counts for h in HISTOGRAMS])) for s in signatures}
    assert len(keys) == MADE
    # the class fractions are shares of points * (points - 1) / 2 pairs, as in a real store: at the
    # tests' 128 points two entries may share them by chance, but hardly more
    assert len(np.unique(np.round(np.array([list(s.fractions.values()) for s in signatures]), 12), axis=0)) >= MADE - 3


def test_every_made_signature_is_consistent_and_near_its_source(stores):
    source, made = stores
    with open_store(made) as reader, open_store(source) as real:
        fractions = reader.column("entries/fractions")
        for i, path in enumerate(reader.paths):
            sig, base = reader.signature(i), real.signature(real.index_of(source_of(path)))
            totals = np.array([sig.histograms[c].total for c in CLASS_NAMES])
            assert sig.histograms["all"].total == totals.sum()  # as many pairs as the classes together
            assert totals.sum() == reader.params.points * (reader.params.points - 1) // 2  # all of them
            assert np.allclose(fractions[i], totals / totals.sum(), rtol=0, atol=1e-15)
            means = np.array([sig.histograms[c].mean for c in CLASS_NAMES])
            assert sig.histograms["all"].mean == pytest.approx(float(fractions[i] @ means), rel=1e-12)
            for name in HISTOGRAMS:
                h, b = sig.histograms[name], base.histograms[name]
                assert h.bin_width == pytest.approx(h.mean / BIN_DIVISOR, rel=1e-15)
                assert (len(h.counts) == 0) == (len(b.counts) == 0)
                if len(h.counts):
                    assert h.counts[-1] > 0  # a real histogram ends on a non-empty bin
                    assert len(h.counts) <= len(b.counts)  # 0-5 last bins dropped, then empty ones
                    assert not b.counts[len(h.counts):len(b.counts) - 5].any()
                    assert 0.98 - 1e-12 <= h.mean / b.mean <= 1.02 + 1e-12
                    # bins keep their emptiness; class counts within [0.9, 1.1] of the source (and rounding)
                    kept = b.counts[: len(h.counts)]
                    assert np.array_equal(h.counts > 0, kept > 0)
                    if name != "all":  # [0.9, 1.1], the rescale to the class's share of the pairs
                        # (a few percent: the real classes already held all pairs), rounding; the
                        # fullest bin also takes the rounding residual
                        assert np.count_nonzero(np.abs(h.counts - kept) > 0.15 * kept + 1) <= 1


def test_a_made_store_ranks_each_entry_nearest_to_its_siblings(stores):
    """The perturbation keeps shapes apart: what came from one real part ranks together."""
    _, made = stores
    with Searcher(made) as searcher:
        paths = [str(p) for p in searcher.metadata_column("path")]
        nearest_sibling = 0
        with_siblings = 0
        for i, path in enumerate(paths):
            d = distances(searcher.view, searcher.signature_at(i), "weighted")
            assert d[i] == 0.0 and np.count_nonzero(d == 0.0) == 1
            siblings = [j for j, p in enumerate(paths) if j != i and source_of(p) == source_of(path)]
            if siblings:
                with_siblings += 1
                d[i] = np.inf
                nearest_sibling += source_of(paths[int(np.argmin(d))]) == source_of(path)
    assert with_siblings > MADE // 2
    assert nearest_sibling >= 0.9 * with_siblings, (nearest_sibling, with_siblings)
    top = json.loads(run_shapeidx("query", "--store", made, "--id", paths[7], "--top", "3", "--json").stdout)["hits"]
    assert [h["relative_path"] for h in top][0] == paths[7] and len(top) == 3


def test_make_store_never_writes_over_a_store(stores):
    source, made = stores
    before = made.stat().st_mtime_ns
    run = subprocess.run([sys.executable, str(REPO / "scripts" / "make_store.py"), str(source), "5", str(made)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 1 and "exists" in run.stderr
    assert made.stat().st_mtime_ns == before


def test_rounding_to_totals_keeps_every_count_at_or_above_zero():
    """A sparse histogram whose many bins all round up holds more pairs than its share: the
    excess comes out of its fullest bins, one pair each at least kept, never below zero (it
    once all came out of the fullest bin: a count of -1, stored as 2^32 - 1, 2 entries in
    500,000, which `shapeidx check` then called damaged)."""
    make_store = load_script("make_store")
    flat = np.array([0.6] * 10 + [3.0, 5.0, 0.0, 0.6])  # two histograms: ten bins of 0.6; four bins
    lengths = np.array([10, 0, 4])
    for totals in ([7, 0, 9], [10, 0, 8], [3, 0, 1], [12, 0, 30]):
        counts = make_store._round_to_totals(flat, lengths, np.array(totals))
        assert counts.min() >= 0
        assert [counts[:10].sum(), counts[10:].sum()] == [totals[0], totals[2]]
    counts = make_store._round_to_totals(flat, lengths, np.array([7, 0, 9]))
    assert counts[:10].tolist() == [0, 0, 0] + [1] * 7 and counts[9] > 0  # the excess from the first bins
    # a chunk whose last histograms are empty (a convex part's OUT and MIXED) rounds too
    counts = make_store._round_to_totals(flat[:10], np.array([10, 0, 0]), np.array([7, 0, 0]))
    assert counts.sum() == 7 and counts.min() >= 0
