"""No silent answers, usage errors as usage errors, output that says what it means (issue 23).

Each command runs as a real process (``run_shapeidx``) on real KiCad parts, and its exit
status is compared with the documented table (shapeidx/console/exits.py).
"""

from __future__ import annotations

import os
import shutil
import struct
from pathlib import Path

import pytest
from clitools import run_shapeidx
from storetools import build, small_kicad

from shapeidx.console import exits
from shapeidx.io.formats import FORMAT_NAMES
from shapeidx.store.lock import StoreLock


@pytest.fixture(scope="module")
def store(data_dir, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("answers")
    tree = small_kicad(data_dir, tmp, ["LED_SMD", "Diode_SMD"])
    path = tmp / "s.shapeidx"
    assert build(tree, path).exit_code == 0
    return tree, path


def parts(tree, n=2):
    return sorted((tree / "LED_SMD").iterdir())[:n]


def one_line(result):
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    return lines[0]


class TestNoSilentAnswers:
    def test_a_query_while_a_first_build_has_committed_nothing(self, store, tmp_path):
        tree, _ = store
        creating = tmp_path / "new.shapeidx"
        creating.mkdir()
        (creating / "build.json").write_text('{"state": "running", "pid": 1}')
        lock = StoreLock(creating)  # what a first build holds before its first commit
        lock.acquire()
        try:
            for args in (("query", parts(tree)[0]), ("stats",), ("cluster",)):
                result = run_shapeidx(*args, "--store", creating)
                assert result.returncode == exits.NO_ANSWER, (args, result.stderr)
                assert "being created" in one_line(result) and "try again" in result.stderr
        finally:
            lock.release()
        # the build killed before its first commit: no "try again", but how to build it
        result = run_shapeidx("query", parts(tree)[0], "--store", creating)
        assert result.returncode == exits.NO_ANSWER, result.stderr
        assert "its first build stopped before committing anything" in one_line(result)
        assert f"'shapeidx build DIR --store {creating}' builds it" in result.stderr

    def test_max_distance_with_no_hit_and_stats_without_failures_say_so(self, store):
        tree, path = store
        entry = f"LED_SMD/{parts(tree)[0].name}"
        result = run_shapeidx("query", "--id", entry, "--exclude-self", "--max-distance", "1e-7", "--store", path)
        assert result.returncode == exits.NO_ANSWER and "--max-distance" in one_line(result) and result.stdout == ""
        result = run_shapeidx("stats", "--failed", "--store", path)
        assert result.returncode == 0 and "no failed file" in one_line(result)

    def test_a_damaged_store_with_several_queries_is_status_5_once(self, store, tmp_path):
        tree, path = store
        damaged = tmp_path / "d.shapeidx"
        shutil.copytree(path, damaged)
        # flip bytes in a ranking array a query reads (its CRC-32 then fails)
        import h5py

        with h5py.File(damaged / "main.h5", "r") as f:
            offset = f["rank/all/counts"].id.get_offset()
        with open(damaged / "main.h5", "r+b") as f:
            f.seek(offset + 64)
            f.write(struct.pack("<I", 0x7F7F7F7F))
        for queries in ([parts(tree)[0]], parts(tree, 3), [tree / "LED_SMD"]):
            result = run_shapeidx("query", *queries, "--metric", "all", "--store", damaged)
            assert result.returncode == exits.DAMAGED, result.stderr
            assert "is damaged" in one_line(result)


class TestUsageErrors:
    def test_an_unknown_type_of_standard_input(self, store):
        tree, path = store
        for name in ("wrl", "jpeg"):
            result = run_shapeidx("query", "-", "--type", name, "--store", path)
            assert result.returncode == exits.USAGE, result.stderr

    def test_type_help_lists_every_format(self):
        text = " ".join(run_shapeidx("query", "--help").stdout.split())
        assert all(name in text for name in FORMAT_NAMES) and "step" in text and "iges" in text

    @pytest.mark.parametrize("name", ["x.jpg", "x.gif", "x"])
    def test_plot_to_a_picture_format_it_does_not_write(self, store, tmp_path, name):
        tree, _ = store
        result = run_shapeidx("plot", parts(tree)[0], "-o", tmp_path / name)
        assert result.returncode == exits.USAGE and "unknown picture format" in one_line(result)
        assert not os.path.exists(tmp_path / name)


def aligned(lines, text_of):
    """Whether the column whose text ``text_of(line)`` gives starts at one offset on every line."""
    return len({line.index(text_of(line)) for line in lines}) == 1


class TestOutput:
    def test_evaluate_csv_has_the_tables_columns_and_the_table_fits_its_labels(self, data_dir, tmp_path):
        import csv
        import io
        import json

        from storetools import copy_tree

        collection = copy_tree(data_dir / "kicad6", tmp_path / "kicad6", ["LED_SMD", "Diode_SMD"])  # in-sample
        store = tmp_path / "k.shapeidx"
        args = ("evaluate", collection, "--store", store, "--points", "128", "-q", "--cross-validate")
        table = run_shapeidx(*args)
        assert table.returncode == 0, table.stderr
        lines = table.stdout.splitlines()
        header = next(line for line in lines if line.startswith("distance"))
        rows = [line for line in lines if ("(cross-validated)" in line or line.startswith("Weighted")) and not line.startswith("note:")]
        assert any("combined-angle (cross-validated)" in line for line in rows)
        import re

        ends = lambda line: [m.end() for m in re.finditer(r"\S+", line)]  # noqa: E731
        heading_ends = ends(header)[1:]  # NN FT ST E DCG kNN NMI ARI
        for line in rows:  # every figure right under its heading, however long the label
            figures = 8 if len(line.split()) >= 8 and "(cross-validated)" not in line else 5
            assert ends(line)[-figures:] == heading_ends[:figures], (header, line)
        notes = [line for line in lines if line.startswith("note:")]
        assert notes and not any("--cross-validate gives" in n for n in notes)  # it was given
        assert all("(cross-validated) row" in n for n in notes)
        result = json.loads(run_shapeidx(*args, "--json").stdout)
        rows = list(csv.DictReader(io.StringIO(run_shapeidx(*args, "--format", "csv").stdout)))
        assert {"knn", "nmi", "ari"} <= set(rows[0])
        for row in rows:
            figures = result["metrics"][row["metric"]]
            for score in ("knn", "nmi", "ari"):
                if score in figures:
                    assert float(row[score]) == pytest.approx(figures[score])
                else:
                    assert row[score] == ""

    def test_classify_and_duplicates_tables_have_headers_and_stay_aligned(self, store, tmp_path):
        tree, path = store
        long_label = "a_category_label_much_longer_than_twenty_four_characters"
        labels = tmp_path / "labels.csv"
        paths = sorted(str(p.relative_to(tree)) for p in tree.rglob("*.wrl"))
        labels.write_text("path,label\n" + "".join(f"{p},{long_label if i % 2 else 'short'}\n" for i, p in enumerate(paths)))
        result = run_shapeidx("classify", parts(tree)[0], "--store", path, "-k", "6", "--labels", labels)
        assert result.returncode == 0, result.stderr
        lines = result.stdout.splitlines()
        assert lines[1].split() == ["distance", "label", "voter"]
        voters = lines[2:]
        assert len(voters) == 6 and aligned(voters, lambda line: line.split()[-1])
        assert aligned([lines[1]] + voters, lambda line: line.split()[-1])

        dup_tree = tmp_path / "dups"
        shutil.copytree(tree, dup_tree)
        original = parts(dup_tree)[0]
        shutil.copy(original, original.parent / ("a_copy_with_a_name_far_longer_than_the_others_" + original.name))
        shutil.copy(parts(dup_tree)[1], dup_tree / "Diode_SMD" / "copy.wrl")
        dup_store = tmp_path / "d.shapeidx"
        assert build(dup_tree, dup_store).exit_code == 0
        result = run_shapeidx("duplicates", "--store", dup_store)
        assert result.returncode == 0, result.stderr
        lines = result.stdout.splitlines()
        headers = [line for line in lines if line.split()[:2] == ["tier", "distance"]]
        rows = [line for line in lines if line.startswith("  ") and line not in headers]
        assert headers and len(rows) >= 2
        assert aligned(headers + rows, lambda line: line.split()[-1])  # the part column

    def test_closer_than_never_says_100_percent(self):
        from shapeidx.pictures.similarity import SimilarityScale, closer_than

        scale = SimilarityScale("weighted", __import__("numpy").linspace(0.001, 1.0, 100_000), 100_000, 10)
        for distance in (1e-9, 0.0005, 0.001, 0.00101, 0.5):
            text = closer_than(scale.share(distance))
            assert "100.0" not in text, (distance, text)
            share = (scale.distances <= distance).mean()  # counted here, not by searchsorted
            if share == 0:
                assert "closest pairs" in text
            else:
                assert f"{min(99.9, 100 * (1 - share)):.1f}%" in text

    def test_dendrogram_labels_keep_the_start_and_end_of_long_names(self, data_dir):
        from shapeidx.families.cluster_plot import LABEL_CHARS, _short

        names = sorted((p.stem for p in (data_dir / "kicad6").rglob("*.wrl")), key=len)
        longest = names[-1]
        assert len(longest) > LABEL_CHARS
        short = _short(longest + ".wrl")
        assert len(short) == LABEL_CHARS and "..." in short
        head, tail = short.split("...")
        assert longest.startswith(head) and longest.endswith(tail) and len(head) >= 15 and len(tail) >= 15


class TestWhatABuildSays:
    def test_an_unreadable_file_is_reported_once_under_quiet(self, data_dir, request):
        if os.geteuid() != 0:
            pytest.skip("needs root to run the builds as another user (a file root cannot be denied)")
        import subprocess
        import sys

        from clitools import shapeidx_command

        import tempfile

        tmp_path = Path(tempfile.mkdtemp(prefix="shapeidx-nobody-"))  # pytest's own folder is private to root
        request.addfinalizer(lambda: shutil.rmtree(tmp_path, ignore_errors=True))
        tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
        secret = parts(tree)[0]
        secret.chmod(0)
        for folder in [tmp_path, *tmp_path.rglob("*")]:
            if folder.is_dir():
                folder.chmod(0o777)
        store = tmp_path / "s.shapeidx"

        setpriv = shutil.which("setpriv")
        if setpriv is None:
            pytest.skip("needs setpriv (util-linux) to run the builds as another user")
        probe = subprocess.run([setpriv, "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable, "-c",
                                "import subprocess, sys; subprocess.run([sys.executable, '-c', ''], check=True)"],
                               capture_output=True, timeout=60)
        if probe.returncode != 0:  # the build's workers are new interpreters: nobody must be able to run one
            pytest.skip(f"user nobody cannot run {sys.executable} (its folder is private); see the plan-level test")

        def nightly():
            env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "HOME": str(tmp_path)}
            as_nobody = [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups"]
            return subprocess.run(as_nobody + shapeidx_command("build", tree, "--store", store, "-q", "--points", "128",
                                                               "--workers", "1"),
                                  capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)

        first = nightly()
        assert first.returncode == 0 and "permission denied" in first.stderr.lower(), first.stderr
        assert secret.name in first.stderr
        second = nightly()
        assert second.returncode == 0 and second.stderr == "", second.stderr  # nothing new: cron mails nothing
        secret.chmod(0o644)  # made readable without a change of content or time: picked up
        third = nightly()
        assert third.returncode == 0 and third.stderr == ""
        stats = run_shapeidx("stats", "--store", store, "--json")
        assert '"failed": 0' in stats.stdout.replace(" ", "").replace('"failed":0', '"failed": 0'), stats.stdout

    def test_a_file_that_could_not_be_read_is_retried_quietly(self, data_dir, tmp_path, monkeypatch):
        """The same at the plan, as root: the worker's read refused (as for a file without read
        permission), its failed entry committed, then the next build's plan."""
        from shapeidx.index import workers
        from shapeidx.index.build import BuildOptions
        from shapeidx.index.plan import make_plan
        from shapeidx.index.walk import walk_parts
        from shapeidx.store import StoreWriter, open_store
        from shapeidx.store.writer import Batch

        tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
        store = tmp_path / "s.shapeidx"
        assert build(tree, store).exit_code == 0
        secret = parts(tree)[0]
        with open_store(store) as reader:
            params = reader.params
        real_hash = workers.file_hash

        def denied(path):
            if os.fspath(path) == os.fspath(secret):
                raise PermissionError(13, "Permission denied", os.fspath(path))
            return real_hash(path)

        monkeypatch.setattr(workers, "file_hash", denied)
        task = workers.Task(f"LED_SMD/{secret.name}", str(secret), None, in_store=True)
        outcome = workers.index_file(task, params, str(tree))
        assert outcome.kind == "failed" and "Permission denied" in outcome.entry.reason
        with StoreWriter(store, params, tree) as writer:
            writer.commit(Batch(entries=[outcome.entry]))
        for _ in range(2):  # the nights after
            with open_store(store) as reader:
                plan = make_plan(walk_parts(tree), reader, BuildOptions())
            assert task.path in {t.path for t in plan.tasks}  # tried again: it may have become readable
            assert task.path in plan.failed_before  # but its failing again is not news under -q

    def test_bytes_that_are_not_utf8_and_bidi_controls_are_escaped(self, data_dir, tmp_path):
        tree = tmp_path / "odd"
        tree.mkdir()
        (tree / "a.wrl").write_bytes(b"#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate {"
                                     b" point [ 0 0 0, 1 0 \xe9, 0 1 0 ] } coordIndex [ 0 1 2 -1 ] } }\n")
        (tree / "b.stl").write_bytes(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 \xe9\n"
                                     b"vertex 0 1 0\nendloop\nendfacet\nendsolid\n")
        real = sorted((data_dir / "kicad6" / "LED_SMD").iterdir())[0]
        spoof = tree / "invoice\u202egpj.wrl"  # shows as "invoicejpg.wrl" when printed raw
        shutil.copy(real, spoof)
        (tree / "empty\u202e.stl").write_bytes(b"")
        store = tmp_path / "s.shapeidx"
        result = run_shapeidx("build", tree, "--store", store, "--points", "128", "--workers", "1")
        assert result.returncode == 0, result.stderr
        failed = run_shapeidx("stats", "--failed", "--store", store)
        query = run_shapeidx("query", spoof, "--store", store)
        for text in (result.stderr, failed.stdout, query.stdout):
            assert "\ufffd" not in text and "\u202e" not in text and "\u00e9" not in text, text
        for text in (result.stderr, failed.stdout):
            assert "found '\\xe9'" in text and "number: '\\xe9'" in text and "empty\\u202e.stl" in text
        assert "invoice\\u202egpj.wrl" in query.stdout

    def test_build_verbose_says_which_merge_happened(self, data_dir, tmp_path):
        """A merge of the journal's newest segments is not 'the journal merged into the store'."""
        tree = small_kicad(data_dir, tmp_path, ["LED_SMD", "Diode_SMD"])
        store = tmp_path / "s.shapeidx"
        result = run_shapeidx("build", tree, "--store", store, "-v", "--points", "128", "--workers", "1",
                              "--commit-interval", "0.05", "--merge-after", "2")
        assert result.returncode == 0, result.stderr
        merges = [line for line in result.stderr.splitlines() if " merged " in line]
        assert merges and all(line.endswith(("merged the journal into the main file",
                                              "merged the journal's newest segments into one")) for line in merges)
        again = run_shapeidx("build", tree, "--store", store, "-v", "--points", "128", "--workers", "1")
        assert again.returncode == 0 and " merged " not in again.stderr  # nothing changed: nothing merged
