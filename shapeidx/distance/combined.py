"""**combined**: a learned distance beyond the paper (its section 5 asks for one).

A non-negative weighted sum of ten per-pair features (:data:`FEATURES`): the four ``D``
values, the three ``|%A - %B|`` and, per class, how much the two parts differ in the ratio of
that class's mean distance to the ALL mean (``|ln(mA_c / mA_all) - ln(mB_c / mB_all)|``). The
paper's per-histogram normalisation by its own mean discards that scale information; the
store keeps the means, so it costs nothing. The weights come from
``shapeidx/distance/combined_metric.json``, written by ``scripts/learn_metric.py``
(neighbourhood component analysis on a labelled collection, with class-wise
cross-validation figures recorded beside the weights).

**combined-angle**: the normal-angle histograms (:mod:`shapeidx.signing.angles`: all pairs,
IN, OUT, MIXED) compared by Hellinger distance, with the six class features of combined (the
three fraction gaps and the three class-mean ratios), learned the same way, with its own
weights (``combined_angle_metric.json``). Of the variants cross-validated on kicad6 (the D2
histograms' own distances added, L1, chi-squared or earth mover's distances of the angle
histograms: docs/results.md) this one ranked best, and it needs no D2 histogram at query
time. A store built before the angle histograms cannot serve it (its entries' angles are
unknown).

**all-angle**: for the same part from another exporter, not for parts of a kind. Plain D2
(ALL) plus :data:`ALL_ANGLE_WEIGHT` times the L1 distance of the ALL angle histograms: no
IN / OUT / MIXED class, which differs between exports of one part (open against closed
meshes), and no learned weight.

**combined-size**: combined-angle's features and two of the part's exact sizes: how much the
middle and the smallest principal radii of the surface differ, ``sqrt|ln rA - ln rB|``
(:data:`SIZE_FEATURES`), learned the same way (``combined_size_metric.json``). The store keeps
the radii (integrated from the surface, no sampling noise); the paper's histograms, each
normalised by its own mean, are blind to size. In a library of one unit some kinds differ by
size alone (pin headers of 1.00, 2.00 and 2.54 mm pitch: the smallest radius scales with the
pitch), and on kicad6 cross-validated it is the best for parts of a kind (docs/results.md,
docs/unified.md "Parts of a kind"). It is not scale-invariant: a part exported in inches is
far from its own export in mm, so it is no metric for a collection of mixed units (ndr).

**unified**: one metric for both questions (issue 24): combined-angle, discounted where
all-angle says the two are the same part from another exporter:
``combined-angle x min(1, all-angle / UNIFIED_TWIN_DISTANCE) ** UNIFIED_POWER``. Pairs whose
all-angle distance is below :data:`UNIFIED_TWIN_DISTANCE` (about that of a KiCad 2017 export
and its KiCad 6 twin) move ahead of the parts of the same kind; every other pair keeps its
combined-angle distance, so the ranking of kinds is combined-angle's. Both factors never
decrease as ``D(ALL)`` grows, so a coarse lower bound serves its query's candidate step.

:func:`metric_values` turns features into every metric, the paper's four included, so one
function serves a pair (:func:`compare`) and a whole store (:mod:`.bank`).
"""

from __future__ import annotations


import numpy as np

from ..signing.angles import ANGLE_HISTOGRAMS, angle_probabilities
from ..signing.histogram import Signature
from ..signing.parameters import HISTOGRAMS
from .metrics import ALL_ANGLE_WEIGHT, METRICS, REGISTRY, learned_weights, metric
from .paper import histogram_distance

#: The per-pair quantities all metrics are made of, in the order of the combined weights.
FEATURES = tuple(f"d_{h}" for h in HISTOGRAMS) + tuple(f"gap_{c}" for c in HISTOGRAMS[1:]) + tuple(
    f"scale_{c}" for c in HISTOGRAMS[1:]
)
#: Distances of the normal-angle histograms (:mod:`shapeidx.signing.angles`), per histogram:
#: L1 (``angle_*``, all-angle's) and Hellinger (``hellinger_angle_*``, combined-angle's).
ANGLE_FEATURES = tuple(f"angle_{h}" for h in ANGLE_HISTOGRAMS) + tuple(f"hellinger_angle_{h}" for h in ANGLE_HISTOGRAMS)
#: The exact sizes' gaps: ``sqrt|ln rA - ln rB|`` of the largest, middle and smallest principal radius.
SIZE_FEATURES = tuple(f"size_r{i}" for i in (1, 2, 3))
#: The learned metrics: their features, in the order of their weights, and their weights' file
#: (from the registry, :mod:`shapeidx.distance.metrics`).
LEARNED = {name: (m.features, m.learned) for name, m in REGISTRY.items() if m.learned}
#: Angle distances a metric reads: ``"hellinger"`` (``hellinger_angle_*``), ``"l1"`` (``angle_*``).
ANGLE_KINDS = {name: tuple(kind for kind, prefix in (("hellinger", "hellinger_angle_"), ("l1", "angle_"))
                           if any(f.startswith(prefix) for f in m.features)) for name, m in REGISTRY.items()}
