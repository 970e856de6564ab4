"""A store sharded by path key (``build --shards N``, ``query`` of it, with and without a Dask
cluster) answers exactly as one store holding every entry: the same hits, in the same order,
with the same distances and metadata, for every metric and for ``--where`` filters.

The reference is an ordinary store built the ordinary way from the same tree (it shares no
code with the sharding: no manifest, no merge of answers). The cluster is real processes
(``dask scheduler`` and ``dask worker``, tests/test_dask_build.py's LocalCluster).
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess

import numpy as np
import pytest
from clitools import cli, cli_json, shapeidx_command
from storetools import FAST_POINTS, build, copy_tree, small_kicad

from shapeidx.distance.metrics import METRICS
from shapeidx.errors import StoreError
from shapeidx.store import open_store
from shapeidx.store.rank import path_keys
from shapeidx.store.shards import shard_count, shard_paths

distributed = pytest.importorskip("distributed", reason="the Dask half needs pip install 'shapeidx[dask]'")

SHARDS = 3
WHERE = ["material=steel"]


@pytest.fixture(scope="module")
def trees(data_dir, tmp_path_factory):
    """A tree of KiCad parts with a metadata table, its ordinary store and its sharded store (built here)."""
    tmp = tmp_path_factory.mktemp("shards")
    tree = small_kicad(data_dir, tmp)
    parts = sorted(p.relative_to(tree).as_posix() for p in tree.rglob("*.wrl"))
    table = tmp / "parts.csv"
    with open(table, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["path", "material"])
        for k, part in enumerate(parts):
            writer.writerow([part, "steel" if k % 3 else "brass"])
    one = tmp / "one.shapeidx"
    result = build(tree, one, "--metadata", table, "--workers", "1")
    assert result.exit_code == 0, result.output
    sharded = tmp / "sharded.shapeidx"
    result = build(tree, sharded, "--metadata", table, "--workers", "1", "--shards", SHARDS)
    assert result.exit_code == 0, result.output + result.stderr
    return tree, table, parts, one, sharded


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    from test_dask_build import LocalCluster

    cluster = LocalCluster(tmp_path_factory.mktemp("dask"))
    try:
        yield cluster
    finally:
        cluster.stop()


def hits(answer: dict) -> list:
    return [(h["rank"], h["relative_path"], h["distance"], h["metadata"]) for h in answer["hits"]]


def test_each_shard_holds_exactly_the_paths_of_its_key(trees):
    _, _, parts, one, sharded = trees
    assert shard_count(sharded) == SHARDS
    seen = []
    for k, shard in enumerate(shard_paths(sharded)):
        with open_store(shard) as reader:
            paths = list(reader.paths)
        # the key of shapeidx.store.rank.path_keys, reduced here by hand
        assert all(int(path_keys([p])[0, 0]) % SHARDS == k for p in paths)
        seen += paths
    assert sorted(seen) == parts
    assert len(set(seen)) == len(seen)
    # one store's reader refuses the sharded store whole, naming the commands that take it
    with pytest.raises(StoreError, match="is a sharded store: build, query"):
        open_store(sharded)


@pytest.mark.parametrize("metric", METRICS)
def test_a_sharded_store_answers_as_one_store_for_every_metric(trees, metric):
    _, _, parts, one, sharded = trees
    for entry in (parts[2], parts[-5]):
        for where in ([], WHERE):
            args = ["--id", entry, "--top", 7, "--metric", metric, *[a for c in where for a in ("--where", c)]]
            expected = cli_json("query", "--store", one, *args)
            got = cli_json("query", "--store", sharded, *args)
            assert hits(got) == hits(expected)
            assert (got["entries"], got["considered"], got["entry"]) == (expected["entries"], expected["considered"],
                                                                        expected["entry"])


def test_ties_a_query_file_and_its_own_entry_merge_as_in_one_store(trees):
    tree, _, parts, one, sharded = trees
    part = tree / parts[5]
    for extra in ([], ["--exclude-self"], ["--top", len(parts) + 3]):
        expected = cli_json("query", part, "--store", one, *extra)
        got = cli_json("query", part, "--store", sharded, *extra)
        assert hits(got) == hits(expected)
        assert got["entry"] == expected["entry"] == parts[5]
    # no hit at all: the same exit status and the nearest distance in the reason
    nothing = cli("query", "--id", parts[5], "--exclude-self", "--max-distance", "1e-9", "--store", sharded)
    reference = cli("query", "--id", parts[5], "--exclude-self", "--max-distance", "1e-9", "--store", one)
    assert nothing.exit_code == reference.exit_code == 6
    assert nothing.stderr.split("no hit", 1)[1] == reference.stderr.split("no hit", 1)[1]


def test_why_no_hit_is_said_as_one_store_says_it(trees, data_dir, tmp_path):
    """Each shard says why it has no hit in a word (Answer.why) and the merge decides on the word,
    not on the shards' texts: the same words as one store's, empty shards or not; a store whose
    every file failed says so (one text for both, with the store's path)."""
    from shapeidx.search import Filters, open_searcher, parse_where

    def said(store, entry, filters=None, **among):
        with open_searcher(store) as searcher:
            answer = searcher.search(searcher.query_of_entry(entry), 3, filters=filters, **among)
            return answer.why, answer.reason.replace(str(store), "STORE")

    _, _, parts, one, sharded = trees
    asked = [{"filters": Filters(where=tuple(parse_where(["material=gold"])))},
             {"filters": Filters(exclude_self=True, max_distance=1e-12)},
             {"among": {"no/such.wrl"}, "among_reason": "no labelled voter is left"}]
    for kind, question in zip(("where", "max_distance", "among"), asked):
        expected = said(one, parts[2], **question)
        assert expected[0] == kind and said(sharded, parts[2], **question) == expected
    # one good file among broken ones, in more shards than files: most shards are empty
    tree = tmp_path / "few"
    tree.mkdir()
    good = sorted((data_dir / "kicad6" / "Diode_SMD").glob("*.wrl"))[0]
    shutil.copy(good, tree / good.name)
    (tree / "broken.wrl").write_text("not a part")
    few_one, few_sharded = tmp_path / "few-one.shapeidx", tmp_path / "few-sharded.shapeidx"
    for store, extra in ((few_one, ()), (few_sharded, ("--shards", 4))):
        assert build(tree, store, "--workers", "1", *extra).exit_code == 0
    alone = {"filters": Filters(exclude_self=True)}
    assert said(few_sharded, good.name, **alone) == said(few_one, good.name, **alone) == (
        "exclude_self", "no entry but the query's own is left (--exclude-self)")
    (tree / good.name).unlink()
    (tree / "also-broken.wrl").write_text("not a part either")
    for store, extra in ((few_one, ()), (few_sharded, ("--shards", 4))):
        assert build(tree, store, "--workers", "1", *extra).exit_code == 0
    part = data_dir / "kicad6" / "Diode_SMD" / good.name
    answers = []
    for store in (few_one, few_sharded):
        with open_searcher(store) as searcher:
            answer = searcher.search(searcher.query_of_part(part), 3)
            answers.append((answer.why, answer.reason.replace(str(store), "STORE")))
    assert answers[0] == answers[1] == (
        "empty", "none of the store's 2 entries could be indexed ('shapeidx stats --failed --store STORE' lists why)")


def test_on_a_dask_cluster_every_shard_answers_from_a_worker(trees, cluster, tmp_path):
    tree, table, parts, one, _ = trees
    # the sharded build on the cluster's workers
    sharded = tmp_path / "on-cluster.shapeidx"
    run = subprocess.run(shapeidx_command("build", tree, "--store", sharded, "--points", FAST_POINTS, "--metadata",
                                          table, "--shards", SHARDS, "--scheduler", cluster.address, "--json"),
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["indexed"] == len(parts) and summary["store"]["ok"] == len(parts)
    built_by = {json.loads((shard / "build.json").read_text())["pid"] for shard in shard_paths(sharded)}
    assert len(built_by) == SHARDS  # each shard by its own process on a worker, not by the client
    for metric in ("weighted", "combined", "combined-angle", "all-angle"):
        for where in ([], WHERE):
            args = ["--id", parts[9], "--top", 6, "--metric", metric, *[a for c in where for a in ("--where", c)],
                    "--json"]
            run = subprocess.run(shapeidx_command("query", "--store", sharded, "--scheduler", cluster.address, *args),
                                 capture_output=True, text=True, timeout=300)
            assert run.returncode == 0, run.stderr
            assert hits(json.loads(run.stdout)) == hits(cli_json("query", "--store", one, *args[:-1]))


def test_an_incremental_build_changes_only_the_shard_of_each_changed_path(trees, tmp_path):
    tree, table, parts, _, sharded = trees
    tree2 = tmp_path / "parts"
    shutil.copytree(tree, tree2)
    store = tmp_path / "s.shapeidx"
    shutil.copytree(sharded, store)
    # a copied store has another root: rebuild from the copy as a new store instead
    shutil.rmtree(store)
    planned = json.loads(build(tree2, store, "--shards", SHARDS, "--dry-run", "--json").stdout)
    assert (planned["planned"], planned["unchanged"]) == (len(parts), 0) and not store.exists()
    assert build(tree2, store, "--workers", "1", "--shards", SHARDS).exit_code == 0
    gone = parts[4]
    (tree2 / gone).unlink()
    before = [len(open_store(s)) for s in shard_paths(store)]
    planned = json.loads(build(tree2, store, "--dry-run", "--json").stdout)  # says it, changes nothing
    assert (planned["planned"], planned["unchanged"], planned["removed"]) == (0, len(parts) - 1, 1)
    assert [len(open_store(s)) for s in shard_paths(store)] == before
    result = build(tree2, store, "--workers", "1")  # the manifest says it is sharded: no --shards needed
    assert result.exit_code == 0, result.output
    after = [len(open_store(s)) for s in shard_paths(store)]
    k = int(path_keys([gone])[0, 0]) % SHARDS
    assert after[k] == before[k] - 1 and np.delete(after, k).tolist() == np.delete(before, k).tolist()
    answer = cli_json("query", "--id", parts[0], "--store", store, "--top", len(parts))
    assert gone not in [h["relative_path"] for h in answer["hits"]] and len(answer["hits"]) == len(parts) - 1
    assert "has 3 shards" in build(tree2, store, "--shards", 2).output


def test_a_sheet_of_a_sharded_store_draws_the_answer_of_one_store(trees, cluster, tmp_path):
    """``query --sheet`` of a sharded store, here and on the cluster: the cards are the one
    store's hits in its order, with their distances and pictures; the words are calibrated on a shard."""
    from test_pictures_sheet import Page

    tree, table, parts, one, sharded = trees
    args = ["--id", parts[9], "--top", 5, "--metric", "weighted"]
    expected = cli_json("query", "--store", one, *args)["hits"]
    for scheduler in ([], ["--scheduler", cluster.address]):
        out = tmp_path / f"sheet-{len(scheduler)}.html"
        run = subprocess.run(shapeidx_command("query", "--store", sharded, *args, *scheduler, "--sheet", out),
                             capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr
        text = out.read_text()
        page = Page(text)
        cards = page.all("article")
        assert [c["data-path"] for c in cards] == [h["relative_path"] for h in expected]
        assert all(f"distance {h['distance']:.4g}" in text for h in expected[1:])
        assert len(page.all("img")) == len(expected) + 1  # the query and every hit, rendered here
        assert "identical signature" in text and f"shard 0 of the {SHARDS}" in text


def test_serve_answers_a_sharded_store_as_one_store(trees, cluster):
    """The web API over a sharded store (here, and with every shard on the cluster's workers)
    answers as over one store: the same hits, distances, metadata and fractions, the same entry
    facts, listing and comparisons; only the words' calibration (on a shard) may differ."""
    pytest.importorskip("starlette")
    pytest.importorskip("httpx")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from starlette.testclient import TestClient

    from shapeidx.web.app import ShardedStoreService, StoreService, create_app, open_service

    tree, table, parts, one, sharded = trees

    def answers(client):
        out = []
        for metric in ("weighted", "all-angle"):
            for where in ([], WHERE):
                got = client.get("/api/query", params={"id": parts[9], "top": 6, "metric": metric,
                                                       "where": where}).json()
                out.append([(h["rank"], h["id"], h["distance"], h["metadata"], h["fractions"]) for h in got["hits"]])
        with open(tree / parts[4], "rb") as f:
            upload = client.post("/api/query", files={"file": (parts[4], f.read())}, data={"top": "4"}).json()
        out.append([(h["id"], h["distance"]) for h in upload["hits"]])
        info = client.get("/api/store").json()
        out.append({k: info[k] for k in ("entries", "ok", "failed", "metadata_keys", "points")})
        listing = client.get("/api/entries", params={"limit": 1000}).json()
        out.append([(e["id"], e["status"], e["fractions"]) for e in listing["entries"]])
        entry = client.get("/api/entry", params={"id": parts[2]}).json()
        out.append({k: entry[k] for k in ("name", "path", "fractions", "metadata")})
        out.append(client.get("/api/compare", params={"a": parts[1], "b": parts[7]}).json()["distances"])
        out.append(client.get("/api/entry", params={"id": "no/such.wrl"}).status_code)
        assert client.get("/api/thumbnail", params={"id": parts[3]}).content[:4] == b"\x89PNG"
        return out

    reference = StoreService(one)
    try:
        expected = answers(TestClient(create_app(reference), base_url="http://127.0.0.1:8765"))
    finally:
        reference.close()
    assert expected[-1] == 404
    for scheduler in (None, cluster.address):
        service = open_service(sharded, scheduler)
        assert isinstance(service, ShardedStoreService)
        try:
            client = TestClient(create_app(service), base_url="http://127.0.0.1:8765")
            assert answers(client) == expected
            assert client.get("/api/store").json()["shards"] == SHARDS
            assert f"shard 0 of the {SHARDS}" in client.get("/api/query", params={"id": parts[0]}).json()["calibration"]
        finally:
            service.close()
    with pytest.raises(Exception, match="not a sharded store"):
        open_service(one, cluster.address)


def test_stats_of_a_sharded_store_are_its_shards_summed(trees):
    _, _, parts, one, sharded = trees
    whole, single = cli_json("stats", "--store", sharded), cli_json("stats", "--store", one)
    # the reference: the ordinary store of the same tree, and each shard opened on its own
    assert (whole["entries"], whole["ok"], whole["failed"]) == (single["entries"], single["ok"], single["failed"])
    assert [s["entries"] for s in whole["shards"]] == [len(open_store(s)) for s in shard_paths(sharded)]
    assert whole["parameters"] == single["parameters"] and not whole["parameters_differ"]
    assert whole["build"]["state"] == "finished" and whole["build"]["indexed"] == len(parts)
    text = cli("stats", "--store", sharded).output
    assert f"entries     {len(parts):,}: {len(parts):,} ok, 0 failed" in text and f"shards      {SHARDS} " in text


def test_check_takes_a_sharded_store_whole_and_names_the_damaged_shard(trees, tmp_path):
    tree, _, parts, _, sharded = trees
    report = cli_json("check", "--store", sharded, "--files")
    assert report["ok"] and report["entries"] == len(parts) and report["files_hashed"] == len(parts)
    assert [s["entries"] for s in report["shards"]] == [len(open_store(s)) for s in shard_paths(sharded)]
    store = tmp_path / "damaged.shapeidx"
    shutil.copytree(sharded, store)
    main = shard_paths(store)[1] / "main.h5"
    data = bytearray(main.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 4000] = bytes(b ^ 0x5A for b in data[middle : middle + 4000])
    main.write_bytes(data)
    result = cli("check", "--store", store)
    assert result.exit_code == 5, result.output
    assert "problem: shards/1/main.h5: " in result.stderr and "Traceback" not in result.output + result.stderr
    assert f"'shapeidx build DIR --store {store} --repair'" in result.stdout
    # a query meets the damage in one line naming the sharded store's own commands, not the shard's
    asked = cli("query", "--id", parts[0], "--store", store)
    assert asked.exit_code == 5 and "Traceback" not in asked.output + asked.stderr, asked.output + asked.stderr
    assert f"'shapeidx check --store {store}' lists every problem" in asked.stderr
    assert f"--store {store} --repair'" in asked.stderr
    assert f"the store {store} (its shard 1) is damaged" in asked.stderr  # the store given, then where
    # the command it names repairs it (the copy's root is the tree the store was built from)
    assert build(tree, store, "--workers", "1", "--repair").exit_code == 0
    healed = cli_json("check", "--store", store)
    assert healed["ok"] and healed["entries"] == len(parts)


def test_duplicates_and_clusters_of_a_sharded_store_are_those_of_one_store(trees, tmp_path):
    tree, table, parts, _, _ = trees
    copy = tmp_path / "parts"
    shutil.copytree(tree, copy)
    for part in parts[:3]:  # identical twins under other names (likely in other shards), so groups exist
        shutil.copy(copy / part, copy / part.replace(".wrl", "_copy.wrl"))
    one, sharded = tmp_path / "one.shapeidx", tmp_path / "sharded.shapeidx"
    assert build(copy, one, "--workers", "1").exit_code == 0
    assert build(copy, sharded, "--workers", "1", "--shards", SHARDS).exit_code == 0
    for command in (("duplicates", "--similar", "--near"), ("cluster", "--clusters", "5")):
        for where in ((), ("--where", "path~*_copy.wrl")):
            whole = cli(*command, "--store", sharded, *where, "--json")
            single = cli(*command, "--store", one, *where, "--json")
            assert whole.exit_code == 0, whole.output + whole.stderr
            assert json.loads(whole.stdout) == json.loads(single.stdout)
    groups = cli_json("duplicates", "--store", sharded)
    assert len(groups) >= 3 and all(any(m.endswith("_copy.wrl") for m in g["members"]) for g in groups[:3])
    # check-new gates a sharded library as one store: a copy found, a changed file news, the same report
    new = tmp_path / "new.wrl"
    shutil.copy(copy / parts[5], new)
    for args in ((new, copy / parts[0]), (copy / parts[1], "--exclude-self")):
        whole = cli("check-new", *args, "--store", sharded, "--format", "json")
        single = cli("check-new", *args, "--store", one, "--format", "json")
        assert whole.exit_code == single.exit_code and whole.exit_code in (0, 7), whole.output + whole.stderr
        assert json.loads(whole.stdout) == json.loads(single.stdout)
    report = json.loads(cli("check-new", new, "--store", sharded, "--format", "json").stdout)[0]
    assert report["status"] == "duplicate" and report["duplicates"][0]["relative_path"] == parts[5]


def test_the_api_opens_and_queries_a_sharded_store_as_one_store(trees):
    import shapeidx

    tree, _, parts, one, sharded = trees
    part = tree / parts[2]
    assert shapeidx.query(sharded, part, top=5, where=WHERE) == shapeidx.query(one, part, top=5, where=WHERE)
    with shapeidx.open_store(sharded) as searcher:
        hits = shapeidx.query(searcher, entry=parts[2], top=3, metric="combined-angle")
    assert hits == shapeidx.query(one, entry=parts[2], top=3, metric="combined-angle") and hits[0]["distance"] == 0


def test_classify_and_plot_take_a_sharded_store_as_one_store(trees, tmp_path):
    tree, table, parts, one, sharded = trees
    labels = tmp_path / "labels.csv"
    with open(labels, "w", newline="") as f:
        csv.writer(f).writerows([("path", "label")] + [(p, "odd" if k % 2 else "even") for k, p in enumerate(parts)])
    asked = [parts[0], parts[7], str(tree / parts[4])]
    for extra in ((), ("--where", WHERE[0]), ("--labels", labels, "-k", 5), ("--metric", "all-angle")):
        whole = cli("classify", *asked, "--store", sharded, *extra, "--json")
        single = cli("classify", *asked, "--store", one, *extra, "--json")
        assert whole.exit_code == 0, whole.output + whole.stderr
        assert json.loads(whole.stdout) == json.loads(single.stdout)
    answer = json.loads(cli("classify", parts[0], "--store", sharded, "--json").stdout)[0]
    assert answer["label"] == parts[0].split("/")[0] and parts[0] not in [n["path"] for n in answer["neighbours"]]
    # no voter left: the same answer as one store's
    whole = cli("classify", parts[0], "--store", sharded, "--where", "material=gold")
    assert whole.output == cli("classify", parts[0], "--store", one, "--where", "material=gold").output
    assert whole.exit_code == 0 and "(no voter)" in whole.output
    for store in (sharded, one):
        out = cli("plot", "--id", parts[3], "--id", parts[9], "--store", store, "-o", tmp_path / f"{store.stem}.png")
        assert out.exit_code == 0, out.output + out.stderr
    assert (tmp_path / "sharded.png").read_bytes() == (tmp_path / "one.png").read_bytes()


@pytest.fixture(scope="module")
def part_trees(data_dir, tmp_path_factory):
    """KiCad parts of several sub-parts each (bodies, pins), as one store and as a sharded store, both with --parts."""
    tmp = tmp_path_factory.mktemp("shard-parts")
    tree = copy_tree(data_dir / "kicad6", tmp / "parts", ("Battery", "Button_Switch_SMD"))
    # a file of five sub-parts again under another name: its sub-parts are shared by two files
    shutil.copy(tree / "Battery/BatteryHolder_Keystone_1042_1x18650.wrl", tree / "Button_Switch_SMD/holder_copy.wrl")
    one, sharded = tmp / "one.shapeidx", tmp / "sharded.shapeidx"
    for store, extra in ((one, ()), (sharded, ("--shards", SHARDS))):
        result = build(tree, store, "--workers", "1", "--parts", *extra)
        assert result.exit_code == 0, result.output + result.stderr
    return tree, one, sharded


def test_where_used_on_a_sharded_store_answers_as_one_store(part_trees, tmp_path):
    import re

    from shapeidx.search import open_searcher

    tree, one, sharded = part_trees
    with open_searcher(one, parts=True) as single, open_searcher(sharded, parts=True) as whole:
        entries = single.entry_paths()
        assert sorted(whole.entry_paths()) == sorted(entries) and any(not e.endswith("#1") for e in entries)
        files = sorted({e.rsplit("#", 1)[0] for e in entries})
        asked = entries[::3] + files[::2]  # sub-entries, files of one part and files of several
        for entry in asked:
            for scale, within in (("sensitive", None), ("invariant", None), ("invariant", 0.003)):
                a = single.where_used(single.question_of_entry(entry), 4, "all-angle", within, scale)
                b = whole.where_used(whole.question_of_entry(entry), 4, "all-angle", within, scale)
                assert (a.to_dict() | {"store": ""}, a.reason) == (b.to_dict() | {"store": ""}, b.reason), entry
        # an entry asked as a query (not as where-used's question): every shard reads its
        # exact measures for the same-size test, not only the shard that holds it
        for entry in entries[::3]:
            a = single.where_used(single.query_of_entry(entry), 6, "all-angle")
            b = whole.where_used(whole.query_of_entry(entry), 6, "all-angle")
            assert a.to_dict() | {"store": ""} == b.to_dict() | {"store": ""}, entry
    # through the command line: a file asked, text and JSON, a sheet with the same pictures
    part = tree / files[1]
    for args in (("--top", 6, "--scale", "invariant"), ("--max-distance", 0.002, "--scale", "invariant", "--json")):
        got, expected = (cli("where-used", part, "--store", store, *args) for store in (sharded, one))
        assert got.exit_code == expected.exit_code == 0, got.output + got.stderr
        assert got.stdout.replace(str(sharded), "") == expected.stdout.replace(f"{one}/parts", "")
    pictures = []
    for store in (sharded, one):
        sheet = tmp_path / f"{store.stem}.html"
        assert cli("where-used", part, "--store", store, "--top", 3, "--scale", "invariant", "--sheet", sheet).exit_code == 0
        pictures.append(re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", sheet.read_text()))
    assert len(pictures[0]) >= 4 and pictures[0] == pictures[1]
    # query --parts ranks every shard's sub-parts: the same hits, with their files and counts
    for args in ((part, "--top", 6), ("--id", entries[4], "--top", 5, "--scale", "sensitive", "--format", "csv")):
        got, expected = (cli("query", *args, "--parts", "--store", store) for store in (sharded, one))
        assert got.exit_code == expected.exit_code == 0, got.output + got.stderr
        assert got.stdout.replace(str(sharded), "") == expected.stdout.replace(f"{one}/parts", "")
        assert "x1" in got.stdout or ",1\n" in got.stdout
    # the page ranks a sharded store's sub-parts as one store's: queries, where used, uploads, pictures
    pytest.importorskip("starlette")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from starlette.testclient import TestClient

    from shapeidx.web.app import ShardedStoreService, create_app, open_service

    def page(store):
        service = open_service(store)
        client = TestClient(create_app(service), base_url="http://127.0.0.1:8765")
        try:
            out = []
            for params in ({"id": entries[4], "parts": "1", "top": 5}, {"id": entries[4], "uses": "1", "top": 4},
                           {"id": files[3], "uses": "1", "top": 4, "metric": "combined-angle"}):
                got = client.get("/api/query", params=params).json()
                out.append([(h["rank"], h["id"], h["distance"], h.get("parent"), h.get("count"), h["metadata"],
                             h["fractions"], "parent_thumbnail" in h) for h in got["hits"]])
                out.append({k: got["query"].get(k) for k in ("name", "parent", "count", "metadata", "fractions")})
            with open(part, "rb") as f:
                upload = client.post("/api/query", files={"file": (part.name, f.read())}, data={"uses": "1"}).json()
            out.append([(h["id"], h["distance"], h["count"]) for h in upload["hits"]])
            out.append(client.get("/api/thumbnail", params={"id": entries[4]}).content)
            files_hits = client.get("/api/query", params={"id": entries[4], "top": 3}).json()["hits"]  # the files
            out.append([(h["id"], h["distance"]) for h in files_hits])
            return service, out, client.get("/api/store").json()["sub_parts"]
        finally:
            service.close()

    (service, whole, sub_parts), (_, single, sub_parts_one) = page(sharded), page(one)
    assert isinstance(service, ShardedStoreService) and whole == single and sub_parts == sub_parts_one == len(entries)
    assert whole[-2][:4] == b"\x89PNG" and len(whole[-1]) == 3 and len(whole[0]) == 5
    # a sharded store built without --parts: one line naming the build that makes them
    plain = tmp_path / "plain.shapeidx"
    assert build(tree, plain, "--workers", "1", "--shards", 2).exit_code == 0
    out = cli("where-used", part, "--store", plain)
    assert out.exit_code != 0 and f"has no sub-parts: build it with 'shapeidx build DIR --store {plain} --parts'" in out.stderr


def test_duplicates_of_sub_parts_of_a_sharded_store_are_those_of_one_store(part_trees):
    _, one, sharded = part_trees
    answers = []
    for where in ((), ("--where", "path~Button*")):
        got, expected = (cli("duplicates", "--parts", "--similar", "--store", store, *where, "--json")
                         for store in (sharded, one))
        assert got.exit_code == expected.exit_code == 0, got.output + got.stderr
        assert json.loads(got.stdout) == json.loads(expected.stdout)
        answers.append(json.loads(got.stdout))
    # the copy's five sub-parts, each shared with the file it copies (another shard, likely); none
    # once --where keeps one of the two files only
    assert len(answers[0]) >= 5 and answers[1] == []
    assert sum(any(m.startswith("Button_Switch_SMD/holder_copy.wrl#") for m in g["members"]) for g in answers[0]) >= 5


def test_the_api_ranks_a_sharded_store_s_sub_parts_only_when_opened_for_them(part_trees):
    """api.query(parts=True) on a sharded store opened for its files is refused, not answered with files."""
    import shapeidx

    tree, one, sharded = part_trees
    part = str(next(tree.rglob("*.wrl")))
    with shapeidx.open_store(sharded) as files:
        with pytest.raises(ValueError, match="parts=True ranks the sub-parts"):
            shapeidx.query(files, part, top=3, parts=True)
    with shapeidx.open_store(sharded, parts=True) as whole, shapeidx.open_store(one, parts=True) as single:
        got = shapeidx.query(whole, part, top=3, parts=True)
        expected = shapeidx.query(single, part, top=3, parts=True)
    assert [h["relative_path"] for h in got] == [h["relative_path"] for h in expected]
    assert all("#" in h["relative_path"] and h["parent"] for h in got)


def test_whole_store_commands_count_every_shard_s_failures(tmp_path):
    """classify and cluster on a sharded store whose every file failed: one line counting the
    failures of every shard (it counted the first shard's), as an ordinary store says it."""
    tree = tmp_path / "tree"
    tree.mkdir()
    for i in range(5):
        (tree / f"bad{i}.stl").write_text("solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0\nendsolid\n")
    answers = {}
    for name, extra in (("one", ()), ("sharded", ("--shards", "2"))):
        store = tmp_path / f"{name}.shapeidx"
        assert cli("build", tree, "--store", store, "-q", *extra).exit_code == 0
        for command in (("classify", str(tree / "bad0.stl")), ("cluster",)):
            result = cli(*command, "--store", store)
            assert result.exit_code == 6, result.output
            answers[name, command[0]] = result.stderr.strip().replace(str(store), "STORE").replace(store.name, "STORE")
    for command in ("classify", "cluster"):
        assert answers["sharded", command] == answers["one", command]
        assert "none of the store's 5 entries could be indexed" in answers["sharded", command]
