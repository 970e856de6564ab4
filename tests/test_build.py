"""``shapeidx build``: incremental runs on real parts, walking rules, failures, options, output."""

from __future__ import annotations

import gzip
import os
import pty
import re
import shutil
import subprocess

import numpy as np
from clitools import cli, shapeidx_command
from storetools import (
    FAST_POINTS,
    build,
    copy_tree,
    small_kicad,
    summary_counts,
)

from shapeidx.index.build import BuildOptions
from shapeidx.index.plan import make_plan
from shapeidx.index.walk import walk_parts
from shapeidx.store import STATUS_FAILED, STATUS_OK, open_store

BROKEN = "mesh-wild/openscad-testdata/testdata/stl/unparseable.stl"


def entries(store) -> dict:
    """path -> (status, reason, hash, size, mtime_ns) of every entry."""
    with open_store(store) as r:
        columns = [r.column(f"entries/{c}") for c in ("status", "reason", "hash", "size", "mtime_ns")]
        return {p: tuple(col[i] for col in columns) for i, p in enumerate(r.paths)}


def signature_of(store, path):
    with open_store(store) as r:
        return r.signature(r.index_of(path))


class TestIncremental:
    """The issue's check: build, build again, touch, change, delete, add a broken file."""

    def test_each_run_summary_and_store(self, data_dir, tmp_path):
        tree = small_kicad(data_dir, tmp_path)
        store = tmp_path / "s.h5"
        files = sorted(p.relative_to(tree).as_posix() for p in tree.rglob("*.wrl"))
        assert len(files) == 30

        first = build(tree, store)
        assert first.exit_code == 0, first.output
        assert summary_counts(first.stdout) == {"indexed": 30, "unchanged": 0, "removed": 0, "failed": 0}
        assert "store: 30 ok, 0 failed" in first.stdout
        after_first = entries(store)
        assert sorted(after_first) == files
        assert {e[0] for e in after_first.values()} == {STATUS_OK}

        main_file = os.stat(store)
        again = build(tree, store)
        assert summary_counts(again.stdout) == {"indexed": 0, "unchanged": 30, "removed": 0, "failed": 0}
        assert "0 new or changed, 30 unchanged" in again.stderr
        assert os.stat(store).st_ino == main_file.st_ino, "a build with nothing to do rewrote the store"

        touched, changed, deleted = files[0], files[11], files[22]
        os.utime(tree / touched, ns=(10**18, 10**18))
        shutil.copy(tree / files[12], tree / changed)  # other content, same name
        (tree / deleted).unlink()
        shutil.copy(data_dir / BROKEN, tree / "Diode_SMD" / "broken.stl")
        sig_changed_before = signature_of(store, changed)

        third = build(tree, store)
        assert third.exit_code == 0, third.output
        assert summary_counts(third.stdout) == {"indexed": 1, "unchanged": 28, "removed": 1, "failed": 1}
        assert "failed Diode_SMD/broken.stl: " in third.stderr
        now = entries(store)
        assert sorted(now) == sorted(set(files) - {deleted} | {"Diode_SMD/broken.stl"})
        assert now[touched][4] == 10**18 and now[touched][2] == after_first[touched][2]
        assert now[changed][2] != after_first[changed][2]
        assert now[changed][2] == now[files[12]][2]
        assert signature_of(store, changed).histograms["all"].counts.tolist() == \
            signature_of(store, files[12]).histograms["all"].counts.tolist()
        assert signature_of(store, changed).histograms["all"].counts.tolist() != \
            sig_changed_before.histograms["all"].counts.tolist()
        status, reason = now["Diode_SMD/broken.stl"][:2]
        assert status == STATUS_FAILED and reason and "\n" not in reason and str(tree) not in reason

        fourth = build(tree, store)  # the broken file is not retried until it changes
        assert summary_counts(fourth.stdout) == {"indexed": 0, "unchanged": 30, "removed": 0, "failed": 0}
        assert "store: 29 ok, 1 failed" in fourth.stdout
        retried = build(tree, store, "--retry-failed")
        assert summary_counts(retried.stdout)["failed"] == 1

        full = build(tree, store, "--full")
        assert summary_counts(full.stdout) == {"indexed": 29, "unchanged": 0, "removed": 0, "failed": 1}
        assert entries(store).keys() == now.keys()

    def test_rehash_finds_content_changed_behind_unchanged_times(self, data_dir, tmp_path):
        tree = small_kicad(data_dir, tmp_path, ["Diode_SMD"])
        store = tmp_path / "s.h5"
        build(tree, store)
        a, b = sorted(tree.rglob("*.wrl"))[:2]
        stat = a.stat()
        data = b.read_bytes()[: stat.st_size].ljust(stat.st_size, b" ")  # same size, other content
        a.write_bytes(data)
        os.utime(a, ns=(stat.st_atime_ns, stat.st_mtime_ns))
        assert summary_counts(build(tree, store).stdout)["indexed"] == 0  # size and time say unchanged
        rehashed = build(tree, store, "--rehash")
        counts = summary_counts(rehashed.stdout)
        assert counts["indexed"] + counts["failed"] == 1 and counts["unchanged"] == 9

    def test_other_parameters_are_refused_and_the_store_kept(self, data_dir, tmp_path):
        tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
        store = tmp_path / "s.h5"
        build(tree, store)
        before = entries(store)
        refused = cli("build", tree, "--store", store, "--points", "256")
        assert refused.exit_code == 1
        assert "points=128 (asked: 256)" in refused.stderr and "another --store" in refused.stderr
        assert entries(store) == before
        default = cli("build", tree, "--store", store)  # no --points: the store's own
        assert default.exit_code == 0 and summary_counts(default.stdout)["unchanged"] == 10


