"""``shapeidx evaluate``: how well each distance retrieves a labelled collection.

A labelled collection is a folder whose immediate sub-folders are the classes. Its store is
built (or brought up to date) like ``shapeidx build`` does, then every model is ranked against
all the others through the search road of ``shapeidx query`` (its per-pair features:
:func:`shapeidx.search.distances.entry_features`), and :mod:`shapeidx.evaluation.retrieval`
scores the rankings.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass

import numpy as np

from ..distance import ANGLE_FEATURES, FEATURES, LEARNED, METRICS, REGISTRY, SIZE_FEATURES, metric_values, metric as metric_record
from ..errors import ShapeidxError
from ..search.distances import entry_features
from ..signing.parameters import HISTOGRAMS
from .learn import cross_validate
from .retrieval import SCORES, retrieval_scores


@dataclass
class LabelledFeatures:
    """The per-pair features of every labelled model against every other."""

    paths: np.ndarray  # (n,) relative paths
    labels: np.ndarray  # (n,) class of each model: its first folder
    features: np.ndarray  # (len(FEATURES), n, n)
    unlabelled: int  # ok entries outside any class folder, left out
    angle_features: np.ndarray | None = None  # (len(ANGLE_FEATURES), n, n); None: a store without angles
    measures: np.ndarray | None = None  # (n, 7) exact measures (shapeidx.search.same_part.shape_measures)
    size_features: np.ndarray | None = None  # (len(SIZE_FEATURES), n, n); 0 where a size is unknown

    def all_features(self) -> np.ndarray:
        """``features`` and, when known, ``angle_features`` and ``size_features``, in the order of :meth:`named`."""
        return np.concatenate([self.features] + [f for f in (self.angle_features, self.size_features) if f is not None])

    def learned_features(self, metric: str) -> np.ndarray:
        """The (F, n, n) features of a learned metric (:data:`~shapeidx.distance.LEARNED`), in
        the order of its weights."""
        named = self.named()
        return np.stack([named[name] for name in LEARNED[metric][0]])

    def named(self) -> dict:
        """Feature name -> (n, n) matrix."""
        names = (FEATURES + (ANGLE_FEATURES if self.angle_features is not None else ())
                 + (SIZE_FEATURES if self.size_features is not None else ()))
        return dict(zip(names, self.all_features()))


def check_labelled_tree(directory, follow_outside_links: bool = False) -> None:
    """Refuse, before any store is built, a folder that is not a labelled collection.

    A labelled collection has sub-folders (the classes) of which at least one holds two part
    files; a folder of loose files would otherwise cost a whole build and leave a store in
    the working directory before being refused.
    """
    from pathlib import Path

    from ..index.build import check_tree
    from ..index.walk import walk_parts

    root = Path(directory).resolve()
    check_tree(directory, root)
    sizes = Counter(class_of(f.path) for f in walk_parts(root, follow_outside_links).files)
    unlabelled = sizes.pop(None, 0)
    if not any(size > 1 for size in sizes.values()):
        raise ShapeidxError(
            f"{directory}: not a labelled collection: {sum(sizes.values())} part file(s) in {len(sizes)} class"
            f" folder(s), {unlabelled} outside any; evaluate needs sub-folders (the classes) that hold at least"
            " two part files each (nothing was built)"
        )


def in_sample(reader, models: int, classes: int, metric: str) -> dict | None:
    """``{"learned_on": name}`` when the weights of the learned ``metric`` were learned on this collection.

    Judged by the indexed folder's name, or its size (models and classes) equal to the
    training collection's: figures measured on it are in-sample and flatter the metric.
    """
    from pathlib import PurePath

    from ..distance import learned_weights

    trained = learned_weights(metric).get("trained_on", {})
    name = trained.get("collection")
    root = PurePath(str(reader.attrs.get("root", ""))).name
    if name and (root == name or (trained.get("models"), trained.get("classes")) == (models, classes)):
        return {"learned_on": name}
    return None


def class_of(path: str) -> str | None:
    """The class of a store path: its first folder (None for a file at the top)."""
    head, sep, _ = path.partition("/")
    return head if sep else None


def labelled_features(store, query_seed: int | None = None) -> LabelledFeatures:
    """Features between all labelled ok entries (sorted by path), through the search road of ``query``.

    ``store``: an open :class:`~shapeidx.search.Searcher`, or an open store reader (its store
    is searched). ``query_seed``: each query is its file signed again with this seed (the
    store's number of points), not its stored signature, so that no query shares its points
    with a stored entry (a real query never does); ``features[:, q, q]`` is then the distance
    of an exact copy, its points drawn again, to its own entry.
    """
    from ..search import Searcher

    if not isinstance(store, Searcher):
        with Searcher(store.path) as searcher:
            return labelled_features(searcher, query_seed)
    searcher = store
    paths = searcher.metadata_column("path")
    order = np.argsort(paths.astype(str), kind="stable")
    classes = [class_of(str(paths[i])) for i in order]
    chosen = order[[c is not None for c in classes]].astype(np.int64)
    angle_p = searcher.view.angle_probabilities(chosen)
    with_angles = np.isfinite(angle_p).all()
    names = FEATURES + (ANGLE_FEATURES if with_angles else ()) + SIZE_FEATURES
    features = np.zeros((len(names), len(chosen), len(chosen)))
    for k, i in enumerate(chosen.tolist()):
        signature = searcher.signature_at(i) if query_seed is None else drawn_again(searcher, i, query_seed)
        values = entry_features(searcher.view, signature, HISTOGRAMS, chosen, with_angles, sizes=True)
        for f, name in enumerate(names):
            features[f, k] = values[name]
    angles_end = len(FEATURES) + (len(ANGLE_FEATURES) if with_angles else 0)
    return LabelledFeatures(
        paths=paths[chosen],
        labels=np.array([class_of(str(paths[i])) for i in chosen], dtype=object),
        features=features[: len(FEATURES)],
        unlabelled=len(paths) - len(chosen),
        angle_features=features[len(FEATURES) : angles_end] if with_angles else None,
        measures=searcher.entry_measures()[chosen],
        size_features=features[angles_end:],
    )


def drawn_again(searcher, position: int, seed: int):
    """The signature of the file of the entry at ``position``, its points drawn with ``seed`` (the
    store's other parameters); raises ShapeidxError when the file is gone or unusable."""
    import os

    from ..io import LoadLimits
    from ..signing.pipeline import signature_of_solid, solid_of_file

    path = os.path.join(searcher.root, searcher.path_at(position))
    solid = solid_of_file(path, LoadLimits(faceting=searcher.params.faceting))
    return signature_of_solid(solid, searcher.params.points, seed, searcher.params.bin_divisor)


def copy_first(distances: np.ndarray) -> float:
    """Share of the rows whose own column (the diagonal) is strictly the smallest: how often an
    exact copy, drawn again, is its own first answer."""
    d = np.asarray(distances, dtype=np.float64)
    own = np.diag(d)[:, None]
    return float(((d <= own).sum(axis=1) == 1).mean())


def same_part_order(distances: np.ndarray, measures: np.ndarray) -> np.ndarray:
    """(n, n) scores of the same-part order (``query --same-part``, :mod:`shapeidx.search.same_part`)
    from a metric's distances and the models' exact measures: each row is a query, its measures
    its own entry's (a copy drawn again has the same surface)."""
    from ..search.same_part import same_part_scores, shape_gap

    return np.stack([same_part_scores(row, shape_gap(measures[q], measures)) for q, row in enumerate(distances)])


def distance_matrices(data: LabelledFeatures, metrics=METRICS) -> dict:
    """Metric name -> (n, n) distances between the labelled models."""
    return metric_values(data.named(), metrics)


def cross_validate_unified(data: LabelledFeatures, folds: int = 4, repeats: int = 3) -> dict:
    """unified's scores with the weights of the metric it is made on (its record's
    ``learned_from``, combined-angle) never trained on the query's class (its twin discount,
    all-angle, learns nothing)."""
    from ..distance.combined import unified_of

    all_angle = distance_matrices(data, ("all-angle",))["all-angle"]
    return cross_validate(data.learned_features(REGISTRY["unified"].learned_from), data.labels, folds, repeats,
                          then=lambda distance: unified_of(distance, all_angle))


#: How a metric made on a learned one (its record's ``learned_from``) is scored cross-validated:
#: its distance from the learned one's is its own formula's, which the record does not give apart.
MADE_ON_LEARNED = {"unified": cross_validate_unified}


def cross_validated_rows(data: LabelledFeatures, metrics) -> dict:
    """The rows of ``--cross-validate``, in the registry's order: ``"NAME (cross-validated)"``
    -> its scores with weights never trained on the query's class.

    A row for the combined metric (always: what the option learns), for each metric of
    ``metrics`` whose record has learned weights (``learned``), and for each one made on such
    a metric (``learned_from``: :data:`MADE_ON_LEARNED` says how).
    """
    rows = {}
    for name, record in REGISTRY.items():
        if name != "combined" and name not in metrics:
            continue
        if record.learned:
            rows[f"{name} (cross-validated)"] = cross_validate(data.learned_features(name), data.labels)
        elif record.learned_from:
            rows[f"{name} (cross-validated)"] = MADE_ON_LEARNED[name](data)
    return rows


def per_class_scores(scores: dict, labels: np.ndarray) -> dict:
    """Class -> mean of each score over that class's queries."""
    per = scores["per_query"]
    grouped = defaultdict(list)
    for position, query in enumerate(per["index"]):
        grouped[labels[query]].append(position)
    return {
        cls: {s: float(np.mean(per[s][positions])) for s in SCORES} | {"queries": len(positions)}
        for cls, positions in sorted(grouped.items())
    }


def evaluate(reader, metrics=METRICS, per_class: bool = False, cross_validated: bool = False,
             query_seeds=()) -> dict:
    """Retrieval scores of each metric over the labelled entries of a store.

    Parameters
    ----------
    reader : an open :class:`~shapeidx.search.Searcher`
        A store whose entries' first folders are their classes.
    metrics : iterable of str
    per_class : bool
        Add each class's scores.
    cross_validated : bool
        Add ``"combined (cross-validated)"``: the combined metric's weights learned on this
        very collection, each query scored with weights that never saw its class; and such a
        row for each learned metric of ``metrics`` and each made on one (:func:`cross_validated_rows`).
    query_seeds : sequence of int
        Sign each query again with each of these seeds (:func:`labelled_features`) instead of
        ranking the stored signatures against each other: every score is then the mean over
        the seeds, ``spread`` gives each score's lowest and highest, ``per_seed`` the seeds'
        own, and ``copy`` how often the query's own entry (an exact copy drawn again) came
        first (``copy_same_part``: in the same-part order). Empty: the stored signatures (they
        share their points with the entries).

    Returns
    -------
    dict
        ``models``, ``classes``, ``unlabelled``, ``points``, ``query_seeds`` and ``metrics``:
        name -> scores; with ``query_seeds`` also ``copy_same_part``: ``copy`` in the same-part
        order (:func:`same_part_order`).
    """
    runs = [_evaluate_once(reader, labelled_features(reader, seed), metrics, per_class, cross_validated, seed is not None)
            for seed in (tuple(query_seeds) or (None,))]
    result = runs[0]
    result["query_seeds"] = [int(seed) for seed in query_seeds]
    if len(runs) > 1:
        for name, entry in result["metrics"].items():
            numbers = [k for k, v in entry.items() if isinstance(v, float)]
            per_seed = [{k: run["metrics"][name][k] for k in numbers} for run in runs]  # before the mean replaces them
            entry.update({k: float(np.mean([one[k] for one in per_seed])) for k in numbers})
            entry["spread"] = {k: [float(min(one[k] for one in per_seed)), float(max(one[k] for one in per_seed))]
                               for k in numbers}
            entry["per_seed"] = dict(zip(map(str, query_seeds), per_seed))
    return result


def _evaluate_once(reader, data: LabelledFeatures, metrics, per_class: bool, cross_validated: bool, drawn: bool) -> dict:
    """:func:`evaluate` on one set of features (with ``drawn``: queries drawn again, so the
    exact copy's figure ``copy`` is added)."""
    if data.angle_features is None:  # a store built before the normal-angle histograms
        metrics = [m for m in metrics if not metric_record(m).angles]
    sizes = Counter(data.labels)
    if sum(size for size in sizes.values() if size > 1) < 2:
        raise ShapeidxError(
            f"{reader.attrs.get('root', reader.path)}: {len(data.labels)} indexed part(s) in {len(sizes)} class folder(s); evaluate needs"
            " a folder whose sub-folders (the classes) hold at least two parts each"
        )
    matrices = distance_matrices(data, metrics)
    result = {
        "models": int(len(data.labels)),
        "classes": int(len(set(data.labels))),
        "unlabelled": data.unlabelled,
        "points": reader.params.points,
        "metrics": {},
    }
    for name in metrics:
        scores = retrieval_scores(matrices[name], data.labels, per_query=per_class)
        entry = {s: scores[s] for s in SCORES}
        if drawn:
            entry["copy"] = copy_first(matrices[name])
            entry["copy_same_part"] = copy_first(same_part_order(matrices[name], data.measures))
        if per_class:
            entry["per_class"] = per_class_scores(scores, data.labels)
        from ..families.scores import family_scores  # classification and clustering (issue 11)

        entry.update(family_scores(matrices[name], data.labels))
        result["metrics"][name] = entry
    for name, entry in result["metrics"].items():
        weights_of = REGISTRY[name].weights_of if name in REGISTRY else None
        if weights_of:
            learned = in_sample(reader, result["models"], result["classes"], weights_of)
            entry["in_sample"] = learned is not None
            if learned:
                entry.update(learned)
    if cross_validated:
        # the angle metrics are out of `metrics` already for a store without angles
        result["metrics"].update(cross_validated_rows(data, metrics))
    result["queries"] = int(retrieval_scores(matrices[metrics[0]], data.labels)["queries"]) if metrics else 0
    return result
