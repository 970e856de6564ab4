#!/usr/bin/env python3
"""kill -9 a real ``shapeidx build`` at random moments, and check the store after each kill.

Usage::

    python scripts/kill_build.py TREE --store S.h5 [--kills 6] [--seed 1] [--points 128] [--workers N] [--parts]

Each round starts ``shapeidx build TREE`` (committing every 0.2 s, merging every 3
batches, so kills land in every phase: computing, writing a batch, writing a merged main
file, renaming) and kills it with SIGKILL: a random fraction of a second after a random
number of indexed files, or during start-up, or as soon as a merge starts writing its
temporary file. Then it checks:

* the store opens (``shapeidx stats`` exits 0) and its entries are unique, sorted, and
  files of the tree;
* it holds at least every entry whose commit the build reported before the kill;
* a query answers, with the queried entry at rank 1;
* the killed build's worker processes are gone;
* the next build plans exactly the files that are not in the store yet.

A last build runs to the end: every file of the tree is then in the store exactly once,
and one more build finds nothing to do. Exits 1 on the first broken promise.

With ``--parts`` the builds also sign the files' sub-parts into ``S/parts``, every fourth
kill lands as a merge of the parts store starts writing, and after each kill also:

* ``shapeidx check --store S`` exits 0 (it checks the parts store too);
* the parts store's entries are unique, sorted, sub-entries of files of the tree, and at
  least every sub-entry whose commit the build reported before the kill;
* ``where-used --id`` of a sub-entry answers, naming its file;
* the next build plans exactly the files without a whole entry or without sub-entries;

and at the end every file of the tree has its sub-entries and one more build makes none.
"""

from __future__ import annotations

import argparse
import json
import random
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

COMMITTED = re.compile(r"committed batch \d+ \((\d+) records\)")
#: The same for the parts store (``build --parts``).
PARTS_COMMITTED = re.compile(r"committed sub-parts batch \d+ \((\d+) records\)")
#: A --verbose line for one indexed file, e.g. "indexed a/b.wrl (0.1s)" (after any prefix).
INDEXED = re.compile(r"\bindexed \S.* \([\d.]+s\)$")


def shapeidx(*args) -> list[str]:
    """The command line running shapeidx with this interpreter."""
    return [sys.executable, "-m", "shapeidx.cli", *map(str, args)]


def children_of(pid: int) -> list[int]:
    """Processes whose parent is ``pid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.append(int(entry.name))
    return found


def alive(pid: int) -> bool:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return False
    return fields[0] != "Z"


def gone_within(pids: list, seconds: float) -> bool:
    """Whether these processes end within ``seconds`` (a worker still starting up notices
    its parent's death only once it runs; one already working is killed at once)."""
    deadline = time.monotonic() + seconds
    while any(alive(pid) for pid in pids):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def merge_in_progress(store: Path, pid: int) -> bool:
    """Process ``pid`` writing a new main file over an existing one (not the first, empty one),
    or a merged journal segment over an existing one (a commit writes a segment of a new number).

    The temporary file's name carries the writer's pid: one left by an earlier killed build
    does not count.
    """
    main = store / "main.h5"
    if main.exists() and main.with_name(f"{main.name}.tmp-{pid}").exists():
        return True
    journal = store / "journal"
    try:
        return any(tmp.name.split(".tmp-")[0] and (journal / tmp.name.split(".tmp-")[0]).exists()
                   for tmp in journal.glob(f"batch-*.h5.tmp-{pid}"))
    except OSError:
        return False


class Moment:
    """When to kill a build: ``after`` indexed files plus ``delay`` s, at ``start`` s, or as a merge starts."""

    def __init__(self, kind: str, count: int = 0, delay: float = 0.0):
        self.kind, self.count, self.delay = kind, count, delay

    def __str__(self) -> str:
        if self.kind == "merge":
            return "as a merge started writing"
        if self.kind == "parts-merge":
            return "as a merge of the parts store started writing"
        if self.kind == "start":
            return f"{self.delay:.2f} s after starting"
        return f"{self.delay:.2f} s after indexed file {self.count}"


def run_and_kill(command: list, store: Path, moment: Moment, log: Path) -> dict:
    """Start ``command`` and SIGKILL it at ``moment`` (if it has not ended by then).

    Returns what happened: exit status, whether it was killed, its workers, its stderr.
    """
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: list = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()
    started = time.monotonic()
    due_at = started + moment.delay if moment.kind == "start" else None
    workers: list = []
    while proc.poll() is None:
        workers = children_of(proc.pid) or workers
        now = time.monotonic()
        if due_at is None and moment.kind == "after":
            if sum(bool(INDEXED.search(line)) for line in list(lines)) >= moment.count:
                due_at = now + moment.delay
        merging = ((moment.kind == "merge" and merge_in_progress(store, proc.pid))
                   or (moment.kind == "parts-merge" and merge_in_progress(store / "parts", proc.pid)))
        if (due_at is not None and now >= due_at) or merging:
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.001)
    status = proc.wait()
    reader.join(timeout=10)
    log.write_text("".join(lines))
    return {"status": status, "killed": status == -signal.SIGKILL, "workers": workers, "log": "".join(lines),
            "mid_merge": merge_in_progress(store, proc.pid) or merge_in_progress(store / "parts", proc.pid)}


