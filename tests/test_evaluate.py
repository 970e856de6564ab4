"""shapeidx evaluate and the learned combined metric."""

from __future__ import annotations

import json

import numpy as np
import pytest

import shapeidx.evaluation.learn as learn
from clitools import cli
from shapeidx.distance import FEATURES, METRICS, combined_weights, compare
from shapeidx.evaluation.evaluate import evaluate
from shapeidx.evaluation.retrieval import retrieval_scores
from shapeidx.store import open_store

CLASSES = ["Crystal", "Fuse", "Relay_THT", "LED_THT"]


@pytest.fixture(scope="module")
def collection(tmp_path_factory, data_dir):
    """Four real kicad6 classes (linked, not copied) plus a stray file at the top."""
    root = tmp_path_factory.mktemp("labelled")
    for name in CLASSES:
        (root / name).symlink_to(data_dir / "kicad6" / name, target_is_directory=True)
    (root / "stray.stl").symlink_to(data_dir / "mesh-wild/trimesh-models/unit_cube.STL")
    store = tmp_path_factory.mktemp("store") / "labelled.h5"
    # the links lead out of the tree: followed only when asked
    result = cli("build", str(root), "--store", str(store), "--points", "256", "-q", "--follow-outside-links")
    assert result.exit_code == 0, result.stderr
    return root, store


def test_scores_equal_an_independent_computation(collection):
    _, store = collection
    with open_store(store) as reader:
        got = evaluate(reader)
        ok = [i for i, p in enumerate(reader.paths) if "/" in p]
        labels = [reader.paths[i].split("/")[0] for i in ok]
        signatures = [reader.signature(i) for i in ok]
    assert got["models"] == 40 and got["classes"] == 4 and got["unlabelled"] == 1
    for metric in METRICS:
        d = np.array([[compare(a, b)[metric] for b in signatures] for a in signatures])
        expected = retrieval_scores(d, labels)
        assert {s: got["metrics"][metric][s] for s in ("nn", "ft", "st", "e", "dcg")} == pytest.approx(
            {s: expected[s] for s in ("nn", "ft", "st", "e", "dcg")}
        ), metric


def test_cli_json_per_class_and_cross_validation(collection):
    root, store = collection
    result = cli("evaluate", str(root), "--store", str(store), "--json", "--per-class", "--cross-validate", "-q", "--follow-outside-links")
    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert set(data["metrics"]) == set(METRICS) | {"combined (cross-validated)", "combined-angle (cross-validated)",
                                                "combined-size (cross-validated)", "unified (cross-validated)"}
    per_class = data["metrics"]["weighted"]["per_class"]
    assert set(per_class) == set(CLASSES) and all(c["queries"] == 10 for c in per_class.values())
    # the mean over classes of equal size is the overall mean
    assert np.mean([c["ft"] for c in per_class.values()]) == pytest.approx(data["metrics"]["weighted"]["ft"])


def test_cli_table(collection):
    root, store = collection
    result = cli("evaluate", str(root), "--store", str(store), "--metric", "weighted", "-q", "--follow-outside-links")
    assert result.exit_code == 0 and "Weighted" in result.stdout and "40 models in 4 classes" in result.stdout


def test_learning_finds_the_informative_feature():
    rng = np.random.default_rng(0)
    labels = np.repeat(np.arange(8), 6)
    position = labels + rng.normal(scale=0.2, size=len(labels))  # a feature that separates classes
    informative = np.abs(position[:, None] - position[None, :])
    noise = [np.abs(rng.normal(size=(len(labels), 1)) - rng.normal(size=(1, len(labels)))) for _ in range(3)]
    features = np.stack([informative] + noise)
    weights = learn.fit_weights(features, labels)
    scaled = weights * np.array([np.median(f) for f in features])
    assert scaled[0] > 5 * scaled[1:].max()
    cv = learn.cross_validate(features, labels, folds=4, repeats=2)
    assert cv["nn"] > 0.9


def test_cross_validation_never_trains_on_the_held_out_class(monkeypatch):
    labels = np.repeat(np.arange(6), 3)
    features = np.random.default_rng(1).random((2, 18, 18))
    seen = []
    real = learn.fit_weights

    def spy(features, labels_, rows=None):
        seen.append(set(labels_[rows]))
        return real(features, labels_, rows)

    monkeypatch.setattr(learn, "fit_weights", spy)
    learn.cross_validate(features, labels, folds=3, repeats=1)
    assert len(seen) == 3
    assert all(len(s) == 4 for s in seen)  # each fold trains on the other two folds' classes
    assert set().union(*[set(range(6)) - s for s in seen]) == set(range(6))


def test_shipped_weights_match_the_features():
    data = combined_weights()
    assert set(data["weights"]) == set(FEATURES)
    assert all(w >= 0 for w in data["weights"].values())
    assert data["cross_validation"]["queries"] == data["trained_on"]["models"]


def test_a_folder_without_classes_is_refused_in_one_line(tmp_path, data_dir):
    (tmp_path / "flat").mkdir()
    (tmp_path / "flat" / "cube.stl").symlink_to(data_dir / "mesh-wild/trimesh-models/unit_cube.STL")
    for folder in (tmp_path / "flat", tmp_path / "empty"):
        folder.mkdir(exist_ok=True)
        result = cli("evaluate", str(folder), "--store", str(tmp_path / f"{folder.name}.h5"), "-q")
        assert result.exit_code == 1, result.stderr
        assert "sub-folders" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_queries_drawn_again_change_the_figures_only_when_their_seed_differs(collection):
    """--query-seed signs every query again: with the store's own seed the figures are the stored
    signatures' (the same points), with other seeds they move (other points) and each query's own
    entry, an exact copy drawn again, is no longer at distance 0; the mean lies within the spread."""
    from shapeidx.signing.pipeline import signature_of_file
    from shapeidx.distance import compare as compare_pair

    root, store = collection
    with open_store(store) as reader:
        stored = evaluate(reader, metrics=("weighted", "all-angle"))
        seed = reader.params.seed
        same = evaluate(reader, metrics=("weighted", "all-angle"), query_seeds=(seed,))
        other = evaluate(reader, metrics=("weighted", "all-angle"), query_seeds=(7, 8, 9))
        first = sorted(p for p in reader.paths if "/" in p)[0]
        own = reader.signature(list(reader.paths).index(first))
    scores = ("nn", "ft", "st", "e", "dcg")
    for metric in ("weighted", "all-angle"):
        assert {s: same["metrics"][metric][s] for s in scores} == {s: stored["metrics"][metric][s] for s in scores}
        assert "copy" not in stored["metrics"][metric] and same["metrics"][metric]["copy"] <= 1.0
        figures = other["metrics"][metric]
        # the exact measures do not move with the points: in the same-part order the copy is first as often at least
        assert figures["copy_same_part"] >= figures["copy"]
        for s in scores + ("copy", "copy_same_part"):
            low, high = figures["spread"][s]
            assert low <= figures[s] <= high
            assert figures[s] == pytest.approx(np.mean([figures["per_seed"][str(k)][s] for k in (7, 8, 9)]))
    assert other["query_seeds"] == [7, 8, 9] and stored["query_seeds"] == []
    moved = [(metric, s) for metric in ("weighted", "all-angle") for s in scores
             if other["metrics"][metric][s] != stored["metrics"][metric][s]]
    assert moved, "queries drawn with other seeds gave exactly the stored figures"
    # the first query drawn again with seed 7 is its file signed with seed 7, not the stored signature
    again = signature_of_file(root / first, points=256, seed=7)
    assert compare_pair(again, own)["weighted"] > 0
