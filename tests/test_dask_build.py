"""Distributed builds (``shapeidx build --scheduler``) against a real local Dask cluster.

The cluster is real processes: ``dask scheduler`` and two ``dask worker`` processes (the
command-line tools of the ``distributed`` package) on 127.0.0.1 with free ports, each in
its own process group, killed with it whatever happens to the tests.
"""

from __future__ import annotations

import json
import os
import random
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from clitools import run_shapeidx, shapeidx_command
from storetools import FAST_POINTS, copy_tree, cpu_seconds, load_script, slow_assembly, small_kicad, summary_counts

from shapeidx.errors import StoreError
from shapeidx.api import query as query_store
from shapeidx.signing.parameters import HISTOGRAMS
from shapeidx.store import STATUS_OK, open_store

#: A --verbose line for one indexed file, e.g. "... shapeidx build: indexed a/b.wrl (0.1s)".
INDEXED = re.compile(r"\bindexed \S.* \([\d.]+s\)$")

distributed = pytest.importorskip("distributed", reason="distributed builds need pip install 'shapeidx[dask]'")

FOLDERS = ("Diode_SMD", "LED_SMD")
COMMITTED = re.compile(r"committed batch \d+ \((\d+) records\)")


class LocalCluster:
    """A scheduler and ``workers`` single-thread workers as real processes (see the module docstring)."""

    def __init__(self, folder: Path, workers: int = 2, env: dict | None = None):
        self.folder = folder
        self.env = {**os.environ, **(env or {})}
        self.processes: list[subprocess.Popen] = []
        self.nannies: list[subprocess.Popen] = []
        dask = Path(sys.executable).with_name("dask")
        self.dask = [str(dask)] if dask.exists() else [sys.executable, "-m", "dask"]
        folder.mkdir(parents=True, exist_ok=True)
        try:
            self._start_all(workers)
        except BaseException:
            self.stop()  # nothing outlives a cluster that did not start
            raise

    def _start_all(self, workers: int) -> None:
        folder = self.folder
        scheduler_file = folder / "scheduler.json"
        self._start("scheduler", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                    "--scheduler-file", scheduler_file)
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() or not scheduler_file.read_text().strip().endswith("}"):
            assert time.monotonic() < deadline, (folder / "scheduler.log").read_text()
            assert self.processes[0].poll() is None, (folder / "scheduler.log").read_text()
            time.sleep(0.1)
        self.address = json.loads(scheduler_file.read_text())["address"]
        for i in range(workers):
            self.nannies.append(self._start(f"worker-{i}", "worker", "--scheduler-file", scheduler_file,
                                            "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard",
                                            "--local-directory", folder / f"worker-{i}", "--name", f"w{i}"))
        self.wait_for_workers(workers)

    def _start(self, name: str, *args) -> subprocess.Popen:
        log = open(self.folder / f"{name}.log", "w")
        proc = subprocess.Popen([*self.dask, *map(str, args)], stdout=log, stderr=subprocess.STDOUT,
                                env=self.env, start_new_session=True)  # its own process group: killed whole
        log.close()
        self.processes.append(proc)
        return proc

    def wait_for_workers(self, n: int, timeout: float = 90) -> None:
        with distributed.Client(self.address, timeout=30, set_as_default=False) as client:
            client.wait_for_workers(n, timeout=timeout)

    def worker_processes(self) -> list[int]:
        """The worker processes the nannies run (the ones that run the tasks)."""
        kill_build = load_script("kill_build")
        return [pid for nanny in self.nannies for pid in kill_build.children_of(nanny.pid)
                if b"spawn_main" in _cmdline(pid)]

    def indexing_processes(self) -> list[int]:
        """The workers' indexing processes (shapeidx.index.remote): this cluster's only, never another's."""
        kill_build = load_script("kill_build")
        return [pid for worker in self.worker_processes() for pid in kill_build.children_of(worker)
                if b"shapeidx.index.remote" in _cmdline(pid)]

    def stop(self) -> None:
        for proc in self.processes:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    folder = tmp_path_factory.mktemp("dask")
    cluster = LocalCluster(folder)
    try:
        yield cluster
    finally:
        cluster.stop()


@pytest.fixture(scope="module")
def reference(data_dir, tmp_path_factory):
    """The tree (20 kicad6 parts) and its store built locally, the ordinary way."""
    tmp = tmp_path_factory.mktemp("reference")
    tree = small_kicad(data_dir, tmp, FOLDERS)
    store = tmp / "local.h5"
    run = run_shapeidx("build", tree, "--store", store, "--points", FAST_POINTS)
    assert run.returncode == 0, run.stderr
    return tree, store


def tree_copy(reference, tmp_path: Path) -> Path:
    return copy_tree(reference[0], tmp_path / "parts")


