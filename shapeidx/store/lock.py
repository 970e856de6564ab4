"""The store's single-writer lock, and the record of the last build that the lock corrects.

One build writes a store at a time: it holds an exclusive ``flock`` on ``STORE/lock``
(:class:`StoreLock`), which the kernel drops when its holder dies, even by kill -9, so a crash
never leaves a stale lock. Readers take no lock; they only ask whether one is held
(:func:`lock_held`): a store whose first build has not committed yet, or whose ``build.json``
says ``running`` while nothing holds the lock (its build was killed).

Its own module so that the reader, the writer, the checker and the layout converter all take
the lock from one place without importing each other.
"""

from __future__ import annotations

import fcntl
import os
import socket
import time
from pathlib import Path

from ..errors import StoreError, StoreLockedError
from ..io.base import read_regular
from .files import build_state_path, lock_path
from .layout import utc_now

#: Largest STORE/build.json read (it holds a few hundred bytes).
STATE_LIMIT = 1 << 20


def record_build(store: Path, state: str, facts: dict | None = None) -> None:
    """Write ``STORE/build.json`` (atomically): the state of the last build (``running``,
    ``finished``, ``interrupted``, ``stopped``), who ran it, when, and ``facts`` (its summary).
    A build killed with -9 leaves ``running`` with no lock held: ``stats`` says it stopped."""
    import json

    path = build_state_path(store)
    record = {"state": state, "pid": os.getpid(), "host": socket.gethostname(), "at": utc_now()}
    try:
        previous = json.loads(read_regular(path, STATE_LIMIT))
    except (OSError, ValueError, RecursionError):
        previous = {}
    record["started"] = utc_now() if state == "running" else previous.get("started")
    if facts:
        record.update(facts)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    try:
        tmp.write_text(json.dumps(record) + "\n")
        os.replace(tmp, path)
    except OSError:  # a report only: a store without it works
        tmp.unlink(missing_ok=True)


def read_build_state(store: Path) -> dict | None:
    """The last build's record with ``state`` corrected by the lock: ``running`` only while a
    build holds it, ``stopped`` when its holder died (kill -9, a crash, a power cut)."""
    import json

    try:
        record = json.loads(read_regular(build_state_path(store), STATE_LIMIT))
    except (OSError, ValueError, RecursionError):  # a FIFO, a directory, garbage, 64 MiB of '{'
        return None
    if not isinstance(record, dict):
        return None
    if record.get("state") == "running" and not lock_held(store):
        record["state"] = "stopped"
    return record


def lock_held(store: Path) -> bool:
    """Whether a build holds the store's lock now (a shared ``flock`` cannot be had)."""
    try:
        fd = os.open(lock_path(store), os.O_RDONLY | os.O_NONBLOCK)  # a FIFO put there never blocks
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    except BlockingIOError:
        return True
    finally:
        os.close(fd)


class StoreLock:
    """The single-writer lock: an exclusive ``flock`` on ``STORE/lock``.

    The kernel drops it when its holder dies, even by kill -9, so a crash never leaves a
    stale lock. Readers take no lock.
    """

    def __init__(self, store: Path, path: Path | None = None):
        self.store = Path(store)
        self.path = path or lock_path(store)
        self.fd: int | None = None

    def acquire(self, wait: bool = False, on_wait=None, timeout: float | None = None) -> None:
        """Take the lock, or raise :class:`StoreLockedError` naming the holder.

        ``wait``: wait for the holder, for at most ``timeout`` seconds (None: as long as it takes).
        """
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NONBLOCK, 0o644)
        except OSError as exc:
            raise StoreError(f"cannot create the lock file {self.path}: {exc.strerror or exc}") from None
        import stat

        if not stat.S_ISREG(os.fstat(fd).st_mode):  # a FIFO, a device: nothing a lock can be taken on
            os.close(fd)
            raise StoreError(f"the lock file {self.path} is not a regular file; remove it (no build is running"
                             " when nothing holds it) and build again")
        os.set_blocking(fd, True)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            name = self.store.name
            if not wait:
                os.close(fd)
                raise StoreLockedError(
                    f"another build is writing {name} ({holder}); try again later, or pass --wait"
                ) from None
            if on_wait:
                on_wait(holder)
            if not _wait_for_lock(fd, timeout):
                os.close(fd)
                raise StoreLockedError(
                    f"another build is still writing {name} after waiting {timeout:g} s ({holder})"
                ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()}, since {utc_now()}\n".encode(), 0)
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            os.ftruncate(self.fd, 0)
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None


def _wait_for_lock(fd: int, timeout: float | None) -> bool:
    """Block until the lock is ours (True), or ``timeout`` seconds pass (False)."""
    if timeout is None:
        fcntl.flock(fd, fcntl.LOCK_EX)
        return True
    deadline = time.monotonic() + timeout
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))


def _holder(fd: int, patience: float = 0.5) -> str:
    """Who holds the lock, as its holder wrote it (it writes right after taking the lock)."""
    deadline = time.monotonic() + patience
    while True:
        text = os.pread(fd, 500, 0).decode(errors="replace").strip()
        if text or time.monotonic() > deadline:
            return text or "a process that did not say who it is"
        time.sleep(0.01)
