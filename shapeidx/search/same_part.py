"""The same-part order: "is this the same part?" answered with the exact measures beside the metric.

A signature is drawn from 1,024 random points, so two drawings of one part differ by sampling
noise, and a series sibling (the same package one pitch longer) can be nearer than the part's
own entry drawn otherwise: an exact copy of a kicad6 part, its points drawn again, was its own
first answer 90-98 % of the time by the metrics alone (docs/sampling.md). The store also keeps,
for every entry, measures integrated exactly from the surface
(:func:`shapeidx.signing.moments.shape_facts`): the principal radii and the area. They carry no
sampling noise at all, and they are what tells siblings apart. With ``same_part`` a query ranks
by

    score = distance + SAME_PART_WEIGHT * d_K * (gap + OTHER_SURFACE_GAP [gap > SAME_SURFACE])

where ``distance`` is the metric's, ``d_K`` the query's :data:`SAME_PART_RANK`-th smallest
distance (the scale of the metric around this query, so one weight serves every metric) and
``gap`` (:func:`shape_gap`) the sum of the ``|ln|`` differences of the proportions ``r2/r1``,
``r3/r1``, of ``area / (r1^2 + r2^2 + r3^2)`` and of the size ``r1``, the size taken modulo the
unit factors (:data:`shapeidx.distance.scale.UNIT_FACTORS`: a part in mm is the same part as its
export in tenths of an inch), plus :data:`MIRROR_GAP` where the two are mirror images by the
handedness the store keeps (:func:`shapeidx.signing.chirality.mirror_relation`): a left and a
right pin header have every measure alike, and D2 cannot tell them apart (a part whose two
principal radii nearly coincide has only the handedness about its one axis, ``h3``, and no
part whose three radii coincide has any: no such gap there). :data:`OTHER_SURFACE_GAP` more
for every entry that is not one surface with the query (its gap beyond :data:`SAME_SURFACE`):
two series siblings can be nearer in every measure than a STEP part and its own VRML export
(a KiCad HC-18/U and HC-49/U crystal: 7e-4 apart; the median STEP/VRML twin: 1e-3), so that
only the surface itself tells a stored copy of the query from its sibling. The candidates are
the :data:`SAME_PART_CANDIDATES` nearest by the metric and as many nearest by the gap. Hits
keep the metric's distance; their order is the score's.

The weight and rank were chosen on kicad6 (exact copies drawn again) and on half A of the
xexp-dev twins, and checked on half B and on kicad6-step; the mirror gap on the SMD pin headers
of Debian's whole library (docs/sampling.md, "The same-part order"). This is for the same-part question (twins, duplicates, a part in another format); for
parts *of a kind* the size and proportions are no distance (a 0402 and a 1206 resistor are one
kind), and the plain order is the one to use.
"""

from __future__ import annotations

import numpy as np

from ..distance.scale import SAME_SIZE_FACTORS
from ..signing.chirality import mirror_relation

#: Weight of the exact-measure gap, in units of the query's SAME_PART_RANK-th distance.
SAME_PART_WEIGHT = 5.0
#: Which of the query's nearest distances (the 11th: its own and ten more) sets the scale of the gap.
SAME_PART_RANK = 11
#: Candidates taken by the metric, and as many by the gap.
SAME_PART_CANDIDATES = 200
#: Gap added for a mirror image: as much as proportions some 10 % off (chosen on the library's SMD pin headers).
MIRROR_GAP = 0.1
#: Largest gap of one surface (also duplicates' ``same`` tier, FINGERPRINT_SURFACE): a rotated,
#: rescaled, mirrored or re-faceted copy keeps its exact moments within it (docs/duplicates.md).
SAME_SURFACE = 1e-4
#: Gap added to every entry that is not one surface with the query: as much as for a mirror image.
OTHER_SURFACE_GAP = MIRROR_GAP
#: ln of every factor a size may be off by and still be the same part.
_LOG_FACTORS = np.log(np.array(SAME_SIZE_FACTORS))


