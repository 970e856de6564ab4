"""Real processes: kill -9 of a build, dying and hanging workers, two builds, queries meanwhile."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time

import pytest
from clitools import run_shapeidx, shapeidx_command
from storetools import (
    FAST_POINTS,
    copy_tree,
    cpu_seconds,
    load_script,
    slow_assembly,
    small_kicad,
    summary_counts,
)

from shapeidx.api import query as query_store
from shapeidx.errors import StoreError
from shapeidx.store.writer import GROWTH
from shapeidx.store import STATUS_FAILED, open_store

KILL_FOLDERS = ("Capacitor_Tantalum_SMD", "Diode_SMD", "LED_SMD", "Relay_THT", "Inductor_SMD", "Resistor_THT")


def test_kill_9_at_random_moments(data_dir, tmp_path):
    """The heart of crash safety; see scripts/kill_build.py for what is checked after each kill."""
    kill_build = load_script("kill_build")
    tree = small_kicad(data_dir, tmp_path, KILL_FOLDERS)
    seed = int(os.environ.get("SHAPEIDX_KILL_SEED", random.randrange(10**6)))
    print(f"kill seed {seed} (set SHAPEIDX_KILL_SEED to repeat)")
    report = kill_build.kill_campaign(tree, tmp_path / "s.h5", kills=6, seed=seed,
                                      build_args=("--points", "256"), log_dir=tmp_path)
    print(report)
    assert report["entries"] == 60
    assert report["mid_merge"] >= 1, "no kill landed while a merged main file was being written"


def test_kill_9_of_a_parts_build_at_random_moments(data_dir, tmp_path):
    """``build --parts`` killed while signing sub-parts and while either store merges: after
    each kill ``check --store`` is ok, no sub-entry reported committed is lost, where-used
    answers, and the next build plans exactly the files without their whole entry or
    sub-entries; the last build gives every file its sub-entries and one more does nothing
    (scripts/kill_build.py ``--parts``). Its log names the parts store's commits apart
    (``committed sub-parts batch``): the bound on what a kill may lose is counted from them."""
    pytest.importorskip("OCP")
    kill_build = load_script("kill_build")
    tree = copy_tree(data_dir / "kicad6-step", tmp_path / "tree", ["Transformer_THT", "Relay_THT"])
    seed = int(os.environ.get("SHAPEIDX_KILL_SEED", random.randrange(10**6)))
    print(f"kill seed {seed} (set SHAPEIDX_KILL_SEED to repeat)")
    report = kill_build.kill_campaign(tree, tmp_path / "s.shapeidx", kills=8, seed=seed, parts=True,
                                      build_args=("--points", "128", "--workers", "1"), log_dir=tmp_path)
    print(report)
    assert report["entries"] == 20 and report["sub_entries"] == 40
    assert report["parts_merges"] >= 1, "no kill landed while a merge of the parts store was being written"
    logs = "".join(p.read_text() for p in tmp_path.glob("build-*.log"))
    assert kill_build.committed_records(logs, kill_build.PARTS_COMMITTED) > 0


def build_process(tree, store, *extra, **popen):
    return subprocess.Popen(
        shapeidx_command("build", tree, "--store", store, "--points", FAST_POINTS, *extra),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint, **popen,
    )


def _default_sigint():
    # A build run from a terminal gets Ctrl-C; a test run from a background job (as CI may
    # be) would pass on the ignored SIGINT that shells give such jobs, and Python would
    # then never raise KeyboardInterrupt.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def worker_pids(build_pid: int) -> list[int]:
    kill_build = load_script("kill_build")
    return [pid for pid in kill_build.children_of(build_pid)
            if b"spawn_main" in open(f"/proc/{pid}/cmdline", "rb").read()]


def test_a_worker_that_dies_costs_only_its_file(data_dir, tmp_path):
    """SIGSEGV in the middle of a file, as a crash in a native library would end a worker."""
    tree = small_kicad(data_dir, tmp_path, ["Diode_SMD"])
    slow_assembly(data_dir, tree / "0_assembly.stl")  # sorted first: the one worker's first file
    proc = build_process(tree, tmp_path / "s.h5", "--workers", "1")
    deadline = time.monotonic() + 120
    while True:  # the worker is busy on the assembly once it has used more CPU than starting takes
        assert proc.poll() is None and time.monotonic() < deadline, "no worker got busy"
        workers = worker_pids(proc.pid)
        if workers and cpu_seconds(workers[0]) > 2.0:
            break
        time.sleep(0.05)
    os.kill(workers[0], signal.SIGSEGV)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert summary_counts(out) == {"indexed": 10, "unchanged": 0, "removed": 0, "failed": 1}
    assert "failed 0_assembly.stl: worker process died (SIGSEGV) while indexing this file" in err
    with open_store(tmp_path / "s.h5") as reader:
        i = reader.index_of("0_assembly.stl")
        assert reader.column("entries/status")[i] == STATUS_FAILED
        assert "SIGSEGV" in reader.column("entries/reason")[i]


def test_a_file_over_the_time_limit_is_failed_and_the_build_goes_on(data_dir, tmp_path):
    tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
    slow_assembly(data_dir, tree / "0_assembly.stl")
    started = time.monotonic()
    result = run_shapeidx("build", tree, "--store", tmp_path / "s.h5", "--points", FAST_POINTS, "--timeout", "2")
    assert result.returncode == 0, result.stderr
    assert summary_counts(result.stdout) == {"indexed": 10, "unchanged": 0, "removed": 0, "failed": 1}
    assert "failed 0_assembly.stl: timed out after 2 s" in result.stderr
    assert time.monotonic() - started < 60
    again = run_shapeidx("build", tree, "--store", tmp_path / "s.h5")  # not retried until it changes
    assert summary_counts(again.stdout)["unchanged"] == 11


class TestTwoBuilds:
    def test_started_together_one_refuses_and_the_store_is_whole(self, data_dir, tmp_path):
        tree = small_kicad(data_dir, tmp_path, ["Diode_SMD", "LED_SMD", "Relay_THT"])
        store = tmp_path / "s.h5"
        first, second = (build_process(tree, store, "--workers", "1") for _ in range(2))
        results = [(p.wait(timeout=300), *p.communicate()) for p in (first, second)]
        assert sorted(code for code, _, _ in results) == [0, 4], results  # 4: locked by another build
        _, _, refusal = next(r for r in results if r[0] == 4)
        assert "another build is writing s.h5 (pid " in refusal and "--wait" in refusal
        assert refusal.count("\n") == 1  # one line
        with open_store(store) as reader:
            assert len(reader) == len(set(reader.paths)) == 30

    def test_with_wait_the_second_finds_nothing_to_do(self, data_dir, tmp_path):
        tree = small_kicad(data_dir, tmp_path, ["Diode_SMD", "LED_SMD"])
        store = tmp_path / "s.h5"
        first, second = (build_process(tree, store, "--wait", "--workers", "1") for _ in range(2))
        outs = [p.communicate(timeout=300) for p in (first, second)]
        assert first.returncode == second.returncode == 0
        counts = sorted((summary_counts(out) for out, _ in outs), key=lambda c: c["indexed"])
        assert counts == [{"indexed": 0, "unchanged": 20, "removed": 0, "failed": 0},
                          {"indexed": 20, "unchanged": 0, "removed": 0, "failed": 0}]
        assert any("waiting for the store's lock" in err for _, err in outs)


def test_queries_keep_working_while_a_build_runs(data_dir, tmp_path):
    tree = small_kicad(data_dir, tmp_path, ["Diode_SMD", "LED_SMD", "Relay_THT", "Inductor_SMD"])
    probe = copy_tree(tree / "Diode_SMD", tmp_path / "probe", [sorted(os.listdir(tree / "Diode_SMD"))[0]])
    store = tmp_path / "s.h5"
    proc = build_process(tree, store, "--commit-interval", "0.1", "--merge-after", "2", "--points", "256")
    sizes, answered = [], 0
    try:
        while proc.poll() is None:
            try:
                with open_store(store) as reader:
                    sizes.append(len(reader))
            except StoreError as exc:
                assert "no store at" in str(exc) or "being created" in str(exc)  # only before the build created it
                time.sleep(0.02)
                continue
            hits = query_store(store, part=next(probe.iterdir()), top=3)
            assert min(3, sizes[-1]) <= len(hits) <= 3  # it may have grown meanwhile
            answered += 1
    finally:
        out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert sizes == sorted(sizes), "a reader saw entries disappear"
    assert answered >= 5 and len(set(sizes)) >= 3, (answered, sizes)
    final = query_store(store, part=next(probe.iterdir()), top=1)
    assert final[0]["distance"] == 0.0 and final[0]["relative_path"].startswith("Diode_SMD/")
    stats = json.loads(run_shapeidx("stats", "--store", store, "--json").stdout)
    assert stats["entries"] == 40
    with open_store(store) as reader:  # merges are size-tiered: the segments left grow geometrically
        rows = [len(source) for source in reader._sources]
        assert all(older > GROWTH * newer for older, newer in zip(rows, rows[1:])), rows


@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGINT"])
def test_a_stopped_build_commits_what_it_did(data_dir, tmp_path, signal_name):
    """SIGTERM (cron's timeout) and Ctrl-C end the build cleanly, keeping finished work."""
    tree = small_kicad(data_dir, tmp_path, ["Diode_SMD", "LED_SMD", "Relay_THT"])
    proc = build_process(tree, tmp_path / "s.h5", "--verbose", "--points", "512", "--workers", "1")
    indexed = 0
    while indexed < 3:
        line = proc.stderr.readline()
        assert line, "the build ended before it was stopped"
        indexed += "shapeidx build: indexed " in line  # after the timestamp
    proc.send_signal(getattr(signal, signal_name))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "interrupted" in err
    with open_store(tmp_path / "s.h5") as reader:
        assert len(reader) >= 3


def test_workers_that_cannot_run_stop_the_build_instead_of_failing_every_file(data_dir, tmp_path):
    """A worker whose Python fails (a broken installation) is the build's failure, not the files'."""
    tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
    script = tmp_path / "run_shapeidx.py"
    script.write_text(
        "import sys\n"
        "if __name__ == '__mp_main__':  # each worker re-imports the main script: make it fail there\n"
        "    raise SystemExit(3)\n"
        "from shapeidx.cli import main\n"
        "sys.exit(main())\n"
    )
    run = subprocess.run([sys.executable, str(script), "build", str(tree), "--store", str(tmp_path / "s.h5"),
                          "--points", FAST_POINTS], capture_output=True, text=True, timeout=120)
    assert run.returncode == 1
    assert "shapeidx: error: a worker process failed to run (exit status 3)" in run.stderr
    with open_store(tmp_path / "s.h5") as reader:
        assert len(reader) == 0  # no file was recorded as failed
