"""One search road: the command line, the Python API, the web API and a sheet give the same
hits, for every metric and filter; metadata joined to shape; filtered answers exact.

The store is real (KiCad parts built by the real command) and so is the metadata table; the
expected answers are computed independently of the search road: every distance by
``shapeidx.compare`` over the stored signatures, filtered and sorted here.
"""

from __future__ import annotations

import csv
import json
import re
import warnings
from html.parser import HTMLParser

import numpy as np
import pytest
from clitools import cli, cli_json
from storetools import build, small_kicad

import shapeidx
from shapeidx.console import exits
from shapeidx.distance import compare
from shapeidx.distance.metrics import METRICS
from shapeidx.search import Searcher

FILTERS = {
    "none": [],
    "steel": ["material=steel"],
    "steel, revision >= 3": ["material=steel", "revision>=3"],
    "not legacy": ["project!=legacy"],
    "LEDs by path": ["path~LED_SMD/*"],
}


@pytest.fixture(scope="module")
def store(data_dir, tmp_path_factory):
    """30 KiCad parts with a metadata table: materials, revisions, projects (one row names no file)."""
    tmp = tmp_path_factory.mktemp("road")
    tree = small_kicad(data_dir, tmp)
    parts = sorted(p.relative_to(tree).as_posix() for p in tree.rglob("*.wrl"))
    table = tmp / "parts.csv"
    with open(table, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["path", "material", "revision", "project"])
        for k, part in enumerate(parts):
            if k % 5 == 4:
                continue  # some parts have no row: empty metadata
            writer.writerow([part, "steel" if k % 2 else "brass", str(k % 7), "legacy" if k % 3 == 0 else "alpha"])
        writer.writerow(["no/such/part.wrl", "gold", "1", "ghost"])
    path = tmp / "s.shapeidx"
    result = build(tree, path, "--metadata", table)
    assert result.exit_code == 0, result.output
    return tree, path, table, parts


def expected_hits(store_path, query_entry: str, metric: str, where: list, top: int, exclude_self=False):
    """The answer computed without the search road: compare() against every stored signature,
    the metadata conditions evaluated by hand on the CSV, sorted by distance then path."""
    with Searcher(store_path) as searcher:
        paths = list(searcher.metadata_column("path"))
        signatures = {p: searcher.signature_at(i) for i, p in enumerate(paths)}
        metadata = {p: searcher.metadata_at(i) for i, p in enumerate(paths)}
    query = signatures[query_entry]

    def holds(path, condition):
        key, op, value = re.match(r"(\w+)(>=|!=|=|~)(.*)", condition).groups()
        have = path if key == "path" else metadata[path].get(key, "")
        if op == "=":
            return have == value
        if op == "!=":
            return have != value
        if op == ">=":
            return have != "" and float(have) >= float(value)
        return re.fullmatch(value.replace("*", ".*"), have, re.I) is not None

    kept = [p for p in paths if all(holds(p, c) for c in where) and not (exclude_self and p == query_entry)]
    scored = sorted(((compare(query, signatures[p])[metric], p != query_entry, p) for p in kept))
    return [(p, d) for d, _, p in scored[:top]]


class Cards(HTMLParser):
    def __init__(self, text):
        super().__init__()
        self.cards = []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "article":
            self.cards.append(attrs["data-path"])


@pytest.fixture(scope="module")
def web(store):
    pytest.importorskip("starlette")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from starlette.testclient import TestClient
    from shapeidx.web.app import StoreService, create_app

    service = StoreService(store[1])
    yield TestClient(create_app(service), base_url="http://127.0.0.1:8765")
    service.close()


