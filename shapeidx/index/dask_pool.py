"""Indexing files on a ``dask.distributed`` cluster: ``shapeidx build DIR --scheduler ADDRESS``.

:class:`DaskPool` has :class:`.workers.WorkerPool`'s interface, so a distributed build is a
local build whose per-file work runs elsewhere: the walk, the plan and the one committer
(:mod:`.commit`) stay on the machine that runs the build, which alone holds the store's
lock and writes its files. The store's guarantees are therefore unchanged.

On the cluster each file runs :func:`.remote.index_on_worker`: the local worker's loop in a
child process of the Dask worker, so a file past ``--timeout`` or one that crashes its
process is recorded as failed, as locally, and never holds a Dask worker.

A Dask worker that dies (kill -9, a lost node) loses nothing: the scheduler gives its files
to other workers, and a file it had finished whose result died with it (the future is
"lost") is submitted again, up to :data:`LOST_RETRIES` times. A file whose workers died more often than the scheduler's
``distributed.scheduler.allowed-failures`` (default 3) is recorded as failed, with that
reason, and retried by the next build only with ``--retry-failed``, as any failed file.

Paths: the workers read the tree themselves. It must be visible to every worker, read-only
is enough, at the same path as on the build's machine, or under another root given as
``worker_root`` (``--worker-root``): the file ``ROOT/a/b.wrl`` is then read as
``WORKER_ROOT/a/b.wrl``. Dask is an optional dependency (``pip install 'shapeidx[dask]'``).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import queue
import time
import uuid

from ..errors import ShapeidxError
from ..store import StoreParams
from .remote import WorkerSetupError, index_on_worker
from .workers import DEFAULT_TIMEOUT, START_TIMEOUT, Outcome, Task, failed_outcome, one_line

#: Files in flight per worker thread: enough that no thread waits for the client, few enough
#: that the scheduler and the client hold little for a tree of a million files.
IN_FLIGHT_PER_THREAD = 4
#: Seconds between asking the scheduler how many threads its workers have.
RESIZE_EVERY = 5.0
#: Times a file is redone because its finished result was lost with a worker that died.
LOST_RETRIES = 3


def _distributed():
    try:
        import distributed
    except ImportError:
        raise ShapeidxError("--scheduler needs dask.distributed: pip install 'shapeidx[dask]'") from None
    return distributed


def dask_client(address: str):
    """A client of the scheduler at ``address`` once a worker has joined (ShapeidxError, in one
    line, when it cannot be reached or no worker joins)."""
    distributed = _distributed()
    # the client's own reconnection and shutdown chatter is not the user's business
    logging.getLogger("distributed").setLevel(logging.ERROR)
    try:
        # how long to try: Dask's own distributed.comm.timeouts.connect (30 s unless configured)
        client = distributed.Client(address, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ShapeidxError(f"cannot reach the dask scheduler at {address}: {one_line(exc)}") from None
    try:
        client.wait_for_workers(1, timeout=START_TIMEOUT)
    except TimeoutError:
        client.close()
        raise ShapeidxError(f"no dask worker joined the scheduler at {address} within {START_TIMEOUT:g} s") from None
    return client


class DaskPool:
    """Tasks indexed on a Dask cluster; the interface of :class:`.workers.WorkerPool`.

    Parameters
    ----------
    address : str
        The scheduler, e.g. ``tcp://10.0.0.5:8786``.
    params : StoreParams
    root : str
        The indexed directory, as this machine sees it.
    timeout : float or None
        Seconds one file may take on a worker; None or 0 for no limit.
    worker_root : str or None
        Where the workers see ``root``; None: at the same path.
    """

    def __init__(self, address: str, params: StoreParams, root: str, timeout: float | None = DEFAULT_TIMEOUT,
                 worker_root: str | None = None):
        if worker_root is not None and not os.path.isabs(worker_root):
            raise ShapeidxError(f"--worker-root {worker_root}: give the workers' path of the tree as an absolute path")
        self.address = address
        self.params = params
        self.root = root
        self.worker_root = worker_root or root
        self.timeout = timeout or None
        self.client = None
        self.running: dict = {}  # future -> the local Task

    def _connect(self):
        return dask_client(self.address)

    def _on_worker(self, task: Task) -> Task:
        """The task as the workers see it (under ``worker_root``)."""
        return dataclasses.replace(task, absolute=os.path.join(self.worker_root, *task.path.split("/")))

    def _threads(self, default: int = 1) -> int:
        """Threads of the cluster's workers now (``default`` while the scheduler does not answer)."""
        try:
            return max(1, sum(self.client.nthreads().values()))
        except Exception:  # noqa: BLE001 (reconnecting: the futures will tell what happened)
            return default

    def run(self, tasks, wake_every: float = 1.0):
        """Yield an :class:`Outcome` per task (in completion order), or None at least every ``wake_every`` s."""
        self.client = self._connect()
        finished = queue.Queue()  # futures, as they finish (their callbacks put them here)
        build = uuid.uuid4().hex[:12]
        pending, number = iter(tasks), 0
        exhausted = False
        window, resized = IN_FLIGHT_PER_THREAD * self._threads(), time.monotonic()
        lost: dict = {}  # task path -> times its result was lost with a dead worker

        def submit(task: Task) -> None:
            nonlocal number
            future = self.client.submit(index_on_worker, self._on_worker(task), self.params,
                                        self.worker_root, self.timeout, key=f"shapeidx-index-{build}-{number}",
                                        pure=False)
            self.running[future] = task
            future.add_done_callback(finished.put)
            number += 1

        try:
            while True:
                while not exhausted and len(self.running) < window:
                    task = next(pending, None)
                    if task is None:
                        exhausted = True
                        break
                    submit(task)
                if not self.running:
                    return
                try:
                    done = [finished.get(timeout=wake_every)]
                except queue.Empty:
                    yield None
                    done = []
                while not finished.empty():
                    done.append(finished.get_nowait())
                for future in done:
                    task = self.running.pop(future, None)
                    if task is None:  # (a callback that fires twice hands a file on once)
                        continue
                    if future.status == "lost" and lost.get(task.path, 0) < LOST_RETRIES:
                        # the file was done, but its result died with its worker before it
                        # reached us: do it again elsewhere (as for a worker that died mid-file)
                        lost[task.path] = lost.get(task.path, 0) + 1
                        submit(task)
                        continue
                    yield self._outcome_of(future, task)
                if time.monotonic() - resized > RESIZE_EVERY:  # workers come and go
                    window = IN_FLIGHT_PER_THREAD * self._threads(window // IN_FLIGHT_PER_THREAD)
                    resized = time.monotonic()
        finally:
            self.close()

    def _outcome_of(self, future, task: Task) -> Outcome:
        distributed = _distributed()
        if future.status == "finished":
            outcome = dataclasses.replace(future.result(), task=task)
            _revision_of_older_worker(outcome)
            if outcome.kind == "missing" and os.path.exists(task.absolute):
                raise ShapeidxError(f"a dask worker cannot see {self._on_worker(task).absolute}, which exists here:"
                                    " the tree must be shared with the workers at the same path, or give --worker-root")
            return outcome
        if future.status == "error":
            error = future.exception()
            if isinstance(error, distributed.KilledWorker):
                allowed = getattr(error, "allowed_failures", None)
                times = "" if allowed is None else f", {allowed + 1} time{'s' * (allowed != 0)}"
                return failed_outcome(task, one_line(f"dask workers died while indexing this file{times}"
                                               " (more than the scheduler's distributed.scheduler.allowed-failures)"))
            if isinstance(error, WorkerSetupError):
                raise ShapeidxError(str(error)) from None
            raise ShapeidxError(one_line(f"a dask worker failed to run shapeidx: {type(error).__name__}: {error}"))
        raise ShapeidxError(f"the dask scheduler at {self.address} dropped the build's work"
                            f" ({future.status}; was it restarted?)")

    def close(self) -> None:
        """Cancel the files still in flight and disconnect."""
        if self.client is None:
            return
        try:
            if self.running:
                self.client.cancel(list(self.running), force=True)
            self.client.close(timeout=5)
        except Exception:  # noqa: BLE001 (a scheduler already gone: nothing left to release)
            pass
        self.running, self.client = {}, None


def _revision_of_older_worker(outcome) -> None:
    """A worker running a shapeidx from before reader revisions sends entries without one:
    its reader is the first revision (left unset, the build would stamp its own, and an entry
    an older reader signed would never be signed again)."""
    from ..store.layout import FIRST_REVISION

    for entry in [outcome.entry, *(outcome.parts or ())]:
        if entry is not None and "revision" not in vars(entry):
            entry.revision = FIRST_REVISION