#: unified = combined-angle x min(1, all-angle / this) ** UNIFIED_POWER: below this all-angle
#: distance a pair counts as the same part. Both chosen on half A of the twin pairs
#: (scripts/twin_study.py) and on kicad6 with combined-angle's weights cross-validated by class
#: folds (scripts/unified_study.py); half B and the other collections are the check.
UNIFIED_TWIN_DISTANCE = 4e-4
UNIFIED_POWER = 1.5
#: A class with no pairs counts, in the scale features, as a mean this share of the ALL mean.
EMPTY_CLASS_SCALE = 1e-3


def require_angles(angles, signature: Signature, metric: str) -> None:
    """Refuse, in one line, a metric that needs normal-angle histograms the store or query lacks.

    ``angles``: the store's (N, 4, bins) probabilities (NaN rows: entries built before them), or None.
    """
    from ..errors import StoreError

    unknown = None if angles is None else int((~np.isfinite(angles).all(axis=(1, 2))).sum())
    if unknown is None or unknown:
        which = "the entries" if unknown is None else f"{unknown} entr{'y' if unknown == 1 else 'ies'}"
        raise StoreError(f"metric {metric} needs the normal-angle histograms, which {which} of this store"
                         " lack (built before them): rebuild it with 'shapeidx build DIR --full'")
    if signature.angles is None:
        raise StoreError(f"metric {metric} needs the query's normal-angle histograms, which its signature lacks")


def size_features(radii_a, radii_b) -> dict:
    """:data:`SIZE_FEATURES` between principal radii ``radii_a`` and ``radii_b`` (..., 3), broadcast
    against each other (None: unknown): name -> (...) array, 0 where either is unknown (an unknown
    size adds nothing, as in the same-part order: a signature made by hand, an entry of a store
    written before the exact measures).

    The square root: near sizes count for more than a difference in ln r would give them (two
    pitches 1.27 and 2.54 mm apart are ln 2 apart, a 0402 and a 2512 resistor ln 6), and far
    ones for less (NCA on kicad6 preferred it: docs/unified.md, "Parts of a kind").
    """
    radii_a, radii_b = (np.full(3, np.nan) if r is None else np.asarray(r, dtype=np.float64) for r in (radii_a, radii_b))
    with np.errstate(divide="ignore", invalid="ignore"):
        gap = np.abs(np.log(radii_a) - np.log(radii_b))
    gap = np.sqrt(np.nan_to_num(gap, nan=0.0, posinf=0.0))
    return {name: gap[..., i] for i, name in enumerate(SIZE_FEATURES)}


def class_scales(means: np.ndarray) -> np.ndarray:
    """``ln(class mean / ALL mean)`` for IN, OUT, MIXED from means in :data:`HISTOGRAMS` order.

    ``means`` is (4,) or (N, 4); a class with no pairs (mean 0) counts as
    :data:`EMPTY_CLASS_SCALE` of the ALL mean.
    """
    means = np.asarray(means, dtype=np.float64)
    overall = np.maximum(means[..., :1], np.finfo(float).tiny)
    return np.log(np.maximum(means[..., 1:], EMPTY_CLASS_SCALE * overall) / overall)


def signature_means(signature: Signature) -> np.ndarray:
    """The four histograms' mean distances, in :data:`HISTOGRAMS` order."""
    return np.array([signature.histograms[h].mean for h in HISTOGRAMS])


def metric_values(features: dict, metrics=METRICS) -> dict:
    """Metrics from per-pair features (numbers, or arrays with one value per pair): each by
    its registry record's formula."""
    values = {}
    for name in metrics:
        record = metric(name)
        missing = [f for f in record.features if f not in features]
        if missing:
            what = ("the normal-angle histograms" if record.angles and missing[0] in ANGLE_FEATURES
                    else "the exact sizes (principal radii)" if missing[0] in SIZE_FEATURES
                    else f"the features {', '.join(missing)}")
            raise ValueError(f"metric {name} needs {what}, which are unknown here")
        values[name] = record.value(features)
    return values


