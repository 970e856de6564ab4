"""The first task's figures on a labelled collection: classification and clustering agreement.

``shapeidx evaluate`` reports them beside the retrieval figures, per metric: ``knn``, the
leave-one-out accuracy of the distance-weighted vote of :mod:`.classify` (each model
classified by all the others); ``nmi`` and ``ari``, the agreement with the classes of the
clustering of :mod:`.cluster` (Ward on the exact distance matrix) cut at as many clusters
as there are classes.
"""

from __future__ import annotations

import numpy as np

from .agreement import ari, nmi
from .classify import DEFAULT_K, leave_one_out
from .cluster import cluster_matrix

FAMILY_SCORES = ("knn", "nmi", "ari")


def family_scores(matrix: np.ndarray, labels, k: int = DEFAULT_K) -> dict:
    """``knn`` (leave-one-out accuracy), ``nmi`` and ``ari`` of one distance matrix."""
    labels = np.asarray(labels, dtype=object)
    classes = len(set(labels.tolist()))
    clusters = cluster_matrix(np.asarray(matrix, dtype=np.float64), clusters=classes)
    return {
        "knn": leave_one_out(matrix, labels, k)["accuracy"],
        "nmi": nmi(labels, clusters),
        "ari": ari(labels, clusters),
    }
