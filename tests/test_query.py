"""Ranking: the vectorised distances equal compare(), the query command, stats."""

from __future__ import annotations

import json

import numpy as np
import pytest
from clitools import cli, cli_json
from storetools import FAST_POINTS, build, copy_tree, small_kicad

from shapeidx.distance import METRICS, HistogramBank, compare, histogram_distance
from shapeidx.search import Searcher
from shapeidx.search.distances import distances


@pytest.fixture(scope="module")
def kicad_store(data_dir, tmp_path_factory):
    """A store of three small KiCad class folders, built by the real command."""
    tmp = tmp_path_factory.mktemp("query")
    tree = small_kicad(data_dir, tmp)
    store = tmp / "s.shapeidx"
    result = build(tree, store)
    assert result.exit_code == 0, result.output
    return tree, store


class TestHistogramBank:
    def test_equal_to_histogram_distance_bit_for_bit(self):
        rng = np.random.default_rng(5)
        lengths = rng.integers(0, 90, 400)
        lengths[:3] = (0, 1, 200)  # empty, single-bin, wider than any query
        counts = rng.integers(1, 50, int(lengths.sum()))
        bank = HistogramBank.from_counts(counts, lengths)
        offsets = np.concatenate([[0], np.cumsum(lengths)])
        rows = [counts[offsets[i] : offsets[i + 1]] for i in range(len(lengths))]
        for query_length in (0, 1, 40, 89, 150, 300):
            q = rng.random(query_length)
            q /= max(q.sum(), 1)
            expected = [histogram_distance(r / r.sum() if len(r) else np.zeros(0), q) for r in rows]
            assert np.array_equal(bank.distances(q), np.array(expected)), query_length

    def test_empty_against_empty_is_zero_and_empty_against_n_bins_is_one_over_n(self):
        bank = HistogramBank.from_counts(np.array([3, 1]), np.array([0, 2]))
        assert list(bank.distances(np.zeros(0))) == [0.0, 1.0 / 2]
        assert list(bank.distances(np.array([0.25, 0.25, 0.5]))) == [1.0 / 3, (0.5 + 0.0 + 0.5) / 3]


class TestRankingEqualsCompare:
    def test_every_pair_every_metric(self, kicad_store):
        """The store ranking (the search road) and compare() give identical numbers for the same pair."""
        _, store = kicad_store
        with Searcher(store) as searcher:
            signatures = [searcher.signature_at(i) for i in range(len(searcher))]
            assert len(searcher) == 30
            for i, query in enumerate(signatures):
                ranked = {m: distances(searcher.view, query, m) for m in METRICS}
                for j, other in enumerate(signatures):
                    expected = compare(query, other)
                    assert {m: ranked[m][j] for m in METRICS} == expected, (i, j)
                assert ranked["avg4"][i] == 0.0

    def test_unknown_metric(self, kicad_store):
        _, store = kicad_store
        with Searcher(store) as searcher:
            sig = searcher.signature_at(0)
            assert len(distances(searcher.view, sig, "weighted")) == 30
            with pytest.raises(ValueError, match="unknown metric"):
                distances(searcher.view, sig, "euclid")


class TestTies:
    def test_ties_broken_by_path_and_the_query_itself_first(self, data_dir, tmp_path):
        """Three byte copies of a part tie at 0: by path, except that the query's own file comes first."""
        part = sorted((data_dir / "kicad6" / "Diode_SMD").glob("*.wrl"))[2]
        tree = tmp_path / "tree"
        tree.mkdir()
        for name in ("a.wrl", "b.wrl", "c.wrl"):
            (tree / name).write_bytes(part.read_bytes())
        other = sorted((data_dir / "kicad6" / "Resistor_SMD").glob("*.wrl"))[0]
        (tree / "d.wrl").write_bytes(other.read_bytes())
        assert build(tree, tmp_path / "s.shapeidx").exit_code == 0
        ranked = [h["relative_path"] for h in cli_json("query", tree / "b.wrl", "--store", tmp_path / "s.shapeidx")["hits"]]
        assert ranked == ["b.wrl", "a.wrl", "c.wrl", "d.wrl"]
        elsewhere = tmp_path / "copy.wrl"
        elsewhere.write_bytes(part.read_bytes())
        answer = cli_json("query", elsewhere, "--store", tmp_path / "s.shapeidx", "--top", "2")
        assert [h["relative_path"] for h in answer["hits"]] == ["a.wrl", "b.wrl"] and answer["entry"] is None


