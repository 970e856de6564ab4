"""Indexing files in worker processes that may crash, hang or run out of memory.

Each worker is a separate process (``spawn``: nothing of the parent's state, open files or
lock is inherited) that receives one task at a time over a pipe. The parent watches every
busy worker's pipe, its process and its deadline together:

* a result arrives: hand it on, give the worker its next task;
* the process dies (a segfault in a native library, the kernel's OOM killer): the file
  it held is recorded as failed with the signal's name, and a fresh worker takes its place;
* the deadline passes: the worker is killed, the file is recorded as timed out, and a
  fresh worker takes its place;
* the file ran the worker out of memory: it is recorded as failed ("out of memory") and the
  worker is replaced too, although it still runs: a native library (Embree, manifold3d)
  whose allocation failed half-way may be left broken, and the next file would crash it.

Each worker runs under a memory limit (``RLIMIT_DATA``, :func:`default_memory_limit`,
``WorkerPool(memory_limit=...)``, ``shapeidx build --worker-memory``): an allocation
beyond it fails with MemoryError inside the worker, which costs one file, instead of
drawing the machine into swap or the kernel's OOM killer. ``RLIMIT_DATA`` counts what the
worker really writes (its heap and private mappings) and not the address space that
Embree's threads reserve and never touch, which ``RLIMIT_AS`` would.

So no file, however hostile, stops a build, and one bad file costs only itself.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import time
from dataclasses import dataclass
from multiprocessing.connection import wait
from pathlib import Path

from ..errors import LoadError, OutOfMemory, ShapeidxError
from ..io.base import file_hash
from ..store import Entry, StoreParams

#: Default per-file time limit, seconds: ample for a part of millions of triangles at 1024
#: points, short enough that a pathological file cannot stall a nightly run for long.
DEFAULT_TIMEOUT = 600.0
#: Upper bound of the default per-worker memory limit.
MAX_DEFAULT_MEMORY = 8 << 30
_REASON_LIMIT = 300


@dataclass(frozen=True)
class Task:
    """One file to look at.

    ``known_hash`` is the stored content hash when the file's size and time changed but its
    content may not have: a worker that finds the same hash does no signature work.
    """

    path: str  # relative to the root, '/'-separated
    absolute: str
    known_hash: str | None = None
    in_store: bool = False
    #: Sign the whole file (False: only its sub-parts are wanted, its entry is up to date).
    whole: bool = True
    #: Also split the file into sub-parts and sign them (``build --parts``).
    parts: bool = False
    #: The content hash the file's stored sub-entries were made from (same content: they are kept).
    parts_hash: str | None = None
    #: The paths of the file's sub-entries now in the parts store (replaced by the new ones).
    old_parts: tuple = ()


@dataclass(frozen=True)
class Outcome:
    """What a worker found: ``kind`` is "indexed", "failed", "same" (content unchanged) or "missing"."""

    task: Task
    kind: str
    entry: Entry | None = None
    size: int = 0
    mtime_ns: int = 0
    seconds: float = 0.0
    #: The worker ran out of memory on this file: replace it before the next one.
    replace_worker: bool = False
    #: With ``task.parts``: the file's sub-entries (``FILE#n``, or one failed entry ``FILE``);
    #: None when they were not made (same content: ``parts_same``).
    parts: list | None = None
    parts_same: bool = False
    #: CPU seconds of the worker by stage ("hash", "load", "solid", "signature", "facts",
    #: "parts"), all its threads counted: where a build's time goes (``build --json``'s profile).
    cpu: dict | None = None


class StageClock:
    """CPU seconds of this process (every thread) by stage: ``lap(name)`` charges the time
    since the previous lap to ``name``."""

    def __init__(self):
        self.last = time.process_time()
        self.seconds: dict[str, float] = {}

    def lap(self, stage: str) -> None:
        now = time.process_time()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self.last
        self.last = now


def one_line(text: str) -> str:
    """A reason on one line, of bounded length."""
    from ..errors import plain_reason

    text = plain_reason(text)  # no b'...' reprs, no control characters
    return text if len(text) <= _REASON_LIMIT else text[: _REASON_LIMIT - 3] + "..."


def reason_of(error: LoadError, absolute: str) -> str:
    """The reason of a LoadError without the file's own (absolute) path, which the entry has."""
    if error.path is not None and os.path.abspath(error.path) != os.path.abspath(absolute):
        return one_line(str(error))  # about another file (e.g. an inlined one): keep its name
    where = f"line {error.line}: " if error.line is not None else ""
    return one_line(where + error.reason)


