#!/usr/bin/env python3
"""Known twins injected into a whole library: what ``shapeidx duplicates`` finds among them.

    python scripts/library_twins.py make --library /work/debian/wrl --step /work/debian/step \
        --work /work/stores/families/twins [--parts 300] [--seed 22]
    shapeidx build WORK/parts --store WORK/twins.h5 --workers 1 -q
    python scripts/library_twins.py measure --store LIBRARY_STORE --twins WORK/twins.h5 \
        [--metric combined-angle] [--sample 40] [--output report.md] [--twin-seed 7 --twin-seed 8 ...]

``make`` draws ``--parts`` parts of the library at random (seeded) and writes, per part, in
``WORK/parts/FOLDER/NAME.VARIANT.stl``: ``rotated`` (a random rotation of its cleaned
surface, as binary STL: an export to STL), ``rescaled`` (x 25.4, as inches to millimetres, and
rotated), ``mirrored`` (x -> -x, then rotated: the mirror image, the same part only for a part
that is its own mirror image), ``refaceted`` (every triangle split in four, rotated); and
``NAME.step``, a link to the library's STEP file of the same package: re-faceted by
OpenCASCADE, 2.54 times larger (KiCad's VRML unit is 0.1 inch).

``sample`` draws a random sample of the groups ``duplicates`` reports (default tiers) on the
library's store alone (``--pool all``), or on the library and the twins together, among the
groups holding a ``converted`` pair (``--pool converted``), or of the groups whose weakest
member is ``similar`` (``duplicates --similar`` on the library, ``--pool similar``), and prints each group's members
with their tier, distance and size (``--sheet DIR``: one PNG of pictures per group), for a
person to judge.

``formats`` loads a store of VRML files and a store of the STEP files of the same packages
(same folders and names) as one table and measures ``converted`` with the names as the truth:
how many STEP files land in the group of their own VRML, and how many pairs listed
``converted`` join two files of one name.

``measure`` loads the library's store and the twins' store as one table (the twins' paths
under ``twins/``), runs :func:`shapeidx.families.duplicates.find_duplicates` on it, and
reports: recall (a twin in its original's group), the tier, size ratio and unit each lands
with, the groups' sizes and the library folders they span, and a random sample of groups for
a person to judge (names, sizes, pictures: ``--sheet DIR`` renders each sampled group's
thumbnails into one PNG). ``--twin-seed S`` (repeatable) measures again with every twin
signed in the process with its points drawn with S (+ 1000 per twin kind, :func:`kind_seed`),
independently of its original's (a store signs every file with one seed, so a rotated copy
gets its original's points): each twin file loaded once, its exact columns kept, one round
per seed beside the stored signatures' table, the twins that move named (``--resign-cache
FILE``: keep the signatures for another run; it is keyed by the twins' paths and the seeds,
not by their contents).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

from _common import machine

VARIANTS = ("rotated", "rescaled", "mirrored", "refaceted", "step")
RESCALE = 25.4
STEP_SCALE = 2.54


def make(args) -> int:
    from duplicates_study import random_rotation, subdivided, write_stl
    from shapeidx.signing.pipeline import solid_of_file

    library, step_root, parts = Path(args.library), Path(args.step), Path(args.work) / "parts"
    files = sorted(p.relative_to(library) for p in library.rglob("*.wrl"))
    rng = np.random.default_rng(args.seed)
    picks = sorted(rng.choice(len(files), min(args.parts, len(files)), replace=False).tolist())
    chosen = []
    for i in picks:
        rel = files[i]
        base = parts / rel.parent / rel.stem
        base.parent.mkdir(parents=True, exist_ok=True)
        rotations = [random_rotation(rng) for _ in range(4)]
        step = step_root / rel.parent / f"{rel.stem}.step"
        if step.exists() and not (base.parent / f"{rel.stem}.step").is_symlink():
            (base.parent / f"{rel.stem}.step").symlink_to(step)
        chosen.append(str(rel))
        outs = {v: base.parent / f"{rel.stem}.{v}.stl" for v in VARIANTS if v != "step"}
        if all(o.exists() for o in outs.values()):
            continue
        try:
            solid = solid_of_file(library / rel)
        except Exception as exc:  # a part the library store failed too: no twin of it
            print(f"skipped {rel}: {exc}", file=sys.stderr)
            continue
        v, f = solid.vertices, solid.faces
        write_stl(outs["rotated"], v @ rotations[0].T, f)
        write_stl(outs["rescaled"], (v * RESCALE) @ rotations[1].T, f)
        write_stl(outs["mirrored"], v @ (rotations[2] @ np.diag([-1.0, 1.0, 1.0])).T, f[:, ::-1])
        sv, sf = subdivided(v, f)
        write_stl(outs["refaceted"], sv @ rotations[3].T, sf)
    (Path(args.work) / "chosen.json").write_text(json.dumps(chosen, indent=0) + "\n")
    print(f"{len(chosen)} parts, twins in {parts}")
    return 0


def combined_table(library_store, twins_store, twins_table=None, library_table=None):
    """The library's and the twins' ok entries as one FamilyTable (twins' paths under twins/);
    ``twins_table`` / ``library_table``: those tables instead of loading them (the twins signed
    again, :func:`drawn_again`)."""
    from shapeidx.families.table import FamilyTable, RaggedHistograms
    from shapeidx.ragged import offsets_of
    from shapeidx.store import open_store

    lib, tw = library_table, twins_table
    if lib is None:
        with open_store(library_store) as r:
            lib = FamilyTable.load(r)
    if tw is None:
        with open_store(twins_store) as r:
            tw = FamilyTable.load(r)

    def ragged(a, b):
        lengths = np.concatenate([a.lengths, b.lengths])
        return RaggedHistograms(np.concatenate([a.p, b.p]), offsets_of(lengths))

    def cat(x, y):
        return None if x is None or y is None else np.concatenate([x, y])

    paths = np.concatenate([lib.paths, np.array(["twins/" + str(p) for p in tw.paths], dtype=object)])
    order = np.argsort(paths, kind="stable")
    table = FamilyTable(
        paths=paths, rows=np.arange(len(paths)), histograms={h: ragged(lib.histograms[h], tw.histograms[h]) for h in lib.histograms},
        fractions=cat(lib.fractions, tw.fractions), means=cat(lib.means, tw.means), hashes=cat(lib.hashes, tw.hashes),
        extents=cat(lib.extents, tw.extents), handedness=cat(lib.handedness, tw.handedness), missing_columns=[],
        bounds=cat(lib.bounds, tw.bounds), moments=cat(lib.moments, tw.moments), angles=cat(lib.angles, tw.angles),
    )
    return table.subset(order), len(lib), len(tw)


def origin(path: str) -> tuple[str, str]:
    """(library part, variant) of a path of the combined table."""
    if not path.startswith("twins/"):
        return path, "original"
    rel = path[len("twins/"):]
    for v in VARIANTS:
        if rel.endswith(f".{v}.stl"):
            return rel[: -len(f".{v}.stl")] + ".wrl", v
    if rel.endswith(".step"):
        return rel[: -len(".step")] + ".wrl", "step"
    return rel, "?"


#: A twin kind's seed in a round of drawing again (``measure --twin-seed S``): S for the
#: rotated twins, S + 1000 for the rescaled, and so on in VARIANTS order, so that no two twins
#: of one part share their points either (one seed on two copies of one triangle list draws
#: the same points on both).
KIND_SEED_STEP = 1000


def kind_seed(seed: int, variant: str) -> int:
    return seed + KIND_SEED_STEP * VARIANTS.index(variant)


def _same_signature(a, b) -> bool:
    if any(not np.array_equal(a.histograms[h].counts, b.histograms[h].counts) for h in a.histograms):
        return False
    return (a.angles is None) == (b.angles is None) and (a.angles is None or np.array_equal(a.angles, b.angles))


def drawn_again(twins_store, seeds, root=None, cache=None, check_every: int = 5):
    """The twins' store's table once per seed of ``seeds``, every twin signed again in this
    process with its points drawn with :func:`kind_seed` (the exact columns kept,
    ``FamilyTable.with_signatures``): ``({seed: FamilyTable}, facts)``. Each twin file is
    loaded once (faceted as the store's, from ``root``, default the store's root) and signed
    once per seed; every ``check_every``-th is signed with the store's own seed too, which
    must give its stored signature (``facts``: checked, matched, seconds loading and signing,
    failed). ``cache``: a pickle of the signatures, read when it holds these seeds and twins,
    else written."""
    import pickle

    from shapeidx.families.table import FamilyTable
    from shapeidx.io import LoadLimits, load
    from shapeidx.signing.pipeline import signature_of_solid
    from shapeidx.signing.solid import make_solid
    from shapeidx.store import open_store

    seeds = [int(x) for x in seeds]
    with open_store(twins_store) as reader:
        table = FamilyTable.load(reader)
        params = reader.params
        stored_root = reader.attrs.get("root")
        root = Path(root or (stored_root.decode() if isinstance(stored_root, bytes) else str(stored_root)))
        paths = [str(p) for p in table.paths]
        kept = None
        if cache and Path(cache).exists():
            kept = pickle.loads(Path(cache).read_bytes())
            if kept.get("paths") != paths or not set(seeds) <= set(kept["signatures"]) \
                    or kept.get("store_seed") != params.seed:
                kept = None
        if kept is None:
            limits = LoadLimits(root=root, faceting=params.faceting)
            signatures = {s: [] for s in seeds}
            facts = {"checked": 0, "matched": 0, "load": 0.0, "sign": 0.0, "failed": [], "twins": len(paths)}
            started = time.perf_counter()
            for k, path in enumerate(paths):
                t0 = time.perf_counter()
                try:
                    solid = make_solid(load(root / path, limits), root / path)
                except Exception as exc:  # kept with its stored signature, and said
                    facts["failed"].append(f"{path}: {exc}")
                    for s in seeds:
                        signatures[s].append(None)
                    continue
                t1 = time.perf_counter()
                variant = origin("twins/" + path)[1]
                for s in seeds:
                    signatures[s].append(signature_of_solid(solid, params.points, kind_seed(s, variant), params.bin_divisor))
                if check_every and k % check_every == 0:
                    again = signature_of_solid(solid, params.points, params.seed, params.bin_divisor)
                    facts["checked"] += 1
                    facts["matched"] += _same_signature(again, reader.signature(int(table.rows[k])))
                facts["load"] += t1 - t0
                facts["sign"] += time.perf_counter() - t1
                if (k + 1) % 100 == 0:
                    print(f"  signed again {k + 1} of {len(paths)} twins, {time.perf_counter() - started:.0f} s",
                          file=sys.stderr, flush=True)
            kept = {"paths": paths, "signatures": signatures, "facts": facts, "store_seed": params.seed}
            if cache:
                Path(cache).write_bytes(pickle.dumps(kept))
    tables = {}
    for s in seeds:
        rows = [k for k, sig in enumerate(kept["signatures"][s]) if sig is not None]
        tables[s] = table.with_signatures(rows, [kept["signatures"][s][k] for k in rows])
    return tables, kept["facts"]


def twin_figures(table, metric, tiers, threads, limits) -> dict:
    """find_duplicates on the combined table, and per twin kind: the twins, those in their
    original's group, the tier each is listed with, the unit and mirror flag of its pair with
    its original (asked directly: the group's representative may be another twin), and the
    distance of every twin to its original."""
    from shapeidx.signing.chirality import is_chiral
    from shapeidx.families.duplicates import find_duplicates, pair_tiers

    started = time.perf_counter()
    groups = find_duplicates(table, metric, tiers=tuple(tiers), threads=threads, limits=limits)
    seconds = time.perf_counter() - started
    group_of, entry_of = {}, {}
    for g, group in enumerate(groups):
        for m in group["members"]:
            group_of[m] = g
        entry_of[group["representative"]] = {"tier": "representative", "unit": None, "mirrored": False}
        for pair in group["pairs"]:
            entry_of[pair["b"]] = pair
    chiral = dict(zip(map(str, table.paths), is_chiral(table.handedness)))
    index = {str(p): i for i, p in enumerate(table.paths)}
    kinds, misses = {}, []
    for v in VARIANTS:
        twins = [p for p in map(str, table.paths) if origin(p)[1] == v]
        if not twins:
            continue
        found = [p for p in twins if origin(p)[0] in group_of and group_of.get(p) == group_of[origin(p)[0]]]
        misses += [(p, v) for p in twins if p not in found]
        everyone = pair_tiers(table, np.array([index[origin(p)[0]] for p in twins], dtype=np.int64),
                              np.array([index[p] for p in twins], dtype=np.int64), metric, limits=limits)
        at = {p: k for k, p in enumerate(twins)}
        picked = np.array([at[p] for p in found], dtype=np.int64)
        kinds[v] = {
            "twins": twins, "found": found, "tiers": Counter(entry_of[p]["tier"] for p in found),
            "units": Counter("none" if not np.isfinite(u) else f"{u:.4g}" for u in everyone["unit"][picked]),
            "mirrored": int(sum(bool(m) for p, m in zip(found, everyone["mirrored"][picked]) if chiral.get(origin(p)[0]))),
            "chiral": sum(bool(chiral.get(origin(p)[0])) for p in twins),
            "distance": dict(zip(twins, everyone["distance"].tolist())),
            "pair_tier": dict(zip(twins, everyone["tier"].tolist())),
        }
    return {"groups": groups, "group_of": group_of, "entry_of": entry_of, "kinds": kinds, "misses": misses,
            "seconds": seconds, "index": index}


def _spread(values) -> str:
    values = np.asarray(values, dtype=np.float64)
    return f"{values.mean():.1f} ({values.min():.0f}-{values.max():.0f})"


def _whereabouts(table, figures, path, metric) -> str:
    """Where a twin is in one round: its group's representative and its pair with it, or its
    closest partner in the whole table when it is in no group; and its distance to its original."""
    i = figures["index"][path]
    original = origin(path)[0]
    d_orig = figures["kinds"][origin(path)[1]]["distance"][path]
    tier = figures["kinds"][origin(path)[1]]["pair_tier"][path] or "none"
    g = figures["group_of"].get(path)
    if g is not None:
        group = figures["groups"][g]
        pair = figures["entry_of"][path]
        joined = (f"in the group of `{group['representative']}`"
                  + ("" if pair["tier"] == "representative" else f" ({pair['tier']}, d {pair['distance']:.3g})"))
    else:
        others = np.array([k for k in range(len(table)) if k != i], dtype=np.int64)
        d = table.pair_distances(np.full(len(others), i, dtype=np.int64), others, metric)
        nearest = int(others[int(np.argmin(d))])
        joined = f"in no group; closest `{table.paths[nearest]}` (d {float(d.min()):.3g})"
    return f"with its original `{original}`: {tier}, d {d_orig:.3g}; {joined}"


def measure(args) -> int:
    from shapeidx.families.duplicates import TIERS
    from shapeidx.families.table import FamilyTable
    from shapeidx.store import open_store

    started = time.perf_counter()
    with open_store(args.store) as r:
        library = FamilyTable.load(r)
    table, n_lib, n_tw = combined_table(args.store, args.twins, library_table=library)
    load = time.perf_counter() - started
    limits = None
    if args.same_limit:
        from shapeidx.families.duplicates import thresholds

        limits = {**thresholds(args.metric), "same": args.same_limit}
    figures = twin_figures(table, args.metric, args.tiers, args.threads, limits)
    groups, misses = figures["groups"], figures["misses"]
    lines = [f"# Twins injected into the library ({args.metric})", "",
             f"`{shlex.join([sys.executable, *sys.argv])}`; {machine()}", "",
             f"{n_lib} library entries, {n_tw} twins; find_duplicates {figures['seconds']:.1f} s (table loaded in {load:.1f} s);"
             f" {len(groups)} groups of {sum(len(g['members']) for g in groups)} entries; tiers {', '.join(args.tiers)}", ""]
    lines += ["| twin | twins | in the original's group | listed in its group as: " + ", ".join(TIERS + ("representative",))
              + " | unit factor reported | mirrored flagged (chiral originals) |",
              "|---|---|---|---|---|---|"]
    for v, k in figures["kinds"].items():
        twins, found, tiers = k["twins"], k["found"], k["tiers"]
        lines.append(f"| {v} | {len(twins)} | {len(found)} ({len(found) / len(twins):.3f}) |"
                     f" {', '.join(str(tiers.get(t, 0)) for t in TIERS + ('representative',))} |"
                     f" {', '.join(f'{u}: {c}' for u, c in sorted(k['units'].items()))} | {k['mirrored']} of {k['chiral']} |")
    total = sum(len(k["twins"]) for k in figures["kinds"].values())
    lines += ["", f"Recall over all twins: {total - len(misses)} of {total} = {(total - len(misses)) / max(total, 1):.4f}", ""]
    if misses:
        lines += ["Twins not in their original's group: " + "; ".join(f"`{p}`" for p, _ in misses[:60]), ""]
    if args.twin_seed:
        lines += drawn_again_report(args, library, table, figures, limits)
    sizes = np.array([len(g["members"]) for g in groups])
    folders = np.array([len({origin(m)[0].split("/")[0] for m in g["members"]}) for g in groups])
    lines += [f"Group sizes: largest {sizes.max() if len(sizes) else 0}, groups larger than 25: {int((sizes > 25).sum())};"
              f" library folders spanned: largest {folders.max() if len(folders) else 0},"
              f" groups spanning more than 3: {int((folders > 3).sum())}", ""]
    # the library's own groups (no twin in them): what a user of the plain library would see
    own = [g for g in groups if not any(m.startswith("twins/") for m in g["members"])]
    lines += [f"Groups of library parts only (what `duplicates` reports on the library itself): {len(own)},"
              f" {sum(len(g['members']) for g in own)} entries; by tier of the weakest member:"
              f" {dict(Counter(g['tier'] for g in own))}", ""]
    rng = np.random.default_rng(args.seed)
    pool = [g for g in groups if len({origin(m)[0] for m in g["members"]}) > 1]
    sample = [pool[i] for i in sorted(rng.choice(len(pool), min(args.sample, len(pool)), replace=False))] if pool else []
    lines += [f"## A random sample of {len(sample)} of the {len(pool)} groups holding more than one library part", ""]
    for g in sample:
        lines.append(f"- group {groups.index(g) + 1} (confidence {g['confidence']:.3f}, {g['tier']}):"
                     f" `{g['representative']}`; " + "; ".join(
            f"`{m['b']}` ({m['tier']}, d {m['distance']:.3g}, size x{m['size_ratio']:.4g}"
            + (f", unit {m['unit']:.4g}" if m.get("unit") else "") + (", mirrored" if m.get("mirrored") else "") + ")"
            for m in g["pairs"]))
    text = "\n".join(lines) + "\n"
    if args.output:
        Path(args.output).write_text(text)
    print(text)
    if args.sheet:
        sheets(sample, groups, args)
    return 0


def drawn_again_report(args, library, shared_table, shared, limits) -> list:
    """The twins table again with every twin signed with the seeds of ``--twin-seed`` (its
    points drawn independently of its original's), beside the shared seed's."""
    from shapeidx.families.duplicates import TIERS

    started = time.perf_counter()
    tables, facts = drawn_again(args.twins, args.twin_seed, root=args.twins_root, cache=args.resign_cache)
    rounds = {}
    for s, tw in tables.items():
        table, _, _ = combined_table(args.store, args.twins, twins_table=tw, library_table=library)
        rounds[s] = (table, twin_figures(table, args.metric, args.tiers, args.threads, limits))
    seconds = time.perf_counter() - started
    seeds = list(tables)
    names = ", ".join(map(str, seeds))
    lines = [f"## Drawn again: every twin signed with seeds {names} (the library with its own)", "",
             f"Each twin loaded once and signed once per round, its kind's points drawn with seed S + 1000 x kind"
             f" (S for rotated, S + 1000 rescaled, ... S + 4000 step); {facts['twins']} twins; loading"
             f" {facts['load']:.0f} s, signing {facts['sign']:.0f} s (this run {seconds:.0f} s with the rounds' find_duplicates);"
             f" signed with the store's seed again: {facts['matched']} of {facts['checked']} checked give the stored"
             f" signature; failed to load: {len(facts['failed'])}", ""]
    lines += ["| twin | twins | in the original's group: shared seed | drawn again: mean (low-high) |"
              " listed as " + ", ".join(TIERS + ("representative",)) + ": shared | drawn again, mean |"
              " mirrored flagged: shared | drawn again | distance to original, median / 99th pct: shared | drawn again |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for v, k in shared["kinds"].items():
        again = [f["kinds"][v] for _, f in rounds.values()]
        tier_means = ", ".join(f"{np.mean([a['tiers'].get(t, 0) for a in again]):.1f}" for t in TIERS + ("representative",))
        d_shared = np.array(list(k["distance"].values()))
        d_again = np.concatenate([np.array(list(a["distance"].values())) for a in again])
        lines.append(
            f"| {v} | {len(k['twins'])} | {len(k['found'])} ({len(k['found']) / len(k['twins']):.3f}) |"
            f" {_spread([len(a['found']) for a in again])} ({np.mean([len(a['found']) for a in again]) / len(k['twins']):.3f}) |"
            f" {', '.join(str(k['tiers'].get(t, 0)) for t in TIERS + ('representative',))} | {tier_means} |"
            f" {k['mirrored']} of {k['chiral']} | {_spread([a['mirrored'] for a in again])} of {k['chiral']} |"
            f" {np.median(d_shared):.3g} / {np.quantile(d_shared, 0.99):.3g} | {np.median(d_again):.3g} / {np.quantile(d_again, 0.99):.3g} |")
    total = sum(len(k["twins"]) for k in shared["kinds"].values())
    found_again = [total - len(f["misses"]) for _, f in rounds.values()]
    lines += ["", f"Recall over all twins drawn again: {_spread(found_again)} of {total}"
              f" (shared seed: {total - len(shared['misses'])}); per round "
              + ", ".join(f"seed {s}: {n}" for s, n in zip(seeds, found_again)), ""]
    lost_shared = {p for p, _ in shared["misses"]}
    lost = {}
    for s, (_, f) in rounds.items():
        for p, _ in f["misses"]:
            lost.setdefault(p, []).append(s)
    changed = sorted(p for p in lost if p not in lost_shared)
    regained = sorted(p for p in lost_shared if len(lost.get(p, [])) < len(seeds))
    lines += [f"Found with the shared seed, lost drawn again (in some round): {len(changed)}", ""]
    for p in changed:
        lines.append(f"- `{p}` lost with seeds {', '.join(map(str, lost[p]))}; shared seed: "
                     + _whereabouts(shared_table, shared, p, args.metric) + "; "
                     + "; ".join(f"seed {s}: " + _whereabouts(rounds[s][0], rounds[s][1], p, args.metric) for s in lost[p]))
    lines += ["", f"Lost with the shared seed, found drawn again (in some round): {len(regained)}", ""]
    for p in regained:
        back = [s for s in seeds if s not in lost.get(p, [])]
        lines.append(f"- `{p}` found with seeds {', '.join(map(str, back))}; shared seed: "
                     + _whereabouts(shared_table, shared, p, args.metric) + "; "
                     + "; ".join(f"seed {s}: " + _whereabouts(rounds[s][0], rounds[s][1], p, args.metric) for s in back))
    lines.append("")
    return lines


def sample(args) -> int:
    from shapeidx.families.duplicates import find_duplicates
    from shapeidx.families.table import FamilyTable
    from shapeidx.store import open_store

    if args.pool in ("all", "similar"):
        with open_store(args.store) as reader:
            table = FamilyTable.load(reader)
    else:
        table, _, _ = combined_table(args.store, args.twins)
    tiers = ("identical", "same", "converted") + (("similar",) if args.pool == "similar" else ())
    groups = find_duplicates(table, args.metric, threads=args.threads, tiers=tiers)
    pool = {"all": groups, "converted": [g for g in groups if any(p["tier"] == "converted" for p in g["pairs"])],
            "similar": [g for g in groups if g["tier"] == "similar"]}[args.pool]
    sizes = [len(g["members"]) for g in groups]
    print(f"`{shlex.join([sys.executable, *sys.argv])}`; {machine()}\n")
    print(f"{len(groups)} groups of {sum(sizes)} entries (largest {max(sizes, default=0)}, widest"
          f" {max((len(g['folders']) for g in groups), default=0)} folders; by tier of the weakest member:"
          f" {dict(Counter(g['tier'] for g in groups))}); {len(pool)} in the pool ({args.pool})\n")
    rng = np.random.default_rng(args.seed)
    chosen = [pool[i] for i in sorted(rng.choice(len(pool), min(args.count, len(pool)), replace=False))] if pool else []
    for g in chosen:
        print(f"- group {groups.index(g) + 1} (confidence {g['confidence']:.3f}, {g['tier']}, {len(g['members'])} members):"
              f" `{g['representative']}`; " + "; ".join(
                  f"`{m['b']}` ({m['tier']}, d {m['distance']:.3g}, size x{m['size_ratio'] or float('nan'):.5g}"
                  + (f", unit {m['unit']:.4g}" if m.get("unit") else "") + (", mirrored" if m.get("mirrored") else "") + ")"
                  for m in g["pairs"]))
    if args.sheet:
        sheets(chosen, groups, args)
    return 0


def formats(args) -> int:
    from shapeidx.families.duplicates import find_duplicates

    table, n_vrml, n_step = combined_table(args.store, args.step_store)
    groups = find_duplicates(table, args.metric, threads=args.threads)
    paths = [str(p) for p in table.paths]
    group_of = {m: i for i, g in enumerate(groups) for m in g["members"]}
    vrml = set(p for p in paths if not p.startswith("twins/"))
    steps = [p for p in paths if p.startswith("twins/") and str(Path(p[len("twins/"):]).with_suffix(".wrl")) in vrml]
    together = [p for p in steps if group_of.get(p, -1) == group_of.get(str(Path(p[len("twins/"):]).with_suffix(".wrl")), -2)]
    converted = [p for g in groups for p in g["pairs"] if p["tier"] == "converted"]

    def stem(path):
        return str(Path(path[len("twins/"):] if path.startswith("twins/") else path).with_suffix(""))

    other = [p for p in converted if stem(p["a"]) != stem(p["b"])]
    print(f"`{shlex.join([sys.executable, *sys.argv])}`; {machine()}\n")
    print(f"{n_vrml} VRML and {n_step} STEP entries; {len(groups)} groups (tiers identical, same, converted)\n")
    print(f"STEP files whose VRML of the same name is in the store: {len(steps)}; in that VRML's group:"
          f" {len(together)} ({len(together) / max(len(steps), 1):.3f})")
    print(f"Pairs listed converted: {len(converted)}; joining two files of one name: {len(converted) - len(other)}")
    for p in other:
        print(f"  other names: `{p['a']}` `{p['b']}` (d {p['distance']:.3g})")
    for p in steps:
        if p not in together:
            print(f"  not with its VRML: `{p}`")
    return 0


def sheets(sample, groups, args) -> None:
    """One PNG per sampled group: each member's thumbnail with its name and size."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import io

    from PIL import Image

    from shapeidx.pictures.render import render_file_png

    out = Path(args.sheet)
    out.mkdir(parents=True, exist_ok=True)
    roots = {"": Path(args.library), "twins/": Path(args.twins_root or ".")}
    for g in sample:
        members = [{"path": g["representative"], "tier": "rep", "size_ratio": 1.0}] + [
            {"path": p["b"], "tier": p["tier"], "size_ratio": p["size_ratio"] or float("nan")} for p in g["pairs"]][:7]
        fig, axes = plt.subplots(1, len(members), figsize=(2.4 * len(members), 2.8))
        for ax, m in zip(np.atleast_1d(axes), members):
            path = m["path"]
            root = roots["twins/"] if path.startswith("twins/") else roots[""]
            file = root / (path[len("twins/"):] if path.startswith("twins/") else path)
            try:
                ax.imshow(Image.open(io.BytesIO(render_file_png(file, size=200))))
            except Exception as exc:  # a picture that cannot be made does not stop the sheet
                ax.text(0.5, 0.5, str(exc)[:40], ha="center")
            ax.set_title(f"{Path(path).name[:28]}\n{m['tier']} x{m['size_ratio']:.3g}", fontsize=7)
            ax.axis("off")
        fig.savefig(out / f"group-{groups.index(g) + 1:04d}.png", dpi=80)
        plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    m = sub.add_parser("make")
    m.add_argument("--library", required=True)
    m.add_argument("--step", required=True)
    m.add_argument("--work", required=True)
    m.add_argument("--parts", type=int, default=300)
    m.add_argument("--seed", type=int, default=22)
    q = sub.add_parser("measure")
    q.add_argument("--store", required=True)
    q.add_argument("--twins", required=True)
    q.add_argument("--metric", default="combined-angle")
    q.add_argument("--tiers", nargs="+", default=["identical", "same", "converted"])
    q.add_argument("--sample", type=int, default=40)
    q.add_argument("--same-limit", type=float, help="the same tier's distance threshold instead of the metric's")
    q.add_argument("--seed", type=int, default=22)
    q.add_argument("--threads", type=int, default=2)
    q.add_argument("--output")
    q.add_argument("--sheet", help="write one PNG per sampled group into this folder")
    q.add_argument("--library", default="/work/debian/wrl", help="the library's folder (for --sheet)")
    q.add_argument("--twins-root", help="the twins' parts folder (for --sheet and --twin-seed; default for"
                                        " --twin-seed: the twins' store's root)")
    q.add_argument("--twin-seed", type=int, action="append", default=[],
                   help="also measure with every twin signed again, its points drawn with this seed (repeatable:"
                        " one round per seed; each twin file loaded once)")
    q.add_argument("--resign-cache", help="a pickle of the twins' signatures drawn again (read if it holds the"
                                          " seeds, else written)")
    s = sub.add_parser("sample")
    s.add_argument("--store", required=True)
    s.add_argument("--twins", help="the twins' store (for --pool converted)")
    s.add_argument("--pool", choices=("all", "converted", "similar"), default="all",
                   help="all groups of the library; those holding a converted pair (library and twins);"
                        " those whose weakest member is similar (library, --similar)")
    s.add_argument("--metric", default="combined-angle")
    s.add_argument("--count", type=int, default=30)
    s.add_argument("--seed", type=int, default=2026)
    s.add_argument("--threads", type=int, default=2)
    s.add_argument("--sheet", help="write one PNG per sampled group into this folder")
    s.add_argument("--library", default="/work/debian/wrl", help="the library's folder (for --sheet)")
    s.add_argument("--twins-root", help="the twins' parts folder (for --sheet)")
    f = sub.add_parser("formats")
    f.add_argument("--store", required=True, help="the VRML files' store")
    f.add_argument("--step-store", required=True, help="the STEP files' store (same folders and names)")
    f.add_argument("--metric", default="combined-angle")
    f.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    return {"make": make, "measure": measure, "sample": sample, "formats": formats}[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