def _learned(name: str, features: dict):
    weights = learned_weights(name)["weights"]
    return sum(weights[f] * features[f] for f in LEARNED[name][0])


def combined(features: dict):
    """**combined**: the learned weights of ``combined_metric.json`` over :data:`FEATURES`."""
    return _learned("combined", features)


def combined_angle(features: dict):
    """**combined-angle**: the learned weights of ``combined_angle_metric.json`` over the class
    features and the angle histograms' Hellinger distances."""
    return _learned("combined-angle", features)


def combined_size(features: dict):
    """**combined-size**: the learned weights of ``combined_size_metric.json`` over combined-angle's
    features and :data:`SIZE_FEATURES` (two of them)."""
    return _learned("combined-size", features)


def all_angle(features: dict):
    """**all-angle**: ``D(ALL) +`` :data:`ALL_ANGLE_WEIGHT` ``x`` the L1 distance of the ALL angle histograms."""
    return features["d_all"] + ALL_ANGLE_WEIGHT * features["angle_all"]


def unified(features: dict):
    """**unified**: combined-angle ``x min(1,`` all-angle ``/`` :data:`UNIFIED_TWIN_DISTANCE` ``) **``
    :data:`UNIFIED_POWER`."""
    return unified_of(combined_angle(features), all_angle(features))


def unified_of(combined_angle_distance, all_angle_distance):
    """unified from its two parts (also with combined-angle's weights learned elsewhere: the
    cross-validated figures of :mod:`shapeidx.evaluation`)."""
    discount = np.minimum(1.0, np.asarray(all_angle_distance) / UNIFIED_TWIN_DISTANCE) ** UNIFIED_POWER
    return combined_angle_distance * discount


def combined_weights() -> dict:
    """The learned weights of the combined metric and how they were obtained."""
    return learned_weights("combined")


def angle_features(a: np.ndarray, b: np.ndarray) -> dict:
    """:data:`ANGLE_FEATURES` between normal-angle probabilities ``a`` and ``b`` (..., H, B),
    broadcast against each other: name -> (...) array (NaN where either is unknown).

    Hellinger distance ``sqrt(sum_k (sqrt p_k - sqrt q_k)^2 / 2)`` lies in [0, 1], as L1 / 2
    does, but weighs a bin's difference by how rare the angle is in both: the few pairs at a
    right angle that tell a flat part from a box count for more than they do in L1. Two
    empty classes (no pairs) are 0 apart, an empty and a filled one ``sqrt(1/2)``.
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    l1 = np.abs(a - b).sum(axis=-1)
    hellinger = np.sqrt(((np.sqrt(a) - np.sqrt(b)) ** 2).sum(axis=-1) / 2)
    count = len(ANGLE_HISTOGRAMS)
    named = {name: l1[..., i] for i, name in enumerate(ANGLE_FEATURES[:count])}
    named.update({name: hellinger[..., i] for i, name in enumerate(ANGLE_FEATURES[count:])})
    return named


def features_between(a: Signature, b: Signature) -> dict:
    """The per-pair features (:data:`FEATURES`) of two signatures."""
    features = {f"d_{h}": histogram_distance(a.histograms[h].p, b.histograms[h].p) for h in HISTOGRAMS}
    fa, fb = a.fractions, b.fractions
    features.update({f"gap_{c}": abs(fa[c] - fb[c]) for c in HISTOGRAMS[1:]})
    scale_gap = np.abs(class_scales(signature_means(a)) - class_scales(signature_means(b)))
    features.update({f"scale_{c}": float(v) for c, v in zip(HISTOGRAMS[1:], scale_gap)})
    if a.angles is not None and b.angles is not None:
        gaps = angle_features(angle_probabilities(a.angles), angle_probabilities(b.angles))
        features.update({name: float(v) for name, v in gaps.items()})
    features.update({name: float(v) for name, v in size_features(a.radii, b.radii).items()})
    return features


def compare(a: Signature, b: Signature) -> dict:
    """Every metric of the registry (:data:`~shapeidx.distance.metrics.METRICS`) between two signatures,
    by name; the metrics that read normal-angle histograms only when both carry them."""
    features = features_between(a, b)
    metrics = [m for m in METRICS if set(metric(m).features) <= set(features)]
    return {name: float(value) for name, value in metric_values(features, metrics).items()}
