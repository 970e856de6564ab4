"""Native readers run in a child process, where a crash or a hang costs one file's error line.

OpenCASCADE (the STEP and IGES reader, :mod:`shapeidx.io.step`) dies with a segmentation
fault on some malformed files (one missing ``)`` in one entity of a real STEP file, an
entity number past 2^31, a missing IGES directory line) and runs for minutes on others.
Nothing in Python can catch a segmentation fault, so :func:`run_contained` runs such a read
in a child process with a time limit and a memory limit (``RLIMIT_DATA``), and turns what
happens to it into one :class:`~shapeidx.errors.LoadError` line:

* the child returns: its result (pickled through a pipe);
* it raises a LoadError: the same LoadError, raised here;
* it dies by a signal: ``FILE: OpenCASCADE crashed reading it (signal 11, SIGSEGV)``;
* it runs past the time limit: it is killed, and
  ``FILE: OpenCASCADE took longer than 120 s reading it (stopped)``;
* it runs out of memory: :class:`~shapeidx.errors.OutOfMemory`.

Every caller (``signature``, ``inspect``, ``compare``, ``query``, ``serve``, the API) goes
through it, because the STEP/IGES reader does. A build's worker processes already contain
whatever a file does to them (:mod:`shapeidx.index.workers`: a time limit, a memory limit,
and a dead worker costs one file): they call :func:`run_here` once, and from then on the
reader runs in their own process, without a second child per file.

The children are forked from a *fork server* (``multiprocessing``'s ``forkserver``
context), a single-threaded process started on first use with the native modules already
imported: forking it is cheap (no import of OpenCASCADE per file), and it is safe from a
threaded parent (the web server), which a plain ``fork`` is not. The cost per file is
measured in docs/reliability.md.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
from multiprocessing.connection import wait

from ..errors import LoadError, OutOfMemory, exception_in_words

__all__ = ["run_contained", "run_here", "is_contained", "DEFAULT_SECONDS"]

#: Seconds a contained read may take by default (``LoadLimits.max_seconds``).
DEFAULT_SECONDS = 120.0
#: Modules the fork server imports once, so that no child imports them again.
#: (An import that fails there is skipped: the child then imports what it needs itself.)
PRELOAD = ["shapeidx.io.step", "OCP.STEPControl", "OCP.IGESControl", "OCP.BRepMesh", "OCP.BRepBuilderAPI",
           "OCP.BRepBndLib", "OCP.TopExp", "OCP.BRep", "OCP.Message"]

_HERE = False
_CONTEXT = None
_LOCK = threading.Lock()


def run_here() -> None:
    """Declare this process a container already (a build worker): reads run in it directly."""
    global _HERE
    _HERE = True


def is_contained() -> bool:
    """Whether native reads run in this process (:func:`run_here` was called, or it is a
    daemonic ``multiprocessing`` worker, which may not have children and whose owner
    contains it)."""
    return _HERE or bool(multiprocessing.current_process().daemon)


def _context():
    global _CONTEXT
    with _LOCK:
        if _CONTEXT is None:
            methods = multiprocessing.get_all_start_methods()
            context = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
            if context.get_start_method() == "forkserver":
                context.set_forkserver_preload(PRELOAD)
            _CONTEXT = context
    return _CONTEXT


def _without_main(get_preparation_data):
    def prepared(name):
        data = get_preparation_data(name)
        data.pop("init_main_from_name", None)
        data.pop("init_main_from_path", None)
        return data

    return prepared


def _start(process) -> None:
    """Start ``process`` without its parent's ``__main__`` being run again in it.

    ``multiprocessing`` re-imports the parent's main module in a child it does not fork
    directly (a user's script without an ``if __name__ == "__main__"`` guard would run again
    there, a script read from stdin cannot be). The children here run a function of
    shapeidx, which needs nothing of ``__main__``: the main module is left out of what the
    child prepares, for the time of the start (under a lock: the patch is process-wide).
    """
    from multiprocessing import spawn

    with _LOCK:
        original = spawn.get_preparation_data
        spawn.get_preparation_data = _without_main(original)
        try:
            process.start()
        finally:
            spawn.get_preparation_data = original


def _limit_memory(limit: int | None) -> None:
    if not limit:
        return
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
        for bound in (soft, hard):  # never above a limit the process already has
            if bound != resource.RLIM_INFINITY:
                limit = min(limit, bound)
        resource.setrlimit(resource.RLIMIT_DATA, (limit, hard))
    except (ImportError, ValueError, OSError):
        pass


def _die_with_parent() -> None:
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _child(conn, function, args, memory: int | None) -> None:
    _die_with_parent()
    # the data the child already holds (the interpreter, OpenCASCADE) does not count against the file
    _limit_memory(memory + _data_bytes() if memory else None)
    try:
        result = ("ok", function(*args))
    except OutOfMemory as exc:
        result = ("oom", exc.path, exc.reason, exc.line)
    except LoadError as exc:
        result = ("error", exc.path, exc.reason, exc.line)
    except MemoryError:
        result = ("oom", None, None, None)
    except RecursionError:
        result = ("error", None, "nesting too deep to read", None)
    except Exception as exc:  # noqa: BLE001 (a reader bug: one line in words, not a traceback on stderr)
        result = ("error", None, f"cannot be read: it holds {exception_in_words(exc)}", None)
    try:
        conn.send(result)
    except MemoryError:
        conn.send(("oom", None, None, None))
    conn.close()


def _data_bytes() -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmData:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _signal_name(number: int) -> str:
    try:
        return f"signal {number}, {signal.Signals(number).name}"
    except ValueError:
        return f"signal {number}"


def run_contained(function, args: tuple, path, what: str = "OpenCASCADE", seconds: float | None = DEFAULT_SECONDS,
                  memory: int | None = None):
    """``function(*args)`` in a child process; its result, or one LoadError line.

    Parameters
    ----------
    function : callable
        A module-level function (it is pickled by name), returning something picklable.
    args : tuple
    path : path-like
        The file being read: named in every error.
    what : str
        Who reads it, for the error lines ("OpenCASCADE").
    seconds : float or None
        Time limit; None or 0 for none.
    memory : int or None
        Bytes of data the child may allocate beyond what it holds at its start
        (``RLIMIT_DATA``); None or 0 for no limit.

    Raises
    ------
    LoadError
        The child raised one, crashed, or ran past ``seconds``.
    OutOfMemory
        The child ran out of memory (a MemoryError under its limit).
    """
    if is_contained():
        return function(*args)
    context = _context()
    receive, send = context.Pipe(duplex=False)
    process = context.Process(target=_child, args=(send, function, args, memory), daemon=True)
    try:
        _start(process)
    except OSError as exc:
        raise LoadError(path, f"cannot start a process to read it in ({exc.strerror or exc})") from None
    finally:
        send.close()
    try:
        ready = wait([receive, process.sentinel], seconds or None)
        if not ready:
            raise LoadError(path, f"{what} took longer than {seconds:g} s reading it (stopped)")
        try:
            result = receive.recv() if receive.poll() else None
        except (EOFError, OSError):
            result = None
        if result is None:
            process.join(5)
            code = process.exitcode
            if code is not None and code < 0:
                if -code == signal.SIGKILL:
                    raise OutOfMemory(path, f"{what} was killed reading it (out of memory?)")
                raise LoadError(path, f"{what} crashed reading it ({_signal_name(-code)})")
            raise LoadError(path, f"{what} stopped reading it (status {code})")
    finally:
        if process.is_alive():
            process.kill()
        process.join()
        receive.close()
        process.close()
    status = result[0]
    if status == "ok":
        return result[1]
    error_path = path if result[1] is None else result[1]
    if status == "oom":
        raise OutOfMemory(error_path, result[2] or f"out of memory while {what} read it")
    raise LoadError(error_path, result[2], result[3])