def dask_build(tree, store, cluster, *extra, **popen):
    return subprocess.Popen(shapeidx_command("build", tree, "--store", store, "--points", FAST_POINTS,
                                             "--scheduler", cluster.address, *extra),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen)


def assert_same_signatures(store: Path, local: Path) -> None:
    """Every file once, ok, with bit for bit the signature a local build gave it."""
    with open_store(store) as got, open_store(local) as want:
        assert list(got.paths) == list(want.paths)
        assert np.all(got.column("entries/status") == STATUS_OK)
        for name in ("entries/hash", "entries/triangles", "entries/fractions"):
            assert np.array_equal(got.column(name), want.column(name)), name
        for name in HISTOGRAMS:
            for a, b in zip(got.counts(name), want.counts(name)):
                assert np.array_equal(a, b), name
            for column in ("mean", "bin_width"):
                assert np.array_equal(got.column(f"histograms/{name}/{column}"),
                                      want.column(f"histograms/{name}/{column}")), name


def test_a_distributed_build_gives_the_local_build_s_store(cluster, reference, tmp_path):
    tree, local = reference
    store = tmp_path / "s.h5"
    run = run_shapeidx("build", tree, "--store", store, "--points", FAST_POINTS, "--scheduler", cluster.address)
    assert run.returncode == 0, run.stderr
    assert summary_counts(run.stdout) == {"indexed": 20, "unchanged": 0, "removed": 0, "failed": 0}
    assert run.stderr.count("\n") <= 1, run.stderr  # the plan line; no chatter from dask
    assert_same_signatures(store, local)


def test_the_scheduler_from_the_environment_and_an_incremental_build(cluster, reference, tmp_path):
    tree, local = reference
    tree = tree_copy(reference, tmp_path)
    store = tmp_path / "s.h5"
    env = {**os.environ, "SHAPEIDX_SCHEDULER": cluster.address}
    first = subprocess.run(shapeidx_command("build", tree, "--store", store, "--points", FAST_POINTS),
                           capture_output=True, text=True, env=env, timeout=300)
    assert summary_counts(first.stdout)["indexed"] == 20, first.stderr
    touched = next((tree / "LED_SMD").iterdir())
    os.utime(touched, ns=(touched.stat().st_atime_ns, touched.stat().st_mtime_ns + 10**9))  # new time, same bytes
    (tree / "Diode_SMD" / sorted(os.listdir(tree / "Diode_SMD"))[0]).unlink()
    second = subprocess.run(shapeidx_command("build", tree, "--store", store, "--json"), capture_output=True,
                            text=True, env=env, timeout=300)
    record = json.loads(second.stdout)
    assert (record["indexed"], record["unchanged"], record["removed"], record["failed"]) == (0, 19, 1, 0)
    assert record["store"]["ok"] == 19


def test_workers_see_the_tree_under_a_mapped_root(cluster, reference, tmp_path):
    """--worker-root: the workers read the files there, not at the build machine's path."""
    tree, local = reference
    here = tmp_path / "here"  # the build machine's view: the same names, but empty files
    for path in tree.rglob("*.wrl"):
        (here / path.relative_to(tree)).parent.mkdir(parents=True, exist_ok=True)
        (here / path.relative_to(tree)).touch()
    mapped = tree_copy(reference, tmp_path / "mapped")
    store = tmp_path / "s.h5"
    run = run_shapeidx("build", here, "--store", store, "--points", FAST_POINTS, "--scheduler", cluster.address,
                       "--worker-root", mapped)
    assert run.returncode == 0, run.stderr
    assert summary_counts(run.stdout)["indexed"] == 20
    assert_same_signatures(store, local)
    nowhere = run_shapeidx("build", here, "--store", tmp_path / "t.h5", "--points", FAST_POINTS,
                           "--scheduler", cluster.address, "--worker-root", tmp_path / "nowhere")
    assert nowhere.returncode == 1
    assert nowhere.stderr.strip().splitlines()[-1].startswith("shapeidx: error: ")
    assert f"a dask worker sees no directory {tmp_path / 'nowhere'}" in nowhere.stderr
    assert "Traceback" not in nowhere.stderr


def test_no_scheduler_there_is_one_line(tmp_path, reference):
    env = {**os.environ, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "1s"}  # Dask's knob; 30 s by default
    run = subprocess.run(shapeidx_command("build", reference[0], "--store", tmp_path / "s.h5", "--scheduler",
                                          "tcp://127.0.0.1:9"), capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 1 and "Traceback" not in run.stderr
    assert "shapeidx: error: cannot reach the dask scheduler at tcp://127.0.0.1:9" in run.stderr


def indexed_count(lines) -> int:
    """Files a --verbose build says it indexed so far (its log lines carry a time and prefix)."""
    return sum(bool(INDEXED.search(line)) for line in list(lines))


def reading(proc) -> list:
    """The lines of ``proc``'s stderr so far (a thread keeps reading them)."""
    lines: list = []
    threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True).start()
    return lines


