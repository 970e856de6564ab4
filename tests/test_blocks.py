"""Bounds that prune in blocks (shapeidx/search/blocks.py): a warm searcher's answers are the
full ranking's, for every metric, with filters, over a store whose journal supersedes rows.

The reference ranks every entry exactly (:func:`shapeidx.search.distances.distances` over all
of them, no bound, no block) and sorts by (distance, own entry first, path) here; the hits'
distances are checked against :func:`shapeidx.compare` of the stored signatures, which shares
no code with either road.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from storetools import build, load_script, small_kicad

from shapeidx.distance import compare
from shapeidx.distance.metrics import METRICS, REGISTRY
from shapeidx.search import Filters, Searcher
from shapeidx.search.blocks import BlockIndex, tree_order
from shapeidx.search.distances import distances
from shapeidx.store import Batch, StoreWriter, open_store

SIZE = 3000


@pytest.fixture(scope="module")
def store(data_dir, tmp_path_factory):
    """SIZE synthetic entries of real kicad6 signatures, then a journal segment that gives the
    first 200 of them new signatures (so the view spans two files and drops superseded rows)."""
    make_store = load_script("make_store")
    tmp = tmp_path_factory.mktemp("blocks")
    tree = small_kicad(data_dir, tmp)
    source = tmp / "source.shapeidx"
    assert build(tree, source, "--workers", "1").exit_code == 0
    real = make_store.real_signatures(source)
    path = tmp / "made.shapeidx"
    make_store.write_store(path, SIZE, real, chunk=1000)
    rng = np.random.default_rng(7)
    picks = rng.integers(0, len(real["paths"]), 200)
    with open_store(path) as reader:
        paths = sorted(reader.paths)[:200]
    entries = [dataclasses.replace(e, path=p)
               for e, p in zip(make_store.synthetic_entries(real, 0, picks, rng, len(str(SIZE - 1))), paths)]
    with StoreWriter(path, real["params"], make_store.SYNTHETIC_ROOT) as writer:
        writer.commit(Batch(entries=entries))
    return path


def full_ranking(searcher, query, metric, top, keep=None, max_distance=None):
    d = distances(searcher.view, query.signature, metric)
    paths = np.array([searcher.path_at(i) for i in range(len(searcher))], dtype=object)
    order = [i for i in range(len(d)) if (keep is None or keep[i]) and (max_distance is None or d[i] <= max_distance)]
    order.sort(key=lambda i: (d[i], i != query.own, paths[i]))
    return [(paths[i], float(d[i])) for i in order[:top]]


def test_the_tree_puts_neighbours_in_one_block():
    rng = np.random.default_rng(0)
    centres = rng.normal(size=(8, 5)) * 10
    points = (centres[rng.integers(0, 8, 4096)] + rng.normal(size=(4096, 5)) * 0.01).astype(np.float32)
    perm = tree_order(points, 64)
    assert np.array_equal(np.sort(perm), np.arange(4096))
    # a leaf spans far less than the cloud: nearly every leaf holds one cluster's points
    spans = [np.ptp(points[perm[s : s + 64]], axis=0).max() for s in range(0, 4096, 64)]
    assert np.median(spans) < 1.0 < np.ptp(points, axis=0).max()


@pytest.mark.parametrize("metric", METRICS)
def test_a_warm_searcher_answers_as_the_full_ranking(store, metric):
    with Searcher(store) as searcher:
        assert len(searcher.view.sources) == 2 and len(searcher) == SIZE
        searcher._blocks = BlockIndex(searcher.view, block=64)  # many blocks for a small store
        assert len(searcher._blocks) == -(-SIZE // 64)
        rng = np.random.default_rng(1)
        for position in rng.integers(0, SIZE, 4).tolist():
            query = searcher.query_of_entry(searcher.path_at(position))
            keep = rng.random(SIZE) < 0.3
            for top, filters, mask in ((10, Filters(), None), (25, Filters(exclude_self=True), None),
                                       (5, Filters(where=("path~synthetic/00*",)), None)):
                answer = searcher.search(query, top, metric, filters)
                if filters.exclude_self:
                    mask = np.ones(SIZE, dtype=bool)
                    mask[query.own] = False
                if filters.where:
                    mask = np.array([p.startswith("synthetic/00") for p in searcher.metadata_column("path")])
                expected = full_ranking(searcher, query, metric, top, mask)
                assert [(h.relative_path, h.distance) for h in answer.hits] == expected
            # the blocks' own road, with an arbitrary keep-mask and a distance bound
            exact = full_ranking(searcher, query, metric, 10**9)
            bound = exact[40][1]
            chosen, values = searcher._blocks.nearest(query.signature, metric, 10, keep, bound)
            reference = full_ranking(searcher, query, metric, 10, keep, bound)
            got = sorted(zip(values.tolist(), [searcher.path_at(int(p)) for p in chosen]))[: len(reference)]
            assert [(p, d) for d, p in got] == sorted(reference, key=lambda r: (r[1], r[0]))
            for relative, d in reference[:3]:  # the distances themselves, against compare()
                other = searcher.query_of_entry(relative).signature
                assert compare(query.signature, other)[metric] == d


def test_a_searcher_of_a_big_store_builds_its_blocks_on_its_second_query(store, monkeypatch):
    import shapeidx.search.blocks as blocks

    monkeypatch.setattr(blocks, "WARM_MIN", 1000)
    with Searcher(store) as searcher:
        query = searcher.query_of_entry(searcher.path_at(5))
        first = searcher.search(query, 10, "weighted")
        assert searcher._blocks is None  # a one-off query never pays for them
        second = searcher.search(query, 10, "weighted")
        assert searcher._blocks is not None
        assert [(h.relative_path, h.distance) for h in first.hits] == [(h.relative_path, h.distance) for h in second.hits]


@pytest.mark.parametrize("metric", METRICS)
def test_every_bound_lies_below_the_exact_distances(store, metric):
    """Each block's bound under the nearest of its entries, each entry's own bound (the float16
    probabilities kept at the finer level, less their slack) under its exact distance."""
    with Searcher(store) as searcher:
        index = BlockIndex(searcher.view, block=64)
        assert any(len(levels) == 2 for levels in index.levels.values())  # finer than the store's level
        for position in (3, 1500, SIZE - 1):
            query = searcher.query_of_entry(searcher.path_at(position)).signature
            exact = distances(searcher.view, query, metric)[index.perm]  # in block order
            assert (index.bounds(query, metric) <= np.minimum.reduceat(exact, index.starts)).all()
            own = index._entry_bounds(query, metric, np.arange(SIZE), 1)
            assert (own <= exact).all()
            if REGISTRY[metric].histograms and not REGISTRY[metric].angles:  # and they bound: not near 0
                assert np.median(own / np.maximum(exact, 1e-300)) > 0.3


def test_the_float16_slack_covers_the_rounding():
    from shapeidx.search.blocks import float16_slack

    rng = np.random.default_rng(3)
    for columns in (1, 7, 48, 200):
        for alpha in (0.01, 1.0, 50.0):  # spiky (many subnormal float16 values) to flat
            p = rng.dirichlet(np.full(columns, alpha), 2000)
            p[::7] = np.eye(columns)[rng.integers(0, columns, len(p[::7]))]
            error = np.abs(p.astype(np.float16).astype(np.float64) - p).sum(axis=1)
            assert error.max() <= float16_slack(columns)
            if columns > 1 and alpha >= 1:  # nor absurdly large
                assert error.max() > float16_slack(columns) / 10
