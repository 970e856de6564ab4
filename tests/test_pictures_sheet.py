"""shapeidx plot, the similarity words, and result sheets (query --sheet, compare --sheet)."""

from __future__ import annotations

import json
import os
import re
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlparse

import numpy as np
import pytest
from PIL import Image
from clitools import cli, cli_json
from storetools import small_kicad

from shapeidx.distance import compare
from shapeidx.pictures.plot import figure_of
from shapeidx.pictures.sheet import PAGE, SheetHit, SheetPart, sheet_html
from shapeidx.pictures.similarity import MAX_DRAWS, WORDS, SimilarityScale
from shapeidx.search import Searcher
from shapeidx.signing.pipeline import signature_of_solid, solid_of_file
from shapeidx.signing.parameters import BIN_DIVISOR, HISTOGRAMS
from shapeidx.store import open_store


@pytest.fixture(scope="module")
def store(data_dir, tmp_path_factory):
    """Three small KiCad class folders (30 parts) built by the real command, full 1024 points."""
    tmp = tmp_path_factory.mktemp("sheet")
    tree = small_kicad(data_dir, tmp)
    path = tmp / "s.shapeidx"
    result = cli("build", tree, "--store", path)
    assert result.exit_code == 0, result.output
    return tree, path


class Page(HTMLParser):
    """What a sheet is made of: its tags with their attributes, and its text."""

    def __init__(self, text):
        super().__init__()
        self.tags, self.text = [], []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data):
        self.text.append(data)

    def all(self, tag, **match):
        return [a for t, a in self.tags if t == tag and all(a.get(k) == v for k, v in match.items())]


class TestPlot:
    def test_curves_are_the_histograms_against_distance_over_mean(self, data_dir):
        kicad = data_dir / "kicad6" / "Battery"
        a = signature_of_solid(solid_of_file(kicad / "BatteryHolder_Keystone_500.wrl"), 256)
        b = signature_of_solid(solid_of_file(kicad / "BatteryHolder_Keystone_3000_1x12mm.wrl"), 256)
        fig = figure_of([("a", a), ("b", b)])
        axes = fig.axes
        assert [ax.get_title() for ax in axes] == ["ALL", "IN", "OUT", "MIXED"]
        for ax, name in zip(axes, HISTOGRAMS):
            lines = ax.get_lines()
            assert len(lines) == 2
            for line, sig in zip(lines, (a, b)):
                p = sig.histograms[name].p
                assert np.allclose(line.get_ydata(), p) and np.allclose(line.get_xdata(), (np.arange(len(p)) + 0.5) / BIN_DIVISOR)
            labels = [t.get_text() for t in ax.get_legend().get_texts()]
            if name != "all":
                assert labels == [f"a ({100 * a.fractions[name]:.2f}%)", f"b ({100 * b.fractions[name]:.2f}%)"]
        title = "\n".join(t.get_text() for t in fig.texts)
        d = compare(a, b)
        assert f"ALL (plain D2) {d['all']:.3g}, AvgOf3 {d['avg3']:.3g}, AvgOf4 {d['avg4']:.3g}, Weighted {d['weighted']:.3g}" in title

    def test_command_writes_png_svg_pdf_and_store_entries_match_files(self, store, tmp_path):
        tree, path = store
        entry = "LED_SMD/" + sorted(p.name for p in (tree / "LED_SMD").iterdir())[0]
        other = tree / "Diode_SMD" / sorted(p.name for p in (tree / "Diode_SMD").iterdir())[0]
        for suffix in (".png", ".svg", ".pdf"):
            out = tmp_path / f"fig{suffix}"
            result = cli("plot", other, "--id", entry, "--store", path, "-o", out, "--label", "diode", "--label", "led")
            assert result.exit_code == 0, result.output
        assert Image.open(tmp_path / "fig.png").size[0] >= 1000
        assert (tmp_path / "fig.pdf").read_bytes().startswith(b"%PDF")
        svg = (tmp_path / "fig.svg").read_text()
        with open_store(path) as reader:
            fractions = reader.column("entries/fractions")[reader.index_of(entry)]
        assert f"led (IN {100 * fractions[0]:.1f}%" in svg and "diode - led: ALL" in svg
        # the same part as a file and as an entry: one curve, so distance 0
        same = cli("plot", tree / entry, "--id", entry, "--store", path, "-o", tmp_path / "same.svg")
        assert same.exit_code == 0 and "ALL (plain D2) 0, AvgOf3 0, AvgOf4 0, Weighted 0" in (tmp_path / "same.svg").read_text()

    def test_bad_arguments_are_one_line_errors(self, store, tmp_path):
        _, path = store
        for args, message, status in (
            (["-o", tmp_path / "x.gif", "--id", "a", "--store", path], "unknown picture format", 2),  # usage
            (["-o", tmp_path / "x.jpg", "--id", "a", "--store", path], "unknown picture format", 2),
            (["--id", "no/such.wrl", "--store", path, "-o", tmp_path / "x.png"], "no entry 'no/such.wrl'", 1),
            ([tmp_path / "missing.stl", "-o", tmp_path / "x.png"], "missing.stl", 1),
        ):
            result = cli("plot", *args)
            assert result.exit_code == status and message in result.stderr and "Traceback" not in result.output