class TestWalk:
    def test_formats_hidden_gzip_and_symlinks(self, data_dir, tmp_path):
        tree = copy_tree(data_dir / "mesh-wild/trimesh-models", tmp_path / "t", ["box.STL", "featuretype.STL"])
        (tree / "sub").mkdir()
        shutil.copy(data_dir / "mesh-wild/assimp-testmodels/usr/share/assimp/models/OFF/Cube.off", tree / "sub")
        (tree / "sub/cube.off.gz").write_bytes(gzip.compress((tree / "sub/Cube.off").read_bytes()))
        (tree / "sub/notes.txt").write_text("not a part")
        (tree / ".hidden").mkdir()
        shutil.copy(tree / "box.STL", tree / ".hidden/box.STL")
        shutil.copy(tree / "box.STL", tree / ".box.STL")
        (tree / "sub/loop").symlink_to(tree, target_is_directory=True)
        (tree / "again").symlink_to(tree / "sub", target_is_directory=True)
        (tree / "link.stl").symlink_to(tree / "box.STL")
        (tree / "dangling.stl").symlink_to(tree / "missing.stl")
        walk = walk_parts(tree)
        assert [f.path for f in walk.files] == ["box.STL", "featuretype.STL", "link.stl", "sub/Cube.off",
                                                 "sub/cube.off.gz"]
        assert any("dangling.stl" in w for w in walk.warnings)

        result = build(tree, tmp_path / "s.h5")
        assert result.exit_code == 0, result.output
        assert summary_counts(result.stdout) == {"indexed": 5, "unchanged": 0, "removed": 0, "failed": 0}
        assert "warning: skipped dangling.stl" in result.stderr

    def test_an_unlistable_folder_does_not_remove_its_entries(self, data_dir, tmp_path):
        """A folder that cannot be listed (permissions, a network glitch) is not a deletion."""
        tree = small_kicad(data_dir, tmp_path, ["Diode_SMD", "LED_SMD"])
        store = tmp_path / "s.h5"
        build(tree, store)
        walk = walk_parts(tree.resolve())
        walk.files = [f for f in walk.files if not f.path.startswith("LED_SMD/")]
        walk.unlisted = ["LED_SMD"]
        with open_store(store) as reader:
            assert make_plan(walk, reader, BuildOptions()).removed == []
            walk.unlisted = ["Diode_SMD"]  # a sibling: LED_SMD's files are then really gone
            assert len(make_plan(walk, reader, BuildOptions()).removed) == 10


class TestFailures:
    def test_broken_real_files_are_recorded_and_the_build_goes_on(self, data_dir, tmp_path):
        broken = data_dir / "mesh-wild/openscad-testdata/testdata/stl"
        tree = copy_tree(broken, tmp_path / "t")
        copy_tree(data_dir / "kicad6", tree, ["Diode_SMD"])
        store = tmp_path / "s.h5"
        result = build(tree, store)
        assert result.exit_code == 0, result.output
        found = entries(store)
        failed = {p: e[1] for p, e in found.items() if e[0] == STATUS_FAILED}
        assert {"empty.stl", "empty2.stl", "unparseable.stl", "invalidvertex.stl"} <= set(failed)
        assert all(reason and "\n" not in reason for reason in failed.values())
        assert sum(e[0] == STATUS_OK for e in found.values()) >= 10
        assert summary_counts(result.stdout)["failed"] == len(failed)
        assert len(re.findall(r"^\S+ shapeidx build: failed ", result.stderr, re.M)) == len(failed)

    def test_strict_exit_status(self, data_dir, tmp_path):
        tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
        store = tmp_path / "s.h5"
        assert build(tree, store, "--strict").exit_code == 0
        shutil.copy(data_dir / BROKEN, tree / "broken.stl")
        assert build(tree, store).exit_code == 0
        assert build(tree, store, "--strict").exit_code == 3  # still failed, though not retried

    def test_the_build_itself_failing(self, data_dir, tmp_path):
        missing = cli("build", tmp_path / "nope", "--store", tmp_path / "s.h5")
        assert missing.exit_code != 0 and "nope" in missing.stderr
        (tmp_path / "t").mkdir()
        shutil.copy(data_dir / BROKEN, tmp_path / "t" / "broken.stl")
        nowhere = cli("build", tmp_path / "t", "--store", tmp_path / "no/such/dir/s.h5")
        assert nowhere.exit_code == 1 and "no directory" in nowhere.stderr
        assert not (tmp_path / "no").exists()


