"""Cold-start time of ``shapeidx check-new`` (a new process each run) for 1, 5 and 20 files,
against one or more stores (of other sizes: the time should grow with the files, not the store).

    .venv/bin/python scripts/bench_checkin.py --store /work/stores/lib.shapeidx \
        [--store SMALLER.shapeidx] --parts /work/shared/data/kicad6 [--runs 5]

The files are copies (outside the store's root, so they are news) of parts of --parts. Prints
a markdown table: per store and file count, the best and median of the runs, and the median's
extra time per file over the one-file run.
"""

import argparse
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--store", required=True, action="append", help="repeatable: one row group per store")
    ap.add_argument("--parts", required=True)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    files = sorted(Path(args.parts).rglob("*.wrl"))
    random.Random(1).shuffle(files)
    print(machine())
    with tempfile.TemporaryDirectory() as tmp:
        copies = []
        for i, f in enumerate(files[:20]):
            copies.append(Path(tmp) / f"{i:02d}_{f.name}")
            shutil.copy(f, copies[-1])
        print("| store | entries | new files | best | median | per extra file (median) |")
        print("|---|---|---|---|---|---|")
        for store in args.store:
            entries = _entries(store)
            first = None
            for n in (1, 5, 20):
                times = []
                for _ in range(args.runs):
                    start = time.perf_counter()
                    done = subprocess.run([sys.executable, "-m", "shapeidx.cli", "check-new", *map(str, copies[:n]),
                                           "--store", store, "--format", "json"], capture_output=True)
                    times.append(time.perf_counter() - start)
                    if done.returncode not in (0, 7):
                        sys.exit(done.stderr.decode())
                median = sorted(times)[len(times) // 2]
                first = median if n == 1 else first
                extra = "" if n == 1 else f"{(median - first) / (n - 1):.3f} s"
                print(f"| {Path(store).name} | {entries:,} | {n} | {min(times):.2f} s | {median:.2f} s | {extra} |")
    print(f"{args.runs} runs each, a new process per run.")


def _entries(store) -> int:
    from shapeidx.search.sharded import open_searcher

    with open_searcher(store) as searcher:
        return len(searcher)

if __name__ == "__main__":
    main()
