"""A store is one thing: a directory a user copies, moves or archives, which then answers
exactly as the original; a store missing part of itself is refused, never answered from
fewer entries; ``stats`` tells a stopped build from a finished one; a store of the older
one-file layout is converted by the next build."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import time

import pytest
from clitools import cli, cli_json
from storetools import build, small_kicad

from shapeidx.console import exits
from shapeidx.store.files import batch_files, journal_dir, main_file


PARTS = 24


@pytest.fixture(scope="module")
def built(data_dir, tmp_path_factory):
    """A store of 24 KiCad parts: 20 in its main file, 3 and 1 in two journal segments (a
    build adding few files to a larger store leaves its segments: size-tiered, not folded)."""
    tmp = tmp_path_factory.mktemp("unit")
    tree = small_kicad(data_dir, tmp)
    store = tmp / "s.shapeidx"
    last = sorted(p.name for p in tree.iterdir())[-1]
    later = sorted((tree / last).iterdir())
    hidden = tmp / "later"
    hidden.mkdir()
    for path in later:
        shutil.move(str(path), hidden / path.name)
    assert build(tree, store).exit_code == 0  # 20 parts: the first build folds them into the main file
    for added in (later[:3], later[3:4]):
        for path in added:
            shutil.move(str(hidden / path.name), path)
        assert build(tree, store).exit_code == 0
    assert len(batch_files(store)) == 2 and len(list(tree.rglob("*.wrl"))) == PARTS
    return tree, store


def answers(store, tree):
    parts = sorted(p.relative_to(tree).as_posix() for p in tree.rglob("*.wrl"))[::6]
    out = []
    for part in parts:
        for metric in ("weighted", "combined-angle"):
            answer = cli_json("query", "--id", part, "--store", store, "--top", "8", "--metric", metric)
            out.append([(h["relative_path"], h["distance"]) for h in answer["hits"]])
    return out


def test_a_copy_a_move_and_a_tar_of_the_directory_answer_exactly_as_the_original(built, tmp_path):
    tree, store = built
    expected = answers(store, tree)
    assert len(expected) >= 8 and all(len(hits) == 8 for hits in expected)
    copied = tmp_path / "copied.shapeidx"
    subprocess.run(["cp", "-a", str(store), str(copied)], check=True)
    assert answers(copied, tree) == expected
    moved = tmp_path / "elsewhere" / "moved.shapeidx"
    moved.parent.mkdir()
    shutil.move(str(copied), moved)
    assert answers(moved, tree) == expected
    archive = tmp_path / "store.tar"
    with tarfile.open(archive, "w") as tar:
        tar.add(moved, arcname="restored.shapeidx")
    with tarfile.open(archive) as tar:
        tar.extractall(tmp_path / "untarred", filter="data")
    restored = tmp_path / "untarred" / "restored.shapeidx"
    assert answers(restored, tree) == expected
    facts = cli_json("stats", "--store", restored)
    assert facts["entries"] == PARTS and facts["build"]["state"] == "finished"
    assert cli("check", "--store", restored).exit_code == 0


def test_the_first_build_leaves_everything_in_the_main_file(data_dir, tmp_path):
    tree = small_kicad(data_dir, tmp_path, ["Battery"])
    store = tmp_path / "s.shapeidx"
    assert build(tree, store, "--commit-interval", "0.05").exit_code == 0
    assert not journal_dir(store).exists() and not batch_files(store)
    import h5py

    with h5py.File(main_file(store), "r") as f:  # readable with h5py alone, as the README shows
        assert len(f["entries/path"]) == len(list(tree.rglob("*.wrl")))


@pytest.mark.parametrize("damage", ["middle segment", "newest segment", "main file", "damaged segment"])
def test_a_store_missing_part_of_itself_is_refused_with_status_5(built, tmp_path, damage):
    tree, store = built
    copy = tmp_path / "s.shapeidx"
    shutil.copytree(store, copy)
    segments = [path for _, path in batch_files(copy)]
    assert len(segments) == 2, segments
    if damage == "middle segment":
        segments[0].unlink()
    elif damage == "newest segment":
        segments[-1].unlink()
    elif damage == "main file":
        main_file(copy).unlink()
    else:
        data = segments[0].read_bytes()
        segments[0].write_bytes(data[: len(data) // 2])  # cut short
    part = next(iter(sorted(tree.rglob("*.wrl"))))
    for command in (("query", part, "--store", copy), ("stats", "--store", copy), ("check", "--store", copy),
                    ("classify", part, "--store", copy)):
        result = cli(*command)
        assert result.exit_code == exits.DAMAGED, (damage, command, result.stdout, result.stderr)
        said = result.stderr + result.stdout
        assert ("damaged" in said or "DAMAGED" in said) and "Traceback" not in said
    # the next build with --repair mends it: it indexes the lost entries' files again
    mended = cli("build", tree, "--store", copy, "--repair")
    assert mended.exit_code == 0, mended.stderr
    assert cli_json("stats", "--store", copy)["entries"] == PARTS
    assert answers(copy, tree) == answers(store, tree)


def test_stats_tells_a_stopped_build_from_a_finished_one(data_dir, tmp_path):
    tree = small_kicad(data_dir, tmp_path)
    store = tmp_path / "s.shapeidx"
    command = [sys.executable, "-m", "shapeidx.cli", "build", str(tree), "--store", str(store), "--points", "256",
               "--commit-interval", "0.05", "--workers", "1"]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and not batch_files(store):
        time.sleep(0.05)
    running = cli_json("stats", "--store", store)
    assert running["build"]["state"] == "running" and running["build"]["pid"] == proc.pid
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    stopped = cli("stats", "--store", store)
    assert stopped.exit_code == 0 and "stopped before it finished" in stopped.stdout
    assert cli_json("stats", "--store", store)["build"]["state"] == "stopped"
    again = cli("build", tree, "--store", store)  # the store's own parameters: what was committed is kept
    assert again.exit_code == 0, again.stderr
    finished = cli_json("stats", "--store", store)
    assert finished["build"]["state"] == "finished" and finished["entries"] == 30
    assert "0 indexed" not in again.stdout.split(";")[0] or finished["entries"] == 30


def test_a_one_file_store_is_refused_in_one_line_and_converted_by_the_next_build(built, tmp_path):
    """The older layout: the main file at STORE, its journal at STORE.journal/."""
    tree, store = built
    expected = answers(store, tree)
    old = tmp_path / "old.h5"
    shutil.copy(main_file(store), old)
    shutil.copytree(journal_dir(store), tmp_path / "old.h5.journal")
    refused = cli("query", "--id", "x", "--store", old)
    assert refused.exit_code == exits.ERROR and "one-file layout" in refused.stderr and "build" in refused.stderr
    assert len(refused.stderr.strip().splitlines()) == 1
    converted = cli("build", tree, "--store", old)
    assert converted.exit_code == 0, converted.stderr
    assert "converted" in converted.stderr and "0 indexed" in converted.stdout  # renames only: nothing signed again
    assert old.is_dir() and main_file(old).exists() and not (tmp_path / "old.h5.journal").exists()
    assert answers(old, tree) == expected


def test_a_folder_of_other_files_is_not_made_a_store(data_dir, tmp_path):
    tree = small_kicad(data_dir, tmp_path, ["Battery"])
    result = cli("build", tree, "--store", tree)  # --store naming the parts folder by mistake
    assert result.exit_code == exits.ERROR and "not a shapeidx store" in result.stderr
    assert not main_file(tree).exists()
    not_a_store = tmp_path / "plain.txt"
    not_a_store.write_text("hello")
    for command in (("stats", "--store", not_a_store), ("build", tree, "--store", not_a_store)):
        result = cli(*command)
        assert result.exit_code == exits.ERROR and "not a shapeidx store" in result.stderr


def test_a_query_of_a_store_with_no_entry_yet_says_why_with_status_6(data_dir, tmp_path):
    """A build that was stopped before its first commit leaves an empty store."""
    tree = small_kicad(data_dir, tmp_path, ["Battery"])
    store = tmp_path / "s.shapeidx"
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "x.stl").write_bytes(b"not a part")
    assert cli("build", empty, "--store", store).exit_code == 0  # one failed file, no ok entry
    part = next(tree.rglob("*.wrl"))
    result = cli("query", part, "--store", store)
    assert result.exit_code == exits.NO_ANSWER and "could be indexed" in result.stderr
    listed = cli("stats", "--store", store, "--failed")
    assert listed.exit_code == 0 and "x.stl" in listed.stdout
    data = json.loads(cli("query", part, "--store", store, "--json").stdout)
    assert data["hits"] == [] and data["reason"]
