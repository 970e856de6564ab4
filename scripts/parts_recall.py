"""Does a pin or a body taken out of a KiCad STEP file find the files that use it? (docs/assemblies.md)

    python scripts/parts_recall.py STORE [--tree ../shared/data/kicad6-step] [--metric weighted ...]
    python scripts/parts_recall.py STORE --tree /work/debian/step --metric all-angle --scale sensitive \
        --sample 200 --truth-cache step-truth.json        # a whole library: a random 200 of its solids
    python scripts/parts_recall.py STORE ... --questions run.json   # ask what an earlier run (its --json) asked
    python scripts/parts_recall.py STORE --query-seed 7 --query-seed 8 --query-seed 9   # drawn again (issue 33)

STORE must be built from the tree with ``shapeidx build TREE --store STORE --parts``.

The truth comes from the files' own solid structure, read with OpenCASCADE independently of
shapeidx's splitting: every solid of every file (plain ``STEPControl_Reader``, ``TopExp`` over
solids), described by exact B-rep invariants (volume, area, principal moments of inertia,
from ``BRepGProp``). Two solids are the same part when these agree within 1e-4. A face going
round its periodic surface more than once (the KiCad transformers' pins) corrupts those
invariants as it corrupts the mesh, so the truth's solids get the reader's repair
(``shapeidx.io.step.unwound``: the one-turn band, checked against the VRML twins) unless
``--raw-truth`` is given (``--truth-cache`` keeps the invariants, which truth they are and
the faces the repair replaces in each file; a cache of the other truth is reused for every
file the repair leaves alone). For each file with several solids, each distinct solid is
written out as a STEP file of its own (moved by a random rigid motion) and asked
``where-used`` (the library's road, shapeidx.search.where_used); the files relevant to it
are those holding a solid with its invariants, and the count each holds is the truth for
the reported ``count``.

Reported per metric and ``--scale`` (sensitive: where-used's default, sub-parts of another
size left out; invariant: the paper's): R-precision (of the R files that hold the part, how
many are in the top R), recall in the top 10, precision and recall with ``--max-distance``
at the metric's duplicate thresholds (``same`` and ``near``, shapeidx/distance/thresholds.json),
and how often the reported count of a relevant file found in the top R is right;
``--show-wrong`` lists each file whose count is wrong (the query's file, the file, our count,
the truth's), per run, and each question whose first R files are not all its holders (what
came first, at what distance, and where its holders are).

The store's seed and the query's: by default each question is signed as the store signs its
entries, with the store's seed, so an exact copy of a stored sub-part (every question here is
one, moved) gets its points at nearly the same places on the surface as the stored sub-part
had: an advantage no real query has. ``--query-seed S`` (repeatable) asks every question again
signed with seed ``S`` (``Searcher.query_of_part(..., seed=S)``: the same written file, the same
rigid motion, only the points drawn otherwise); each run is then reported with the store's
seed and, drawn again, as the mean and the lowest-highest over the seeds. The JSON keeps the
store's-seed runs as ``runs`` (as without the option) and every seed's own as
``drawn_again``'s ``per_seed``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import DATA, machine  # noqa: E402

TOLERANCE = 1e-4


#: Whether the truth's solids have their multi-turn faces replaced by one turn (``--raw-truth``: not)
UNWIND = True


def solids_of(path: Path) -> tuple[list, int]:
    """The file's solids (repaired unless ``--raw-truth``) and how many faces the repair
    replaces in it (counted either way)."""
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_SOLID
    from OCP.TopExp import TopExp_Explorer

    from shapeidx.io.step import unwound

    reader = STEPControl_Reader()
    if str(reader.ReadFile(str(path))).rsplit(".", 1)[-1] != "IFSelect_RetDone":
        return [], 0
    reader.TransferRoots()
    shape = reader.OneShape()
    (repaired,), count = unwound([shape])
    if UNWIND:
        shape = repaired
    out, explorer = [], TopExp_Explorer(shape, TopAbs_SOLID)
    while explorer.More():
        out.append(explorer.Current())
        explorer.Next()
    return out, count


def invariants(solid) -> np.ndarray:
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    volume, area = GProp_GProps(), GProp_GProps()
    BRepGProp.VolumeProperties_s(solid, volume)
    BRepGProp.SurfaceProperties_s(solid, area)
    m = volume.MatrixOfInertia()
    inertia = np.linalg.eigvalsh(np.array([[m.Value(i, j) for j in (1, 2, 3)] for i in (1, 2, 3)]))
    return np.concatenate([[abs(volume.Mass()), area.Mass()], np.sort(inertia)])


def same(a: np.ndarray, b: np.ndarray) -> bool:
    scale = np.maximum(np.abs(a), np.abs(b))
    return bool(np.all(np.abs(a - b) <= TOLERANCE * scale + 1e-9 * np.max(scale)))


def same_rows(table: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """The rows of ``table`` that are the same solid as ``inv`` (``same``, vectorised)."""
    scale = np.maximum(np.abs(table), np.abs(inv))
    return np.all(np.abs(table - inv) <= TOLERANCE * scale + 1e-9 * scale.max(axis=1, keepdims=True), axis=1)


def read_truth(tree: Path, files: list, cache: Path | None) -> tuple[dict, dict]:
    """Each file's solids' invariants (relative path -> list of arrays), read with OCCT once,
    and how many faces the repair replaces in each file (relative path -> count).

    The cache records which truth it holds (``unwound``: repaired or raw) and, per file, the
    faces the repair replaces (``repaired``). A cache of the other truth is not thrown away:
    a file in which the repair replaces no face has the same solids either way, so only the
    others' invariants are computed again (finding them takes a read of each file not yet
    counted, ~0.1 s, not the BRepGProp invariants that make the hour of a whole library).
    """
    known = json.loads(cache.read_text()) if cache and cache.exists() else {}
    if known.get("tree") != str(tree):
        known = {}
    solids, repaired = known.get("files", {}), known.get("repaired", {})
    if known and known.get("unwound", False) != UNWIND:
        for name in files:
            if name in solids and name not in repaired:
                repaired[name] = solids_of(tree / name)[1]
        solids = {name: v for name, v in solids.items() if repaired.get(name) == 0}
    known = {"tree": str(tree), "unwound": UNWIND, "files": solids, "repaired": repaired}
    for name in files:
        if name not in solids:
            read, repaired[name] = solids_of(tree / name)
            solids[name] = [invariants(s).tolist() for s in read]
    if cache:
        cache.write_text(json.dumps(known))
    return ({name: [np.array(v) for v in solids[name]] for name in files},
            {name: repaired[name] for name in files if name in repaired})


def random_rigid(rng):
    from OCP.gp import gp_Quaternion, gp_Trsf, gp_Vec

    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    rotation, translation = gp_Trsf(), gp_Trsf()
    rotation.SetRotation(gp_Quaternion(*q))
    translation.SetTranslation(gp_Vec(*rng.uniform(-50, 50, 3)))
    return translation.Multiplied(rotation)


def write_solid(solid, trsf, path: Path) -> None:
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    from shapeidx.io.step import quiet_opencascade

    quiet_opencascade()
    writer = STEPControl_Writer()
    writer.Transfer(BRepBuilderAPI_Transform(solid, trsf, True).Shape(), STEPControl_AsIs)
    writer.Write(str(path))


def new_result(tiers) -> dict:
    """What one run (a seed, metric, scale and size) gathers over its questions."""
    return {"r_precision": [], "recall_10": [], "count_right": [], "count_right_same": [], "wrong": [],
            "misses": [], "at": {t: [0, 0, 0] for t in tiers}}


def ask(searcher, question, name, holders, res, metric, scale, size, tiers) -> None:
    """Ask ``question`` (a solid of file ``name``, held by ``holders``: file -> count) one run's
    where-used and add what it found to ``res``."""
    r = len(holders)
    answer = searcher.where_used(question, top=max(10, r), metric=metric, scale=scale, same_size=size)
    ranked = [u.relative_path for u in answer.uses]
    res["r_precision"].append(len(set(ranked[:r]) & set(holders)) / r)
    res["recall_10"].append(len(set(ranked[:10]) & set(holders)) / r)
    res["count_right"].extend(u.count == holders[u.relative_path] for u in answer.uses[:r]
                              if u.relative_path in holders)
    res["wrong"].extend({"query": name, "file": u.relative_path, "part": u.part, "count": u.count,
                         "truth": holders[u.relative_path], "distance": u.distance}
                        for u in answer.uses[:r]
                        if u.relative_path in holders and u.count != holders[u.relative_path])
    if set(ranked[:r]) != set(holders):
        res["misses"].append({"query": name, "holders": sorted(holders),
                              "first": [{"file": u.relative_path, "part": u.part, "distance": u.distance,
                                         "holds": u.relative_path in holders} for u in answer.uses[:r + 2]],
                              "holders_at": {u.relative_path: [u.rank, u.distance] for u in answer.uses
                                             if u.relative_path in holders}})
    for tier, t in tiers.items():
        uses = searcher.where_used(question, top=10**6, metric=metric, max_distance=t, scale=scale,
                                   same_size=size).uses
        within = {u.relative_path for u in uses}
        if tier == "same":
            res["count_right_same"].extend(u.count == holders[u.relative_path] for u in uses
                                           if u.relative_path in holders)
        res["at"][tier][0] += len(within & set(holders))
        res["at"][tier][1] += len(within)
        res["at"][tier][2] += r


def summarise(res, tiers) -> dict:
    """One run's figures (what the JSON's ``runs`` hold)."""
    return {
        "r_precision": float(np.mean(res["r_precision"])),
        "recall_top10": float(np.mean(res["recall_10"])),
        "count_right": f"{sum(res['count_right'])}/{len(res['count_right'])}",
        "count_right_within_same": f"{sum(res['count_right_same'])}/{len(res['count_right_same'])}",
        "wrong_counts": res["wrong"],
        "misses": res["misses"],
        "max_distance": {tier: {"threshold": tiers[tier], "precision": (f / w if w else float("nan")),
                                "recall": f / r} for tier, (f, w, r) in res["at"].items()},
    }


#: The figures a drawn-again run reports as mean and lowest-highest over the seeds
SPREAD = ("r_precision", "recall_top10", "count_right", "count_right_within_same",
          "same_precision", "same_recall", "near_precision", "near_recall")


def figures_of(run: dict) -> dict:
    """A summarised run's figures as numbers (a count right as its share; ``"a/b"`` kept beside)."""
    out = {"r_precision": run["r_precision"], "recall_top10": run["recall_top10"]}
    for key in ("count_right", "count_right_within_same"):
        right, of = map(int, run[key].split("/"))
        out[key] = right / of if of else float("nan")
    for tier, v in run["max_distance"].items():
        out[f"{tier}_precision"], out[f"{tier}_recall"] = v["precision"], v["recall"]
    return out