class TestSimilarity:
    def test_words_follow_the_share_of_closer_pairs(self):
        scale = SimilarityScale("weighted", np.linspace(0.001, 1.0, 1000), 1000, 10)
        assert scale.words(0.0) == "identical signature"
        assert scale.share(0.0005) == 0 and scale.words(0.0005) == WORDS[0][1]
        assert scale.words(0.0305) == "similar"  # 30 of 1000 pairs are closer
        assert scale.words(0.9) == "not similar"
        assert "closer than 97.0% of the store's pairs" in scale.explain(0.0305)

    def test_calibration_ranks_sampled_entries_against_all_others(self, store):
        _, path = store
        with Searcher(path) as searcher:
            scale = SimilarityScale.of_store(searcher, "weighted")
            signatures = [searcher.signature_at(i) for i in range(len(searcher))]
            n = len(searcher)
        assert scale.draws == min(n, MAX_DRAWS) and scale.pairs == scale.draws * (n - 1)
        # with every entry drawn, the sample is exactly every ordered pair's distance
        expected = sorted(compare(signatures[i], signatures[j])["weighted"] for i in range(n) for j in range(n) if i != j)
        assert np.allclose(scale.distances, expected)

    def test_calibration_is_kept_beside_the_store_until_it_changes(self, store, tmp_path):
        _, path = store
        with Searcher(path) as searcher:
            fresh = SimilarityScale.of_store(searcher, "avg4")
            first = SimilarityScale.cached(searcher, "avg4", tmp_path)
            kept = list(tmp_path.glob("calibration-avg4-*.npz"))
            again = SimilarityScale.cached(searcher, "avg4", tmp_path)
        assert len(kept) == 1 and np.array_equal(first.distances, fresh.distances)
        assert np.array_equal(again.distances, fresh.distances) and again.pairs == fresh.pairs
        # another store file (a new build): drawn again, the old sample replaced
        os.utime(path / "main.h5", ns=(1, 1))
        with Searcher(path) as searcher:
            SimilarityScale.cached(searcher, "avg4", tmp_path)
        assert [p.name for p in tmp_path.glob("calibration-avg4-*.npz")] != [p.name for p in kept]
        assert len(list(tmp_path.glob("calibration-avg4-*.npz"))) == 1


def query_json(store_path, *args):
    """The hits of ``shapeidx query --json``, each ``path`` relative to the indexed folder."""
    hits = cli_json("query", *args, "--store", store_path)["hits"]
    return [{**hit, "path": hit["relative_path"]} for hit in hits]


