"""Start-up time of the ``shapeidx`` command: ``--version``, ``--help``, a command's ``--help``.

Each case runs ``--repeat`` times as a fresh process; the median wall time and the median CPU
time (user + system of the child, from wait4: little affected by other load on the machine)
are printed beside two references: a bare ``python -c pass`` and the imports the command made
up front before issue 15 (``shapeidx.index.build``, ``shapeidx.ranking``, ``shapeidx.api``,
``shapeidx.store``: numpy, h5py, scipy, trimesh, Embree).

    python scripts/bench_startup.py --repeat 15
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path


def run_once(command: list[str]) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of one run of ``command``."""
    started = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - started
    proc.returncode = os.waitstatus_to_exitcode(status)
    return wall, usage.ru_utime + usage.ru_stime


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--command", default=str(Path(sys.executable).with_name("shapeidx")))
    args = parser.parse_args()
    python = sys.executable
    cases = {
        "python -c pass (reference)": [python, "-c", "pass"],
        "old up-front imports (reference)": [python, "-c", "import shapeidx.index.build, shapeidx.search.searcher, "
                                             "shapeidx.api, shapeidx.store, shapeidx.signing.pipeline"],
        "shapeidx --version": [args.command, "--version"],
        "shapeidx --help": [args.command, "--help"],
        "shapeidx query --help": [args.command, "query", "--help"],
        "shapeidx build --help": [args.command, "build", "--help"],
    }
    load = os.getloadavg()[0]
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, load average {load:.1f};"
          f" Python {platform.python_version()}; {args.repeat} runs each")
    print(f"{'case':36s} {'wall (median)':>14s} {'CPU (median)':>13s}")
    for name, command in cases.items():
        runs = [run_once(command) for _ in range(args.repeat)]
        wall = statistics.median(r[0] for r in runs)
        cpu = statistics.median(r[1] for r in runs)
        print(f"{name:36s} {wall:12.3f} s {cpu:11.3f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