def busy_on_the_assembly(cluster, proc, lines, small: int = 10) -> int:
    """The indexing process working on the tree's last file, a slow assembly.

    Once the ``small`` quick files before it are indexed, it is the process whose CPU time
    grows by a second.
    """
    deadline = time.monotonic() + 180
    while indexed_count(lines) < small:
        assert proc.poll() is None and time.monotonic() < deadline, "".join(lines)
        time.sleep(0.02)
    baseline: dict = {}
    while True:
        assert proc.poll() is None and time.monotonic() < deadline, "no indexing process got busy"
        for pid in cluster.indexing_processes():
            try:
                used = cpu_seconds(pid)
            except OSError:
                continue
            if used - baseline.setdefault(pid, used) > 1.0:
                return pid
        time.sleep(0.05)


def test_a_file_past_the_time_limit_is_failed_on_the_cluster(cluster, data_dir, tmp_path):
    """As locally: recorded as timed out, and the workers go on with the other files."""
    tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
    slow_assembly(data_dir, tree / "z_assembly.stl")
    started = time.monotonic()
    run = run_shapeidx("build", tree, "--store", tmp_path / "s.h5", "--points", FAST_POINTS,
                       "--scheduler", cluster.address, "--timeout", "2")
    assert run.returncode == 0, run.stderr
    assert summary_counts(run.stdout) == {"indexed": 10, "unchanged": 0, "removed": 0, "failed": 1}
    assert "failed z_assembly.stl: timed out after 2 s (the per-file limit, --timeout)" in run.stderr
    assert time.monotonic() - started < 90


def test_a_file_that_crashes_its_process_is_failed_on_the_cluster(cluster, data_dir, tmp_path):
    """SIGSEGV in the middle of a file, as a crash in a native library: only that file fails."""
    tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
    slow_assembly(data_dir, tree / "z_assembly.stl")
    proc = dask_build(tree, tmp_path / "s.h5", cluster, "--verbose")
    lines = reading(proc)
    os.kill(busy_on_the_assembly(cluster, proc, lines), signal.SIGSEGV)
    out = proc.stdout.read()
    assert proc.wait(timeout=300) == 0, "".join(lines)
    assert summary_counts(out) == {"indexed": 10, "unchanged": 0, "removed": 0, "failed": 1}
    time.sleep(0.2)
    reason = "failed z_assembly.stl: worker process died (SIGSEGV) while indexing this file"
    assert any(line.rstrip("\n").endswith(reason) for line in lines), lines  # after the log prefix
    with open_store(tmp_path / "s.h5") as reader:
        assert "SIGSEGV" in reader.column("entries/reason")[reader.index_of("z_assembly.stl")]


def test_two_distributed_builds_exclude_each_other(cluster, reference, tmp_path):
    tree, _ = reference
    store = tmp_path / "s.h5"
    first, second = (dask_build(tree, store, cluster) for _ in range(2))
    results = [(p.wait(timeout=300), *p.communicate()) for p in (first, second)]
    assert sorted(code for code, _, _ in results) == [0, 4], results  # 4: locked by another build
    refusal = next(err for code, _, err in results if code == 4)
    assert "another build is writing s.h5 (pid " in refusal and refusal.count("\n") == 1
    with open_store(store) as reader:
        assert len(reader) == len(set(reader.paths)) == 20


def test_a_query_during_a_distributed_build_sees_every_committed_entry(cluster, reference, tmp_path):
    tree, local = reference
    store = tmp_path / "s.h5"
    proc = dask_build(tree, store, cluster, "--commit-interval", "0.1", "--merge-after", "2", "--verbose")
    lines = reading(proc)
    probe = next((tree / "LED_SMD").iterdir())
    sizes, answered = [], 0
    while proc.poll() is None:
        committed = sum(int(m.group(1)) for m in map(COMMITTED.search, list(lines)) if m)
        try:
            with open_store(store) as reader:
                sizes.append(len(reader))
        except StoreError:
            time.sleep(0.02)  # not created yet
            continue
        assert sizes[-1] >= committed, f"{committed} records committed, a reader sees {sizes[-1]}"
        hits = query_store(store, part=probe, top=3)
        assert min(3, sizes[-1]) <= len(hits) <= 3  # it may have grown meanwhile
        answered += 1
    out = proc.stdout.read()
    assert proc.returncode == 0, "".join(lines)
    assert sizes == sorted(sizes) and answered >= 3 and len(set(sizes)) >= 3, (answered, sizes)
    assert summary_counts(out)["indexed"] == 20
    assert_same_signatures(store, local)


