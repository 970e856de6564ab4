"""Build workers run under a memory limit, and one that ran out of memory is replaced.

A part that needs more memory than the worker may use fails as "out of memory" (one line),
never as the kernel's OOM killer or swap; the worker that saw the MemoryError is not given
another file (a native library may have been left broken by the failed allocation: the
adversarial run saw the next good file die with SIGSEGV), and the next good file is indexed.
"""

from __future__ import annotations

import os
import resource
import shutil

import numpy as np
import pytest

from shapeidx.signing.parameters import SIGNATURE_VERSION
from shapeidx.signing.histogram import BIN_DIVISOR
from shapeidx.store import StoreParams
from shapeidx.index.workers import Task, WorkerPool, default_memory_limit, limit_memory

PARAMS = StoreParams(points=64, seed=7, bin_divisor=BIN_DIVISOR, signature_version=SIGNATURE_VERSION)
LIMIT = 900 << 20  # the workers' RLIMIT_DATA in these tests


@pytest.fixture
def parts(tmp_path, data_dir):
    big = tmp_path / "big.obj"
    # 8 million vertex lines (64 MB): reading them as text takes several GiB of Python objects
    big.write_bytes(b"v 0 0 1\n" * 8_000_000 + b"f 1 2 3\n")
    good = tmp_path / "good.wrl"
    shutil.copy(data_dir / "kicad6" / "Diode_SMD" / sorted(os.listdir(data_dir / "kicad6" / "Diode_SMD"))[0], good)
    return tmp_path, big, good


def test_a_worker_that_ran_out_of_memory_is_replaced_and_the_next_file_is_indexed(parts):
    root, big, good = parts
    tasks = [Task(p.name, str(p)) for p in (good, big, good)]
    pool = WorkerPool(1, PARAMS, str(root), timeout=300, memory_limit=LIMIT)
    outcomes, pids = [], []  # the worker's process id whenever the pool yields
    for outcome in pool.run(tasks, wake_every=0.2):
        pids.append(pool.workers[0].process.pid)
        if outcome is not None:
            outcomes.append(outcome)
    assert [o.kind for o in outcomes] == ["indexed", "failed", "indexed"]
    assert "out of memory" in outcomes[1].entry.reason and outcomes[1].replace_worker
    assert not outcomes[0].replace_worker and not outcomes[2].replace_worker
    # the first worker indexed the good file and ran out of memory on the big one; the big
    # one was tried again in a fresh worker (the first might only have held memory an
    # earlier file freed), which ran out too and was replaced for the last file
    assert len(dict.fromkeys(pids)) == 3


def test_default_memory_limit_is_a_share_of_the_machine():
    physical = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    one, four = default_memory_limit(1), default_memory_limit(4)
    assert (1 << 30) <= four <= one <= 8 << 30
    assert four <= max(1 << 30, 0.8 * physical / 4) + 1


def test_limit_memory_sets_rlimit_data_in_the_calling_process():
    # in a child process: the test process keeps its own limits
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        os.close(read)
        ok = limit_memory(256 << 20)
        try:
            np.ones(64 << 20)  # 512 MB
            result = b"allocated"
        except MemoryError:
            result = b"MemoryError"
        os.write(write, (b"limited " if ok else b"not limited ") + result + b" %d" % resource.getrlimit(resource.RLIMIT_DATA)[0])
        os._exit(0)
    os.close(write)
    answer = os.read(read, 200).decode()
    os.waitpid(pid, 0)
    assert answer == f"limited MemoryError {256 << 20}"


def test_no_signature_is_started_without_the_memory_embree_needs(tmp_path):
    # Embree aborts the process when an allocation is refused: the worker checks first
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        os.close(read)
        from shapeidx.errors import OutOfMemory
        from shapeidx.index.workers import _data_bytes, check_signature_headroom

        limit_memory(_data_bytes() + (200 << 20))
        answers = []
        for triangles in (1_000, 5_000_000):
            try:
                check_signature_headroom("part.stl", triangles)
                answers.append("ok")
            except OutOfMemory as exc:
                answers.append(str(exc))
        os.write(write, "\n".join(answers).encode())
        os._exit(0)
    os.close(write)
    answers = os.read(read, 2000).decode().split("\n")
    os.waitpid(pid, 0)
    assert answers[1].startswith("part.stl: out of memory: the signature of 5,000,000 triangles needs about")