def spread_of(per_seed: list) -> dict:
    """Mean, lowest and highest over the seeds' runs of each figure of :data:`SPREAD` (the
    counts right also as the seeds' ``"a/b"``)."""
    numbers = [figures_of(run) for run in per_seed]
    out = {key: {"mean": float(np.mean([n[key] for n in numbers])), "low": float(min(n[key] for n in numbers)),
                 "high": float(max(n[key] for n in numbers))} for key in SPREAD if key in numbers[0]}
    for key in ("count_right", "count_right_within_same"):
        out[key]["per_seed"] = [run[key] for run in per_seed]
    out["thresholds"] = {tier: v["threshold"] for tier, v in per_seed[0]["max_distance"].items()}
    return out


def describe(run: dict) -> str:
    tiers = "  ".join(f"{tier} (<= {v['threshold']:.4g}): P {v['precision']:.3f} R {v['recall']:.3f}"
                      for tier, v in run["max_distance"].items())
    return (f"R-precision {run['r_precision']:.3f}  recall@10 {run['recall_top10']:.3f}  count right"
            f" {run['count_right']} (within same: {run['count_right_within_same']})  {tiers}")


def describe_spread(spread: dict) -> str:
    def f(key):
        v = spread[key]
        return f"{v['mean']:.3f} ({v['low']:.3f}-{v['high']:.3f})"

    tiers = "  ".join(f"{tier} (<= {t:.4g}): P {f(tier + '_precision')} R {f(tier + '_recall')}"
                      for tier, t in spread["thresholds"].items())
    return (f"R-precision {f('r_precision')}  recall@10 {f('recall_top10')}  count right"
            f" {' '.join(spread['count_right']['per_seed'])} (within same:"
            f" {' '.join(spread['count_right_within_same']['per_seed'])})  {tiers}")


