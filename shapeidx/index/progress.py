"""What a build tells its user while it runs, on stderr.

* On a terminal: a progress bar with the rate and the time left.
* Elsewhere (cron, a log file): plain lines, a progress line every :data:`LOG_EVERY` seconds.
* Either way: each failed file on one line (``failed PATH: reason``); ``quiet`` keeps only
  the files that failed for the first time (a file that failed before and still fails is
  not news); ``verbose`` adds a line per indexed file and per commit.

Every line starts with ``shapeidx build:``; elsewhere than on a terminal it is preceded by a
timestamp, so that a log of nightly runs can be read back. File names are printed with their
control characters escaped (a newline in a name cannot forge a line) and reasons without
Python's byte reprs. scripts/kill_build.py finds ``committed batch N (M records)`` and
``indexed PATH (1.2s)`` anywhere in a line: keep those texts (the parts store's commits,
``build --parts``, say ``committed sub-parts batch N (M records)``).
"""

from __future__ import annotations

import sys
import time

import click

from ..errors import plain_reason, timestamp
from ..errors import printable

#: Seconds between progress lines when stderr is not a terminal.
LOG_EVERY = 30.0


def duration(seconds: float) -> str:
    """``42s``, ``3m05s``, ``2h07m``."""
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


def plan_words(plan) -> str:
    """``120 files: 3 new or changed, 37 signed by an older STEP reader, 80 unchanged, 0 to remove``:
    what a build's plan holds. The files an older revision of their reader signed (unchanged
    otherwise: :attr:`shapeidx.index.plan.Plan.older`) are named apart, so that the user sees
    why they are indexed again."""
    from .plan import older_words

    older, older_parts = getattr(plan, "older", {}) or {}, getattr(plan, "older_parts", {}) or {}
    only_parts = sum(not getattr(task, "whole", True) for task in plan.tasks)
    changed = len(plan.tasks) - only_parts - sum(older.values())
    text = f"{plan.found} files: {changed} new or changed, "
    text += f"{older_words(older)}, " if older else ""
    text += f"{plan.unchanged} unchanged, {len(plan.removed)} to remove"
    if only_parts:
        text += f"; {only_parts} to split into sub-parts"
    if older_parts:  # made again whatever their file's own entry needs
        text += f"; {older_words(older_parts, 'files whose sub-parts were made')}"
    return text


class BuildReporter:
    """Prints a build's progress; see the module docstring.

    Parameters
    ----------
    quiet, verbose : bool
    terminal : bool or None
        Draw a progress bar; None: when stderr is a terminal.
    """

    def __init__(self, quiet: bool = False, verbose: bool = False, terminal: bool | None = None):
        #: Paths that had failed before this build: their failing again is not news under ``quiet``.
        self.failed_before: set = set()
        self.quiet = quiet
        self.verbose = verbose and not quiet
        self.terminal = sys.stderr.isatty() if terminal is None else terminal
        self.bar = None
        self.total = self.done = self.failed = 0
        self.started = self.last_line = time.monotonic()

    def _say(self, text: str) -> None:
        """One line on stderr: prefixed, and timestamped when not on a terminal."""
        if not text.startswith("shapeidx build: "):
            text = "shapeidx build: " + text
        if self.bar is not None:
            text = "\r\033[K" + text  # over the bar, which redraws on its next step
        elif not self.terminal:
            text = f"{timestamp()} {text}"
        click.echo(text, err=True)

    def say(self, text: str) -> None:
        """A line the user must see, even under ``quiet`` (e.g. why --strict fails the run)."""
        self._say(text)

    def waiting(self, holder: str) -> None:
        if not self.quiet:
            self._say(f"shapeidx build: waiting for the store's lock ({holder})")

    def warning(self, text: str) -> None:
        self._say(f"shapeidx build: warning: {text}")

    def planned(self, plan) -> None:
        self.failed_before = set(getattr(plan, "failed_before", ()))
        self.total = len(plan.tasks)
        self.started = self.last_line = time.monotonic()
        if self.quiet:
            return
        self._say("shapeidx build: " + plan_words(plan))
        if self.terminal and self.total:
            self.bar = click.progressbar(
                length=self.total, file=sys.stderr, show_eta=True, show_pos=True, item_show_func=self._rate_text
            )
            self.bar.__enter__()

    def _rate_text(self, _item=None) -> str:
        elapsed = max(time.monotonic() - self.started, 1e-9)
        failed = f", {self.failed} failed" if self.failed else ""
        return f"{self.done / elapsed:.1f} files/s{failed}"

    def outcome(self, outcome) -> None:
        self.done += 1
        if outcome.kind == "failed":
            self.failed += 1
            if not self.quiet or outcome.task.path not in self.failed_before:
                self._say(f"failed {printable(outcome.task.path)}: {plain_reason(outcome.entry.reason)}")
        elif self.verbose and outcome.kind == "indexed":
            self._say(f"indexed {printable(outcome.task.path)} ({outcome.seconds:.1f}s)")
        if self.bar is not None:
            self.bar.update(1)
        elif not self.quiet and time.monotonic() - self.last_line >= LOG_EVERY:
            self._progress_line()

    def _progress_line(self) -> None:
        self.last_line = time.monotonic()
        elapsed = self.last_line - self.started
        rate = self.done / max(elapsed, 1e-9)
        left = duration((self.total - self.done) / rate) if rate > 0 else "?"
        percent = 100.0 * self.done / max(self.total, 1)
        self._say(f"shapeidx build: {self.done}/{self.total} files ({percent:.0f}%), {self._rate_text()}, {left} left")

    def committed(self, seq: int, records: int, store: str = "") -> None:
        """A batch was committed; ``store``: which one, when not the whole-file store (``sub-parts``)."""
        if self.verbose:
            self._say(f"committed {store + ' ' if store else ''}batch {seq} ({records} records)")

    def merged(self, what: str = "main", store: str = "") -> None:
        """A merge happened: ``what`` is :meth:`~shapeidx.store.StoreWriter.compact`'s answer."""
        if self.verbose:
            journal = f"the {store + ' ' if store else ''}journal"
            self._say(f"merged {journal} into the main file" if what == "main"
                      else f"merged {journal}'s newest segments into one")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None
