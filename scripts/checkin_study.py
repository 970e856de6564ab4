"""Truth of check-new on a store of Debian's whole KiCad library (docs/checkin.md):

* recall (leave one out, by ``--exclude-self``): every member of every ``duplicates`` group
  checked as new against the store without its own entry: are its group's other members found
  (as duplicates)?
* false alarms: N random entries in no group, checked the same way: how many get a duplicate.
* ``--xexp``: the 2017 exports of xexp-dev/kicad2017 checked as new parts against the store:
  "already in the library" is true of the pairs still the same model (scripts/twin_study.py's
  rule: 69 of 80; the other 11 were remodelled), found when the KiCad 6 twin (by file name) is
  among the duplicates reported. Precision, recall, and what the remodelled parts get.

Each question is asked with the new parts' points drawn with each ``--query-seed`` (default
three seeds other than the store's: no stored entry shares a query's points) and reported as
the mean over the seeds with their spread.

    .venv/bin/python scripts/checkin_study.py --store /work/stores/lib.shapeidx [--random 500] [--xexp] [--metric M]
"""

import argparse
import os
import random
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import DATA  # noqa: E402

from shapeidx.families.checkin import CANDIDATES  # noqa: E402
from shapeidx.families.duplicates import DEFAULT_TIERS  # noqa: E402

SEEDS = (7, 8, 9)


def leave_one_out(checker, groups, seed, max_members: int, randoms: int) -> dict:
    members = [(m, g) for g in groups for m in g["members"]]
    if max_members:
        members = random.Random(2).sample(members, min(max_members, len(members)))
    root = checker.searcher.root
    found_all = found_any = 0
    misses = []
    for m, g in members:
        report = checker.check(os.path.join(root, m), exclude_self=True, seed=seed)
        got = {d["relative_path"] for d in report["duplicates"]}
        others = set(g["members"]) - {m}
        found_all += others <= got
        found_any += bool(others & got)
        if not others <= got:
            misses.append((m, sorted(others - got)))
    grouped = {m for g in groups for m in g["members"]}
    alone = [str(p) for p in checker.table.paths if str(p) not in grouped]
    sample = random.Random(1).sample(alone, min(randoms, len(alone)))
    alarms = []
    for p in sample:
        report = checker.check(os.path.join(root, p), exclude_self=True, seed=seed)
        if report["duplicates"]:
            alarms.append((p, [(d["relative_path"], d["tier"]) for d in report["duplicates"]]))
    return {"members": len(members), "found_all": found_all, "found_any": found_any, "misses": misses,
            "checked": len(sample), "alarms": alarms}


def xexp(checker, seed) -> dict:
    from twin_study import EXCLUDED

    rows = []
    for path in sorted((DATA / "xexp-dev" / "kicad2017").glob("*.wrl")):
        # every candidate kept as a look-alike, so the twin's tier is known wherever it ranks
        report = checker.check(str(path), seed=seed, look_alikes=CANDIDATES)
        twin = [d for d in report["duplicates"] + report["look_alikes"]
                if os.path.basename(d["relative_path"]) == path.name]
        rows.append({"name": path.name, "same_model": path.name not in EXCLUDED, "status": report["status"],
                     "twin_tier": twin[0]["tier"] if twin else None,
                     "first": report["duplicates"][0] if report["duplicates"] else None})
    positives = [r for r in rows if r["same_model"]]
    tiers = Counter(r["twin_tier"] or "not among the candidates" for r in positives)
    remodelled = Counter(r["twin_tier"] or "not among the candidates" for r in rows if not r["same_model"])
    flagged = [r for r in rows if r["status"] == "duplicate"]
    right = [r for r in flagged if r["twin_tier"] in DEFAULT_TIERS and r["same_model"]]
    return {"rows": rows, "positives": len(positives), "tiers": tiers, "remodelled": remodelled, "flagged": len(flagged), "right": len(right),
            "recall": len([r for r in positives if r["twin_tier"] in DEFAULT_TIERS]) / len(positives),
            "precision": len(right) / max(len(flagged), 1)}


def spread(values) -> str:
    values = np.asarray(values, dtype=float)
    return f"{values.mean():.3f} (seeds {', '.join(f'{v:.3f}' for v in values)})"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--store", required=True)
    ap.add_argument("--random", type=int, default=500)
    ap.add_argument("--max-members", type=int, default=0, help="check at most this many members (0: all)")
    ap.add_argument("--query-seed", type=int, action="append", help=f"repeatable (default {SEEDS})")
    ap.add_argument("--xexp", action="store_true", help="only the xexp-dev/kicad2017 question")
    ap.add_argument("--metric", default=None, help="the gate's metric (default: check-new's own)")
    args = ap.parse_args()
    from shapeidx.cli import _family_table
    from shapeidx.families.checkin import Checker
    from shapeidx.families.duplicates import find_duplicates

    seeds = args.query_seed or SEEDS
    started = time.time()
    metric = {"metric": args.metric} if args.metric else {}
    with Checker(args.store, **metric) as checker:
        print(f"metric {checker.metric}, {CANDIDATES} candidates per part")
        if args.xexp:
            runs = [xexp(checker, seed) for seed in seeds]
            first = runs[0]
            print(f"xexp-dev/kicad2017 against {args.store}: {len(first['rows'])} parts, {first['positives']} still"
                  f" the same model as their KiCad 6 twin")
            print("recall (twin reported as a duplicate):", spread([r["recall"] for r in runs]))
            print("precision (a part reported as a duplicate is a same-model pair whose twin is among them):",
                  spread([r["precision"] for r in runs]))
            print("flagged:", [r["flagged"] for r in runs])
            for label, key in (("same-model twins", "tiers"), ("remodelled parts", "remodelled")):
                names = sorted({t for run in runs for t in run[key]})
                print(f"{label}, their twin's tier by seed:",
                      "; ".join(f"{t} {'/'.join(str(run[key][t]) for run in runs)}" for t in names))
            for k, row in enumerate(first["rows"]):
                tiers = [run["rows"][k]["twin_tier"] for run in runs]
                if not row["same_model"] or any(t is None for t in tiers):
                    firsts = [run["rows"][k]["first"] for run in runs]
                    other = next((f for f in firsts if f and os.path.basename(f["relative_path"]) != row["name"]), None)
                    print(f"  {row['name']}: {'same model' if row['same_model'] else 'remodelled'}; twin by seed: {tiers}"
                          + (f"; reported instead {other['relative_path']} ({other['tier']})" if other else ""))
        else:
            groups = find_duplicates(_family_table(args.store, "combined-angle"))
            runs = [leave_one_out(checker, groups, seed, args.max_members, args.random) for seed in seeds]
            n, m = runs[0]["members"], runs[0]["checked"]
            print(f"{len(groups)} groups, {n} members checked, queries drawn with seeds {', '.join(map(str, seeds))}")
            print("all others found:", spread([r["found_all"] / n for r in runs]))
            print("at least one found:", spread([r["found_any"] / n for r in runs]))
            print(f"false alarms of {m} parts in no group:", spread([len(r["alarms"]) / m for r in runs]))
            for run, seed in zip(runs, seeds):
                for member, rest in run["misses"][:6]:
                    print(f"  seed {seed} miss: {member} -> {rest}")
                for p, d in run["alarms"][:6]:
                    print(f"  seed {seed} alarm: {p} -> {d}")
    print(f"{time.time() - started:.0f} s")


if __name__ == "__main__":
    main()