def show_wrong(run: dict) -> None:
    for w in run["wrong_counts"]:
        print(f"    wrong count: pin of {w['query']} in {w['file']} ({w['part']}): {w['count']}, truth {w['truth']}")
    for m in run["misses"]:
        first = ", ".join(f"{u['file']} ({u['part'].rsplit('#', 1)[-1]}) {u['distance']:.3g}"
                          + ("" if u["holds"] else " [not a holder]") for u in m["first"])
        print(f"    miss: {m['query']}: first {first}; holders at {m['holders_at']}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store")
    parser.add_argument("--tree", default=str(DATA / "kicad6-step"))
    parser.add_argument("--metric", action="append", dest="metrics")
    parser.add_argument("--scale", action="append", dest="scales", choices=("sensitive", "invariant"))
    parser.add_argument("--same-size", action="append", dest="sizes", type=float)
    parser.add_argument("--seed", type=int, default=0, help="the sample's draw and the questions' rigid motions")
    parser.add_argument("--query-seed", action="append", dest="query_seeds", type=int, default=[], metavar="S",
                        help="also sign every question with seed S instead of the store's (repeatable)")
    parser.add_argument("--json", dest="json_out")
    parser.add_argument("--show-wrong", action="store_true", help="list the files whose reported count is wrong")
    parser.add_argument("--sample", type=int, help="ask a random N of the distinct solids (a whole library has thousands)")
    parser.add_argument("--questions", metavar="RUN.json",
                        help="ask the solids an earlier run asked (its --json output's 'asked'), not a sample")
    parser.add_argument("--truth-cache", help="JSON file keeping the solids' invariants between runs")
    parser.add_argument("--raw-truth", action="store_true",
                        help="the truth's solids as OpenCASCADE reads them, multi-turn faces and all")
    args = parser.parse_args()
    global UNWIND
    UNWIND = not args.raw_truth
    metrics = args.metrics or ["weighted", "combined-angle", "all-angle", "all"]
    scales = args.scales or ["sensitive", "invariant"]
    from shapeidx.families.duplicates import thresholds as duplicate_thresholds
    from shapeidx.io.step import quiet_opencascade

    quiet_opencascade()
    tree = Path(args.tree).resolve()
    rng = np.random.default_rng(args.seed)

    started = time.monotonic()
    files = sorted(p.relative_to(tree).as_posix() for p in tree.rglob("*") if p.suffix.lower() in (".step", ".stp"))
    truth, repaired = read_truth(tree, files, Path(args.truth_cache) if args.truth_cache else None)
    print(f"read {len(files)} files' solids in {time.monotonic() - started:.0f} s", file=sys.stderr)
    turning = {name: count for name, count in repaired.items() if count}
    if len(repaired) == len(files):  # a cache of before the count may lack it
        print(f"{len(turning)} files with faces going round their surface more than once"
              f" ({sum(turning.values())} faces; {'repaired' if UNWIND else 'not repaired'} in the truth)",
              file=sys.stderr)

    # every solid of every file in one array: which file, its invariants
    owner = np.array([i for i, name in enumerate(files) for _ in truth[name]], dtype=np.int64)
    table = np.array([inv for name in files for inv in truth[name]]).reshape(-1, 5)
    questions = []  # (file, index of the solid in the file, invariants, {file: count})
    for name in files:
        distinct: list = []
        if len(truth[name]) < 2:
            continue
        for index, inv in enumerate(truth[name]):
            if not any(same(inv, truth[name][d]) for d in distinct):
                distinct.append(index)
        for index in distinct:
            inv = truth[name][index]
            holders = np.bincount(owner[same_rows(table, inv)], minlength=len(files))
            questions.append((name, index, inv, {files[f]: int(holders[f]) for f in np.flatnonzero(holders)}))
    multi = sum(len(truth[name]) >= 2 for name in files)
    print(f"{multi} files with several solids, {len(questions)} distinct solids", file=sys.stderr)
    distinct_solids = len(questions)
    if args.questions:
        # by file and solid number: another truth (--raw-truth or not) may make two solids asked
        # there one part now (the transformers' two kinds of pin), asked once
        wanted = {(q["query"], q["solid"]) for q in json.loads(Path(args.questions).read_text())["asked"]}
        questions = [q for q in questions if any((q[0], i) in wanted for i, other in enumerate(truth[q[0]])
                                                 if same(q[2], other))]
        print(f"asking the {len(questions)} of them {args.questions} asked ({len(wanted)} there)", file=sys.stderr)
    elif args.sample and args.sample < len(questions):
        questions = [questions[i] for i in sorted(rng.choice(len(questions), args.sample, replace=False))]
        print(f"asking a random {len(questions)} of them (--sample, --seed {args.seed})", file=sys.stderr)
    queries = [(name, solids_of(tree / name)[0][index], inv, holders) for name, index, inv, holders in questions]

    from shapeidx.search import Searcher

    sizes = args.sizes or [0.05]
    runs = [(m, sc, z) for m in metrics for sc in scales for z in sizes]
    limits = {m: duplicate_thresholds(m) for m in metrics}
    seeds = [None] + [seed for seed in dict.fromkeys(args.query_seeds)]  # None: the store's
    results = {(seed, *run): new_result(limits[run[0]]) for seed in seeds for run in runs}
    from shapeidx.errors import ShapeidxError

    index_of = [index for _, index, _, _ in questions]
    refused, asked = [], []
    with tempfile.TemporaryDirectory() as folder, Searcher(args.store, parts=True) as searcher:
        store_seed = searcher.params.seed
        for k, (name, solid, inv, holders) in enumerate(queries):
            path = Path(folder) / f"q{k}.step"
            write_solid(solid, random_rigid(rng), path)
            try:
                # the same file for every seed: only where its points are drawn differs
                signed = {seed: searcher.query_of_part(str(path), seed=seed) for seed in seeds}
            except ShapeidxError as exc:  # a solid the loader refuses alone is a query a user could not ask
                refused.append({"query": name, "solid": index_of[k], "reason": str(exc).split(": ", 1)[-1]})
                print(f"refused: a solid of {name}: {refused[-1]['reason']}", file=sys.stderr)
                continue
            asked.append({"query": name, "solid": index_of[k], "holders": holders})
            for seed, question in signed.items():
                for metric, scale, size in runs:
                    ask(searcher, question, name, holders, results[(seed, metric, scale, size)], metric, scale, size,
                        limits[metric])
    summary = {"machine": machine(), "tree": str(tree), "files": len(files), "multi_solid_files": multi,
               "distinct_solids": distinct_solids, "queries": len(asked), "refused": refused,
               "relevant_files": int(sum(len(q["holders"]) for q in asked)), "truth_unwound": UNWIND,
               "multi_turn_faces": turning if len(repaired) == len(files) else None, "asked": asked,
               "store_seed": store_seed, "query_seeds": seeds[1:], "runs": [], "drawn_again": []}
    for metric, scale, size in runs:
        mine = summarise(results[(None, metric, scale, size)], limits[metric])
        summary["runs"].append({"metric": metric, "scale": scale, "same_size": size, **mine})
        line = f"{metric:15s} {scale:9s} same-size {size}"
        print(f"{line}  store's seed {store_seed}: {describe(mine)}")
        if args.show_wrong:
            show_wrong(mine)
        if len(seeds) > 1:
            per_seed = {seed: summarise(results[(seed, metric, scale, size)], limits[metric]) for seed in seeds[1:]}
            spread = spread_of(list(per_seed.values()))
            summary["drawn_again"].append({"metric": metric, "scale": scale, "same_size": size, **spread,
                                           "per_seed": {str(seed): v for seed, v in per_seed.items()}})
            print(f"{line}  drawn again, seeds {', '.join(map(str, seeds[1:]))}: {describe_spread(spread)}")
            if args.show_wrong:
                for seed, v in per_seed.items():
                    print(f"  seed {seed}:")
                    show_wrong(v)
    text = json.dumps(summary, indent=1)
    if args.json_out:
        Path(args.json_out).write_text(text + "\n")


if __name__ == "__main__":
    main()
