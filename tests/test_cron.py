"""``shapeidx build`` under cron: what it says (and does not), its statuses, its refusals."""

from __future__ import annotations

import json
import re
import shutil
import time

import pytest
from clitools import assert_one_line_error, cli, cli_json, run_shapeidx
from storetools import FAST_POINTS, build, copy_tree, small_kicad

from shapeidx.console import exits
from shapeidx.store import open_store
from shapeidx.store.lock import StoreLock

BROKEN = "mesh-wild/openscad-testdata/testdata/stl/unparseable.stl"
#: "invalidvertex.stl" fails with a reason whose Python text holds a bytes repr (b'blah').
BYTES_REASON = "mesh-wild/openscad-testdata/testdata/stl/invalidvertex.stl"
LOG_LINE = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d{4} shapeidx build: ")


@pytest.fixture
def tree(data_dir, tmp_path):
    return small_kicad(data_dir, tmp_path, ["LED_SMD"])


def test_log_lines_carry_a_timestamp_and_the_prefix_every_one(tree, data_dir, tmp_path):
    shutil.copy(data_dir / BROKEN, tree / "broken.stl")
    shutil.copy(data_dir / BYTES_REASON, tree / "bytes.stl")
    result = run_shapeidx("build", tree, "--store", tmp_path / "s.h5", "--points", FAST_POINTS, "-v")
    assert result.returncode == 0, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) > 12 and all(LOG_LINE.match(line) for line in lines), lines
    assert sum("failed broken.stl: " in line for line in lines) == 1
    assert any(re.search(r"committed batch \d+ \(\d+ records\)", line) for line in lines)  # kill_build.py's
    assert any(re.search(r"\bindexed \S.* \([\d.]+s\)$", line) for line in lines)
    bytes_line = next(line for line in lines if "failed bytes.stl" in line)
    assert "b'" not in bytes_line and 'b"' not in bytes_line and "'blah'" in bytes_line
    failed = cli_json("stats", "--store", tmp_path / "s.h5", "--failed")["failed"]
    assert all("b'" not in item["reason"] for item in failed)


def test_quiet_still_reports_a_first_failure_and_strict_says_why(tree, data_dir, tmp_path):
    store = tmp_path / "s.h5"
    assert build(tree, store, "-q").stderr == ""
    shutil.copy(data_dir / BROKEN, tree / "broken.stl")
    first = run_shapeidx("build", tree, "--store", store, "--points", FAST_POINTS, "-q", "--strict")
    assert first.returncode == exits.FAILED_FILES and first.stdout == ""
    lines = first.stderr.splitlines()
    assert len(lines) == 2 and "failed broken.stl: " in lines[0]
    assert "exit status 3 (--strict)" in lines[1] and "1 failed file" in lines[1] and "stats --failed" in lines[1]
    again = run_shapeidx("build", tree, "--store", store, "-q", "--strict")
    assert again.returncode == exits.FAILED_FILES
    assert len(again.stderr.splitlines()) == 1  # not news any more: only why the status is 3


def test_stats_failed_lists_paths_with_reasons(tree, data_dir, tmp_path):
    shutil.copy(data_dir / BROKEN, tree / "broken.stl")
    store = tmp_path / "s.h5"
    build(tree, store)
    table = cli("stats", "--store", store, "--failed")
    assert table.exit_code == 0
    assert table.stdout.startswith(str(tree.resolve() / "broken.stl") + ": ")
    data = cli_json("stats", "--store", store, "--failed")
    assert [f["relative_path"] for f in data["failed"]] == ["broken.stl"] and data["failed"][0]["reason"]
    assert "--failed" in cli("stats", "--store", store).stdout


def test_wait_has_a_time_limit(tree, tmp_path):
    store = tmp_path / "s.h5"
    assert build(tree, store).exit_code == 0
    lock = StoreLock(store)
    lock.acquire()
    try:
        started = time.monotonic()
        result = run_shapeidx("build", tree, "--store", store, "--wait-timeout", "1.5")
        waited = time.monotonic() - started
        refused = run_shapeidx("build", tree, "--store", store)
    finally:
        lock.release()
    assert result.returncode == exits.LOCKED and 1.5 <= waited < 60
    assert "after waiting 1.5 s" in result.stderr and "waiting for the store's lock" in result.stderr
    assert refused.returncode == exits.LOCKED and len(refused.stderr.strip().splitlines()) == 1
    assert run_shapeidx("build", tree, "--store", store, "--wait-timeout", "5").returncode == 0


def test_evaluate_without_classes_refuses_before_building(data_dir, tmp_path, monkeypatch):
    flat = copy_tree(data_dir / "kicad6/LED_SMD", tmp_path / "flat")
    monkeypatch.chdir(tmp_path)
    result = cli("evaluate", flat)
    assert_one_line_error(result, flat)
    assert "nothing was built" in result.stderr and not (tmp_path / "shapeidx.h5").exists()


def test_a_folder_without_part_files_is_refused(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs/readme.txt").write_text("no parts")
    result = cli("build", tmp_path / "docs", "--store", tmp_path / "s.h5")
    assert_one_line_error(result, tmp_path / "docs")
    assert "no part files" in result.stderr and not (tmp_path / "s.h5").exists()


def test_links_out_of_the_tree_are_not_followed(tree, tmp_path, data_dir):
    outside = copy_tree(data_dir / "kicad6/Diode_SMD", tmp_path / "outside")
    (tree / "x.wrl").symlink_to("/etc/passwd")
    (tree / "diodes").symlink_to(outside, target_is_directory=True)
    (tree / "inside.wrl").symlink_to(sorted((tree / "LED_SMD").iterdir())[0])
    store = tmp_path / "s.h5"
    result = build(tree, store, "--json")
    assert result.exit_code == 0, result.stderr
    with open_store(store) as reader:
        paths = list(reader.paths)
        reasons = list(reader.column("entries/reason"))
    assert "x.wrl" not in paths and not any(p.startswith("diodes/") for p in paths)
    assert "inside.wrl" in paths and len(paths) == 11
    assert "root:" not in result.stderr + "".join(reasons)
    assert result.stderr.count("a symbolic link out of the indexed folder") == 2
    followed = build(tree, store, "--follow-outside-links", "--json")
    data = json.loads(followed.stdout)
    assert data["indexed"] == 10 and data["failed"] == 1
    assert "root:" not in json.dumps(data) + followed.stderr  # what /etc/passwd holds is not quoted
    kept = build(tree, store, "--json")  # without the option again: their entries stay
    assert json.loads(kept.stdout)["removed"] == 0


def test_a_newline_in_a_file_name_cannot_forge_a_log_line(tree, data_dir, tmp_path):
    shutil.copy(data_dir / BROKEN, tree / "evil\n2026-01-01T00:00:00+0000 shapeidx build: all fine.stl")
    result = run_shapeidx("build", tree, "--store", tmp_path / "s.h5", "--points", FAST_POINTS)
    lines = result.stderr.splitlines()
    assert all(LOG_LINE.match(line) for line in lines)
    assert sum("evil\\n2026" in line for line in lines) == 1
