"""How the signature of a solid model changes with the fidelity of its faceting (docs/faceting.md).

The paper leaves open (section 5) how matching depends on the fidelity epsilon of the
faceting. Every STEP part of a labelled folder (by default ../shared/data/kicad6-step) is
read once by OpenCASCADE and faceted at each fidelity of :data:`LEVELS`, from coarse to very
fine; at each one its signature is computed with the default parameters (1024 points, the
fixed seed). Reported, per fidelity:

* the paper's Weighted and plain ALL distance between each part's signature and its
  signature at the finest faceting, beside the **noise floor**: the distance between two
  samplings (two seeds) of the same finest mesh;
* retrieval (NN, FT; labels = class folder) of the whole set faceted at that fidelity;
* triangles, measured maximum chordal error, and time per part (read + facet + signature).

Run (about 15 minutes on 2 cores for the 336 parts)::

    python scripts/faceting_study.py ../shared/data/kicad6-step --workers 2 \\
        --cache /tmp/faceting.pkl --markdown docs/faceting.md --plot docs/faceting.png

``--cache`` keeps the raw results, so that the report can be written again without
recomputing (``--limit N`` runs on the first N parts of each class folder instead).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import pickle
import platform
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

#: (relative linear deflection, angular deflection in rad), coarse to fine; the last is the reference.
LEVELS = [
    (0.05, 1.0),
    (0.01, 0.6),
    (0.005, 0.5),
    (0.002, 0.35),
    (0.001, 0.25),
    (0.0002, 0.1),
]
#: A second seed for the noise floor (two samplings of the same finest mesh).
NOISE_SEED = 7


def study_part(path: str) -> dict:
    """Read one STEP file once; facet, sign and time it at every level."""
    from shapeidx.errors import LoadError
    from shapeidx.io import LoadLimits, PolygonMesh
    from shapeidx.io.faceting import Faceting
    from shapeidx.io.step import chordal_error, read_shape, tessellate, triangles_of
    from shapeidx.signing.pipeline import signature_of_solid
    from shapeidx.signing.parameters import DEFAULT_SEED
    from shapeidx.signing.solid import make_solid

    result = {"path": path, "levels": [], "error": None}
    try:
        started = time.perf_counter()
        read = read_shape(Path(path), None, LoadLimits())
        result["read_seconds"] = time.perf_counter() - started
        for linear, angular in LEVELS:
            started = time.perf_counter()
            diagonal = tessellate(read.shape, Faceting(linear, angular), path)
            vertices, triangles, _, _ = triangles_of(read.shape)
            facet_seconds = time.perf_counter() - started
            started = time.perf_counter()
            solid = make_solid(PolygonMesh.from_triangles(vertices, triangles, "step"), path)
            signature = signature_of_solid(solid, seed=DEFAULT_SEED)
            sign_seconds = time.perf_counter() - started
            error, _ = chordal_error(read.shape, np.random.default_rng(0))
            level = {
                "triangles": int(len(triangles)),
                "chordal": error / diagonal,
                "facet_seconds": facet_seconds,
                "sign_seconds": sign_seconds,
                "signature": signature,
                "watertight": solid.watertight,
            }
            if (linear, angular) == LEVELS[-1]:
                level["noise_signature"] = signature_of_solid(solid, seed=NOISE_SEED)
            result["levels"].append(level)
    except LoadError as exc:
        result["error"] = str(exc)
    return result


def part_files(folder: Path, limit: int | None) -> list:
    files = []
    for cls in sorted(p for p in folder.iterdir() if p.is_dir()):
        found = sorted(cls.glob("*.step"))
        files.extend(found[:limit] if limit else found)
    return [str(f) for f in files]


def run(folder: Path, workers: int, limit: int | None) -> dict:
    files = part_files(folder, limit)
    started = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(workers, maxtasksperchild=50) as pool:
        parts = []
        for i, part in enumerate(pool.imap(study_part, files, chunksize=2)):
            parts.append(part)
            if (i + 1) % 25 == 0:
                print(f"{i + 1}/{len(files)} parts, {time.perf_counter() - started:.0f} s", file=sys.stderr)
    return {
        "folder": str(folder),
        "parts": parts,
        "levels": LEVELS,
        "workers": workers,
        "limit": limit,
        "seconds": time.perf_counter() - started,
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
    }


# --------------------------------------------------------------------------- analysis


def analyse(raw: dict) -> dict:
    from shapeidx.distance import compare
    from shapeidx.evaluation.retrieval import retrieval_scores

    good = [p for p in raw["parts"] if p["error"] is None]
    failed = [p for p in raw["parts"] if p["error"] is not None]
    labels = np.array([Path(p["path"]).parent.name for p in good])
    n, levels = len(good), raw["levels"]
    # the reference is the finest mesh sampled with the *other* seed: the same seed on two similar
    # meshes draws nearly the same points (most faces are planes, faceted alike at every level),
    # which would hide the noise; so each level is one independent resampling away from its
    # reference, as the noise floor is, and the ratio to the floor tends to 1 once faceting stops mattering
    reference = [p["levels"][-1]["noise_signature"] for p in good]
    noise = {m: np.array([compare(p["levels"][-1]["signature"], p["levels"][-1]["noise_signature"])[m] for p in good])
             for m in ("weighted", "all")}
    rows = []
    for k, (linear, angular) in enumerate(levels):
        sigs = [p["levels"][k]["signature"] for p in good]
        to_ref = {m: np.array([compare(s, r)[m] for s, r in zip(sigs, reference)]) for m in ("weighted", "all")}
        matrices = {m: np.zeros((n, n)) for m in ("weighted", "all")}
        for i in range(n):
            for j in range(i + 1, n):
                d = compare(sigs[i], sigs[j])
                for m in matrices:
                    matrices[m][i, j] = matrices[m][j, i] = d[m]
        scores = {m: retrieval_scores(matrices[m], labels) for m in matrices}
        seconds = np.array([p["read_seconds"] + p["levels"][k]["facet_seconds"] + p["levels"][k]["sign_seconds"]
                            for p in good])
        excess = {}
        for m in to_ref:
            diff = to_ref[m] - noise[m]
            half = 1.96 * diff.std(ddof=1) / np.sqrt(n) if n > 1 else float("nan")
            ratio = to_ref[m] / np.maximum(noise[m], 1e-12)
            excess[m] = {
                "mean": diff.mean() / noise[m].mean(), "half": half / noise[m].mean(),
                "beyond2": int(np.sum(ratio > 2)),
                "outliers": [(str(Path(good[i]["path"]).parent.name + "/" + Path(good[i]["path"]).name), float(ratio[i]))
                             for i in np.flatnonzero(ratio > 2)],
            }
        rows.append({
            "linear": linear,
            "angular": angular,
            "excess": excess,
            "to_ref": to_ref,
            "scores": scores,
            "triangles": np.array([p["levels"][k]["triangles"] for p in good]),
            "chordal": np.array([p["levels"][k]["chordal"] for p in good]),
            "seconds": seconds,
            "facet_seconds": np.array([p["read_seconds"] + p["levels"][k]["facet_seconds"] for p in good]),
            "watertight": int(sum(p["levels"][k]["watertight"] for p in good)),
        })
    return {"rows": rows, "noise": noise, "n": n, "failed": failed, "classes": len(set(labels))}


#: A part this many times its own noise floor away from its finest faceting has changed.
OUTLIER_RATIO = 5.0
#: A mean excess over the noise floor smaller than this share of it is not worth a finer faceting.
NEGLIGIBLE_EXCESS = 0.02


def outliers(row: dict, metric: str) -> list:
    """(part, ratio to its own noise floor) of the parts more than OUTLIER_RATIO times their floor away."""
    return [(name, ratio) for name, ratio in row["excess"][metric]["outliers"] if ratio > OUTLIER_RATIO]


def measurably_off(row: dict, metric: str) -> bool:
    """Whether the faceting of ``row`` still changes the signature measurably (see :func:`stops_changing`)."""
    e = row["excess"][metric]
    return (e["mean"] > e["half"] and e["mean"] >= NEGLIGIBLE_EXCESS) or bool(outliers(row, metric))


def stops_changing(result: dict, metric: str = "weighted") -> int:
    """First level from which no finer one is measurably off its finest faceting.

    Measurably off: the mean excess of the distance to the finest faceting over the noise floor
    (paired, part by part) is above zero by more than its 95% confidence half-width and at least
    NEGLIGIBLE_EXCESS of the floor, or some part is more than OUTLIER_RATIO times its own floor away.
    (A single part at two or three times its floor is common: its floor is one draw of the noise.)
    """
    rows = result["rows"][:-1]
    off = [measurably_off(r, metric) for r in rows]
    for k in range(len(off)):
        if not any(off[k:]):
            return k
    return len(off)


def _non_in_pairs(raw: dict, name: str, level: int) -> tuple:
    for p in raw["parts"]:
        if p["path"].endswith(name) and p["error"] is None:
            points = p["levels"][level]["signature"].points
            pairs = points * (points - 1) // 2
            share = lambda sig: round(pairs * (1 - sig.fractions["in"]))  # noqa: E731
            return share(p["levels"][level]["signature"]), share(p["levels"][-1]["signature"])
    return None, None


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"][:-1]
    x = np.array([r["linear"] for r in rows])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    ax = axes[0]
    for metric, colour, label in (("weighted", "C0", "Weighted"), ("all", "C1", "ALL")):
        med = np.array([np.median(r["to_ref"][metric]) for r in rows])
        lo = np.array([np.percentile(r["to_ref"][metric], 25) for r in rows])
        hi = np.array([np.percentile(r["to_ref"][metric], 75) for r in rows])
        ax.plot(x, med, "o-", color=colour, label=f"{label}: to the finest faceting (median)")
        ax.fill_between(x, lo, hi, color=colour, alpha=0.15)
        floor = result["noise"][metric]
        ax.axhline(np.median(floor), color=colour, ls="--", label=f"{label}: noise floor (two seeds, median)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.invert_xaxis()
    ax.set_xlabel("linear deflection / part diagonal (coarse → fine)")
    ax.set_ylabel("distance (bands: quartiles)")
    ax.set_title("Signature against the finest faceting")
    ax.legend(fontsize=7.5)
    ax = axes[1]
    xs = np.array([r["linear"] for r in result["rows"]])
    for metric, colour, label in (("weighted", "C0", "Weighted"), ("all", "C1", "ALL")):
        ax.plot(xs, [r["scores"][metric]["nn"] for r in result["rows"]], "o-", color=colour, label=f"{label} NN")
        ax.plot(xs, [r["scores"][metric]["ft"] for r in result["rows"]], "s--", color=colour, label=f"{label} FT")
    ax.set_xscale("log")
    ax.invert_xaxis()
    ax.set_xlabel("linear deflection / part diagonal (coarse → fine)")
    ax.set_ylabel("retrieval score")
    ax.set_title(f"Retrieval, {result['n']} parts in {result['classes']} classes")
    ax.legend(fontsize=8)
    ax = axes[2]
    ax.plot(xs, [np.median(r["seconds"]) for r in result["rows"]], "o-", color="C2", label="read + facet + signature")
    ax.plot(xs, [np.median(r["facet_seconds"]) for r in result["rows"]], "s--", color="C3", label="read + facet")
    ax.set_xscale("log")
    ax.invert_xaxis()
    ax.set_xlabel("linear deflection / part diagonal (coarse → fine)")
    ax.set_ylabel("median seconds per part")
    ax2 = ax.twinx()
    ax2.plot(xs, [np.median(r["triangles"]) for r in result["rows"]], "^:", color="C4", label="triangles (median)")
    ax2.set_yscale("log")
    ax2.set_ylabel("median triangles per part", color="C4")
    ax.set_title("Cost per part (one core)")
    handles = ax.get_legend_handles_labels()
    handles2 = ax2.get_legend_handles_labels()
    ax.legend(handles[0] + handles2[0], handles[1] + handles2[1], fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def markdown(raw: dict, result: dict, plot_name: str | None, command: str) -> str:
    rows = result["rows"]
    noise = result["noise"]
    floor_w, floor_a = np.median(noise["weighted"]), np.median(noise["all"])
    k_w = stops_changing(result, "weighted")
    k_a = stops_changing(result, "all")
    k = max(k_w, k_a)
    chosen = rows[k] if k < len(rows) - 1 else rows[-1]
    subset = f"the first {raw['limit']} parts of each class" if raw["limit"] else "all the parts"
    lines = [
        "# Faceting fidelity and the signature (the paper's open question)",
        "",
        "<!-- generated by scripts/faceting_study.py; do not edit by hand -->",
        "",
        "The paper (section 5) asks how matching changes with the fidelity epsilon of the faceting. "
        f"Here {subset} of `{Path(raw['folder']).name}` ({result['n']} STEP solids in {result['classes']} classes) were "
        "read once by OpenCASCADE and faceted by `BRepMesh_IncrementalMesh` at each fidelity below, "
        "from coarse to very fine: the linear deflection is relative to the part's bounding-box diagonal, "
        "the angular one in radians. At each fidelity every part was signed with the default parameters "
        "(1024 points, the fixed seed).",
        "",
        "* **to finest**: the distance between a part's signature and its signature at the finest faceting "
        f"({rows[-1]['linear']:g}, {rows[-1]['angular']:g} rad) drawn with another seed ({NOISE_SEED}): with the same seed, "
        "two similar meshes give nearly the same points (most faces are planes, faceted alike at every "
        "fidelity) and the distance would fall below the sampling noise;",
        f"* **noise floor**: the distance between two samplings (seeds 20020101 and {NOISE_SEED}) of the same finest "
        f"mesh: median **{floor_w:.4f}** (Weighted), **{floor_a:.5f}** (ALL). A distance to the finest faceting "
        "near this floor means the faceting no longer changes the signature more than drawing other points does;",
        "* **chordal**: the largest distance from facet points (centroids and edge midpoints of up to 24 "
        "triangles per curved face) to the exact surface, measured with `GeomAPI_ProjectPointOnSurf`, relative "
        "to the diagonal;",
        "* **NN, FT**: retrieval of the whole set faceted at that fidelity (labels: class folders); "
        "**time**: read + facet + signature of one part on one core.",
        "",
    ]
    if plot_name:
        lines += [f"![distance to the finest faceting, retrieval and cost against the fidelity]({plot_name})", ""]
    header = ("| linear | angular | triangles (median) | chordal (max of parts, median) | Weighted to finest: median (p90) "
              "| ratio to floor | ALL to finest: median (p90) | ratio to floor | NN W | FT W | NN ALL | FT ALL | s / part (median) |")
    lines += [header, "|" + "---|" * 13]
    for r in rows:
        w, a = r["to_ref"]["weighted"], r["to_ref"]["all"]
        finest = False  # the finest row is the noise floor itself: its own mesh, the other seed
        cells = [
            f"{r['linear']:g}", f"{r['angular']:g}", f"{int(np.median(r['triangles'])):,}",
            f"{np.max(r['chordal']):.2g}, {np.median(r['chordal']):.2g}",
            "reference" if finest else f"{np.median(w):.4f} ({np.percentile(w, 90):.4f})",
            "" if finest else f"{np.median(w) / floor_w:.2f}",
            "reference" if finest else f"{np.median(a):.5f} ({np.percentile(a, 90):.5f})",
            "" if finest else f"{np.median(a) / floor_a:.2f}",
            f"{r['scores']['weighted']['nn']:.3f}", f"{r['scores']['weighted']['ft']:.3f}",
            f"{r['scores']['all']['nn']:.3f}", f"{r['scores']['all']['ft']:.3f}",
            f"{np.median(r['seconds']):.3f}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        f"Noise floor, 90th percentile: {np.percentile(noise['weighted'], 90):.4f} (Weighted), "
        f"{np.percentile(noise['all'], 90):.5f} (ALL).",
        "",
        "## Where the signature stops changing",
        "",
        "The medians above sit on the noise floor at every fidelity. A finer test, part by part: the distance "
        "to the finest faceting minus the part's own noise floor, averaged over the parts (as a share of the "
        "mean floor, with its 95% confidence half-width), and the parts more than twice their own floor away:",
        "",
        f"| linear | angular | Weighted: mean excess | parts > 2x floor (> {OUTLIER_RATIO:g}x) | ALL: mean excess | parts > 2x floor (> {OUTLIER_RATIO:g}x) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows[:-1]:
        w, a = r["excess"]["weighted"], r["excess"]["all"]
        lines.append(f"| {r['linear']:g} | {r['angular']:g} | {100 * w['mean']:+.1f}% ± {100 * w['half']:.1f}% "
                     f"| {w['beyond2']} ({len(outliers(r, 'weighted'))}) "
                     f"| {100 * a['mean']:+.1f}% ± {100 * a['half']:.1f}% | {a['beyond2']} ({len(outliers(r, 'all'))}) |")
    far = sorted({(name, k, m, ratio) for k, r in enumerate(rows[:-1]) for m in ("weighted", "all")
                  for name, ratio in outliers(r, m)})
    lines += ["", f"A change counts when the mean excess is beyond its 95% half-width and at least {100 * NEGLIGIBLE_EXCESS:g}% of "
              f"the floor, or when some part is more than {OUTLIER_RATIO:g} times its own floor away (a part at two or three "
              "times is common by chance: its floor is a single draw of the noise)."]
    if far:
        described = []
        for name, k, m, ratio in far:
            here, finest = _non_in_pairs(raw, name, k)
            described.append(f"`{name}` at {rows[k]['linear']:g} ({m}, {ratio:.1f}x its floor; {here} pairs not IN, "
                             f"{finest} at the finest faceting)")
        lines += ["", "The parts far beyond their floor: " + "; ".join(described) + ". These are (nearly) convex parts: "
                  "their Weighted distance rests on the handful of pairs that are not IN, so a faceting that lets a few "
                  "segments graze outside moves it far, while the ALL histogram does not move."]
    lines += [
        "",
        f"So the Weighted signature stops changing measurably at linear deflection **{rows[k_w]['linear']:g}** "
        f"(angular {rows[k_w]['angular']:g} rad) and the ALL histogram at **{rows[k_a]['linear']:g}** "
        f"(angular {rows[k_a]['angular']:g} rad): from there on, no finer faceting moves any part far beyond its "
        "sampling noise, nor the parts on average measurably beyond it.",
        "",
    ]
    lines += conclusion_lines(rows, k, chosen, floor_w)
    lines += [
        "",
        "## How this was made",
        "",
        f"`{command}` on {raw['machine']}, {raw['workers']} worker processes, {raw['seconds']:.0f} s in all "
        f"(the machine was shared with other sessions' builds and tests, at a load average of 15 to 20 on its 2 cores: "
        "absolute times are several times those of a quiet machine). Times are per part on one core and include "
        "reading the STEP file once (OpenCASCADE's import of the module itself, about 2 s per process, is not "
        "counted).",
    ]
    if result["failed"]:
        lines += ["", f"{len(result['failed'])} parts could not be read and are left out:", ""]
        lines += [f"* `{Path(p['path']).parent.name}/{Path(p['path']).name}`: {p['error']}" for p in result["failed"]]
    return "\n".join(lines) + "\n"


def conclusion_lines(rows, k, chosen, floor_w) -> list:
    from shapeidx.io.faceting import DEFAULT_ANGULAR_DEFLECTION, DEFAULT_LINEAR_DEFLECTION

    default = [r for r in rows if (r["linear"], r["angular"]) == (DEFAULT_LINEAR_DEFLECTION, DEFAULT_ANGULAR_DEFLECTION)]
    lines = [
        f"The default of `shapeidx` is linear deflection **{DEFAULT_LINEAR_DEFLECTION:g}** of the diagonal and "
        f"angular deflection **{DEFAULT_ANGULAR_DEFLECTION:g} rad** (`shapeidx/io/faceting.py`); the coarsest "
        f"fidelity from which the signature no longer moves measurably is {chosen['linear']:g} / {chosen['angular']:g} rad.",
    ]
    if default and default[0]["linear"] < chosen["linear"]:
        lines += [
            "",
            "The default is finer than that on purpose: the KiCad parts are mostly boxes with small curved "
            "features (pins, fillets), which hardly weigh in 1024 samples; a part whose area is mostly curved "
            "(a sphere, a large fillet) needs more. The margin costs little, since the signature, not the "
            "faceting, dominates the time per part (table above).",
        ]
    if default:
        d = default[0]
        lines += [
            "",
            f"At the default the median part has {int(np.median(d['triangles'])):,} triangles and takes "
            f"{np.median(d['seconds']):.3f} s; the finest faceting takes {np.median(rows[-1]['seconds']):.3f} s "
            f"with {int(np.median(rows[-1]['triangles'])):,} triangles.",
        ]
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folder", type=Path, nargs="?", default=REPO.parent / "shared" / "data" / "kicad6-step")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--limit", type=int, help="Parts per class folder (default: all).")
    parser.add_argument("--cache", type=Path, help="Raw results: read if present, else computed and written.")
    parser.add_argument("--markdown", type=Path)
    parser.add_argument("--plot", type=Path)
    args = parser.parse_args(argv)
    if args.cache and args.cache.exists():
        raw = pickle.loads(args.cache.read_bytes())
    else:
        raw = run(args.folder, args.workers, args.limit)
        if args.cache:
            args.cache.write_bytes(pickle.dumps(raw))
    analysis = args.cache.with_suffix(".analysis.pkl") if args.cache else None
    if analysis and analysis.exists() and analysis.stat().st_mtime >= args.cache.stat().st_mtime:
        result = pickle.loads(analysis.read_bytes())  # the all-pairs distances take minutes
    else:
        result = analyse(raw)
        if analysis:
            analysis.write_bytes(pickle.dumps(result))
    if args.plot:
        plot(result, args.plot)
    command = "python scripts/faceting_study.py ../shared/data/kicad6-step --workers 2"
    command += f" --limit {raw['limit']}" if raw["limit"] else ""
    command += " --markdown docs/faceting.md --plot docs/faceting.png"
    text = markdown(raw, result, args.plot.name if args.plot else None, command)
    if args.markdown:
        args.markdown.write_text(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