class TestQueryCommand:
    def test_a_file_in_the_store_is_rank_one(self, kicad_store):
        tree, store = kicad_store
        for part in sorted(tree.rglob("*.wrl"))[::7]:
            answer = cli_json("query", part, "--store", store, "--top", "5")
            assert answer["query"] == str(part) and answer["metric"] == "weighted"
            assert answer["root"] == str(tree.resolve()) and answer["store"] == str(store.resolve())
            hits = answer["hits"]
            assert hits[0]["relative_path"] == part.relative_to(tree).as_posix()
            assert hits[0]["path"] == str(tree.resolve() / hits[0]["relative_path"])
            assert hits[0]["distance"] == 0.0
            assert [h["rank"] for h in hits] == [1, 2, 3, 4, 5]
            assert all(set(h) == {"rank", "path", "relative_path", "distance", "metadata"} for h in hits)
            assert [h["distance"] for h in hits] == sorted(h["distance"] for h in hits)

    def test_a_copy_outside_the_tree_finds_the_original(self, kicad_store, tmp_path):
        tree, store = kicad_store
        original = sorted(tree.rglob("*.wrl"))[3]
        copy = copy_tree(original.parent, tmp_path / "elsewhere", [original.name]) / original.name
        hits = cli_json("query", copy, "--store", store, "--top", "1")["hits"]
        relative = original.relative_to(tree).as_posix()
        assert hits == [{"rank": 1, "path": str(tree.resolve() / relative), "relative_path": relative, "distance": 0.0,
                         "metadata": {}}]

    def test_id_and_metrics(self, kicad_store):
        tree, store = kicad_store
        entry = "Diode_SMD/" + sorted(p.name for p in (tree / "Diode_SMD").iterdir())[4]
        for metric in METRICS:
            hits = cli_json("query", "--id", entry, "--store", store, "--top", "30", "--metric", metric)["hits"]
            assert hits[0]["relative_path"] == entry and len(hits) == 30
            assert [h["distance"] for h in hits] == sorted(h["distance"] for h in hits)
        weighted = cli_json("query", "--id", entry, "--store", store, "--top", "30")
        assert weighted == cli_json("query", "--id", entry, "--store", store, "--top", "30", "--metric", "weighted")

    def test_human_output(self, kicad_store):
        tree, store = kicad_store
        part = sorted(tree.rglob("*.wrl"))[0]
        result = cli("query", part, "--store", store, "--top", "3")
        assert result.exit_code == 0
        lines = result.stdout.splitlines()
        assert len(lines) == 3
        rank, distance, path = lines[0].split()
        assert (rank, float(distance), path) == ("1", 0.0, str(part.resolve()))
        relative = cli("query", part, "--store", store, "--top", "1", "--relative").stdout.split()
        assert relative == ["1", "0", part.relative_to(tree).as_posix()]

    def test_the_store_comes_from_the_environment(self, kicad_store):
        tree, store = kicad_store
        result = cli("query", "--id", "LED_SMD/" + sorted(p.name for p in (tree / "LED_SMD").iterdir())[0],
                     "--top", "1", env={"SHAPEIDX_STORE": str(store)})
        assert result.exit_code == 0 and result.stdout.split()[0] == "1"

    def test_errors_are_one_line(self, kicad_store, data_dir, tmp_path):
        tree, store = kicad_store
        cases = [
            (("query", "--id", "nope.wrl", "--store", store), "no entry 'nope.wrl'"),
            (("query", data_dir / "mesh-wild/trimesh-models/empty.stl", "--store", store), "empty.stl"),
            (("query", "--id", "x", "--store", tmp_path / "none.h5"), "no store at"),
            (("stats", "--store", tmp_path / "none.h5"), "no store at"),
        ]
        for args, message in cases:
            result = cli(*args)
            assert result.exit_code != 0, args
            assert message in result.stderr and "Traceback" not in result.stderr
        usage = cli("query", "--store", store)
        assert usage.exit_code == 2 and "give either FILE or --id PATH" in usage.stderr

    def test_a_failed_entry_cannot_be_the_query(self, data_dir, tmp_path):
        tree = copy_tree(data_dir / "mesh-wild/trimesh-models", tmp_path / "t", ["empty.stl", "box.STL"])
        assert build(tree, tmp_path / "s.h5").exit_code == 0
        result = cli("query", "--id", "empty.stl", "--store", tmp_path / "s.h5")
        assert result.exit_code == 1 and "failed to index" in result.stderr


def test_stats_command(kicad_store):
    tree, store = kicad_store
    facts = cli_json("stats", "--store", store)
    assert (facts["entries"], facts["ok"], facts["failed"]) == (30, 30, 0)
    assert facts["parameters"]["points"] == int(FAST_POINTS)
    assert facts["root"] == str(tree.resolve())
    assert facts["bytes"] == sum(p.stat().st_size for p in store.rglob("*") if p.is_file())
    text = cli("info", "--store", store)
    assert text.exit_code == 0
    assert "30 ok, 0 failed" in text.stdout and f"{FAST_POINTS} points" in text.stdout


def test_json_distances_are_compare_values(kicad_store):
    """What the user sees from query --json is what compare gives for that pair."""
    tree, store = kicad_store
    parts = sorted(tree.rglob("*.wrl"))
    query, others = parts[0], parts[1:6]
    hits = {h["relative_path"]: h["distance"] for h in cli_json("query", query, "--store", store, "--top", "30")["hits"]}
    for other in others:
        direct = json.loads(cli("compare", query, other, "--points", FAST_POINTS, "--json").stdout)
        assert hits[other.relative_to(tree).as_posix()] == direct["weighted"]