def index_file(task: Task, params: StoreParams, root: str) -> Outcome:
    """Hash and, unless the content is known, sign one file (and with ``task.parts`` its
    sub-parts). Never raises for a bad file.

    Its entries record the revision of this process's reader of the file's format
    (``entries/revision``): on a Dask worker, the worker's, which may be older than the
    build's (its entries are then signed again by the next build)."""
    from ..io.registry import reader_revision

    outcome = _index_file(task, params, root)
    revision = reader_revision(task.path)
    for entry in [outcome.entry, *(outcome.parts or ())]:
        if entry is not None and entry.revision is None:
            entry.revision = revision
    return outcome


def _index_file(task: Task, params: StoreParams, root: str) -> Outcome:
    from ..io import LoadLimits, load
    from ..signing.solid import make_solid

    started = time.monotonic()
    clock = StageClock()
    try:
        stat = os.stat(task.absolute)
        digest = file_hash(task.absolute)
        clock.lap("hash")
    except FileNotFoundError:
        return Outcome(task, "missing")
    except OSError as exc:
        entry = Entry.failed(task.path, "", 0, 0, one_line(f"cannot read: {exc.strerror or exc}"))
        return Outcome(task, "failed", entry, parts=_failed_parts(task, entry))
    size, mtime = stat.st_size, stat.st_mtime_ns
    whole = task.whole and not (task.known_hash is not None and digest == task.known_hash)
    parts = task.parts and not (task.parts_hash is not None and digest == task.parts_hash)
    same = {"parts_same": task.parts and not parts}
    if not whole and not parts:
        return Outcome(task, "same" if task.whole else "skipped", size=size, mtime_ns=mtime, cpu=clock.seconds, **same)
    limits = LoadLimits(root=Path(root), faceting=params.faceting)
    mesh = entry = None
    try:
        mesh = load(task.absolute, limits)
        clock.lap("load")
        solid = make_solid(mesh, task.absolute)
        clock.lap("solid")
        entry = _signed(task.path, digest, size, mtime, solid, params, task.absolute, clock)
        kind = "indexed"
    except OutOfMemory as exc:
        entry = Entry.failed(task.path, digest, size, mtime, reason_of(exc, task.absolute))
        return Outcome(task, "failed" if task.whole else "skipped", entry, size, mtime, time.monotonic() - started,
                       replace_worker=True, parts=_failed_parts(task, entry))
    except LoadError as exc:
        entry, kind = Entry.failed(task.path, digest, size, mtime, reason_of(exc, task.absolute)), "failed"
    except MemoryError:
        entry = Entry.failed(task.path, digest, size, mtime, "out of memory")
        return Outcome(task, "failed" if task.whole else "skipped", entry, size, mtime, time.monotonic() - started,
                       replace_worker=True, parts=_failed_parts(task, entry))
    except Exception as exc:  # a bug in a later stage must cost one file, not the build
        from ..errors import exception_in_words

        reason = one_line(f"cannot be signed: it holds {exception_in_words(exc)}")
        entry, kind = Entry.failed(task.path, digest, size, mtime, reason), "failed"
    sub = None
    if parts:
        sub = _failed_parts(task, entry) if kind == "failed" else _guarded_parts(task, digest, size, mtime, mesh, entry,
                                                                                params, limits)
        clock.lap("parts")
    if not whole:
        kind = "same" if task.whole else "skipped"
        entry = None
    clock.lap("failed" if kind == "failed" else "other")
    return Outcome(task, kind, entry, size, mtime, time.monotonic() - started, parts=sub, cpu=clock.seconds, **same)


def _signed(path: str, digest: str, size: int, mtime: int, solid, params: StoreParams, absolute: str,
            clock: StageClock | None = None) -> Entry:
    """The ok entry of one solid (a file, or a sub-part ``FILE#n``); ``absolute`` names the file in errors."""
    from ..signing.pipeline import signature_of_solid

    check_signature_headroom(absolute, len(solid.faces))
    facts = solid.facts  # the exact measures, once: the store keeps them, the signature reads the radii
    if clock is not None:
        clock.lap("facts")
    signature = signature_of_solid(solid, params.points, params.seed, params.bin_divisor)
    if clock is not None:
        clock.lap("signature")
    entry = Entry.indexed(path, digest, size, mtime, signature, solid.describe(), facts)
    if clock is not None:
        clock.lap("facts")
    return entry


def part_path(path: str, number: int) -> str:
    """The entry of the ``number``-th (1-based) sub-part of the file at ``path``."""
    return f"{path}#{number}"