class TestOutput:
    def test_log_lines_quiet_and_verbose(self, data_dir, tmp_path):
        tree = small_kicad(data_dir, tmp_path, ["Diode_SMD"])
        shutil.copy(data_dir / BROKEN, tree / "broken.stl")
        verbose = build(tree, tmp_path / "a.h5", "--verbose")
        assert verbose.stderr.count("indexed Diode_SMD/") == 10
        assert "committed batch 1 (11 records)" in verbose.stderr and "failed broken.stl: " in verbose.stderr
        normal = build(tree, tmp_path / "b.h5")
        assert "indexed Diode_SMD/" not in normal.stderr and "failed broken.stl: " in normal.stderr
        assert "\r" not in normal.stderr  # no progress bar when not on a terminal
        quiet = build(tree, tmp_path / "c.h5", "--quiet")  # a file failing for the first time is news
        assert quiet.exit_code == 0 and quiet.stdout == ""
        assert len(quiet.stderr.splitlines()) == 1 and "shapeidx build: failed broken.stl: " in quiet.stderr
        again = build(tree, tmp_path / "c.h5", "--quiet", "--retry-failed")  # failing again is not
        assert again.exit_code == 0 and again.stdout == "" and again.stderr == ""

    def test_progress_bar_on_a_terminal(self, data_dir, tmp_path):
        tree = small_kicad(data_dir, tmp_path, ["Diode_SMD"])
        leader, follower = pty.openpty()
        proc = subprocess.Popen(
            shapeidx_command("build", tree, "--store", tmp_path / "s.h5", "--points", FAST_POINTS),
            stdout=subprocess.PIPE, stderr=follower, text=True,
        )
        os.close(follower)
        seen = b""
        while True:
            try:
                chunk = os.read(leader, 4096)
            except OSError:  # the terminal closed with the process
                break
            if not chunk:
                break
            seen += chunk
        os.close(leader)
        assert proc.wait(timeout=120) == 0
        text = seen.decode()
        assert "10/10" in text and "files/s" in text and "\r" in text
        assert "indexed" in proc.stdout.read()


def test_workers_use_separate_processes_and_agree_with_one(data_dir, tmp_path):
    """Parallel and serial builds give the same store (the seed policy is fixed)."""
    tree = small_kicad(data_dir, tmp_path, ["LED_SMD", "Diode_SMD"])
    one = build(tree, tmp_path / "one.h5", "--workers", "1")
    two = build(tree, tmp_path / "two.h5", "--workers", "2")
    assert one.exit_code == two.exit_code == 0
    with open_store(tmp_path / "one.h5") as a, open_store(tmp_path / "two.h5") as b:
        assert list(a.paths) == list(b.paths)
        for name in ("all", "mixed"):
            assert np.array_equal(a.counts(name)[0], b.counts(name)[0])


def test_json_profile_accounts_for_the_workers_cpu(data_dir, tmp_path):
    """``build --json`` says where the CPU went: every stage a file passes through, the
    processes started, and stages that add up to no more than the processes' own CPU time
    (counted by the kernel, not by the build's clocks)."""
    import json

    tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
    result = build(tree, tmp_path / "p.shapeidx", "--workers", "2", "--json", "-q")
    assert result.exit_code == 0
    profile = json.loads(result.stdout)["profile"]
    cpu = profile["cpu_seconds"]
    assert profile["workers_started"] == 2
    named = {k: v for k, v in cpu["workers"].items() if k != "other"}
    assert {"hash", "load", "solid", "signature", "facts"} <= set(named)
    assert all(v >= 0 for v in cpu["workers"].values()) and named["signature"] > 0
    assert sum(named.values()) <= cpu["workers_total"] + 0.05
    assert abs(sum(cpu["workers"].values()) - cpu["workers_total"]) < 0.05
    assert {"start", "setup", "commit", "progress", "other"} == set(cpu["parent"])
    assert abs(sum(cpu["parent"].values()) - cpu["parent_total"]) < 0.01
    unchanged = json.loads(build(tree, tmp_path / "p.shapeidx", "--workers", "2", "--json", "-q").stdout)
    assert unchanged["indexed"] == 0 and unchanged["profile"]["workers_started"] == 0
