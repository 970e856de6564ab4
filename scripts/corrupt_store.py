#!/usr/bin/env python3
"""Corrupt every kind of file a store has, the way a bad disk or an attacker would, and check
that every command still answers as promised.

Usage::

    python scripts/corrupt_store.py TREE --work DIR [--seed 1] [--points 128] [--json out.json] [--only NAME]

A store of TREE is built (with a metadata table, a journal segment beside the main file and a
few thumbnails), its answers are recorded, and then, for each case, a copy of it is damaged:
``main.h5``, a ``journal/`` segment, ``committed``, ``build.json``, ``verified``,
``metadata.h5``, ``thumbs/`` and ``lock`` (random bytes flipped, ranges zeroed, truncation,
deletion, garbage of the same size, HDF5 global heap damage, forged records, a FIFO or a
directory in a file's place). On each copy it runs ``check``, ``stats``, ``query --id`` and
``query FILE``, a query sheet, and ``build`` (and ``build --repair`` when the build refuses).

A case **held** when every command ended within its time limit with a documented status and no
traceback, an error was one line, no answer differed from the intact store's (a command that
answers answers right), and a refused store was rebuilt by ``build --repair`` to the intact
store's answers. Anything else **fell short**, with what happened. Prints a table and the
totals tried / held / fell short.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import random
import shutil
import struct
import subprocess
import sys
import time
from pathlib import Path

TIMEOUT = 120
DOCUMENTED = {0, 1, 2, 3, 4, 5, 6}


def shapeidx(*args) -> list[str]:
    return [sys.executable, "-m", "shapeidx.cli", *map(str, args)]


def run(*args, timeout=TIMEOUT) -> dict:
    started = time.monotonic()
    try:
        done = subprocess.run(shapeidx(*args), capture_output=True, text=True, timeout=timeout,
                              stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        return {"status": "hang", "seconds": timeout, "stdout": "", "stderr": ""}
    return {"status": done.returncode, "seconds": round(time.monotonic() - started, 1), "stdout": done.stdout,
            "stderr": done.stderr}


# ----------------------------------------------------------------------------- the damage


def flip(path: Path, rng: random.Random, count: int = 1, lo: int = 0) -> str:
    data = bytearray(path.read_bytes())
    at = []
    for _ in range(count):
        k = rng.randrange(lo, len(data))
        data[k] ^= 1 << rng.randrange(8)
        at.append(k)
    path.write_bytes(bytes(data))  # in place: same inode
    return f"bit flipped at {at[0]:,}" + (f" (+{count - 1})" if count > 1 else "")


def zero_range(path: Path, rng: random.Random, size: int = 4096) -> str:
    length = path.stat().st_size
    start = rng.randrange(0, max(1, length - size))
    with open(path, "r+b") as f:
        f.seek(start)
        f.write(b"\0" * min(size, length - start))
    return f"{size} bytes zeroed at {start:,}"


def truncate(path: Path, rng: random.Random, share: float = 0.5) -> str:
    length = path.stat().st_size
    os.truncate(path, int(length * share))
    return f"truncated to {int(length * share):,} of {length:,} bytes"


def garbage(path: Path, rng: random.Random) -> str:
    path.write_bytes(bytes(rng.randrange(256) for _ in range(path.stat().st_size)))
    return "replaced by random bytes of the same size"


def heap_free_zero(path: Path, rng: random.Random) -> str:
    """The free-space object of the first global heap collection that has one given size 0."""
    data = path.read_bytes()
    at = data.find(b"GCOL")
    while at >= 0:
        size = struct.unpack_from("<Q", data, at + 8)[0]
        p, end = at + 16, min(at + size, len(data))
        while p + 16 <= end:
            index, length = struct.unpack_from("<H", data, p)[0], struct.unpack_from("<Q", data, p + 8)[0]
            if index == 0 and length >= 16:
                with open(path, "r+b") as f:
                    f.seek(p + 8)
                    f.write(struct.pack("<Q", 0))
                return f"global heap free space at {p:,} (collection at {at:,}) given size 0"
            step = length if index == 0 else 16 + (length + 7) // 8 * 8
            if step < 16:
                break
            p += step
        at = data.find(b"GCOL", at + 4)
    return "no free space object (nothing done)"


def heap_object_size(path: Path, rng: random.Random) -> str:
    data = path.read_bytes()
    at = data.find(b"GCOL")
    if at < 0:
        return "no global heap (nothing done)"
    with open(path, "r+b") as f:
        f.seek(at + 16 + 8)
        f.write(struct.pack("<Q", 2**64 - 32))
    return "first global heap object's size wrapped"


def fifo_in_place(path: Path, rng: random.Random) -> str:
    if path.exists() or path.is_symlink():
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()
    os.mkfifo(path)
    return "replaced by a FIFO"


def dir_in_place(path: Path, rng: random.Random) -> str:
    if path.exists():
        path.unlink()
    path.mkdir()
    (path / "x").write_text("x")
    return "replaced by a directory"


def delete(path: Path, rng: random.Random) -> str:
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink()
    return "deleted"


def write_text(text: str):
    def apply(path: Path, rng: random.Random) -> str:
        path.write_text(text)
        return f"content {text[:40]!r}"
    return apply


def huge(path: Path, rng: random.Random) -> str:
    path.write_bytes(b"{" * (64 << 20))
    return "64 MiB of '{'"


def link_to(target: str):
    def apply(path: Path, rng: random.Random) -> str:
        if path.exists():
            path.unlink()
        path.symlink_to(target)
        return f"symbolic link to {target}"
    return apply


def forged_verified_after(damage):
    """``damage`` the main file, then record its new identity in STORE/verified (as the store's
    own build would after a full read): the cheap check trusts it."""
    def apply(path: Path, rng: random.Random) -> str:
        store = path.parent
        what = damage(store / "main.h5", rng)
        stat = os.stat(store / "main.h5")
        (store / "verified").write_text(json.dumps({k: int(getattr(stat, k)) for k in
                                                    ("st_dev", "st_ino", "st_size", "st_mtime_ns", "st_ctime_ns")}))
        return what + "; verified forged to match"
    return apply


def newest_segment(store: Path) -> Path:
    segments = sorted((store / "journal").glob("batch-*.h5"))
    return segments[-1]


def fake_segment(path: Path, rng: random.Random) -> str:
    store = path.parent.parent
    newest = newest_segment(store)
    number = int(newest.stem.split("-")[1]) + 5
    shutil.copy(newest, newest.with_name(f"batch-{number:010d}.h5"))
    return f"a copy of the newest segment added as segment {number}"


def first_thumbnail(store: Path) -> Path:
    return sorted((store / "thumbs").glob("*.png"))[0]


def cases(rng_seed: int) -> list:
    """(name, file, damage): ``file`` is a path relative to the store, or a function of it."""
    out = []
    main = "main.h5"
    for k in range(6):
        out.append((f"main.h5 bit flip {k + 1}", main, lambda p, r: flip(p, r)))
    out += [
        ("main.h5 8 bit flips", main, lambda p, r: flip(p, r, 8)),
        ("main.h5 superblock bit flip", main, lambda p, r: flip(p, r, 1) if False else _flip_head(p, r)),
        ("main.h5 4 KiB zeroed", main, zero_range),
        ("main.h5 64 KiB zeroed", main, lambda p, r: zero_range(p, r, 65536)),
        ("main.h5 truncated to half", main, truncate),
        ("main.h5 truncated to 0", main, lambda p, r: truncate(p, r, 0.0)),
        ("main.h5 random bytes", main, garbage),
        ("main.h5 deleted", main, delete),
        ("main.h5 global heap free size 0", main, heap_free_zero),
        ("main.h5 global heap size wraps", main, heap_object_size),
        ("main.h5 a FIFO", main, fifo_in_place),
        ("main.h5 a directory", main, dir_in_place),
    ]
    segment = lambda store: newest_segment(store)  # noqa: E731
    for k in range(3):
        out.append((f"segment bit flip {k + 1}", segment, lambda p, r: flip(p, r)))
    out += [
        ("segment truncated", segment, truncate),
        ("segment random bytes", segment, garbage),
        ("segment deleted", segment, delete),
        ("segment global heap free size 0", segment, heap_free_zero),
        ("segment a FIFO", segment, fifo_in_place),
        ("segment: a fake newer one", segment, fake_segment),
        ("committed: garbage", "committed", write_text("\x00\xff not a number")),
        ("committed: a larger number", "committed", write_text("999\n")),
        ("committed: 0", "committed", write_text("0\n")),
        ("committed: empty", "committed", write_text("")),
        ("committed deleted", "committed", delete),
        ("committed a FIFO", "committed", fifo_in_place),
        ("build.json: garbage", "build.json", write_text("{not json")),
        ("build.json: a list", "build.json", write_text("[1, 2]")),
        ("build.json: running, dead pid", "build.json",
         write_text('{"state": "running", "pid": 999999, "host": "x", "started": "2026-01-01T00:00:00+00:00"}')),
        ("build.json: 64 MiB", "build.json", huge),
        ("build.json deleted", "build.json", delete),
        ("build.json a FIFO", "build.json", fifo_in_place),
        ("verified: garbage", "verified", write_text("\x00garbage")),
        ("verified deleted", "verified", delete),
        ("verified forged after a main.h5 bit flip", "verified", forged_verified_after(lambda p, r: flip(p, r))),
        ("verified forged after heap damage", "verified", forged_verified_after(heap_free_zero)),
        ("metadata.h5 bit flip", "metadata.h5", lambda p, r: flip(p, r)),
        ("metadata.h5 truncated", "metadata.h5", truncate),
        ("metadata.h5 random bytes", "metadata.h5", garbage),
        ("metadata.h5 deleted", "metadata.h5", delete),
        ("metadata.h5 global heap free size 0", "metadata.h5", heap_free_zero),
        ("thumbs: a PNG of random bytes", lambda s: first_thumbnail(s), garbage),
        ("thumbs: a PNG as a link to /etc/passwd", lambda s: first_thumbnail(s), link_to("/etc/passwd")),
        ("thumbs: a PNG as a FIFO", lambda s: first_thumbnail(s), fifo_in_place),
        ("thumbs: the folder a file", "thumbs", lambda p, r: (shutil.rmtree(p), p.write_text("x"))[-1] or "a file"),
        ("thumbs deleted", "thumbs", delete),
        ("lock: garbage", "lock", write_text("\x00\xffgarbage")),
        ("lock deleted", "lock", delete),
        ("lock a directory", "lock", dir_in_place),
        ("lock a FIFO", "lock", fifo_in_place),
        ("lock a link to /dev/zero", "lock", link_to("/dev/zero")),
    ]
    return out


def _flip_head(path: Path, rng: random.Random) -> str:
    data = bytearray(path.read_bytes())
    k = rng.randrange(8, 96)
    data[k] ^= 1 << rng.randrange(8)
    path.write_bytes(bytes(data))
    return f"bit flipped at {k} (superblock)"


# ----------------------------------------------------------------------------- the commands


def answers(store: Path, tree: Path, entries: list, query_file: Path, work: Path) -> dict:
    """What each command says about ``store``."""
    out = {"check": run("check", "--store", store),
           "stats": run("stats", "--store", store, "--json"),
           "query_id": run("query", "--store", store, "--json", "--top", "5", *sum((["--id", e] for e in entries), [])),
           "query_file": run("query", query_file, "--store", store, "--json", "--top", "5"),
           "sheet": run("query", "--id", entries[0], "--store", store, "--sheet", work / "sheet.html", "--thumbnails", "3",
                        "--top", "3")}
    return out


def hits_of(result: dict):
    if result["status"] != 0:
        return None
    try:
        data = json.loads(result["stdout"])
    except ValueError:
        return "unparseable"
    blocks = data if isinstance(data, list) else [data]
    return [[(h["relative_path"], round(h["distance"], 9)) for h in b["hits"]] for b in blocks]


def entries_of(result: dict):
    if result["status"] != 0:
        return None
    data = json.loads(result["stdout"])
    return data.get("entries"), data.get("ok"), data.get("failed")


def judge(name: str, got: dict, intact: dict) -> list:
    """What fell short (empty: the case held)."""
    problems = []
    for command, result in got.items():
        status = result["status"]
        if status == "hang":
            problems.append(f"{command} hangs (> {TIMEOUT} s)")
            continue
        if status not in DOCUMENTED:
            problems.append(f"{command} exit {status}")
        if "Traceback" in result["stderr"]:
            problems.append(f"{command} prints a traceback")
        errors = [line for line in result["stderr"].splitlines() if line.startswith("shapeidx: error")]
        if command not in ("check", "build", "repair") and status not in (0,) and len(result["stderr"].strip().splitlines()) > 1:
            problems.append(f"{command}: {len(result['stderr'].strip().splitlines())} lines on stderr")
        if len(errors) > 1:
            problems.append(f"{command}: {len(errors)} error lines")
    for command in ("query_id", "query_file", "after_repair_query_id"):
        if command in got and hits_of(got[command]) is not None and hits_of(got[command]) != hits_of(intact["query_id" if "id" in command else command]):
            problems.append(f"{command} answers differently from the intact store (a silent wrong answer)")
    if "stats" in got and entries_of(got["stats"]) is not None and entries_of(got["stats"]) != entries_of(intact["stats"]):
        problems.append(f"stats counts {entries_of(got['stats'])}, the intact store {entries_of(intact['stats'])}")
    if got.get("check", {}).get("status") == 0 and any(got[c]["status"] == 5 for c in ("query_id", "stats") if c in got):
        problems.append("check passes a store that other commands find damaged")
    if "after_repair_check" in got and got["after_repair_check"]["status"] != 0:
        problems.append(f"after build --repair, check exits {got['after_repair_check']['status']}")
    if "after_repair_query_id" in got and hits_of(got["after_repair_query_id"]) is None:
        problems.append("after build --repair, the query fails")
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("tree", type=Path)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--points", type=int, default=128)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--only", help="run only the cases whose name contains this text")
    args = parser.parse_args()
    tree, work = args.tree.resolve(), args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    base = work / "base.shapeidx"
    build_args = ("--points", args.points, "--workers", "1", "-q")
    files = sorted(p for p in tree.rglob("*") if p.is_file())
    store_tree = work / "tree"  # a copy: three of its files are edited to give the store a journal segment
    if not base.exists():
        shutil.rmtree(store_tree, ignore_errors=True)
        shutil.copytree(tree, store_tree)
        table = work / "metadata.csv"
        with open(table, "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["path", "material"])
            for k, p in enumerate(sorted(p for p in store_tree.rglob("*") if p.is_file())):
                writer.writerow([str(p.relative_to(store_tree)), ("steel", "brass", "nylon")[k % 3]])
        done = run("build", store_tree, "--store", base, "--metadata", table, *build_args, timeout=3600)
        assert done["status"] == 0, done["stderr"]
        for p in sorted(store_tree.rglob("*.wrl"))[:3]:
            with open(p, "ab") as f:
                f.write(b"\n# edited\n")
        done = run("build", store_tree, "--store", base, *build_args, timeout=3600)
        assert done["status"] == 0, done["stderr"]
    assert list((base / "journal").glob("batch-*.h5")), "the base store has no journal segment"
    entries = [str(p.relative_to(store_tree)) for p in sorted(store_tree.rglob("*.wrl"))[::max(1, len(files) // 3)][:3]]
    query_file = sorted(store_tree.rglob("*.wrl"))[len(files) // 2]
    intact_copy = work / "intact.shapeidx"
    shutil.rmtree(intact_copy, ignore_errors=True)
    shutil.copytree(base, intact_copy, symlinks=True)
    intact = answers(intact_copy, store_tree, entries, query_file, work)
    assert intact["check"]["status"] == 0 and hits_of(intact["query_id"]), intact
    assert list((intact_copy / "thumbs").glob("*.png")), "no thumbnails in the base store"
    shutil.rmtree(base / "thumbs", ignore_errors=True)
    shutil.copytree(intact_copy / "thumbs", base / "thumbs")
    rng = random.Random(args.seed)
    report = []
    for name, target, damage in cases(args.seed):
        if args.only and args.only not in name:
            continue
        case = work / "case.shapeidx"
        shutil.rmtree(case, ignore_errors=True)
        shutil.copytree(base, case, symlinks=True)
        path = target(case) if callable(target) else case / target
        what = damage(path, rng)
        got = answers(case, store_tree, entries, query_file, work)
        got["build"] = run("build", store_tree, "--store", case, *build_args)
        if got["build"]["status"] == 5:
            got["repair"] = run("build", store_tree, "--store", case, "--repair", *build_args, timeout=3600)
            got["after_repair_check"] = run("check", "--store", case)
            got["after_repair_query_id"] = run("query", "--store", case, "--json", "--top", "5",
                                               *sum((["--id", e] for e in entries), []))
        problems = judge(name, got, intact)
        row = {"case": name, "damage": what, "held": not problems, "problems": problems,
               "statuses": {c: r["status"] for c, r in got.items()},
               "seconds": round(sum(r["seconds"] for r in got.values()), 1)}
        report.append(row)
        mark = "held" if not problems else "FELL SHORT: " + "; ".join(problems)
        print(f"{name:45s} {' '.join(f'{c}={s}' for c, s in row['statuses'].items())}  {mark}", flush=True)
        shutil.rmtree(case, ignore_errors=True)
    held = sum(r["held"] for r in report)
    print(f"tried {len(report)}, held {held}, fell short {len(report) - held}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    return 0 if held == len(report) else 1


if __name__ == "__main__":
    sys.exit(main())
