"""Retrieval metrics by hand on a tiny labelled collection."""

from __future__ import annotations

import numpy as np
import pytest

from shapeidx.evaluation.retrieval import rank_lists, retrieval_scores


def collection():
    # three "a" models (0, 1, 2) and two "b" models (3, 4); rows are queries
    d = np.array(
        [
            [0, 1, 3, 2, 4],  # 0 ranks 1, 3, 2, 4: relevant, no, relevant, no
            [1, 0, 2, 3, 4],  # 1 ranks 0, 2, 3, 4: relevant, relevant, no, no
            [3, 2, 0, 1, 4],  # 2 ranks 3, 1, 0, 4: no, relevant, relevant, no
            [2, 3, 1, 0, 4],  # 3 ranks 2, 0, 1, 4: no, no, no, relevant
            [4, 4, 4, 4, 0],  # 4 ranks 0, 1, 2, 3 (ties by index): no, no, no, relevant
        ],
        dtype=float,
    )
    return d, ["a", "a", "a", "b", "b"]


def test_ranking_leaves_the_query_out_and_breaks_ties_by_index():
    d, _ = collection()
    assert rank_lists(d).tolist() == [[1, 3, 2, 4], [0, 2, 3, 4], [3, 1, 0, 4], [2, 0, 1, 4], [0, 1, 2, 3]]


def test_scores_by_hand():
    d, labels = collection()
    s = retrieval_scores(d, labels, per_query=True)
    q = s["per_query"]
    np.testing.assert_allclose(q["nn"], [1, 1, 0, 0, 0])
    # C - 1 = 2 for class a, 1 for class b
    np.testing.assert_allclose(q["ft"], [1 / 2, 2 / 2, 1 / 2, 0, 0])
    np.testing.assert_allclose(q["st"], [2 / 2, 2 / 2, 2 / 2, 0, 0])  # b: top 2 holds no relevant model
    # E over the top min(32, 4) results: P = found / 4, R = found / (C - 1)
    def e(found, wanted):
        p, r = found / 4, found / wanted
        return 2 * p * r / (p + r)
    np.testing.assert_allclose(q["e"], [e(2, 2), e(2, 2), e(2, 2), e(1, 1), e(1, 1)])
    # DCG with G_1 + sum G_i / log2(i), over the ideal 1 + sum_{j=2}^{C-1} 1 / log2(j)
    ideal_a, ideal_b = 1 + 1 / np.log2(2), 1.0
    dcg = [
        (1 + 1 / np.log2(3)) / ideal_a,
        (1 + 1 / np.log2(2)) / ideal_a,
        (1 / np.log2(2) + 1 / np.log2(3)) / ideal_a,
        (1 / np.log2(4)) / ideal_b,
        (1 / np.log2(4)) / ideal_b,
    ]
    np.testing.assert_allclose(q["dcg"], dcg)
    assert s["nn"] == pytest.approx(0.4) and s["queries"] == 5


def test_perfect_and_singleton_classes():
    labels = ["a", "a", "b", "b", "c"]  # c has no relevant model: not a query
    d = np.array([[0 if x == y else 1 for y in labels] for x in labels], float)
    s = retrieval_scores(d, labels)
    assert s["queries"] == 4
    assert all(s[k] == pytest.approx(1.0) for k in ("nn", "ft", "st", "dcg"))


def test_no_query_has_a_relevant_answer():
    s = retrieval_scores(np.zeros((2, 2)), ["a", "b"])
    assert s["queries"] == 0 and np.isnan(s["nn"])
    assert retrieval_scores(np.zeros((0, 0)), [])["queries"] == 0