def test_killed_workers_lose_nothing(cluster, reference, tmp_path):
    """kill -9 of a worker at random moments, up to three times: its files are redone elsewhere."""
    tree, local = reference
    seed = int(os.environ.get("SHAPEIDX_KILL_SEED", random.randrange(10**6)))
    print(f"kill seed {seed} (set SHAPEIDX_KILL_SEED to repeat)")
    rng = random.Random(seed)
    # a fast machine indexes the 20 files in well under a second, so a build may end before the
    # first kill lands; such a build proves nothing and is run again on a fresh store
    for attempt in range(5):
        store = tmp_path / f"s{attempt}.h5"
        proc = dask_build(tree, store, cluster, "--verbose", "--commit-interval", "0.2")
        lines = reading(proc)
        kills = 0
        while kills < 3 and proc.poll() is None:
            target = indexed_count(lines) + rng.randint(0, 3)
            while proc.poll() is None and indexed_count(lines) < target:
                time.sleep(0.01)
            if kills:  # the first kill as soon as its moment comes, the later ones a little after
                time.sleep(rng.uniform(0, 0.3))
            workers = cluster.worker_processes()  # the nanny restarts a killed one: any may be new
            if proc.poll() is None and workers:
                os.kill(rng.choice(workers), signal.SIGKILL)
                kills += 1
        out = proc.stdout.read()
        assert proc.wait(timeout=300) == 0, "".join(lines)
        assert summary_counts(out) == {"indexed": 20, "unchanged": 0, "removed": 0, "failed": 0}, "".join(lines)
        assert_same_signatures(store, local)
        cluster.wait_for_workers(2)
        if kills:
            break
    assert kills >= 1, "every build ended before a worker was killed"


def test_killing_the_distributed_build_at_random_moments(cluster, reference, tmp_path):
    """kill -9 of the build (scripts/kill_build.py checks the store after each), then a last build."""
    tree, local = reference
    kill_build = load_script("kill_build")
    seed = int(os.environ.get("SHAPEIDX_KILL_SEED", random.randrange(10**6)))
    print(f"kill seed {seed} (set SHAPEIDX_KILL_SEED to repeat)")
    store = tmp_path / "s.h5"
    report = kill_build.kill_campaign(tree, store, kills=3, seed=seed, log_dir=tmp_path,
                                      build_args=("--points", FAST_POINTS, "--scheduler", cluster.address))
    assert report["entries"] == 20
    assert_same_signatures(store, local)


def test_a_file_whose_workers_keep_dying_is_failed_with_the_reason(data_dir, tmp_path):
    """More deaths than the scheduler allows (here 0 retries): the file is failed, the others indexed."""
    cluster = LocalCluster(tmp_path / "cluster", workers=1,
                           env={"DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "0"})
    try:
        tree = small_kicad(data_dir, tmp_path, ["LED_SMD"])
        slow_assembly(data_dir, tree / "z_assembly.stl")
        proc = dask_build(tree, tmp_path / "s.h5", cluster, "--verbose")
        lines = reading(proc)
        busy_on_the_assembly(cluster, proc, lines)
        os.kill(cluster.worker_processes()[0], signal.SIGKILL)
        out = proc.stdout.read()
        assert proc.wait(timeout=300) == 0, "".join(lines)
        assert summary_counts(out) == {"indexed": 10, "unchanged": 0, "removed": 0, "failed": 1}
        time.sleep(0.2)
        reason = ("failed z_assembly.stl: dask workers died while indexing this file, 1 time (more than the"
                  " scheduler's distributed.scheduler.allowed-failures)")
        assert any(line.rstrip("\n").endswith(reason) for line in lines), lines  # after the log prefix
    finally:
        cluster.stop()


def test_a_distributed_build_signs_again_what_an_older_reader_signed(cluster, data_dir, tmp_path):
    """The workers' entries record their reader's revision: a store whose STEP entries an older
    reader signed is brought up to date on the cluster, the VRML and STL entries left alone."""
    from test_reader_revision import assert_same, contents, mixed_tree, set_revision

    tree = mixed_tree(data_dir, tmp_path)
    store, fresh = tmp_path / "s.h5", tmp_path / "fresh.h5"
    for path in (fresh, store):
        run = run_shapeidx("build", tree, "--store", path, "--points", FAST_POINTS)
        assert run.returncode == 0, run.stderr
    assert set_revision(store, 1) == 2
    run = run_shapeidx("build", tree, "--store", store, "--scheduler", cluster.address, "--json")
    assert run.returncode == 0, run.stderr
    record = json.loads(run.stdout)
    assert (record["indexed"], record["unchanged"], record["older_reader"]) == (2, 11, {"STEP": 2})
    assert "2 signed by an older STEP reader" in run.stderr
    assert_same(contents(store), contents(fresh))
