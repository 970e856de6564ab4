"""Committing a build's outcomes: a journal batch every interval, a merge now and then.

Every outcome goes to the :class:`Committer`, which writes a journal batch at least every
``commit_interval`` seconds, so a killed build that is run again redoes at most that much.
Merges are size-tiered (:meth:`StoreWriter.compact`): they rewrite the newest segments of
the journal, and the main file only once the journal holds about as many rows as it does.
"""

from __future__ import annotations

import time

from ..store import Batch, StoreWriter
from .workers import Outcome

#: Seconds between commits of a running build (the work a kill can lose).
DEFAULT_COMMIT_INTERVAL = 60.0
#: Entries a batch holds at most (bounds the builder's memory, whatever the tree's size).
BATCH_ENTRIES = 500
#: Journal batches that trigger a (size-tiered) merge before the build ends.
MERGE_AFTER = 64


class Committer:
    """Collects outcomes into batches and commits them to the journal on time.

    A batch is committed when it holds :data:`BATCH_ENTRIES` records or when
    ``interval`` seconds passed since the last commit; the journal is merged into the main
    file once it holds ``merge_after`` new batches, and by :meth:`finish`; a merge is
    size-tiered (:meth:`StoreWriter.compact`), so it costs about what the batches hold.
    """

    #: Which store the reporter's commit and merge lines name ("": the whole-file store).
    store = ""

    def __init__(self, writer: StoreWriter, interval: float, merge_after: int, reporter):
        self.writer = writer
        self.interval = interval
        self.merge_after = merge_after
        self.reporter = reporter
        self.batch = Batch()
        self.last = time.monotonic()

    def add(self, outcome: Outcome) -> None:
        if outcome.kind in ("indexed", "failed"):
            self.batch.entries.append(outcome.entry)
        elif outcome.kind == "same":
            self.batch.touched.append((outcome.task.path, outcome.size, outcome.mtime_ns))
        elif outcome.kind == "missing" and outcome.task.in_store:
            self.batch.removed.append(outcome.task.path)

    def remove(self, paths: list) -> None:
        self.batch.removed.extend(paths)

    def tick(self) -> None:
        """Commit if the batch is full or old; merge if the journal is long."""
        due = time.monotonic() - self.last >= self.interval
        if len(self.batch) >= BATCH_ENTRIES or (due and len(self.batch)):
            self.commit()
            if self.writer.pending_batches >= self.merge_after:
                merged = self.writer.compact()
                if merged:
                    self.reporter.merged(merged, self.store)

    def commit(self) -> None:
        if len(self.batch):
            seq = self.writer.commit(self.batch)
            self.reporter.committed(seq, len(self.batch), self.store)
            self.batch = Batch()
        self.last = time.monotonic()

    def finish(self) -> None:
        self.commit()
        merged = self.writer.checkpoint()  # the journal folded into the main file once it is large enough
        if merged:
            self.reporter.merged(merged, self.store)


class PartsCommitter(Committer):
    """The sub-entries of ``build --parts``, committed to the parts store (``STORE/parts``):
    a file's new sub-entries replace its old ones."""

    store = "sub-parts"

    #: Sub-entries removed by this build (of files gone, and without ``--parts`` of files signed again).
    removed_count = 0

    def add(self, outcome: Outcome) -> None:
        task = outcome.task
        if not task.parts:  # a build without --parts (index.plan.prune_parts): no sub-part is made
            same = outcome.kind == "same" or (outcome.kind in ("indexed", "failed") and task.parts_hash is not None
                                               and outcome.entry is not None and outcome.entry.hash == task.parts_hash)
            if task.old_parts and same:  # the same content: its sub-parts stand, with the file's new times
                self.batch.touched.extend((p, outcome.size, outcome.mtime_ns) for p in task.old_parts)
            elif task.old_parts and outcome.kind in ("indexed", "failed", "missing"):
                self.batch.removed.extend(task.old_parts)
                self.removed_count += len(task.old_parts)
            return
        if outcome.parts is not None:
            self.batch.removed.extend(p for p in task.old_parts if p not in {e.path for e in outcome.parts})
            self.batch.entries.extend(outcome.parts)
        elif outcome.parts_same:
            self.batch.touched.extend((p, outcome.size, outcome.mtime_ns) for p in task.old_parts)
        elif outcome.kind == "missing":
            self.batch.removed.extend(task.old_parts)