def store_paths(store: Path) -> list[str]:
    """Entry paths of the store, read by a separate process like any user would."""
    out = subprocess.run(
        [sys.executable, "-c", "import sys, json; from shapeidx.store import open_store;"
         " r = open_store(sys.argv[1]); print(json.dumps(list(r.paths)))", str(store)],
        capture_output=True, text=True,
    )
    check(out.returncode == 0, f"the store does not open: {out.stderr.strip()}")
    return json.loads(out.stdout)


def check(condition: bool, message: str) -> None:
    if not condition:
        raise AssertionError(message)


def check_store(store: Path, tree_files: set, at_least: int) -> list[str]:
    """The promises that must hold after any kill; returns the entry paths."""
    if not store.exists() and at_least == 0:
        return []  # killed before it created the store: nothing was committed, nothing is lost
    stats = subprocess.run(shapeidx("stats", "--store", store, "--json"), capture_output=True, text=True)
    check(stats.returncode == 0, f"stats failed: {stats.stderr.strip()}")
    paths = store_paths(store)
    check(len(paths) == len(set(paths)), "an entry is in the store twice")
    check(paths == sorted(paths), "entries are not sorted by path")
    check(set(paths) <= tree_files, f"entries not in the tree: {sorted(set(paths) - tree_files)[:3]}")
    check(len(paths) >= at_least, f"{len(paths)} entries, but {at_least} were reported committed")
    check(json.loads(stats.stdout)["entries"] == len(paths), "stats and the reader disagree")
    if paths:
        query = subprocess.run(
            shapeidx("query", "--store", store, "--id", paths[len(paths) // 2], "--top", "3", "--json"),
            capture_output=True, text=True,
        )
        check(query.returncode == 0, f"query failed: {query.stderr.strip()}")
        check(json.loads(query.stdout)["hits"][0]["relative_path"] == paths[len(paths) // 2],
              "the queried entry is not at rank 1")
    return paths


def parts_paths(store: Path) -> tuple[list, list]:
    """(paths, parents) of the sub-entries of ``store``'s parts store, read by a separate process."""
    out = subprocess.run(
        [sys.executable, "-c", "import sys, json; from shapeidx.store import open_store;"
         " r = open_store(sys.argv[1]); print(json.dumps([[str(p) for p in r.paths],"
         " [str(p) for p in r.column('entries/parent')]]))", str(store / "parts")],
        capture_output=True, text=True,
    )
    check(out.returncode == 0, f"the parts store does not open: {out.stderr.strip()}")
    paths, parents = json.loads(out.stdout)
    return paths, parents


def check_parts(store: Path, tree_files: set, at_least: int) -> tuple[list, list]:
    """The promises about the parts store (``build --parts``) that must hold after any kill."""
    if not (store / "parts" / "main.h5").exists() and at_least == 0:
        return [], []  # killed before the parts store was made: nothing of it was committed
    checked = subprocess.run(shapeidx("check", "--store", store), capture_output=True, text=True)
    check(checked.returncode == 0, f"check --store failed: {(checked.stdout + checked.stderr).strip()[-500:]}")
    paths, parents = parts_paths(store)
    check(len(paths) == len(set(paths)), "a sub-entry is in the parts store twice")
    check(paths == sorted(paths), "sub-entries are not sorted by path")
    check(set(parents) <= tree_files, f"sub-entries of files not in the tree: {sorted(set(parents) - tree_files)[:3]}")
    check(len(paths) >= at_least, f"{len(paths)} sub-entries, but {at_least} were reported committed")
    if paths:
        k = len(paths) // 2
        used = subprocess.run(shapeidx("where-used", "--store", store, "--id", paths[k], "--top", "3", "--json"),
                              capture_output=True, text=True)
        check(used.returncode == 0, f"where-used failed: {used.stderr.strip()}")
        check(parents[k] in {u["relative_path"] for u in json.loads(used.stdout)["uses"]},
              f"where-used --id {paths[k]} does not name its file {parents[k]}")
    return paths, parents


def moments(rng: random.Random, round_: int, left: int, parts: bool = False) -> Moment:
    """Round 0 and every third: as a merge starts; round 1: during start-up; else mid-work.
    With ``parts``, every fourth round instead: as a merge of the parts store starts."""
    if parts and round_ % 4 == 3:
        return Moment("parts-merge")
    if round_ % 3 == 0:
        return Moment("merge")
    if round_ == 1:
        return Moment("start", delay=rng.uniform(0.1, 1.5))
    return Moment("after", count=rng.randint(1, max(1, left // 2)), delay=rng.uniform(0.0, 0.4))


def kill_campaign(tree: Path, store: Path, kills: int, seed: int, build_args=(), log_dir: Path | None = None,
                  say=print, parts: bool = False) -> dict:
    """Kill builds of ``tree`` ``kills`` times at :func:`moments`, check after each, then finish.
    ``parts``: the builds sign sub-parts too (``--parts``), checked by :func:`check_parts`.

    Returns counts: rounds, kills that left a merge's temporary file behind, final entries
    (and with ``parts``: final sub-entries, and kills as a merge of the parts store started).
    """
    rng = random.Random(seed)
    tree_files = set(tree_file_paths(tree))
    log_dir = log_dir or store.parent
    build_args = tuple(build_args) + (("--parts",) if parts else ())
    command = shapeidx("build", tree, "--store", store, "--verbose", "--commit-interval", "0.2",
                       "--merge-after", "3", *build_args)
    entries, mid_merge, parts_merges = 0, 0, 0
    sub, orphans = set(), 0  # sub-entries; those of files without a whole entry (their next commit may touch them)
    for round_ in range(kills):
        moment = moments(rng, round_, len(tree_files) - entries, parts)
        result = run_and_kill(command, store, moment, log_dir / f"build-{round_}.log")
        committed = committed_records(result["log"])
        mid_merge += result["killed"] and result["mid_merge"]
        parts_merges += result["killed"] and moment.kind == "parts-merge"
        check(gone_within(result["workers"], 5.0), f"round {round_}: workers outlived the build")
        paths = check_store(store, tree_files, entries + committed)
        entries = len(paths)
        plan = plan_of(tree, store, build_args)
        check(plan["planned"] == len(tree_files) - entries,
              f"round {round_}: the next build plans {plan['planned']} files, {len(tree_files) - entries} are left")
        words = ""
        if parts:
            # a commit's records are new sub-entries, but for the times given to those already
            # committed whose file had no whole entry yet
            before = sub
            found, parents = check_parts(store, tree_files,
                                         len(before) + committed_records(result["log"], PARTS_COMMITTED) - orphans)
            sub = set(found)
            check(before <= sub, f"round {round_}: sub-entries lost: {sorted(before - sub)[:3]}")
            orphans = sum(parent not in set(paths) for parent in parents)
            left = len(tree_files - (set(paths) & set(parents)))  # no whole entry, or no sub-entries
            check(plan["parts"]["planned"] == left,
                  f"round {round_}: the next build makes the sub-parts of {plan['parts']['planned']} files, {left} are left")
            words = f", {len(sub)} sub-entries"
        say(f"round {round_}: {'killed' if result['killed'] else 'ended'} {moment}; {entries} entries{words}")
    final = subprocess.run(command, capture_output=True, text=True)
    check(final.returncode == 0, f"the final build failed: {final.stderr[-500:]}")
    paths = check_store(store, tree_files, len(tree_files))
    check(set(paths) == tree_files, "the final store misses files")
    again = build_record(tree, store, build_args)
    check(again["planned"] == 0 and again["indexed"] == 0, f"a build after the last did work: {again}")
    report = {"rounds": kills, "mid_merge": mid_merge, "entries": len(paths), "final": final.stdout.strip()}
    if parts:
        found, parents = check_parts(store, tree_files, len(sub))
        check(set(parents) == tree_files, f"files without sub-entries after the last build: {sorted(tree_files - set(parents))[:3]}")
        check(again["parts"]["planned"] == 0 and again["parts"]["indexed"] == 0 and again["parts"]["removed"] == 0,
              f"a build after the last did work on the sub-parts: {again['parts']}")
        report.update(sub_entries=len(found), parts_merges=parts_merges)
    return report


def committed_records(log: str, pattern: re.Pattern = COMMITTED) -> int:
    """Records the build's --verbose log says it committed (``pattern``: :data:`COMMITTED`,
    or :data:`PARTS_COMMITTED` for the parts store); a commit line that does not parse fails
    the check (a changed message must not make the lower bound silently 0)."""
    marker = "committed sub-parts batch" if pattern is PARTS_COMMITTED else "committed batch"
    lines = [line for line in log.splitlines() if marker in line]
    counts = [pattern.search(line) for line in lines]
    check(all(counts), f"unparsable commit line in the build's log: {lines[counts.index(None)]!r}" if None in counts else "")
    return sum(int(m.group(1)) for m in counts)


def build_record(tree: Path, store: Path, build_args=(), *extra) -> dict:
    """The JSON record of ``shapeidx build --json`` (read strictly: a record that does not parse
    or lacks a count fails the check, it never passes it)."""
    out = subprocess.run(shapeidx("build", tree, "--store", store, "--json", *build_args, *extra),
                         capture_output=True, text=True)
    check(out.returncode == 0, f"build --json failed: {out.stderr.strip()[-500:]}")
    try:
        record = json.loads(out.stdout)
    except json.JSONDecodeError:
        raise AssertionError(f"build --json printed no JSON record: {out.stdout[-300:]!r}") from None
    for key in ("found", "planned", "indexed", "unchanged", "removed", "failed"):
        check(isinstance(record.get(key), int), f"build --json record lacks {key!r}: {record}")
    return record


def plan_of(tree: Path, store: Path, build_args=()) -> dict:
    """What the next build would do, from its machine-readable dry-run record."""
    return build_record(tree, store, build_args, "--dry-run")


def tree_file_paths(tree: Path) -> list[str]:
    """What shapeidx build should index under ``tree``."""
    from shapeidx.index.walk import walk_parts

    return [f.path for f in walk_parts(tree.resolve()).files]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("tree", type=Path)
    parser.add_argument("--store", type=Path, required=True)
    parser.add_argument("--kills", type=int, default=6)
    parser.add_argument("--seed", type=int, default=int(time.time()))
    parser.add_argument("--points", type=int, default=128)
    parser.add_argument("--workers", type=int, default=0, help="worker processes of each build (0: the build's default)")
    parser.add_argument("--parts", action="store_true", help="build with --parts and check the parts store too")
    args = parser.parse_args()
    print(f"seed {args.seed}")
    try:
        build_args = ("--points", args.points) + (("--workers", args.workers) if args.workers else ())
        report = kill_campaign(args.tree, args.store.resolve(), args.kills, args.seed, build_args, parts=args.parts)
    except AssertionError as exc:
        print(f"FAILED: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
