"""Distances between signatures.

    paper.py     the paper's D and its four distances: ALL, AvgOf3, AvgOf4, Weighted (3.2.5)
    combined.py  the learned combined distances (combined, combined-angle), every metric from per-pair features
    bank.py      one query against many signatures at once (what ranking a store runs)
    scale.py     --scale invariant | sensitive: a size band that keeps parts of other sizes apart
"""

from .bank import METRIC_HISTOGRAMS, HistogramBank, distances_to_many, features_to_many
from .combined import (
    ANGLE_FEATURES,
    ANGLE_METRICS,
    FEATURES,
    LEARNED,
    METRICS,
    combined_weights,
    compare,
    features_between,
    learned_weights,
    metric_values,
)
from .paper import MIN_AGREEMENT, PAPER_METRICS, histogram_distance, paper_distances

__all__ = [
    "ANGLE_FEATURES",
    "ANGLE_METRICS",
    "LEARNED",
    "learned_weights",
    "FEATURES",
    "METRICS",
    "METRIC_HISTOGRAMS",
    "MIN_AGREEMENT",
    "PAPER_METRICS",
    "HistogramBank",
    "combined_weights",
    "compare",
    "features_between",
    "histogram_distance",
    "metric_values",
    "paper_distances",
    "distances_to_many",
    "features_to_many",
]
