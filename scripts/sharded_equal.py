#!/usr/bin/env python3
"""A sharded store answers as one store: every question of every command, on a real tree.

    python scripts/sharded_equal.py ONE.shapeidx SHARDED.shapeidx [--questions 300] [--seed 5]

ONE and SHARDED are built from the same tree with ``--parts`` (SHARDED with ``--shards N``):

    shapeidx build TREE --store one.shapeidx --parts
    shapeidx build TREE --store sharded.shapeidx --parts --shards 4

For ``--questions`` entries drawn at random (files and sub-parts), it asks both stores the
same questions through the one search road and counts the answers that differ: ``query``
(files, two metrics, ``--scale sensitive``), ``query --parts``, ``where-used`` (both scales,
and with ``--max-distance``), ``classify`` (folders as labels), and, once over the whole store,
``duplicates --parts`` and ``cluster`` tables. It prints one line per question kind and exits 1
when any answer differs. The store paths in the answers are left out of the comparison.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def _hits(answer) -> list:
    return [(h.rank, h.relative_path, h.distance, h.parent, h.count) for h in answer.hits]


def _uses(answer) -> tuple:
    found = answer.to_dict()
    found.pop("store")
    return found, answer.reason


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("one")
    parser.add_argument("sharded")
    parser.add_argument("--questions", type=int, default=300)
    parser.add_argument("--seed", type=int, default=5)
    args = parser.parse_args(argv)

    from shapeidx.families.classify import classify_parts
    from shapeidx.families.labels import labels_from_paths
    from shapeidx.search import Filters, open_searcher

    rng = np.random.default_rng(args.seed)
    tally: dict = {}

    def count(kind: str, same: bool, seconds: float):
        asked, differ, spent = tally.get(kind, (0, 0, 0.0))
        tally[kind] = (asked + 1, differ + (not same), spent + seconds)

    started = time.perf_counter()
    with open_searcher(args.one) as one, open_searcher(args.sharded) as sharded:
        files = one.entry_paths()
        asked = [files[i] for i in rng.choice(len(files), min(args.questions, len(files)), replace=False)]
        for entry in asked:
            for metric, scale in (("weighted", "invariant"), ("combined-angle", "sensitive")):
                filters = Filters(scale=scale, exclude_self=True)
                t = time.perf_counter()
                same = _hits(one.search(one.query_of_entry(entry), 10, metric, filters)) == _hits(
                    sharded.search(sharded.query_of_entry(entry), 10, metric, filters))
                count("query", same, time.perf_counter() - t)
        labels = labels_from_paths(files)
        t = time.perf_counter()
        a = classify_parts(one, asked, dict(zip(files, labels)), 3, "combined-angle")
        b = classify_parts(sharded, asked, dict(zip(sharded.entry_paths(), labels_from_paths(sharded.entry_paths()))),
                           3, "combined-angle")
        for x, y in zip(a, b):
            count("classify", x == y, (time.perf_counter() - t) / len(a))
    with open_searcher(args.one, parts=True) as one, open_searcher(args.sharded, parts=True) as sharded:
        subs = one.entry_paths()
        picked = [subs[i] for i in rng.choice(len(subs), min(args.questions, len(subs)), replace=False)]
        wholes = sorted({s.rsplit("#", 1)[0] for s in picked})
        for entry in picked:
            t = time.perf_counter()
            same = _hits(one.search(one.query_of_entry(entry), 10, "all-angle")) == _hits(
                sharded.search(sharded.query_of_entry(entry), 10, "all-angle"))
            count("query --parts", same, time.perf_counter() - t)
        for entry in picked + wholes:
            for scale, within in (("sensitive", None), ("invariant", None), ("invariant", 0.002)):
                t = time.perf_counter()
                same = _uses(one.where_used(one.question_of_entry(entry), 10, "all-angle", within, scale)) == _uses(
                    sharded.where_used(sharded.question_of_entry(entry), 10, "all-angle", within, scale))
                count("where-used", same, time.perf_counter() - t)
    from click.testing import CliRunner

    from shapeidx.cli import main as cli

    for command in (["duplicates", "--parts", "--similar"], ["cluster", "--clusters", "20"]):
        t = time.perf_counter()
        got = [CliRunner().invoke(cli, [*command, "--store", store, "--json"]) for store in (args.sharded, args.one)]
        same = all(r.exit_code == 0 for r in got) and json.loads(got[0].output) == json.loads(got[1].output)
        count(" ".join(command[:2]), same, time.perf_counter() - t)
    for kind, (n, differ, spent) in tally.items():
        print(f"{kind:22s} {n:5d} questions, {differ} answered otherwise ({spent / n * 1e3:.1f} ms each, both stores)")
    print(f"{sum(t[0] for t in tally.values())} questions in {time.perf_counter() - started:.0f} s")
    return 1 if any(t[1] for t in tally.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
