#!/usr/bin/env python3
"""Known twins injected into a whole library: what ``shapeidx duplicates`` finds among them.

    python scripts/library_twins.py make --library /work/debian/wrl --step /work/debian/step \
        --work /work/stores/families/twins [--parts 300] [--seed 22]
    shapeidx build WORK/parts --store WORK/twins.h5 --workers 1 -q
    python scripts/library_twins.py measure --store LIBRARY_STORE --twins WORK/twins.h5 \
        [--metric combined-angle] [--sample 40] [--output report.md]

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
thumbnails into one PNG).
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


def combined_table(library_store, twins_store):
    """The library's and the twins' ok entries as one FamilyTable (twins' paths under twins/)."""
    from shapeidx.families.table import FamilyTable, RaggedHistograms
    from shapeidx.ragged import offsets_of
    from shapeidx.store import open_store

    with open_store(library_store) as r:
        lib = FamilyTable.load(r)
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


def measure(args) -> int:
    from shapeidx.signing.chirality import is_chiral
    from shapeidx.families.duplicates import TIERS, find_duplicates, pair_tiers

    started = time.perf_counter()
    table, n_lib, n_tw = combined_table(args.store, args.twins)
    load = time.perf_counter() - started
    started = time.perf_counter()
    limits = None
    if args.same_limit:
        from shapeidx.families.duplicates import thresholds

        limits = {**thresholds(args.metric), "same": args.same_limit}
    groups = find_duplicates(table, args.metric, tiers=tuple(args.tiers), threads=args.threads, limits=limits)
    seconds = time.perf_counter() - started
    group_of, entry_of = {}, {}
    for g, group in enumerate(groups):
        for m in group["members"]:
            group_of[m] = g
        entry_of[group["representative"]] = {"tier": "representative", "unit": None, "mirrored": False}
        for pair in group["pairs"]:
            entry_of[pair["b"]] = pair
    chiral = dict(zip(map(str, table.paths), is_chiral(table.handedness)))
    lines = [f"# Twins injected into the library ({args.metric})", "",
             f"`{shlex.join([sys.executable, *sys.argv])}`; {machine()}", "",
             f"{n_lib} library entries, {n_tw} twins; find_duplicates {seconds:.1f} s (table loaded in {load:.1f} s);"
             f" {len(groups)} groups of {sum(len(g['members']) for g in groups)} entries; tiers {', '.join(args.tiers)}", ""]
    lines += ["| twin | twins | in the original's group | listed in its group as: " + ", ".join(TIERS + ("representative",))
              + " | unit factor reported | mirrored flagged (chiral originals) |",
              "|---|---|---|---|---|---|"]
    misses = []
    for v in VARIANTS:
        twins = [p for p in map(str, table.paths) if origin(p)[1] == v]
        if not twins:
            continue
        found = [p for p in twins if origin(p)[0] in group_of and group_of.get(p) == group_of[origin(p)[0]]]
        misses += [(p, v) for p in twins if p not in found]
        # the tier, unit and mirror flag of the pair (original, twin), asked directly: the group's
        # representative may be another twin
        index = {str(p): i for i, p in enumerate(table.paths)}
        said = pair_tiers(table, np.array([index[origin(p)[0]] for p in found], dtype=np.int64),
                          np.array([index[p] for p in found], dtype=np.int64), args.metric, limits=limits)
        tiers = Counter(entry_of[p]["tier"] for p in found)
        units = Counter("none" if not np.isfinite(u) else f"{u:.4g}" for u in said["unit"])
        mirrored = int(sum(bool(m) for p, m in zip(found, said["mirrored"]) if chiral.get(origin(p)[0])))
        chiral_n = sum(bool(chiral.get(origin(p)[0])) for p in twins)
        lines.append(f"| {v} | {len(twins)} | {len(found)} ({len(found) / len(twins):.3f}) |"
                     f" {', '.join(str(tiers.get(t, 0)) for t in TIERS + ('representative',))} |"
                     f" {', '.join(f'{u}: {c}' for u, c in sorted(units.items()))} | {mirrored} of {chiral_n} |")
    total = sum(1 for p in map(str, table.paths) if origin(p)[1] in VARIANTS)
    lines += ["", f"Recall over all twins: {total - len(misses)} of {total} = {(total - len(misses)) / max(total, 1):.4f}", ""]
    if misses:
        lines += ["Twins not in their original's group: " + "; ".join(f"`{p}`" for p, _ in misses[:60]), ""]
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
    q.add_argument("--twins-root", help="the twins' parts folder (for --sheet)")
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
