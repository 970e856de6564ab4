"""Distances between signatures.

    metrics.py   the registry: one record per metric (name, label, what it reads, its formula,
                 whether it can be bounded, its first-order terms, its learned weights, the
                 tasks it is the default of, its duplicate thresholds)
    paper.py     the paper's D and its four distances: ALL, AvgOf3, AvgOf4, Weighted (3.2.5)
    combined.py  the learned combined distances (combined, combined-angle, combined-size), all-angle, and every
                 metric from per-pair features (metric_values)
    bank.py      one query against many signatures at once (the arithmetic a store ranking runs)
    scale.py     --scale invariant | sensitive: a size band that keeps parts of other sizes apart

Names load on first use: the command line reads the registry without importing numpy.
"""

from .._lazy import attach

_NAMES = {
    **dict.fromkeys(["Metric", "REGISTRY", "METRICS", "PAPER_METRICS", "ANGLE_METRICS", "SIZE_METRICS",
                     "BOUNDED_METRICS", "metric",
                     "label", "duplicate_metrics", "default_metric", "learned_weights", "TASKS"], ".metrics"),
    **dict.fromkeys(["MIN_AGREEMENT", "histogram_distance"], ".paper"),
    **dict.fromkeys(["ANGLE_FEATURES", "FEATURES", "SIZE_FEATURES", "LEARNED", "combined_weights", "compare", "features_between",
                     "metric_values"], ".combined"),
    **dict.fromkeys(["METRIC_HISTOGRAMS", "HistogramBank", "distances_to_many", "features_to_many"], ".bank"),
}
__all__ = sorted(_NAMES)
__getattr__, __dir__ = attach(__name__, _NAMES)