class TestQuerySheet:
    def test_sheet_is_self_contained_and_matches_the_query(self, store, tmp_path):
        tree, path = store
        entry = "Diode_SMD/" + sorted(p.name for p in (tree / "Diode_SMD").iterdir())[2]
        out = tmp_path / "q.html"
        result = cli("query", tree / entry, "--store", path, "-k", "7", "--sheet", out)
        assert result.exit_code == 0, result.output
        text = out.read_text()
        page = Page(text)
        # no network: no http(s) reference anywhere, every image embedded
        assert not re.search(r"(src|href)=\"https?:", text)
        images = page.all("img")
        assert images and all(img["src"].startswith("data:image/png;base64,") for img in images)
        cards = page.all("article")
        expected = query_json(path, tree / entry, "-k", "7")
        assert [c["data-path"] for c in cards] == [h["path"] for h in expected]
        assert cards[0]["data-path"] == entry and "identical signature" in text
        # links: absolute file:// URLs of files that exist
        links = [a["href"] for a in page.all("a")]
        assert len(links) == 8  # the query and 7 hits
        for href in links:
            url = urlparse(href)
            assert url.scheme == "file" and Path(unquote(url.path)).is_file()
        # each hit: distance, words, fractions, four histogram panels (query reused by <use>)
        with open_store(path) as reader:
            fractions = reader.column("entries/fractions")[reader.index_of(expected[1]["path"])]
        # the metadata the command line prints (here what the files say: none for KiCad VRML)
        assert all(h["metadata"] == {} for h in expected)
        assert f"IN {100 * fractions[0]:.1f}% · OUT {100 * fractions[1]:.1f}% · MIXED {100 * fractions[2]:.1f}%" in text
        assert len(page.all("svg", **{"class": "overlay"})) == 7
        assert len([a for t, a in page.tags if t == "use"]) == 7 * 4
        assert f"distance {expected[1]['distance']:.4g}" in text

    def test_second_sheet_renders_nothing_new(self, store, tmp_path):
        tree, path = store
        thumbs = path / "thumbs"
        args = ("query", "--id", "LED_SMD/" + sorted(p.name for p in (tree / "LED_SMD").iterdir())[0], "--store", path, "-k", "10")
        assert cli(*args, "--sheet", tmp_path / "a.html").exit_code == 0
        before = {p.name: p.stat().st_mtime_ns for p in thumbs.iterdir()}
        assert len(before) >= 10
        assert cli(*args, "--sheet", tmp_path / "b.html").exit_code == 0
        assert {p.name: p.stat().st_mtime_ns for p in thumbs.iterdir()} == before
        assert (tmp_path / "a.html").read_text().split("<main")[1] == (tmp_path / "b.html").read_text().split("<main")[1]

    def test_thumbnails_limit_and_bad_output(self, store, tmp_path):
        tree, path = store
        out = tmp_path / "q.html"
        result = cli("query", "--id", "LED_SMD/" + sorted(p.name for p in (tree / "LED_SMD").iterdir())[0], "--store", path,
                     "-k", "5", "--sheet", out, "--thumbnails", "2")
        assert result.exit_code == 0
        page = Page(out.read_text())
        assert len(page.all("img")) == 3  # the query and two hits
        assert out.read_text().count("no picture beyond the first 2 hits") == 3
        bad = cli("query", "--id", "x", "--store", path, "--sheet", tmp_path / "no" / "q.html")
        assert bad.exit_code == 1 and "no folder" in bad.stderr

    def test_a_missing_hit_file_is_a_note_not_a_failure(self, store, tmp_path):
        tree, path = store
        victim = sorted((tree / "Capacitor_Tantalum_SMD").iterdir())[0]
        moved = tmp_path / victim.name
        victim.rename(moved)
        try:
            entry = "Capacitor_Tantalum_SMD/" + victim.name
            result = cli("query", "--id", entry, "--store", path, "-k", "3", "--sheet", tmp_path / "q.html")
            assert result.exit_code == 0, result.output
            assert "no picture:" in (tmp_path / "q.html").read_text()
        finally:
            moved.rename(victim)

    def test_compare_sheet(self, store, tmp_path, monkeypatch):
        tree, _ = store
        monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # not the user's own cache
        a, b = sorted((tree / "LED_SMD").iterdir())[:2]
        out = tmp_path / "c.html"
        result = cli("compare", a, b, "--sheet", out, "--json")
        assert result.exit_code == 0
        distances = json.loads(result.stdout)
        page = Page(out.read_text())
        assert len(page.all("img")) == 2 and len(page.all("article")) == 1
        assert f"Weighted {distances['weighted']:.4g}" in out.read_text()
        assert len(list((tmp_path / "cache" / "shapeidx" / "thumbs").glob("*.png"))) == 2


class TestLongSheets:
    def test_two_thousand_hits_are_paged_and_lazy(self, store):
        _, path = store
        with Searcher(path) as searcher:
            signatures = [searcher.signature_at(i) for i in range(len(searcher))]
        query = SheetPart("q", None, signatures[0], None, "no picture")
        png = Image.new("RGBA", (8, 8))
        import io

        buffer = io.BytesIO()
        png.save(buffer, format="PNG")
        hits = [SheetHit(SheetPart(f"part{k}", None, signatures[k % len(signatures)], buffer.getvalue()), k + 1, 0.01)
                for k in range(2000)]
        text = sheet_html("long", query, hits, [])
        page = Page(text)
        cards = page.all("article")
        assert len(cards) == 2000 and {c["data-page"] for c in cards} == {str(p) for p in range(2000 // PAGE)}
        images = page.all("img")
        assert sum(img.get("loading") == "lazy" for img in images) == 2000 - 12
        assert "<script>" in text
        assert len(text) / 2000 < 8000  # the query's curves are not repeated in every card
