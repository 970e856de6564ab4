"""A file's work on a machine that is not the build's: what a Dask worker runs.

:func:`index_on_worker` is the function a distributed build sends to the cluster (see
:mod:`.dask_pool`); it never imports Dask. It runs :func:`.workers.index_file` as the local
build does, in a child process of the worker (one per worker thread, started once and kept),
so a file keeps the local guarantees wherever it runs:

* past the time limit, the child is killed and the file recorded as timed out; the Dask
  worker itself is never blocked for longer than the limit;
* a crash of the child (a segfault in a native library, the OOM killer) is the file's
  failure, recorded with the signal's name; a fresh child takes the next file;
* a child that cannot run Python at all, a worker of another signature version, or one
  that does not see the tree raises :class:`WorkerSetupError`: that stops the build with
  one line instead of recording every file as failed.

The child is a plain ``subprocess`` (not ``multiprocessing``): Dask's worker processes are
daemonic, and daemonic processes may not start ``multiprocessing`` children. It talks over
two pipes with :class:`multiprocessing.connection.Connection`, and it is the same loop as a
local worker's (:func:`.workers.worker_main`).

    python -m shapeidx.index.remote FD_IN FD_OUT PARENT_PID    # the child; not for users
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection

from ..errors import ShapeidxError
from ..signing.parameters import SIGNATURE_VERSION
from ..store import StoreParams
from .workers import READY, START_TIMEOUT, Outcome, Task, failed_outcome, worker_main, death_reason


class WorkerSetupError(ShapeidxError):
    """A Dask worker cannot index files at all (not one file's fault): the build stops."""


class _Duplex:
    """Two one-way pipe connections as the one duplex connection a worker loop expects."""

    def __init__(self, incoming: Connection, outgoing: Connection):
        self.recv, self.poll = incoming.recv, incoming.poll
        self.send = outgoing.send
        self._ends = (incoming, outgoing)

    def close(self) -> None:
        for end in self._ends:
            end.close()


class _Child:
    """One child process indexing files for one worker thread (see the module docstring)."""

    def __init__(self, params: StoreParams, root: str):
        self.params, self.root = params, root
        to_child, from_parent = os.pipe()
        to_parent, from_child = os.pipe()
        self.process = subprocess.Popen(
            [sys.executable, "-m", "shapeidx.index.remote", str(to_child), str(from_child), str(os.getpid())],
            pass_fds=(to_child, from_child), stdin=subprocess.DEVNULL,
        )
        os.close(to_child)
        os.close(from_child)
        self.conn = _Duplex(Connection(to_parent, writable=False), Connection(from_parent, readable=False))
        self.conn.send((params, root))
        self.ready = False

    def wait_ready(self) -> None:
        """Wait until the child has imported what indexing needs (not part of a file's time)."""
        if not self.ready and self.conn.poll(START_TIMEOUT):
            try:
                self.ready = self.conn.recv() == READY
            except (EOFError, OSError):
                pass
        if not self.ready:
            status = self.process.poll()
            self.kill()
            raise WorkerSetupError(f"{socket.gethostname()}: the indexing process of a dask worker did not start"
                                   f" ({'exit status ' + str(status) if status is not None else 'no answer'}"
                                   f" within {START_TIMEOUT:g} s)")

    def index(self, task: Task, timeout: float | None) -> tuple[Outcome, bool]:
        """The outcome of ``task``, and whether the child is lost (dead or killed)."""
        self.wait_ready()
        deadline = time.monotonic() + timeout if timeout else None
        try:
            self.conn.send(task)
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            if self.conn.poll(remaining):
                return self.conn.recv(), False
        except (EOFError, OSError):
            pass  # the child died: judged below by its exit status
        else:
            if self.process.poll() is None:  # nothing came, and it still runs: the time limit passed
                self.kill()
                return failed_outcome(task, f"timed out after {timeout:g} s (the per-file limit, --timeout)"), True
        try:
            status = self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            status = None
        self.kill()
        if status is not None and status > 0:
            raise WorkerSetupError(f"{socket.gethostname()}: the indexing process of a dask worker failed to run"
                                   f" (exit status {status})")
        return failed_outcome(task, death_reason(status)), True

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
        self.conn.close()


#: Each worker thread's child, kept between files (starting one costs the imports).
_children = threading.local()


def index_on_worker(task: Task, params: StoreParams, root: str, timeout: float | None) -> Outcome:
    """Index one file on this machine, as a local build's worker would; see the module docstring.

    ``task.absolute`` and ``root`` are paths as this machine sees them.

    Raises
    ------
    WorkerSetupError
        This worker cannot index any file (another signature version, no tree at ``root``,
        an indexing process that cannot run).
    """
    if params.signature_version != SIGNATURE_VERSION:
        raise WorkerSetupError(f"{socket.gethostname()}: this dask worker's shapeidx makes signature version"
                               f" {SIGNATURE_VERSION}, the store's is {params.signature_version}: install the"
                               " same shapeidx on the workers as on the machine that runs the build")
    if not os.path.isdir(root):
        raise WorkerSetupError(f"{socket.gethostname()}: a dask worker sees no directory {root} (the tree must be"
                               " shared with the workers at the same path, or give --worker-root)")
    child = getattr(_children, "child", None)
    if child is not None and (child.params, child.root) != (params, root):
        child.kill()
        child = None
    if child is None or child.process.poll() is not None:
        child = _children.child = _Child(params, root)
    outcome, lost = child.index(task, timeout)
    if lost:
        _children.child = None
    return outcome


def _child_main(argv: list[str]) -> None:
    incoming, outgoing, parent = int(argv[0]), int(argv[1]), int(argv[2])
    conn = _Duplex(Connection(incoming, writable=False), Connection(outgoing, readable=False))
    params, root = conn.recv()
    # blocked as a local worker's are at its spawn: worker_main unblocks them once it ignores them
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    worker_main(conn, params, root, parent)


if __name__ == "__main__":
    _child_main(sys.argv[1:])