def _failed_parts(task: Task, entry: Entry) -> list | None:
    """A file that cannot be read has one failed sub-entry, ``FILE`` itself (so that it is not
    tried again until it changes)."""
    if not task.parts:
        return None
    failed = Entry.failed(task.path, entry.hash, entry.size, entry.mtime_ns, entry.reason)
    failed.parent = task.path
    return [failed]


def _guarded_parts(task: Task, digest: str, size: int, mtime: int, mesh, whole: Entry, params: StoreParams,
                   limits) -> list:
    """:func:`_part_entries`, whose failure costs the file's sub-entries (one failed ``FILE``),
    never its whole entry or the build."""
    try:
        return _part_entries(task, digest, size, mtime, mesh, whole, params, limits)
    except (LoadError, OutOfMemory) as exc:
        reason = reason_of(exc, task.absolute)
    except MemoryError:
        reason = "out of memory while splitting it into sub-parts"
    except Exception as exc:  # a bug in the split must cost the file's sub-parts, not the build
        from ..errors import exception_in_words

        reason = one_line(f"cannot be split into sub-parts: it holds {exception_in_words(exc)}")
    return _failed_parts(task, Entry.failed(task.path, digest, size, mtime, reason))


def _part_entries(task: Task, digest: str, size: int, mtime: int, mesh, whole: Entry, params: StoreParams,
                  limits) -> list:
    """The sub-entries of a file read and signed (``whole``): one per distinct sub-part, or
    ``FILE#1`` with the whole file's signature when the file is one part."""
    import dataclasses

    from ..io.parts import split_parts
    from ..signing.solid import make_solid

    try:
        parts = split_parts(task.absolute, limits, mesh=mesh)
    except LoadError:
        parts = None  # the split failed where the whole file did not: the file is its own one part
    if not parts:
        if whole is None:  # only the parts were asked and the file is one part: sign it as a whole
            whole = _signed(task.path, digest, size, mtime, make_solid(mesh, task.absolute), params, task.absolute)
        one = dataclasses.replace(whole, path=part_path(task.path, 1), parent=task.path, count=1,
                                  histograms=dict(whole.histograms))
        return [one]
    entries = []
    for number, part in enumerate(parts, start=1):
        path = part_path(task.path, number)
        try:
            entry = _signed(path, digest, size, mtime, make_solid(part.mesh, task.absolute), params, task.absolute)
        except LoadError as exc:
            entry = Entry.failed(path, digest, size, mtime, one_line(exc.reason))
        entry.parent, entry.count = task.path, part.count
        if part.name:
            entry.title = part.name
        entries.append(entry)
    return entries


#: What a signature allocates beyond the solid, mostly Embree's, which aborts the process
#: instead of failing cleanly when an allocation is refused: per triangle, plus a fixed part,
#: larger the first time (the Embree device and its threads). Measured by the lowest
#: RLIMIT_DATA under which signatures of 180,000 and 720,000 triangles still succeed:
#: some 370 MB + 300 bytes per triangle above what cleaning left.
SIGNATURE_BYTES_PER_TRIANGLE = 400
SIGNATURE_BYTES_FIRST = 400 << 20
SIGNATURE_BYTES_FIXED = 64 << 20


def _data_bytes() -> int | None:
    """This process's VmData (what RLIMIT_DATA counts), or None where unknown."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmData:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_signature_headroom(path: str, triangles: int) -> None:
    """Raise OutOfMemory when the memory limit leaves too little for a signature of
    ``triangles`` triangles: Embree would die with SIGSEGV on the refused allocation."""
    try:
        import resource

        limit = resource.getrlimit(resource.RLIMIT_DATA)[0]
    except (ImportError, ValueError, OSError):
        return
    if limit == resource.RLIM_INFINITY:
        return
    from ..signing.occlusion import embree_device

    first = embree_device.cache_info().currsize == 0
    need = SIGNATURE_BYTES_PER_TRIANGLE * triangles + (SIGNATURE_BYTES_FIRST if first else SIGNATURE_BYTES_FIXED)
    used = _data_bytes()
    if used is None or limit - used >= need:
        return
    try:  # give what cleaning freed back to the system, and look again
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    used = _data_bytes() or used
    if limit - used < need:
        raise OutOfMemory(
            path,
            f"out of memory: the signature of {triangles:,} triangles needs about {need >> 20:,} MiB more, "
            f"beyond the worker's memory limit of {limit >> 20:,} MiB (shapeidx build --worker-memory)",
        )


def _die_with_parent() -> None:
    """Ask Linux to kill this worker when its parent dies (even by kill -9)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass  # not Linux: the worker still ends when its pipe closes


