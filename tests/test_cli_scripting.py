"""The command line as scripts use it: pipes, paths that open, several queries, formats,
exit statuses, one-line errors, option values, help texts."""

from __future__ import annotations

import csv
import io
import json
import os
import re
import subprocess
from pathlib import Path

import click
import pytest
from clitools import assert_one_line_error, cli, cli_json, run_shapeidx, shapeidx_command
from storetools import build, small_kicad

from shapeidx.cli import main
from shapeidx.console import exits
from shapeidx.distance.metrics import METRICS

REPO = Path(__file__).resolve().parents[1]
CUBE = "mesh-wild/trimesh-models/unit_cube.STL"


@pytest.fixture(scope="module")
def store(data_dir, tmp_path_factory):
    """Two small real KiCad classes (20 parts), built by the real command."""
    tmp = tmp_path_factory.mktemp("scripting")
    tree = small_kicad(data_dir, tmp, ["LED_SMD", "Diode_SMD"])
    path = tmp / "s.h5"
    assert build(tree, path).exit_code == 0
    return tree, path


def first_part(tree: Path) -> Path:
    return sorted((tree / "LED_SMD").iterdir())[0]


class TestPipes:
    def test_a_closed_pipe_is_not_an_error(self, store):
        tree, path = store
        head = subprocess.Popen(["head", "-1"], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        proc = subprocess.run(shapeidx_command("query", tree, "--store", path, "--top", "20"),
                              stdout=head.stdin, stderr=subprocess.PIPE, text=True, timeout=300)
        head.stdin.close()
        assert len(head.stdout.read().splitlines()) == 1
        head.wait()
        assert proc.returncode == 0 and proc.stderr == ""

    def test_help_into_a_closed_pipe(self):
        head = subprocess.Popen(["head", "-c", "1"], stdin=subprocess.PIPE, stdout=subprocess.DEVNULL)
        proc = subprocess.run(shapeidx_command("build", "--help"), stdout=head.stdin, stderr=subprocess.PIPE,
                              text=True, timeout=60)
        head.stdin.close()
        head.wait()
        assert proc.returncode == 0 and "Traceback" not in proc.stderr


class TestQueryPaths:
    def test_hits_open_from_another_directory(self, store, tmp_path, monkeypatch):
        tree, path = store
        monkeypatch.chdir(tmp_path)
        answer = cli_json("query", first_part(tree), "--store", path, "--top", "3")
        assert answer["root"] == str(tree.resolve())
        for hit in answer["hits"]:
            assert os.path.isabs(hit["path"]) and Path(hit["path"]).is_file()
            assert Path(answer["root"], hit["relative_path"]) == Path(hit["path"])
        table = cli("query", first_part(tree), "--store", path, "--top", "3")
        assert all(Path(line.split()[-1]).is_file() for line in table.stdout.splitlines())

    def test_id_takes_relative_absolute_and_working_directory_paths(self, store, monkeypatch):
        tree, path = store
        part = first_part(tree)
        relative = part.relative_to(tree).as_posix()
        expected = cli_json("query", "--id", relative, "--store", path, "--top", "4")["hits"]
        assert cli_json("query", "--id", part.resolve(), "--store", path, "--top", "4")["hits"] == expected
        monkeypatch.chdir(tree / "LED_SMD")
        assert cli_json("query", "--id", part.name, "--store", path, "--top", "4")["hits"] == expected

    def test_exclude_self_and_max_distance(self, store):
        tree, path = store
        part = first_part(tree)
        hits = cli_json("query", part, "--store", path, "--top", "5")["hits"]
        assert hits[0]["distance"] == 0.0 and hits[0]["path"] == str(part.resolve())
        without = cli_json("query", part, "--store", path, "--top", "4", "--exclude-self")["hits"]
        assert [h["relative_path"] for h in without] == [h["relative_path"] for h in hits[1:5]]
        assert [h["rank"] for h in without] == [1, 2, 3, 4]
        limit = (hits[2]["distance"] + hits[3]["distance"]) / 2
        near = cli_json("query", part, "--store", path, "--top", "10", "--max-distance", limit)["hits"]
        assert [h["relative_path"] for h in near] == [h["relative_path"] for h in hits[:3]]
        zero = cli_json("query", part, "--store", path, "--max-distance", 0)["hits"]
        assert zero[0]["path"] == str(part.resolve()) and all(h["distance"] == 0 for h in zero)


class TestSeveralQueries:
    def test_files_a_directory_and_stdin(self, store, data_dir):
        tree, path = store
        parts = sorted((tree / "LED_SMD").iterdir())[:2]
        answers = cli_json("query", *parts, "--store", path, "--top", "2")
        assert [a["query"] for a in answers] == [str(p) for p in parts]
        assert [a["hits"][0]["path"] for a in answers] == [str(p.resolve()) for p in parts]
        folder = cli_json("query", tree / "LED_SMD", "--store", path, "--top", "1")
        assert len(folder) == 10 and all(a["hits"][0]["distance"] == 0.0 for a in folder)
        with open(parts[0], "rb") as f:
            stdin = run_stdin(["query", "-", "--type", "vrml", "--store", path, "--top", "1", "--json"], f.read())
        assert stdin.returncode == 0, stdin.stderr
        answer = json.loads(stdin.stdout)
        assert answer["query"] == "-" and answer["query_path"] is None
        assert answer["hits"][0]["relative_path"] == parts[0].relative_to(tree).as_posix()

    def test_one_block_per_query_in_every_format(self, store):
        tree, path = store
        parts = sorted((tree / "Diode_SMD").iterdir())[:3]
        table = cli("query", *parts, "--store", path, "--top", "2").stdout
        assert table.count("query ") == 3 and len(table.strip().split("\n\n")) == 3
        rows = list(csv.DictReader(io.StringIO(cli("query", *parts, "--store", path, "--top", "2", "--format", "csv").stdout)))
        assert len(rows) == 6 and list(rows[0]) == ["query", "rank", "distance", "path", "relative_path"]
        assert {r["query"] for r in rows} == {str(p) for p in parts}
        tsv = cli("query", *parts, "--store", path, "--top", "2", "--format", "tsv").stdout.splitlines()
        assert len(tsv) == 7 and tsv[0].split("\t")[0] == "query"
        lines = cli("query", *parts, "--store", path, "--top", "2", "--format", "jsonl").stdout.splitlines()
        records = [json.loads(line) for line in lines]
        assert len(records) == 6 and all(r["metric"] == "weighted" for r in records)
        assert float(rows[1]["distance"]) == records[1]["distance"]

    def test_a_bad_query_among_several_is_one_line_and_status_1(self, store, data_dir):
        tree, path = store
        bad = data_dir / "mesh-wild/trimesh-models/emptyIO/stl_empty_bin.stl"
        result = cli("query", first_part(tree), bad, "--store", path, "--top", "1", "--json")
        assert result.exit_code == 1
        assert len(result.stderr.strip().splitlines()) == 1 and "stl_empty_bin.stl" in result.stderr
        assert len(json.loads(result.stdout)) == 1

    def test_json_and_format_together_must_agree(self, store):
        tree, path = store
        assert cli("query", first_part(tree), "--store", path, "--json", "--format", "csv").exit_code == 2


def run_stdin(args, data: bytes):
    return subprocess.run(shapeidx_command(*args), input=data, capture_output=True, timeout=300)


class TestFormatsOfOtherCommands:
    def test_compare_stats_evaluate_rows(self, store, data_dir):
        tree, path = store
        cube = data_dir / CUBE
        rows = list(csv.DictReader(io.StringIO(cli("compare", cube, cube, "--points", 64, "--format", "csv").stdout)))
        assert {r["metric"] for r in rows} == set(METRICS)
        assert all(float(r["distance"]) == 0 for r in rows)
        stats = cli("stats", "--store", path, "--format", "tsv")
        assert stats.exit_code == 0 and stats.stdout.splitlines()[0] == "count\treason"


class TestExitStatuses:
    def test_the_documented_table_is_the_codes(self):
        text = (REPO / "docs/cli.md").read_text()
        table = text[text.index("<!-- exit-statuses -->"):]
        documented = {int(code) for code in re.findall(r"^\| (\d+) \|", table, re.M)}
        assert documented == set(exits.EXIT_STATUSES)
        assert len(set(exits.EXIT_STATUSES)) == len(exits.EXIT_STATUSES)

    def test_usage_error_and_bug_differ(self, monkeypatch, tmp_path):
        assert cli("query", "--top", "zero").exit_code == exits.USAGE
        import shapeidx.search

        def bug(*args, **kwargs):
            raise ZeroDivisionError("a bug")

        monkeypatch.setattr(shapeidx.search, "open_searcher", lambda store, *args, **kwargs: _FakeSearcher(store))
        _FakeSearcher.search = bug
        result = cli("query", "--id", "a", "--store", tmp_path / "x")
        assert result.exit_code == exits.INTERNAL and "internal error: ZeroDivisionError" in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1


class _FakeSearcher:
    """A searcher whose search is a bug: the command line must say so in one line."""

    def __init__(self, store):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def resolve_entry(self, entry):
        return entry

    def metadata_keys(self):
        return ("path",)

    def query_of_entry(self, entry):
        return None


class TestUnreadableInput:
    @pytest.mark.parametrize("command", [["inspect"], ["signature"], ["query", "--store", "s.h5"],
                                         ["compare", "SELF"]])
    def test_a_directory_as_file_is_one_line(self, command, store, tmp_path):
        tree, path = store
        folder = tmp_path / "folder.stl"
        folder.mkdir()
        args = [a if a != "SELF" else str(folder) for a in command]
        if command[0] == "query":
            args = ["query", "--store", path]
            (folder / "notes.txt").write_text("no parts here")
        result = cli(*args, folder)
        assert_one_line_error(result, folder)

    @pytest.mark.parametrize("command", ["build", "evaluate"])
    def test_a_file_as_directory_is_one_line(self, command, tmp_path, data_dir):
        result = cli(command, data_dir / CUBE, "--store", tmp_path / "s.h5")
        assert_one_line_error(result, data_dir / CUBE)
        assert "not a directory" in result.stderr and not (tmp_path / "s.h5").exists()

    def test_a_directory_as_store_is_one_line(self, tmp_path):
        result = cli("stats", "--store", tmp_path)
        assert_one_line_error(result, tmp_path)

    def test_unreadable_file_as_a_real_user(self, data_dir, tmp_path):
        """chmod 000 stops a user that is not root: run as nobody when we are root."""
        secret = tmp_path / "secret.stl"
        secret.write_bytes((data_dir / CUBE).read_bytes())
        secret.chmod(0)
        tmp_path.chmod(0o755)
        command = shapeidx_command("inspect", secret)
        if os.geteuid() == 0:
            if not _nobody_can_run():
                pytest.skip("cannot run the interpreter as nobody here")
            command = ["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups", *command]
        proc = subprocess.run(command, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 1, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1 and "secret.stl" in proc.stderr
        assert "ermission denied" in proc.stderr


def _nobody_can_run() -> bool:
    try:
        probe = subprocess.run(["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups",
                                *shapeidx_command("--version")], capture_output=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return probe.returncode == 0


class TestOptionValues:
    @pytest.mark.parametrize("option", [["--timeout", "nan"], ["--timeout", "inf"], ["--timeout", "-1"],
                                        ["--commit-interval", "nan"], ["--commit-interval", "-inf"],
                                        ["--seed", "-1"], ["--points", "0"], ["--workers", "0"],
                                        ["--wait-timeout", "nan"], ["--wait-timeout", "-5"]])
    def test_build_refuses_them_as_usage_errors(self, option, tmp_path, data_dir):
        result = cli("build", data_dir / "mesh-wild/trimesh-models", "--store", tmp_path / "s.h5", *option)
        assert result.exit_code == exits.USAGE, result.output
        assert option[0] in result.stderr and not (tmp_path / "s.h5").exists()

    @pytest.mark.parametrize("args", [["signature", CUBE, "--seed", "-1"], ["query", CUBE, "--max-distance", "nan"],
                                      ["query", CUBE, "--top", "0"], ["query", CUBE, "--max-distance", "-1"]])
    def test_other_commands_refuse_them(self, args, data_dir):
        args = [str(data_dir / a) if a == CUBE else a for a in args]
        assert cli(*args).exit_code == exits.USAGE


class TestHelp:
    def test_every_command_has_an_example(self):
        ctx = click.Context(main)
        for name in main.list_commands(ctx):
            command = main.get_command(ctx, name)
            if command.hidden or name == "info":
                continue
            text = cli(name, "--help").stdout
            assert "Example:" in text and f"shapeidx {name}" in text.split("Example:")[1], name

    def test_bare_shapeidx_prints_the_help_with_status_0(self):
        result = run_shapeidx()
        assert result.returncode == 0 and "Commands:" in result.stdout and "query" in result.stdout

    def test_help_documents_exit_statuses_completion_and_debug(self):
        text = cli("--help").stdout
        assert "Exit status" in text and "_SHAPEIDX_COMPLETE" in text and "SHAPEIDX_DEBUG" in text

    def test_evaluate_says_all_is_plain_d2(self):
        text = " ".join(cli("evaluate", "--help").stdout.split())
        assert "plain D2" in text and "not every metric" in text


class TestInSample:
    def test_the_combined_metric_is_marked_in_sample_on_its_training_collection(self):
        from shapeidx.distance import combined_weights
        from shapeidx.evaluation.evaluate import in_sample

        trained = combined_weights()["trained_on"]

        class Reader:
            def __init__(self, root):
                self.attrs = {"root": root}

        assert in_sample(Reader(f"/data/{trained['collection']}"), 10, 2, "combined") == {"learned_on": trained["collection"]}
        assert in_sample(Reader("/data/other"), trained["models"], trained["classes"], "combined") is not None
        assert in_sample(Reader("/data/other"), 10, 2, "combined") is None

    def test_evaluate_prints_the_mark(self, data_dir, tmp_path):
        from storetools import copy_tree

        collection = copy_tree(data_dir / "kicad6", tmp_path / "kicad6", ["LED_SMD", "Diode_SMD"])
        table = cli("evaluate", collection, "--store", tmp_path / "k.h5", "--points", 128, "-q")
        assert table.exit_code == 0, table.stderr
        assert "combined (in-sample)" in table.stdout and "note: combined's weights were learned" in table.stdout
        rows = list(csv.DictReader(io.StringIO(cli("evaluate", collection, "--store", tmp_path / "k.h5", "--format",
                                                   "csv", "-q").stdout)))
        marks = {r["metric"]: r["in_sample"] for r in rows}
        assert marks["combined"] == "true" and marks["weighted"] == "false"