@pytest.mark.parametrize("metric", METRICS)
@pytest.mark.parametrize("name", FILTERS)
def test_cli_api_web_and_sheet_give_the_same_hits(store, web, metric, name, tmp_path):
    tree, path, _, parts = store
    where = FILTERS[name]
    entry = parts[7]
    top = 6
    expected = expected_hits(path, entry, metric, where, top)
    assert expected, "every filter here leaves some entry"
    where_args = [arg for condition in where for arg in ("--where", condition)]
    # the command line
    answer = cli_json("query", "--id", entry, "--store", path, "--top", top, "--metric", metric, *where_args)
    from_cli = [(h["relative_path"], h["distance"]) for h in answer["hits"]]
    # the Python API
    from_api = [(h["relative_path"], h["distance"]) for h in shapeidx.query(path, entry=entry, top=top, metric=metric,
                                                                            where=where)]
    # the web API
    params = [("id", entry), ("top", str(top)), ("metric", metric)] + [("where", c) for c in where]
    response = web.get("/api/query", params=params)
    assert response.status_code == 200, response.text
    from_web = [(h["relative_path"], h["distance"]) for h in response.json()["hits"]]
    # a sheet
    sheet = tmp_path / "q.html"
    result = cli("query", "--id", entry, "--store", path, "--top", top, "--metric", metric, *where_args,
                 "--sheet", sheet, "--thumbnails", "0")
    assert result.exit_code == 0, result.stderr
    from_sheet = Cards(sheet.read_text()).cards
    assert [p for p, _ in expected] == [p for p, _ in from_cli]
    np.testing.assert_allclose([d for _, d in from_cli], [d for _, d in expected], rtol=1e-12, atol=1e-15)
    assert from_cli == from_api == from_web  # bit for bit, field for field
    assert from_sheet == [p for p, _ in from_cli]
    # the same fields everywhere
    api_hit = shapeidx.query(path, entry=entry, top=1, metric=metric, where=where)[0]
    web_hit = response.json()["hits"][0]
    assert set(api_hit) == set(answer["hits"][0]) == {"rank", "distance", "path", "relative_path", "metadata"}
    assert {k: web_hit[k] for k in api_hit} == api_hit == answer["hits"][0]


def test_a_filter_keeps_exactly_the_matching_entries_and_shows_their_metadata(store):
    tree, path, _, parts = store
    answer = cli_json("query", "--id", parts[3], "--store", path, "--top", "100", "--where", "material=steel",
                      "--where", "project!=legacy")
    assert answer["considered"] == len(answer["hits"]) > 0 and answer["entries"] == len(parts)
    assert all(h["metadata"]["material"] == "steel" and h["metadata"]["project"] != "legacy" for h in answer["hits"])
    assert answer["filters"] == ["--where material=steel", "--where project!=legacy"]
    table = cli("query", "--id", parts[3], "--store", path, "--top", "3", "--where", "material=steel").stdout
    assert all("material=steel" in line for line in table.strip().splitlines())
    rows = list(csv.DictReader(cli("query", "--id", parts[3], "--store", path, "--format", "csv").stdout.splitlines()))
    assert {"material", "revision", "project"} <= set(rows[0]) and rows[0]["relative_path"] == parts[3]


def test_a_filter_that_matches_nothing_says_so_with_status_6(store):
    tree, path, _, parts = store
    for where in (["material=gold"], ["revision>100"]):  # gold: only the row of a file not in the tree
        result = cli("query", "--id", parts[0], "--store", path, *[a for w in where for a in ("--where", w)])
        assert result.exit_code == exits.NO_ANSWER and result.stdout == ""
        assert "no entry of the store matches" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    far = cli("query", "--id", parts[0], "--store", path, "--exclude-self", "--max-distance", "1e-12")
    assert far.exit_code == exits.NO_ANSWER and "no hit within --max-distance" in far.stderr
    as_json = cli("query", "--id", parts[0], "--store", path, "--where", "material=gold", "--json")
    assert as_json.exit_code == exits.NO_ANSWER and json.loads(as_json.stdout)["hits"] == []
    assert "reason" in json.loads(as_json.stdout)
    assert shapeidx.query(path, entry=parts[0], where=["material=gold"]) == []


def test_a_key_the_store_does_not_have_is_a_usage_error(store):
    _, path, _, parts = store
    result = cli("query", "--id", parts[0], "--store", path, "--where", "materal=steel")
    assert result.exit_code == exits.USAGE and "no entry of the store has metadata 'materal'" in result.stderr
    assert "material" in result.stderr  # the keys it has are listed
    bad = cli("query", "--id", parts[0], "--store", path, "--where", "revision>three")
    assert bad.exit_code == exits.USAGE and "compares numbers" in bad.stderr
    with pytest.raises(shapeidx.ShapeidxError, match="materal"):
        shapeidx.query(path, entry=parts[0], where=["materal=steel"])