#: Signals a worker ignores: Ctrl-C or a SIGTERM sent to the whole process group is the
#: parent's to handle (it commits, then stops its workers), never a failure of a file.
_PARENT_SIGNALS = {signal.SIGINT, signal.SIGTERM}


def default_memory_limit(workers: int) -> int:
    """Bytes each of ``workers`` workers may use: their share of 80 % of the machine's
    memory, at least 1 GiB and at most :data:`MAX_DEFAULT_MEMORY` (8 GiB)."""
    try:
        physical = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return MAX_DEFAULT_MEMORY
    return int(min(MAX_DEFAULT_MEMORY, max(1 << 30, 0.8 * physical / max(1, workers))))


def limit_memory(limit: int | None) -> bool:
    """Limit this process's data (``RLIMIT_DATA``) to ``limit`` bytes; False where impossible."""
    if not limit:
        return False
    try:
        import resource

        _, hard = resource.getrlimit(resource.RLIMIT_DATA)
        if hard != resource.RLIM_INFINITY:
            limit = min(limit, hard)
        resource.setrlimit(resource.RLIMIT_DATA, (limit, hard))
    except (ImportError, ValueError, OSError):
        return False
    return True


def worker_main(conn, params: StoreParams, root: str, parent: int, memory_limit: int | None = None) -> None:
    """A worker process's loop: say :data:`READY`, then index each task received on ``conn`` until told to stop."""
    from ..io.contained import run_here
    from ..system import keep_freed_memory

    run_here()  # this process contains native crashes and hangs already: no child per file
    _die_with_parent()
    limit_memory(memory_limit)
    keep_freed_memory()
    if os.getppid() != parent:  # the parent died before the request above took effect
        return
    for signum in _PARENT_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _PARENT_SIGNALS)  # blocked since the spawn
    from ..signing import pipeline  # noqa: F401 (imported before the first file's clock starts)

    conn.send(READY)
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        conn.send(index_file(task, params, root))


#: What a worker sends once it has imported what indexing needs.
READY = "ready"
#: Seconds a new worker may take to start (imports on a loaded machine) before the build gives up.
START_TIMEOUT = 120.0


def death_reason(exitcode: int | None) -> str:
    """Why a worker process ended while indexing a file, in words."""
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        hint = " (out of memory?)" if -exitcode == signal.SIGKILL else ""
        return f"worker process died ({name}{hint}) while indexing this file"
    return f"worker process ended (status {exitcode}) while indexing this file"


class _Worker:
    def __init__(self, context, params: StoreParams, root: str, memory_limit: int | None = None):
        self.conn, child = context.Pipe()
        self.process = context.Process(
            target=worker_main, args=(child, params, root, os.getpid(), memory_limit), daemon=True
        )
        # the new process inherits blocked signals: none can reach it before it ignores them
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, _PARENT_SIGNALS)
        try:
            self.process.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        child.close()
        self.task: Task | None = None
        self.deadline = float("inf")
        self.done = 0  # files this process has finished
        self.ready = False

    def wait_ready(self) -> None:
        """Wait until the worker has started: a file's time limit does not include the imports.

        A worker that dies or never starts is left to the caller, which gives it the file
        anyway and then sees it dead (judged by its exit code, as any death).
        """
        if self.ready:
            return
        if wait([self.conn, self.process.sentinel], START_TIMEOUT) and self.conn.poll():
            try:
                self.ready = self.conn.recv() == READY
            except (EOFError, OSError):
                pass

    def give(self, task: Task, timeout: float | None) -> None:
        self.wait_ready()
        self.task = task
        self.deadline = time.monotonic() + timeout if timeout else float("inf")
        try:
            self.conn.send(task)
        except (BrokenPipeError, ConnectionResetError):
            pass  # it died before it could take the file: judged by its exit code, as any death

    def kill(self) -> None:
        if self.process.is_alive():
            self.process.kill()
        self.process.join()
        self.conn.close()


