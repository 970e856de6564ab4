"""**combined**: a learned distance beyond the paper (its section 5 asks for one).

A non-negative weighted sum of ten per-pair features (:data:`FEATURES`): the four ``D``
values, the three ``|%A - %B|`` and, per class, how much the two parts differ in the ratio of
that class's mean distance to the ALL mean (``|ln(mA_c / mA_all) - ln(mB_c / mB_all)|``). The
paper's per-histogram normalisation by its own mean discards that scale information; the
store keeps the means, so it costs nothing. The weights come from
``shapeidx/distance/combined_metric.json``, written by ``scripts/learn_metric.py``
(neighbourhood component analysis on a labelled collection, with class-wise
cross-validation figures recorded beside the weights).

:func:`metric_values` turns features into every metric, the paper's four included, so one
function serves a pair (:func:`compare`) and a whole store (:mod:`.bank`).
"""

from __future__ import annotations

import json
from functools import lru_cache
from importlib import resources

import numpy as np

from ..signing.histogram import Signature
from ..signing.parameters import HISTOGRAMS
from .paper import PAPER_METRICS, histogram_distance, paper_distances

#: Every metric, by the name ``--metric`` takes.
METRICS = PAPER_METRICS + ("combined",)
#: The per-pair quantities all metrics are made of, in the order of the combined weights.
FEATURES = tuple(f"d_{h}" for h in HISTOGRAMS) + tuple(f"gap_{c}" for c in HISTOGRAMS[1:]) + tuple(
    f"scale_{c}" for c in HISTOGRAMS[1:]
)
#: A class with no pairs counts, in the scale features, as a mean this share of the ALL mean.
EMPTY_CLASS_SCALE = 1e-3


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
    """Metrics from per-pair features (numbers, or arrays with one value per pair)."""
    d = {h: features[f"d_{h}"] for h in HISTOGRAMS}
    gap = {c: features[f"gap_{c}"] for c in HISTOGRAMS[1:]}
    values = paper_distances(d, gap)
    if "combined" in metrics:
        weights = combined_weights()["weights"]
        values["combined"] = sum(weights[name] * features[name] for name in FEATURES)
    return {m: values[m] for m in metrics}


@lru_cache(maxsize=1)
def combined_weights() -> dict:
    """The learned weights of the combined metric and how they were obtained."""
    data = json.loads(resources.files(__package__).joinpath("combined_metric.json").read_text())
    if set(data["weights"]) != set(FEATURES):
        raise ValueError("combined_metric.json does not match shapeidx.distance.FEATURES")
    return data


def features_between(a: Signature, b: Signature) -> dict:
    """The per-pair features (:data:`FEATURES`) of two signatures."""
    features = {f"d_{h}": histogram_distance(a.histograms[h].p, b.histograms[h].p) for h in HISTOGRAMS}
    fa, fb = a.fractions, b.fractions
    features.update({f"gap_{c}": abs(fa[c] - fb[c]) for c in HISTOGRAMS[1:]})
    scale_gap = np.abs(class_scales(signature_means(a)) - class_scales(signature_means(b)))
    features.update({f"scale_{c}": float(v) for c, v in zip(HISTOGRAMS[1:], scale_gap)})
    return features


def compare(a: Signature, b: Signature) -> dict:
    """Every metric between two signatures: ``{"all", "avg3", "avg4", "weighted", "combined"}``."""
    return {name: float(value) for name, value in metric_values(features_between(a, b)).items()}
