"""Truth of check-new on a store (leave one out, by --exclude-self):

* recall: every member of every ``duplicates`` group checked as new against the store without
  its own entry: are its group's other members found (as duplicates)?
* false alarms: N random entries in no group: how many get a duplicate.

    .venv/bin/python scripts/checkin_study.py --store /work/stores/lib.shapeidx [--random 500]
"""

import argparse
import os
import random
import sys
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--store", required=True)
    ap.add_argument("--random", type=int, default=500)
    ap.add_argument("--max-members", type=int, default=0, help="check at most this many members (0: all)")
    args = ap.parse_args()
    from shapeidx.cli import _family_table
    from shapeidx.families.checkin import Checker
    from shapeidx.families.duplicates import find_duplicates

    started = time.time()
    groups = find_duplicates(_family_table(args.store, "combined-angle"))
    members = [(m, g) for g in groups for m in g["members"]]
    if args.max_members:
        members = random.Random(2).sample(members, min(args.max_members, len(members)))
    found_all = found_any = 0
    misses = []
    with Checker(args.store) as checker:
        root = checker.searcher.root
        for m, g in members:
            report = checker.check(os.path.join(root, m), exclude_self=True)
            got = {d["relative_path"] for d in report["duplicates"]}
            others = set(g["members"]) - {m}
            found_all += others <= got
            found_any += bool(others & got)
            if not others <= got:
                misses.append((m, sorted(others - got)))
        grouped = {m for g in groups for m in g["members"]}
        alone = [str(p) for p in checker.table.paths if str(p) not in grouped]
        sample = random.Random(1).sample(alone, min(args.random, len(alone)))
        alarms = []
        for p in sample:
            report = checker.check(os.path.join(root, p), exclude_self=True)
            if report["duplicates"]:
                alarms.append((p, [(d["relative_path"], d["tier"]) for d in report["duplicates"]]))
    n = len(members)
    print(f"{len(groups)} groups, {n} members checked: all others found {found_all}/{n} ({found_all / max(n, 1):.1%}),"
          f" at least one found {found_any}/{n}")
    print(f"false alarms: {len(alarms)}/{len(sample)} ({len(alarms) / max(len(sample), 1):.1%})")
    for m, rest in misses[:10]:
        print("miss:", m, "->", rest)
    for p, d in alarms[:10]:
        print("alarm:", p, "->", d)
    print(f"{time.time() - started:.0f} s")


if __name__ == "__main__":
    main()
