"""Learning the weights of the combined metric, and checking them honestly.

The combined distance is ``sum_k w_k f_k`` over the per-pair features of
:data:`shapeidx.distance.FEATURES`, with ``w_k >= 0``. The weights maximise the neighbourhood
component analysis objective (Goldberger et al., NIPS 2004): each model picks another with
probability proportional to ``exp(-distance)``, and the mean log-probability of picking a
model of its own class is maximised (with a small L2 penalty on ``log w``). The features are
first divided by their median over the training pairs, so the penalty treats them alike.

Cross-validation holds out whole classes: the models of a fold's classes are ranked (against
every model of the collection) with weights learned without any model of those classes. That
is the situation of a new collection, whose classes the weights have never seen.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from ..distance import FEATURES
from .retrieval import SCORES, retrieval_scores

#: L2 penalty on log-weights.
PENALTY = 1e-3


def _objective(theta: np.ndarray, features: np.ndarray, same: np.ndarray):
    """NCA loss and gradient for log-weights ``theta`` over (F, n, n) features."""
    w = np.exp(theta)
    distance = np.tensordot(w, features, axes=1)
    logits = -distance
    np.fill_diagonal(logits, -np.inf)
    logits -= logits.max(axis=1, keepdims=True)
    p = np.exp(logits)
    p /= p.sum(axis=1, keepdims=True)
    p_same = (p * same).sum(axis=1)
    n = len(p)
    loss = -np.log(p_same + 1e-300).mean() + PENALTY * float(theta @ theta)
    # d loss / d distance_ij = (p_ij * same_ij / p_same_i - p_ij) / n
    g = (p * same / (p_same[:, None] + 1e-300) - p) / n
    grad = np.einsum("ij,kij->k", g, features) * w + 2 * PENALTY * theta
    return loss, grad


def fit_weights(features: np.ndarray, labels, rows=None) -> np.ndarray:
    """Non-negative weights for (F, n, n) feature matrices, learned on the models ``rows``.

    Returns weights for the *unscaled* features: ``distance = weights @ features``.
    """
    labels = np.asarray(labels)
    rows = np.arange(len(labels)) if rows is None else np.asarray(rows)
    train = features[:, rows][:, :, rows]
    upper = np.triu_indices(len(rows), k=1)
    scale = np.array([np.median(f[upper]) for f in train])
    scale = np.where(scale > 0, scale, 1.0)
    same = labels[rows][:, None] == labels[rows][None, :]
    result = minimize(_objective, np.zeros(len(train)), args=(train / scale[:, None, None], same), jac=True, method="L-BFGS-B")
    return np.exp(result.x) / scale


def class_folds(labels, folds: int, seed: int) -> list[np.ndarray]:
    """Classes shuffled by ``seed`` and dealt into ``folds`` groups."""
    classes = np.random.default_rng(seed).permutation(np.unique(labels))
    return [fold for fold in np.array_split(classes, folds) if len(fold)]


def cross_validated_distances(features: np.ndarray, labels, folds: int = 4, seed: int = 0) -> np.ndarray:
    """(n, n) learned distances in which every query's row comes from weights learned without
    its class (one deal of the classes into ``folds`` folds, by ``seed``)."""
    labels = np.asarray(labels)
    distance = np.zeros(features.shape[1:])
    for fold in class_folds(labels, folds, seed):
        held_out = np.isin(labels, fold)
        weights = fit_weights(features, labels, np.flatnonzero(~held_out))
        distance[held_out] = np.tensordot(weights, features[:, held_out], axes=1)
    return distance


def cross_validate(features: np.ndarray, labels, folds: int = 4, repeats: int = 3, seed: int = 0, then=None) -> dict:
    """Retrieval scores of the combined metric with weights never trained on the query's class.

    For each of ``repeats`` random deals of the classes into ``folds`` folds, every query is
    ranked with the weights learned on the other folds; the scores are averaged over the
    repeats (``"std"`` gives their spread). ``then``: a function of the (n, n) cross-validated
    distances giving the distances ranked (a metric built on a learned one: unified).
    """
    then = then or (lambda distance: distance)
    labels = np.asarray(labels)
    runs = [retrieval_scores(then(cross_validated_distances(features, labels, folds, seed + r)), labels)
            for r in range(repeats)]
    result = {s: float(np.mean([run[s] for run in runs])) for s in SCORES}
    result["std"] = {s: float(np.std([run[s] for run in runs])) for s in SCORES}
    result.update(folds=folds, repeats=repeats, queries=runs[0]["queries"])
    return result


def weights_by_name(weights: np.ndarray, names=FEATURES) -> dict:
    """``{feature name: weight}`` in the order of ``names`` (default :data:`FEATURES`)."""
    if len(names) != len(weights):
        raise ValueError(f"{len(weights)} weights for {len(names)} features")
    return {name: float(w) for name, w in zip(names, weights)}
