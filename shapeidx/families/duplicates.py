"""``shapeidx duplicates``: groups of store entries that are one part, a person could keep one of.

Every pair found is put in one tier:

* ``identical``: the same file content (SHA-256);
* ``same``: the same surface: its exact moments agree to :data:`FINGERPRINT_SURFACE`
  (:func:`fingerprint_gap`; a rotated, mirrored, rescaled or re-faceted copy keeps them to
  rounding), the sizes agree (:func:`unit_factor`: equal within :data:`SIZE_TOLERANCE`, or
  apart by a unit factor such as 25.4, which the pair reports) and the shape distance is
  within :data:`EXACT_DISTANCE_FACTOR` times the noise of signing one part with other random
  points (``thresholds.json``, measured per metric by ``scripts/duplicates_study.py
  --noise``). The sizes are needed because a shape distance is blind to size (an 0402 and an
  0805 resistor); the moments because the sampling noise of D2 at 1024 points is larger than
  the distance between many pairs of different parts of one family;
* ``converted``: one part written by two programs: in two file formats (a VRML and the STEP
  file it was made from, faceted again by another program, whose moments move by up to
  :data:`FINGERPRINT_SAME`) or in two units (a unit factor: KiCad's 2017 exports in millimetres
  beside KiCad 6's files in tenths of an inch): the pair meets the ``similar`` rules and each
  is the other's closest partner of that kind, format and unit (so a STEP file of one package
  is paired with one VRML, not with every package of the same body). One library keeps one
  format and one unit, so a pair across them is a conversion, not a series sibling;
* ``similar``: one body, details may differ: distance within the ``same`` noise threshold,
  moments within :data:`FINGERPRINT_SAME` (or within :data:`FINGERPRINT_EXACT` up to
  :data:`EXACT_DISTANCE_FACTOR` times that threshold), sizes as for ``same``. On the whole
  KiCad 6 library most such pairs are one package body with other pins, pin pitch or printed
  segments (docs/duplicates.md): reported only when asked for (``tiers``);
* ``near``: a near duplicate: distance within the looser ``near`` threshold, moments within
  :data:`FINGERPRINT_NEAR`, sizes as for ``same``. Reported only when asked for.

Stores without the moments (layout 1) have no :func:`fingerprint_gap`: their pairs are
``same`` by the distance and the sizes alone, as before the moments existed.

Groups do not chain. Each group has a *representative*, and every other member is within the
tier's thresholds of the representative itself (so, the metric being a sum of distances, two
members are at most twice the threshold apart), not merely linked to it through a chain of
neighbours. Files with one content (``identical``) always stay together. Representatives are
chosen greedily, the entry with the most ``same`` partners first; a member is an entry paired
with the representative itself by the candidate step. Groups come in order of
*confidence* (:func:`group_confidence`: the tier of their weakest member, then how deep inside
its thresholds that member lies), not of size.

Each member's pair with the representative also says ``size_ratio`` (member over
representative, radii of gyration in file units, so a copy saved in inches shows 1/25.4),
``unit`` (that ratio's unit factor, or None) and ``mirrored`` (one is the mirror image of the
other, :func:`shapeidx.signing.chirality.mirror_relation`; always false for parts that are
their own mirror image). With ``scale="sensitive"`` no unit factor is allowed.

Candidates come from :class:`shapeidx.store.candidates.CandidateIndex`, twice: each
entry's nearest neighbours in the metric's embedding, and in the space of its exact moments
(:func:`fingerprint_vectors`), every pair confirmed with the exact distance; entries with one
exact fingerprint (copies of one surface) are all paired with each other. The work grows as N k,
not N^2, and is done in blocks of :data:`PAIR_BLOCK` entries, each block's pairs cut to the
loosest tier's distance before the next. Nothing is ever deleted or moved.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from ..distance.metrics import default_metric
from ..errors import ShapeidxError
from ..store.candidates import OVERFETCH as OVERFETCH_MOMENTS
from ..signing.chirality import mirror_relation
from ..distance.scale import SAME_SIZE_FACTORS, check_scale
from ..search.same_part import SAME_SURFACE

TIERS = ("identical", "same", "converted", "similar", "near")
DEFAULT_METRIC = default_metric("duplicates")
#: Tiers reported unless asked otherwise: those whose precision docs/duplicates.md measured
#: high enough (0.9 or more) on the whole library.
DEFAULT_TIERS = ("identical", "same", "converted")
#: Largest ``|ln|`` gap between a size ratio and 1 or a unit factor (radii of gyration are
#: exact integrals: of 1,500 twins injected into the whole library the STL copies keep their
#: ratio within 0.42% (a part whose touching bodies are cleaned otherwise once it is one STL
#: body), the STEP files faceted again by OpenCASCADE within 0.19%, docs/duplicates.md; at 1%
#: two BGAs of one 11 mm body and 100 or 169 balls, 0.8% apart, were one part).
SIZE_TOLERANCE = 0.005
#: Candidate neighbours per entry.
DEFAULT_NEIGHBOURS = 20
#: Largest :func:`fingerprint_gap` for ``same``: one surface, the tolerance the same-part order
#: uses too. Of 1,200 copies of library parts (rotated, rescaled, mirrored, re-faceted STL) 1,190
#: keep their moments within it; of the library's pairs within :data:`FINGERPRINT_SAME`, those
#: beyond it were nearly all one body with other pins (docs/duplicates.md).
FINGERPRINT_SURFACE = SAME_SURFACE
#: Largest :func:`fingerprint_gap` for ``similar`` and ``converted`` (the STEP files of 300
#: library parts, faceted again by OpenCASCADE: within 0.0057 at the 99th percentile), and
#: for ``near`` (docs/duplicates.md).
FINGERPRINT_SAME = 0.01
FINGERPRINT_NEAR = 0.06
#: The exact road to ``similar``: moments within this and sizes as for ``same`` make a pair
#: ``similar`` up to :data:`EXACT_DISTANCE_FACTOR` times the ``same`` distance (as ``same``
#: is, whose moments agree closer still). Some parts'
#: signatures move far between two samplings (a box drawn as coincident bodies: 70 between
#: its VRML and its own mirror image or re-faceted copy), while their exact moments do not;
#: on the whole library this road added one pair of library parts to ``same`` (two names
#: of one box) and 7 of 1,500 twins (docs/duplicates.md).
FINGERPRINT_EXACT = 0.002
EXACT_DISTANCE_FACTOR = 4.0


def thresholds(metric: str) -> dict:
    """``{"same": d, "near": d}`` for ``metric`` (its registry record's, see the module docstring)."""
    from ..distance.metrics import REGISTRY, duplicate_metrics

    found = REGISTRY[metric].duplicate_thresholds if metric in REGISTRY else None
    if found is None:
        raise ShapeidxError(f"no duplicate thresholds measured for metric {metric!r} (have: {', '.join(duplicate_metrics())})")
    return found


def aspect_gap(extents_a: np.ndarray, extents_b: np.ndarray) -> np.ndarray:
    """Largest ``|ln|`` difference of the proportions r2/r1 and r3/r1 (NaN: unknown)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        pa = np.log(extents_a[:, 1:] / extents_a[:, :1])
        pb = np.log(extents_b[:, 1:] / extents_b[:, :1])
        return np.abs(pa - pb).max(axis=1)


def fingerprint_gap(table, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """How far apart two parts' exact, scale-free surface moments are (NaN: unknown).

    The largest of: the proportions' ``|ln|`` gaps (:func:`aspect_gap`), the ``|ln|`` gap of
    area / sum r^2, and the gaps of the absolute skewnesses along the principal axes. These
    are integrals of the surface, not samples: a rotated, mirrored, rescaled or re-saved copy
    has the same values to rounding, where D2 distances carry the sampling noise.
    """
    def features():  # per entry, once: ln r2/r1, ln r3/r1, ln(area / sum r^2), |skewness| x 3
        with np.errstate(divide="ignore", invalid="ignore"):
            parts = [np.log(table.extents[:, 1:] / table.extents[:, :1])]
            if table.moments is not None:
                parts += [np.log(table.moments[:, :1]), table.moments[:, 1:]]
        return np.concatenate(parts, axis=1)

    f = table._cached("fingerprint_features", features) if hasattr(table, "_cached") else features()
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    out = np.full(len(a), np.nan)
    step = 1 << 20
    for lo in range(0, len(a), step):
        gaps = np.abs(f[a[lo:lo + step]] - f[b[lo:lo + step]])
        # the proportions' gap is known only when both proportions are; each other term on its own
        proportions = gaps[:, :2].max(axis=1)
        stacked = np.stack([proportions, gaps[:, 2], gaps[:, 3:].max(axis=1)] if gaps.shape[1] > 2 else [proportions], axis=1)
        known = ~np.isnan(stacked).all(axis=1)
        part = np.full(len(stacked), np.nan)
        part[known] = np.nanmax(stacked[known], axis=1)
        out[lo:lo + step] = part
    return out


def fingerprint_vectors(table) -> np.ndarray | None:
    """The moments of :func:`fingerprint_gap` as vectors (NaN as 0), or None if all unknown."""
    if table.moments is None:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        proportions = np.log(table.extents[:, 1:] / table.extents[:, :1])
        vectors = np.concatenate([proportions, np.log(table.moments[:, :1]), table.moments[:, 1:]], axis=1)
    if np.isnan(vectors).all():
        return None
    return np.nan_to_num(vectors, nan=0.0, posinf=0.0, neginf=0.0)


#: Entries sharing one exact fingerprint (copies of one surface) are all paired with each
#: other up to this many; a larger set pairs each member with the first and its neighbours.
ALL_PAIRS_LIMIT = 200


#: Entries per block of the pair stage: the candidate pairs of this many entries are found,
#: confirmed with the exact distance and cut to the loosest tier's distance before the next
#: block, so that the pairs held at once are PAIR_BLOCK x (OVERFETCH k), not N x (OVERFETCH k)
#: (docs/performance-families.md: 10^6 entries).
PAIR_BLOCK = 20_000


def _directed(lists: np.ndarray, lo: int, n: int) -> np.ndarray:
    """Sorted keys ``row (n + 1) + column`` of candidate lists (rows ``lo`` on), padding as column ``n``."""
    cols = np.where(lists < 0, n, lists)
    cols.sort(axis=1)
    return (np.arange(lo, lo + len(lists), dtype=np.int64)[:, None] * (n + 1) + cols).ravel()


def _contains(keys: np.ndarray, a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Whether ``b`` is in the candidate list of ``a``, for every pair (``keys`` from :func:`_directed`)."""
    want = a * (n + 1) + b
    at = np.minimum(np.searchsorted(keys, want), len(keys) - 1) if len(keys) else np.zeros(len(want), np.int64)
    return (keys[at] == want) if len(keys) else np.zeros(len(want), bool)


def _candidates(table, metric, k, method, threads, limit, judge=None) -> dict:
    """Candidate pairs by the D2 embedding and by the exact moments, confirmed with the exact
    distance, those within ``limit`` kept, each once: ``{"a", "b", "d"}`` arrays, a < b, and
    what ``judge(a, b, d)`` says of them (a dict of arrays; its ``keep`` mask, if any, drops
    pairs: so that each block's pairs are cut before the next).

    Each entry's :data:`~shapeidx.store.candidates.OVERFETCH` k nearest in the embedding;
    copies of one surface share their moments exactly, so they would fill each other's
    nearest-moment lists: the moment search runs over the distinct fingerprints (each once),
    pairs the first entry of each with the first of its neighbours, and pairs the entries of
    one fingerprint among themselves. All of it in blocks of :data:`PAIR_BLOCK` entries (or
    fingerprints); a pair in both its entries' lists is confirmed once, in the list of the
    smaller one, and a moment pair already in the embedding's lists is not confirmed again.
    """
    from ..store.candidates import CandidateIndex, embed

    n = len(table)
    found = []
    survivors = []

    def confirm(a, b):
        a, b = np.minimum(a, b), np.maximum(a, b)
        key = np.unique((a * n + b)[a != b])
        a, b = key // n, key % n
        d = table.pair_distances(a, b, metric) if len(key) else np.zeros(0)
        close = d <= limit
        part = {"a": a[close], "b": b[close], "d": d[close]}
        if judge is not None:
            part.update(judge(part["a"], part["b"], part["d"]))
            keep = part.pop("keep", None)
            if keep is not None:
                part = {name: values[keep] for name, values in part.items()}
        survivors.append(part)

    index = CandidateIndex(embed(table, metric), method, threads)
    fetch = min(OVERFETCH_MOMENTS * k, max(n - 1, 0))
    for lo in range(0, n, PAIR_BLOCK):
        found.append(_directed(index.neighbours(fetch, lo, lo + PAIR_BLOCK), lo, n))
    embedded = np.concatenate(found) if found else np.zeros(0, np.int64)
    del index, found
    for lo in range(0, len(embedded), PAIR_BLOCK * max(fetch, 1)):
        keys = embedded[lo:lo + PAIR_BLOCK * max(fetch, 1)]
        a, b = keys // (n + 1), keys % (n + 1)
        valid = b < n
        a, b = a[valid], b[valid]
        # a pair in both lists: confirmed from the smaller entry's list only
        mine = (a < b) | ~_contains(embedded, b, a, n)
        confirm(a[mine], b[mine])
    vectors = fingerprint_vectors(table)
    if vectors is not None:
        unique, first, inverse = np.unique(vectors, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.ravel()
        if len(unique) > 1:
            moments = CandidateIndex(unique, method, threads)
            width = min(OVERFETCH_MOMENTS * k, len(unique) - 1) + 1
            for lo in range(0, len(unique), PAIR_BLOCK):
                _, near = moments.search(unique[lo:lo + PAIR_BLOCK], width)
                rows = np.repeat(first[lo:lo + PAIR_BLOCK], near.shape[1])
                cols = near.ravel()
                keep = cols >= 0
                a, b = rows[keep], first[cols[keep]]
                known = _contains(embedded, a, b, n) | _contains(embedded, b, a, n)
                confirm(a[~known], b[~known])
            del moments
        order = np.argsort(inverse, kind="stable")
        bounds = np.flatnonzero(np.diff(np.concatenate([[-1], inverse[order], [-2]])))
        pieces_a, pieces_b = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            members = order[lo:hi]
            if len(members) < 2:
                continue
            if len(members) <= ALL_PAIRS_LIMIT:
                i, j = np.triu_indices(len(members), 1)
                pieces_a.append(members[i])
                pieces_b.append(members[j])
            else:
                pieces_a.append(np.full(len(members) - 1, members[0]))
                pieces_b.append(members[1:])
        a, b = np.concatenate(pieces_a), np.concatenate(pieces_b)
        for lo in range(0, len(a), PAIR_BLOCK * max(fetch, 1)):
            x, y = a[lo:lo + PAIR_BLOCK * max(fetch, 1)], b[lo:lo + PAIR_BLOCK * max(fetch, 1)]
            known = _contains(embedded, x, y, n) | _contains(embedded, y, x, n)
            confirm(x[~known], y[~known])
    if not survivors:
        confirm(np.zeros(0, np.int64), np.zeros(0, np.int64))
    out = {name: np.concatenate([part[name] for part in survivors]) for name in survivors[0]}
    # a pair confirmed twice (by the moments and by a fingerprint's set): once
    _, first = np.unique(out["a"] * n + out["b"], return_index=True)
    return {name: values[first] for name, values in out.items()}


def unit_factor(ratios: np.ndarray, scale: str = "invariant") -> tuple[np.ndarray, np.ndarray]:
    """Whether each size ratio means one size: (ok, factor), factor 1 for equal sizes, one of
    :data:`~shapeidx.distance.scale.UNIT_FACTORS` (or its inverse) for a unit change, NaN where it is neither. An unknown
    ratio (NaN: a store without sizes) is ok with factor NaN."""
    ratios = np.asarray(ratios, dtype=np.float64)
    factors = _ALL_FACTORS
    if check_scale(scale) == "sensitive":
        factors = np.ones(1)
    logs = np.log(factors)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.log(ratios)
    # the nearest factor (on the log axis) is one of the two around each ratio
    upper = np.clip(np.searchsorted(logs, x), 1, len(logs) - 1) if len(logs) > 1 else np.zeros(len(x), np.int64)
    lower = np.maximum(upper - 1, 0)
    best = np.where(np.abs(x - logs[lower]) <= np.abs(x - logs[upper]), lower, upper)
    with np.errstate(invalid="ignore"):
        close = np.abs(x - logs[best]) <= SIZE_TOLERANCE
    unknown = np.isnan(ratios)
    factor = np.where(close, factors[best], np.nan)
    return close | unknown, factor


def file_formats(table) -> np.ndarray:
    """Each entry's file format (:data:`shapeidx.io.formats.SUFFIXES`, "" if none), from its path
    (a sub-part's, ``FILE#n``, from its file's)."""
    from ..io.formats import SUFFIXES

    def formats():
        by_suffix = {suffix: name for name, suffixes in SUFFIXES.items() for suffix in suffixes}
        out = []
        for path in table.paths:
            name = str(path).lower()
            name = name.rsplit("#", 1)[0] if "#" in name.rsplit("/", 1)[-1] else name
            name = name[:-3] if name.endswith(".gz") else name
            dot = name.rfind(".")
            out.append(by_suffix.get(name[dot:], "") if dot >= 0 else "")
        return np.array(out, dtype=object)

    return table._cached("file_formats", formats) if hasattr(table, "_cached") else formats()


def _pair_facts(table, a, b, d, limits: dict, scale: str) -> dict:
    """Tier codes (0 identical, 1 same, 2 converted, 3 similar, 4 near, 5 none) and what each pair
    says. ``converted`` here is every pair of two formats within the ``similar`` rules:
    :func:`_closest_across_formats` keeps the closest ones."""
    hashes = table.hashes
    hashed = table._cached("hashed", lambda: np.array([len(h) > 0 for h in hashes], dtype=bool))
    identical = (hashes[a] == hashes[b]) & hashed[a]
    gap = fingerprint_gap(table, a, b)
    unknown = np.isnan(gap)
    ratios = table.size_ratios(a, b)
    sized, factor = unit_factor(ratios, scale)
    with np.errstate(invalid="ignore"):
        exact = sized & ~unknown & (gap <= FINGERPRINT_EXACT) & (d <= EXACT_DISTANCE_FACTOR * limits["same"])
        surface = sized & ~unknown & (gap <= FINGERPRINT_SURFACE) & (d <= EXACT_DISTANCE_FACTOR * limits["same"])
        similar = (sized & (d <= limits["same"]) & (unknown | (gap <= FINGERPRINT_SAME))) | exact
        near = sized & (d <= limits["near"]) & (unknown | (gap <= FINGERPRINT_NEAR))
    same = surface | (similar & unknown)  # no moments: the distance and sizes alone, as before them
    across = _conversion_kind(table, a, b, factor) != 0
    tier = np.where(identical, 0, np.where(same, 1, np.where(similar, np.where(across, 2, 3), np.where(near, 4, 5))))
    # how deep inside its tier's thresholds the pair lies: 0 at the centre, 1 at the edge
    with np.errstate(divide="ignore", invalid="ignore"):
        size_gap = np.nan_to_num(np.abs(np.log(ratios / np.where(np.isnan(factor), 1.0, factor))))
        fp = np.nan_to_num(gap)

        def edge(distance_limit, fp_limit):
            return np.nanmax(np.stack([d / distance_limit, fp / fp_limit, size_gap / SIZE_TOLERANCE]), axis=0)

        loose = np.where(exact, np.minimum(edge(limits["same"], FINGERPRINT_SAME),
                                           edge(EXACT_DISTANCE_FACTOR * limits["same"], FINGERPRINT_EXACT)),
                         edge(limits["same"], FINGERPRINT_SAME))
        margin = np.where(tier == 1, np.where(unknown, loose, edge(EXACT_DISTANCE_FACTOR * limits["same"], FINGERPRINT_SURFACE)),
                          np.where(tier == 4, edge(limits["near"], FINGERPRINT_NEAR), loose))
    margin = np.where(tier == 0, 0.0, np.clip(margin, 0.0, 1.0))
    return {"tier": tier, "distance": np.where(identical, 0.0, d), "size_ratio": ratios,
            "unit": np.where(np.isnan(factor) | (factor == 1.0), np.nan, factor),
            "mirrored": mirror_relation(table.handedness[a], table.handedness[b]), "margin": margin,
            "loose": np.where(tier == 0, 0.0, np.clip(loose, 0.0, np.inf))}


#: Every size factor a pair can be apart by (1, each unit factor and its inverse), sorted: a
#: pair's place in it codes the unit part of its conversion kind.
_ALL_FACTORS = np.sort(np.array(SAME_SIZE_FACTORS))


def _conversion_kind(table, a, b, factor, reverse: bool = False) -> np.ndarray:
    """What ``b`` is to ``a`` as a conversion: 0 for none (one format, one unit), else a code
    of (``b``'s format, the size factor from ``a`` to ``b``, NaN read as 1); ``reverse``: what
    ``a`` is to ``b``."""
    codes = table._cached("format_codes", lambda: np.unique(file_formats(table), return_inverse=True)[1].ravel())
    factor = np.asarray(factor, dtype=np.float64)
    factor = np.where(np.isfinite(factor), factor, 1.0)
    if reverse:
        factor = 1.0 / factor
    logs, x = np.log(_ALL_FACTORS), np.log(factor)
    upper = np.clip(np.searchsorted(logs, x), 1, len(logs) - 1)
    unit = np.where(np.abs(x - logs[upper - 1]) <= np.abs(x - logs[upper]), upper - 1, upper)  # the nearest factor
    partner = codes[a] if reverse else codes[b]
    kind = 1 + partner * len(_ALL_FACTORS) + unit
    return np.where((codes[a] != codes[b]) | (factor != 1.0), kind, 0)


def _closest_across_formats(table, a, b, facts) -> np.ndarray:
    """Which pairs stay ``converted``: those whose two entries are each the other's closest
    partner of that conversion kind (:func:`_conversion_kind`: the partner's format and unit;
    by the ``similar`` margin, among the pairs of tier ``same`` to ``converted``); the others
    are ``similar``. A STEP file of a 4 x 4 mm QFN meets the ``similar`` rules with the VRML of
    every QFN of that body: only its own is closest."""
    tier, loose = facts["tier"], facts["loose"]
    keep = np.zeros(len(a), dtype=bool)
    factor = np.where(np.isnan(facts["unit"]), 1.0, facts["unit"])
    forward = _conversion_kind(table, a, b, factor)
    pool = np.flatnonzero((tier >= 1) & (tier <= 2) & (forward != 0))
    if not len(pool):
        return keep
    backward = _conversion_kind(table, a[pool], b[pool], factor[pool], reverse=True)
    kinds = int(max(forward.max(), backward.max())) + 1
    # both directions: (entry, what its partner is to it) -> the smallest margin
    ahead, behind = a[pool] * kinds + forward[pool], b[pool] * kinds + backward
    key = np.concatenate([ahead, behind])
    score = np.concatenate([loose[pool], loose[pool]])
    uniq, inverse = np.unique(key, return_inverse=True)
    best = np.full(len(uniq), np.inf)
    np.minimum.at(best, inverse.ravel(), score)
    lookup = dict(zip(uniq.tolist(), best.tolist()))
    for k, i in enumerate(pool.tolist()):
        if tier[i] == 2:
            keep[i] = loose[i] <= lookup[int(ahead[k])] and loose[i] <= lookup[int(behind[k])]
    return keep


def pair_tiers(table, a: np.ndarray, b: np.ndarray, metric: str = DEFAULT_METRIC, scale: str = "invariant",
               limits: dict | None = None, closest: bool = False) -> dict:
    """The tier :func:`find_duplicates` gives the pairs ``a``-``b`` (rows of ``table``), asked directly.

    ``converted`` is said of every pair of two formats or units within the ``similar`` rules:
    whether each is the other's closest partner of that kind depends on the other entries, and
    :func:`find_duplicates` lists the pairs that are not as ``similar``. ``closest``: judge
    that among the pairs given (check-new: a new part and its candidates).

    Returns
    -------
    dict
        Arrays aligned with the pairs: ``tier`` (one of :data:`TIERS`, or "" for none),
        ``distance``, ``size_ratio`` (b over a), ``unit`` (the ratio's unit factor, NaN for
        none), ``mirrored``, ``margin`` (0 at the centre of the tier, 1 at its edge).
    """
    check_scale(scale)
    limits = limits or thresholds(metric)
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    d = table.pair_distances(a, b, metric) if len(a) else np.zeros(0)
    facts = _pair_facts(table, a, b, d, limits, scale)
    if closest and len(a):
        facts["tier"] = np.where((facts["tier"] == 2) & ~_closest_across_formats(table, a, b, facts), 3, facts["tier"])
    names = np.array(TIERS + ("",))
    return {**facts, "tier": names[facts["tier"]]}


def group_confidence(tier: int, margin: float) -> float:
    """A group's place in the report, from its weakest member: identical 1; then each tier in a
    band of 0.2 (same 0.98 to 0.8, converted 0.78 to 0.6, similar 0.58 to 0.4, near 0.38 to
    0.2), lower as that member's pair nears the edge of its tier (``margin``). An order, not a
    probability: each tier's measured precision is in docs/duplicates.md."""
    if tier == 0:
        return 1.0
    top = 1.0 - 0.2 * (tier - 1)
    return float(top - 0.2 * (0.1 + 0.9 * margin))


def find_duplicates(table, metric: str = DEFAULT_METRIC, scale: str = "invariant", k: int = DEFAULT_NEIGHBOURS,
                    method: str = "auto", threads: int | None = None, limits: dict | None = None,
                    tiers=DEFAULT_TIERS, keep=None) -> list[dict]:
    """Duplicate groups of a :class:`~shapeidx.families.table.FamilyTable` (module docstring).

    Parameters
    ----------
    tiers : tuple of str
        The tiers reported (default :data:`DEFAULT_TIERS`); ``identical`` always is.
    keep : (N,) bool, optional
        Only these entries (a ``--where`` filter's keep-mask over the table's entries).

    Returns
    -------
    list of dict
        Groups, most confident first: ``representative`` (a path), ``members`` (paths, the
        representative first), ``tier`` (of the weakest member), ``confidence``
        (:func:`group_confidence`), ``folders`` (the top-level folders its members are in),
        and ``pairs``, one per other member: ``a`` (the representative), ``b``, ``tier``,
        ``distance``, ``size_ratio``, ``unit``, ``mirrored``.
    """
    check_scale(scale)
    if keep is not None:
        table = table.subset(keep)
    limits = limits or thresholds(metric)
    tiers = tuple(t for t in TIERS if t in set(tiers) | {"identical"})
    loosest = max(TIERS.index(t) for t in tiers)
    n = len(table)
    if n == 0:
        return []
    # atoms: files of one content, never split
    keys = np.array([str(h) if len(h) else f"\0{i}" for i, h in enumerate(table.hashes)], dtype=object)
    _, atom = np.unique(keys, return_inverse=True)
    atom = atom.ravel().astype(np.int64)
    atoms = int(atom.max()) + 1
    first_of = np.full(atoms, n, dtype=np.int64)
    np.minimum.at(first_of, atom, np.arange(n))  # each atom's first entry (paths are sorted)
    pair_a = np.zeros(0, np.int64)
    pair_b = np.zeros(0, np.int64)
    facts = {"tier": np.zeros(0, np.int64), "margin": np.zeros(0)}
    if n > 1 and loosest > 0:
        def judge(a, b, d):  # each block's pairs: their facts, those of a reported tier kept
            facts = _pair_facts(table, a, b, d, limits, scale)
            return {**facts, "keep": (atom[a] != atom[b]) & (facts["tier"] <= loosest)}

        facts = _candidates(table, metric, min(k, n - 1), method, threads,
                            max(limits["near"], EXACT_DISTANCE_FACTOR * limits["same"]), judge)
        a, b = facts.pop("a"), facts.pop("b")
        del facts["d"]
        # a pair of two formats stays converted only between closest partners
        facts["tier"] = np.where((facts["tier"] == 2) & ~_closest_across_formats(table, a, b, facts), 3, facts["tier"])
        good = facts["tier"] <= loosest
        pair_a, pair_b = a[good], b[good]
        facts = {key: value[good] for key, value in facts.items()}
        # one pair per two atoms: the best (tier, then margin)
        x, y = np.minimum(atom[pair_a], atom[pair_b]), np.maximum(atom[pair_a], atom[pair_b])
        order = np.lexsort((facts["margin"], facts["tier"], x * atoms + y))
        first = order[np.concatenate([[True], np.diff((x * atoms + y)[order]) != 0])] if len(order) else order
        pair_a, pair_b = pair_a[first], pair_b[first]
        facts = {key: value[first] for key, value in facts.items()}
    # both directions of every atom pair, by atom: (neighbour atom, pair, whether reversed)
    xa, xb = atom[pair_a], atom[pair_b]
    src = np.concatenate([xa, xb])
    dst = np.concatenate([xb, xa])
    which = np.concatenate([np.arange(len(pair_a)), np.arange(len(pair_a))])
    flipped = np.concatenate([np.zeros(len(pair_a), bool), np.ones(len(pair_a), bool)])
    by_src = np.argsort(src, kind="stable")
    starts = np.searchsorted(src[by_src], np.arange(atoms + 1))
    size = np.bincount(atom, minlength=atoms)
    strict = np.bincount(src, weights=(facts["tier"][which] <= 1), minlength=atoms)
    loose = np.bincount(src, minlength=atoms)
    # representatives: most same-tier partners first, then most partners, then most copies
    order = np.lexsort((first_of, -size, -loose, -strict))
    assigned = np.zeros(atoms, dtype=bool)
    members_of_atom = _members(atom, atoms)
    groups = []
    for rep in order.tolist():
        if assigned[rep] or (starts[rep] == starts[rep + 1] and size[rep] < 2):
            continue
        assigned[rep] = True
        # members: the atoms paired with the representative itself, not yet in a group
        edges = by_src[starts[rep]:starts[rep + 1]]
        edges = edges[~assigned[dst[edges]]]
        assigned[dst[edges]] = True
        group = _group(table, rep, dst[edges], which[edges], flipped[edges], facts, members_of_atom, first_of)
        if len(group["members"]) > 1:
            groups.append(group)
    groups.sort(key=lambda g: (-g["confidence"], -len(g["members"]), g["members"][0]))
    return groups


def _members(labels: np.ndarray, count: int) -> list:
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(count + 1))
    return [order[lo:hi] for lo, hi in zip(bounds[:-1], bounds[1:])]


def _group(table, rep: int, chosen: np.ndarray, pairs_of: np.ndarray, flipped: np.ndarray, facts: dict,
           members_of_atom, first_of) -> dict:
    """One group: the representative's atom, then each chosen atom's files with its pair."""
    paths = table.paths
    head = first_of[rep]
    pairs = []
    weakest = (0, 0.0)
    for other in members_of_atom[rep]:
        if other != head:
            pairs.append({"a": str(paths[head]), "b": str(paths[other]), "tier": "identical", "distance": 0.0,
                          "size_ratio": 1.0, "unit": None, "mirrored": False})
    for atom_b, k, back in zip(chosen.tolist(), pairs_of.tolist(), flipped.tolist()):
        tier, margin = int(facts["tier"][k]), float(facts["margin"][k])
        weakest = max(weakest, (tier, margin))
        ratio, unit = float(facts["size_ratio"][k]), float(facts["unit"][k])
        if back:  # the pair was found as (member, representative): sizes the other way round
            ratio, unit = 1.0 / ratio, 1.0 / unit
        for other in members_of_atom[atom_b]:
            pairs.append({"a": str(paths[head]), "b": str(paths[other]), "tier": TIERS[tier],
                          "distance": float(facts["distance"][k]),
                          "size_ratio": None if not np.isfinite(ratio) else ratio,
                          "unit": None if not np.isfinite(unit) else unit, "mirrored": bool(facts["mirrored"][k])})
    pairs.sort(key=lambda p: (TIERS.index(p["tier"]), p["distance"], p["b"]))
    members = [str(paths[head])] + [p["b"] for p in pairs]
    folders = sorted({m.split("/", 1)[0] if "/" in m else "" for m in members})
    return {"representative": str(paths[head]), "members": members, "tier": TIERS[weakest[0]],
            "confidence": group_confidence(*weakest), "folders": folders, "pairs": pairs}


def shared_sub_parts(table, parents, metric: str = DEFAULT_METRIC, scale: str = "invariant", threads: int | None = None,
                     tiers=DEFAULT_TIERS, keep=None, counts=None) -> list[dict]:
    """Duplicate groups of sub-parts (a parts store's table, ``build --parts``) that span
    several files: the same pin in two connectors. ``parents``: the file of each entry of
    ``table`` (its ``entries/parent``); ``counts``: how many times its file holds it
    (``entries/count``; None: once each).

    The sub-entries of one file share its content hash, which for whole files makes them
    one "identical" atom; here each sub-entry is its own atom (its hash made unique by its
    path), so sub-parts are grouped by their geometry alone. Each group also has ``files``
    (its members' files, sorted). Kept: the groups whose members lie in two files or more,
    one of them an assembly (a file of several sub-parts, or of one placed several times).
    A group of files that are each one part is a duplicate of whole files, which
    :func:`find_duplicates` on the whole-file store reports: on Debian's KiCad STEP library
    such groups were 498 of 549, burying the 51 of shared sub-parts.
    """
    import dataclasses

    hashes = np.array([h + b"#" + str(p).encode("utf-8", "surrogatepass") if len(h) else h
                       for h, p in zip(table.hashes, table.paths)], dtype=object)
    table = dataclasses.replace(table, hashes=hashes)
    parents = [str(p) for p in parents]
    parent_of = dict(zip(table.paths.tolist(), parents))
    held = Counter(parents)  # sub-entries per file
    if counts is not None:
        held.update({parent: int(n) - 1 for parent, n in zip(parents, counts) if int(n) > 1})
    groups = find_duplicates(table, metric, scale, threads=threads, tiers=tiers, keep=keep)
    shared = []
    for group in groups:
        files = sorted({parent_of.get(m, m) for m in group["members"]})
        if len(files) > 1 and any(held[f] > 1 for f in files):
            shared.append({**group, "files": files})
    return shared
