"""No silent answers, usage errors as usage errors, output that says what it means (issue 23).

Each command runs as a real process (``run_shapeidx``) on real KiCad parts, and its exit
status is compared with the documented table (shapeidx/console/exits.py).
"""

from __future__ import annotations

import os
import shutil
import struct

import pytest
from clitools import run_shapeidx
from storetools import build, small_kicad

from shapeidx.console import exits
from shapeidx.io.formats import FORMAT_NAMES


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
        (creating / "lock").write_text("")  # what a first build makes before its first commit
        (creating / "build.json").write_text('{"state": "running", "pid": 1}')
        for args in (("query", parts(tree)[0]), ("stats",), ("cluster",)):
            result = run_shapeidx(*args, "--store", creating)
            assert result.returncode == exits.NO_ANSWER, (args, result.stderr)
            assert "being created" in one_line(result) and "try again" in result.stderr

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