def shape_measures(extents, moments, handedness) -> np.ndarray:
    """``(..., 7)``: ``ln r1, ln(r2/r1), ln(r3/r1), ln(area / sum r^2)`` and the three handedness
    pseudo-scalars, from the principal radii ``(..., 3)``, the moments ``(..., 4)`` and the
    handedness ``(..., 3)`` the store keeps (NaN where unknown)."""
    e = np.asarray(extents, dtype=np.float64)
    m = np.asarray(moments, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.stack([np.log(e[..., 0]), np.log(e[..., 1] / e[..., 0]), np.log(e[..., 2] / e[..., 0]),
                         np.log(m[..., 0])], axis=-1)
    return np.concatenate([logs, np.asarray(handedness, dtype=np.float64)], axis=-1)


def radii_of_measures(measures) -> np.ndarray:
    """The principal radii ``(..., 3)`` that :func:`shape_measures` ``(..., 7)`` were made from
    (NaN where unknown): ``r1 = exp m0``, ``r2 = r1 exp m1``, ``r3 = r1 exp m2``."""
    m = np.asarray(measures, dtype=np.float64)
    return np.exp(m[..., :1]) * np.exp(np.concatenate([np.zeros_like(m[..., :1]), m[..., 1:3]], axis=-1))


def measures_of_solid(solid) -> np.ndarray:
    """:func:`shape_measures` of a loaded part, as the store computes them for its entries."""
    facts = solid.facts
    return shape_measures(facts["extents"], facts["moments"], facts["handedness"])


def shape_gap(query: np.ndarray, entries: np.ndarray) -> np.ndarray:
    """The exact-measure gap between the query's measures ``(7,)`` and each entry's ``(N, 7)``
    (:func:`shape_measures`): the proportions' and area's ``|ln|`` differences, plus the size's,
    modulo a unit factor, plus :data:`MIRROR_GAP` for a mirror image. An unknown measure adds nothing."""
    entries = np.atleast_2d(np.asarray(entries, dtype=np.float64))
    query = np.asarray(query, dtype=np.float64)
    shape = np.nan_to_num(np.abs(entries[:, 1:4] - query[1:4]), nan=0.0).sum(axis=1)
    size = size_gap(query[0], entries[:, 0])
    mirrored = mirror_relation(query[4:], entries[:, 4:])
    return shape + np.nan_to_num(size, nan=0.0) + MIRROR_GAP * mirrored


def size_gap(ln_a, ln_b) -> np.ndarray:
    """``|ln a - ln b|`` of two sizes (broadcast), modulo a unit factor: the smallest over
    :data:`shapeidx.distance.scale.SAME_SIZE_FACTORS` (NaN where a size is unknown)."""
    d = np.subtract(np.asarray(ln_a, dtype=np.float64), np.asarray(ln_b, dtype=np.float64))
    return np.abs(d[..., None] - _LOG_FACTORS).min(axis=-1)


def same_part_scores(distances: np.ndarray, gaps: np.ndarray, nearest=None) -> np.ndarray:
    """The order's score of each candidate (see the module docstring). ``nearest``: the query's
    smallest distances (at least :data:`SAME_PART_RANK` of them where there are), when the
    candidates are not all there is (a sharded store's merge); default: ``distances``."""
    distances, gaps = np.asarray(distances, dtype=np.float64), np.asarray(gaps, dtype=np.float64)
    scale = query_scale(distances if nearest is None else nearest)
    return distances + SAME_PART_WEIGHT * scale * (gaps + OTHER_SURFACE_GAP * (gaps > SAME_SURFACE))


def query_scale(distances: np.ndarray) -> float:
    """``d_K``: the :data:`SAME_PART_RANK`-th smallest finite distance (the largest when fewer; 0: none)."""
    finite = np.asarray(distances, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    if not len(finite):
        return 0.0
    k = min(SAME_PART_RANK, len(finite)) - 1
    return float(np.partition(finite, k)[k])
