"""Where-used's question drawn again (issue 33): ``query_of_part(..., seed=)`` on a sub-parts store.

A question signed with the store's own seed gets its points where the stored sub-part had
them (for a file of the tree: its stored signature, bit for bit); drawn with another seed it is
another signature, and the file must still come first. Both searcher kinds (an ordinary and a
sharded ``--parts`` store) on real KiCad STEP files. scripts/parts_recall.py's
``--query-seed`` asks every question so; its mean and spread over the seeds are checked here too.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from clitools import cli
from shapeidx.search.sharded import ShardedSearcher, open_searcher

#: Four small one-solid KiCad STEP files of different shapes (each its own sub-entry FILE#1)
FILES = ("Crystal/Crystal_HC52-6mm_Horizontal.step",
         "Resistor_THT/R_Axial_DIN0207_L6.3mm_D2.5mm_P5.08mm_Vertical.step",
         "Capacitor_THT/C_Axial_L5.1mm_D3.1mm_P10.00mm_Horizontal.step",
         "Capacitor_THT/C_Rect_L9.0mm_W3.3mm_P7.50mm_MKT.step")
#: Fewer points than the store's default, as the store tests sign; enough to rank four parts
POINTS = "512"


def same_signature(a, b) -> bool:
    return ((a.points, a.seed) == (b.points, b.seed) and a.histograms.keys() == b.histograms.keys()
            and all(np.array_equal(a.histograms[k].counts, b.histograms[k].counts)
                    and a.histograms[k].mean == b.histograms[k].mean for k in a.histograms))


@pytest.fixture(scope="module")
def stores(data_dir, tmp_path_factory):
    """The four files in a tree, built with --parts once as one store and once in 2 shards."""
    top = tmp_path_factory.mktemp("seeds")
    tree = top / "tree"
    for name in FILES:
        (tree / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(data_dir / "kicad6-step" / name, tree / name)
    made = {}
    for kind, extra in (("one", ()), ("sharded", ("--shards", "2"))):
        store = top / f"{kind}.shapeidx"
        result = cli("build", tree, "--store", store, "--parts", "--points", POINTS, "--workers", "1", "-q", *extra)
        assert result.exit_code == 0, result.output + result.stderr
        made[kind] = store
    return tree, made


@pytest.mark.parametrize("kind", ["one", "sharded"])
def test_a_question_drawn_again_is_another_signature_and_still_finds_its_file(stores, kind):
    tree, made = stores
    with open_searcher(made[kind], parts=True) as searcher:
        assert isinstance(searcher, ShardedSearcher) == (kind == "sharded")
        store_seed = searcher.params.seed
        other = store_seed + 7
        for name in FILES:
            stored = searcher.signature_of(f"{name}#1")
            # the store's seed, by default or given: the stored signature exactly, at distance 0
            for seed in (None, store_seed):
                question = searcher.query_of_part(tree / name, seed=seed)
                assert same_signature(question.signature, stored), (name, seed)
                first = searcher.where_used(question, top=2).uses[0]
                assert (first.relative_path, first.part, first.distance) == (name, f"{name}#1", 0)
            # drawn again: its points elsewhere, another signature; its own file still first
            drawn = searcher.query_of_part(tree / name, seed=other)
            assert drawn.signature.seed == other and drawn.signature.points == stored.points
            assert not same_signature(drawn.signature, stored)
            assert not np.array_equal(drawn.signature.histograms["all"].counts, stored.histograms["all"].counts)
            uses = searcher.where_used(drawn, top=4, scale="invariant").uses
            assert uses[0].relative_path == name and uses[0].distance > 0, (name, [(u.relative_path, u.distance) for u in uses])
            assert uses[0].distance < uses[1].distance


def test_parts_recall_reports_mean_and_spread_over_the_query_seeds():
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    import parts_recall

    tiers = {"same": 0.003, "near": 0.01}

    def run(r, right, of):
        return {"r_precision": r, "recall_top10": 1.0, "count_right": f"{right}/{of}",
                "count_right_within_same": f"{right}/{of}",
                "max_distance": {t: {"threshold": v, "precision": r, "recall": 1.0} for t, v in tiers.items()}}

    spread = parts_recall.spread_of([run(1.0, 89, 89), run(0.9, 80, 89), run(0.95, 85, 89)])
    assert spread["r_precision"] == {"mean": pytest.approx(0.95), "low": 0.9, "high": 1.0}
    assert spread["count_right"]["per_seed"] == ["89/89", "80/89", "85/89"]
    assert spread["count_right"]["low"] == pytest.approx(80 / 89)
    assert spread["same_precision"]["mean"] == pytest.approx(0.95) and spread["thresholds"] == tiers
    assert "R-precision 0.950 (0.900-1.000)" in parts_recall.describe_spread(spread)