def test_changed_metadata_is_read_again_without_signing_again(store, tmp_path):
    tree, path, table, parts = store
    copy = tmp_path / "s.shapeidx"
    import shutil

    shutil.copytree(path, copy)
    changed = tmp_path / "parts.csv"
    text = table.read_text().replace(",brass,", ",bronze,")
    changed.write_text(text)
    summary = json.loads(cli("build", tree, "--store", copy, "--metadata", changed, "--json").stdout)
    assert summary["indexed"] == 0 and summary["unchanged"] == len(parts)
    assert summary["metadata"] == {"rows": len(text.strip().splitlines()) - 1, "changed": True}
    assert cli_json("query", "--id", parts[0], "--store", copy, "--where", "material=bronze", "--top", "50")["hits"]
    assert cli("query", "--id", parts[0], "--store", copy, "--where", "material=brass").exit_code == exits.NO_ANSWER
    again = json.loads(cli("build", tree, "--store", copy, "--metadata", changed, "--json").stdout)
    assert again["metadata"]["changed"] is False
    kept = json.loads(cli("build", tree, "--store", copy, "--json").stdout)  # no --metadata: the table stays
    assert kept["metadata"] is None and cli_json("stats", "--store", copy)["metadata"]["rows"] == again["metadata"]["rows"]


def test_a_bad_metadata_table_changes_nothing(store, tmp_path):
    tree, path, _, _ = store
    before = sorted(p.name for p in path.iterdir())
    for content, message in (("material,revision\nsteel,1\n", "no path column"), ("", "no header"),
                             ("path,x\n/etc/passwd,1\n", "outside the indexed folder")):
        bad = tmp_path / "bad.csv"
        bad.write_text(content)
        result = cli("build", tree, "--store", path, "--metadata", bad)
        assert result.exit_code == exits.ERROR and message in result.stderr, result.stderr
        assert len(result.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in path.iterdir()) == before


def test_what_step_files_say_of_themselves_is_metadata(data_dir, tmp_path):
    """The STEP product's name and id become ``title`` and ``product_id``, filtered like any key."""
    import shutil

    folder = tmp_path / "step"
    folder.mkdir()
    sources = sorted((data_dir / "kicad6-step" / "Battery").glob("*.step"))[:3]
    for source in sources:
        shutil.copy(source, folder / source.name)
    assert build(folder, tmp_path / "s.shapeidx").exit_code == 0
    first = sources[0]
    product = re.search(r"PRODUCT\s*\(\s*'([^']*)'\s*,\s*'([^']*)'", first.read_text(errors="replace"))
    answer = cli_json("query", folder / first.name, "--store", tmp_path / "s.shapeidx", "--top", "3",
                      "--where", f"product_id={product.group(1)}")
    assert [h["relative_path"] for h in answer["hits"]] == [first.name]
    assert answer["hits"][0]["metadata"] == {"title": product.group(2), "product_id": product.group(1)}


def test_every_searcher_offers_the_query_interface(tmp_path, data_dir):
    """A sharded store's searcher answers the query road's surfaces as one store's does: the
    same methods with the same parameters (Searcher.search also takes classify's voter mask)."""
    import inspect

    from clitools import cli
    from storetools import FAST_POINTS, small_kicad

    from shapeidx.search.searcher import QUERY_ATTRIBUTES, QUERY_INTERFACE, Searcher
    from shapeidx.search.sharded import ShardedSearcher, open_searcher

    def parameters(cls, name):
        return [(p.name, p.default) for p in inspect.signature(getattr(cls, name)).parameters.values()
                if p.name not in ("threads", "among", "among_reason")]

    for name in QUERY_INTERFACE:
        assert parameters(Searcher, name) == parameters(ShardedSearcher, name), name
    tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
    for extra in ((), ("--shards", "2")):
        store = tmp_path / f"s{len(extra)}.shapeidx"
        assert cli("build", tree, "--store", store, "--points", FAST_POINTS, "--workers", "1", *extra).exit_code == 0
        with open_searcher(store) as searcher:
            assert isinstance(searcher, ShardedSearcher if extra else Searcher)
            assert all(getattr(searcher, a) is not None for a in QUERY_ATTRIBUTES)
            part = sorted(tree.rglob("*.wrl"))[0]
            answer = searcher.search(searcher.query_of_part(part), top=3)
            assert answer.hits[0].path == str(part) and answer.hits[0].distance == 0
            drawn = searcher.query_of_part(part, seed=7).signature  # its points drawn again: another signature
            assert drawn.seed == 7 and drawn.fractions != searcher.signature_of(answer.hits[0].relative_path).fractions