class WorkerPool:
    """``workers`` processes indexing tasks; see the module docstring for failure handling.

    Parameters
    ----------
    workers : int
    params : StoreParams
    root : str
        The indexed directory (VRML Inline may not leave it).
    timeout : float or None
        Seconds one file may take; None or 0 for no limit.
    memory_limit : int or None
        Bytes of data each worker may use (``RLIMIT_DATA``); None for
        :func:`default_memory_limit`, 0 for no limit.
    """

    def __init__(
        self,
        workers: int,
        params: StoreParams,
        root: str,
        timeout: float | None = DEFAULT_TIMEOUT,
        memory_limit: int | None = None,
    ):
        self.context = multiprocessing.get_context("spawn")
        self.size = max(1, workers)
        self.memory_limit = default_memory_limit(self.size) if memory_limit is None else memory_limit
        self.params = params
        self.root = root
        self.timeout = timeout or None
        self.workers: list[_Worker] = []
        #: Worker processes started (the first ones and every replacement): each pays the imports.
        self.started = 0

    def run(self, tasks, wake_every: float = 1.0):
        """Yield an :class:`Outcome` per task (in completion order), or None at least every ``wake_every`` s.

        The None ticks let the caller commit on time while every worker is busy on slow files.
        """
        try:
            count = len(tasks)
        except TypeError:
            count = self.size
        # as many workers as there are files, up to the pool's size, importing side by side;
        # a build with nothing to do starts none
        idle = [self._spawn() for _ in range(min(self.size, count))]
        pending = iter(tasks)
        busy: list[_Worker] = []
        exhausted = False
        try:
            while True:
                while (idle or len(busy) < self.size) and not exhausted:
                    task = next(pending, None)
                    if task is None:
                        exhausted = True
                        break
                    worker = idle.pop() if idle else self._spawn()
                    if not worker.process.is_alive():  # died while idle (killed from outside)
                        worker = self._replace(worker)
                    worker.give(task, self.timeout)
                    busy.append(worker)
                if not busy:
                    return
                yield from self._collect(busy, idle, wake_every)
        finally:
            self.close()

    def _spawn(self) -> _Worker:
        self.started += 1
        worker = _Worker(self.context, self.params, self.root, self.memory_limit)
        self.workers.append(worker)
        return worker

    def _replace(self, worker: _Worker) -> _Worker:
        worker.kill()
        self.workers.remove(worker)
        return self._spawn()

    def _collect(self, busy: list, idle: list, wake_every: float):
        now = time.monotonic()
        until = min([w.deadline for w in busy] + [now + wake_every])
        ready = wait([w.conn for w in busy] + [w.process.sentinel for w in busy], max(0.0, until - now))
        yielded = False
        for worker in list(busy):
            outcome, lost = self._outcome_of(worker, ready)
            if outcome is None:
                continue
            busy.remove(worker)
            task, worker.task, worker.deadline = worker.task, None, float("inf")
            worker.done += 1
            if outcome.replace_worker and worker.done > 1:
                # out of memory in a worker that still holds what earlier files freed (glibc
                # keeps it): once more in a fresh one, so that only the file decides
                fresh = self._replace(worker)
                fresh.give(task, self.timeout)
                busy.append(fresh)
                continue
            idle.append(self._replace(worker) if lost or outcome.replace_worker else worker)
            yielded = True
            yield outcome
        if not yielded:
            yield None

    def _outcome_of(self, worker: _Worker, ready) -> tuple[Outcome | None, bool]:
        """The worker's outcome if it has one, and whether the worker is lost (dead or killed)."""
        task = worker.task
        if worker.conn in ready:
            try:
                return worker.conn.recv(), False
            except (EOFError, OSError):
                pass  # died while sending: judged below by its exit code
        if worker.conn in ready or worker.process.sentinel in ready:
            worker.process.join(timeout=5)
            if worker.process.exitcode and worker.process.exitcode > 0:
                # Python itself failed in the worker (a broken installation, not a bad file):
                # recording every file as failed would hide it, and they would not be retried
                raise ShapeidxError(f"a worker process failed to run (exit status {worker.process.exitcode})")
            return failed_outcome(task, death_reason(worker.process.exitcode)), True
        if time.monotonic() >= worker.deadline:
            return failed_outcome(task, f"timed out after {self.timeout:g} s (the per-file limit, --timeout)"), True
        return None, False

    def close(self) -> None:
        """Stop every worker: idle ones are asked to exit, busy ones killed."""
        for worker in self.workers:
            try:
                if worker.task is None and worker.process.is_alive():
                    worker.conn.send(None)
            except OSError:
                pass
            worker.process.join(timeout=0.5)
            worker.kill()
        self.workers = []


def failed_outcome(task: Task, reason: str) -> Outcome:
    """A file whose worker died or timed out: failed, with what is known of it."""
    try:
        stat = os.stat(task.absolute)
        size, mtime = stat.st_size, stat.st_mtime_ns
    except OSError:
        size = mtime = 0
    entry = Entry.failed(task.path, "", size, mtime, reason)
    return Outcome(task, "failed" if task.whole else "skipped", entry, size, mtime, parts=_failed_parts(task, entry))
