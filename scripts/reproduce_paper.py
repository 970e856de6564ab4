#!/usr/bin/env python3
"""Reproduce Ip et al. (2002) on the National Design Repository parts; write docs/paper-reproduction.md.

    python scripts/reproduce_paper.py                 # ../shared/data/ndr, store in a temp folder

Every figure of ours in the document is computed here; the paper's figures are quoted from
its Table 1, Table 2 and Figure 5.
"""

from __future__ import annotations

import argparse
import datetime
import sys
import tempfile
from pathlib import Path

import numpy as np

from _common import DATA, REPO, quiet_build
from shapeidx.signing.classify import IN, TANGENT, classify_pairs, pair_indices
from shapeidx.signing.mesh import unit_normals
from shapeidx.distance import PAPER_METRICS, compare
from shapeidx.system import keep_freed_memory
from shapeidx.signing.pipeline import signature_of_solid, solid_of_file
from shapeidx.api import query as query_store
from shapeidx.signing.sampling import sample_surface

NDR = DATA / "ndr"

# The paper's Table 1 (% IN, % OUT, % MIXED) and Table 2 (ALL, AvgOf3, AvgOf4, Weighted).
PAPER_TABLE_1 = {
    "Cheese": (3.59, 1.66, 94.74),
    "Socket": (23.92, 4.76, 71.31),
    "Boeing": (16.43, 4.80, 78.75),
    "Simple Boeing": (16.64, 5.76, 77.58),
    "Team": (16.09, 0.79, 83.10),
    "Team2": (25.40, 0.93, 73.66),
}
PAPER_TABLE_2 = {
    ("Boeing", "Simple Boeing"): (4.33, 8.72, 7.62, 26.41),
    ("Boeing", "Team"): (13.86, 22.35, 20.23, 69.41),
    ("Boeing", "Team2"): (10.65, 22.80, 26.85, 85.10),
    ("Simple Boeing", "Team"): (15.13, 19.45, 20.89, 65.45),
    ("Simple Boeing", "Team2"): (11.30, 23.39, 27.42, 86.95),
    ("Team", "Team2"): (10.53, 24.00, 28.49, 88.80),
    ("Cheese", "Socket"): (3.97, 18.30, 23.08, 79.40),
}
# Where the paper's models are in ndr/, per exporter (SOURCES.tsv): ACIS through Drexel's
# Sat2Vrml (the paper's group) and SDRC I-DEAS.
MODELS = {
    "Boeing": "ACIS/NIST/boeing_part/boeing_part",
    "Simple Boeing": "ACIS/NIST/simple_boeing_part/simple_boeing_part",
    "Team": "Allied-Signal/team/team",
    "Team2": "Allied-Signal/team2/team2",
}
EXPORTERS = {"ACIS (Sat2Vrml)": ".hh.sat.wrl", "I-DEAS": ".wrl"}
SEEDS = range(5)


def fractions_table(lines: list[str]) -> dict:
    lines += [
        "## Table 1: distribution of classifications",
        "",
        "Our fractions are the mean over the default seed and four more (the ± is their standard",
        "deviation: what sampling alone moves), for each exporter's file of the same part.",
        "",
        "| model | paper IN / OUT / MIXED | exporter | ours IN | OUT | MIXED | IN - paper | MIXED - paper |",
        "|---|---|---|---|---|---|---|---|",
    ]
    gaps = {}
    for name, paper in PAPER_TABLE_1.items():
        if name not in MODELS:
            lines.append(f"| {name} | {' / '.join(f'{v:.2f}' for v in paper)} | (not in ndr) | | | | | |")
            continue
        for exporter, suffix in EXPORTERS.items():
            solid = solid_of_file(NDR / (MODELS[name] + suffix))
            runs = np.array([[signature_of_solid(solid, seed=s).fractions[c] for c in ("in", "out", "mixed")] for s in SEEDS]) * 100
            mean, std = runs.mean(axis=0), runs.std(axis=0)
            gaps[(name, exporter)] = mean - np.array(paper)
            cells = " | ".join(f"{m:.2f} ± {s:.2f}" for m, s in zip(mean, std))
            lines.append(
                f"| {name} | {' / '.join(f'{v:.2f}' for v in paper)} | {exporter} | {cells} | "
                f"{mean[0] - paper[0]:+.2f} | {mean[2] - paper[2]:+.2f} |"
            )
    lines.append("")
    return gaps


def on_face_share(lines: list[str]) -> None:
    """Could the gaps come from segments lying on a face (IN for us, by the closed-set rule)?"""
    lines += [
        "### Where the IN excess does not come from",
        "",
        "A segment lying on a face is IN by our closed-set definition; an implementation that",
        "did not count those as IN would report fewer IN pairs. The share of our IN pairs whose",
        "both ends run along their face plane (ACIS files, five seeds):",
        "",
        "| model | ours IN | IN lying in a face plane | IN without them | paper IN |",
        "|---|---|---|---|---|",
    ]
    for name, stem in MODELS.items():
        solid = solid_of_file(NDR / (stem + ".hh.sat.wrl"))
        shares = []
        for seed in SEEDS:
            points, face_index = sample_surface(solid.vertices, solid.faces, 1024, seed)
            _, classes = classify_pairs(solid.vertices, solid.faces, points, face_index, solid.watertight)
            normals = unit_normals(solid.vertices, solid.faces[face_index])
            i, j = pair_indices(len(points))
            delta = points[j] - points[i]
            length = np.linalg.norm(delta, axis=1)
            flat = (np.abs(np.einsum("ij,ij->i", delta, normals[i])) < TANGENT * length) & (
                np.abs(np.einsum("ij,ij->i", delta, normals[j])) < TANGENT * length
            )
            shares.append((np.mean(classes == IN) * 100, np.mean(flat & (classes == IN)) * 100))
        ours, flat = np.mean(shares, axis=0)
        lines.append(f"| {name} | {ours:.2f} | {flat:.2f} | {ours - flat:.2f} | {PAPER_TABLE_1[name][0]:.2f} |")
    lines += [
        "",
        "Leaving them out would overshoot by far (and break the Boeing parts, which agree), so",
        "that is not the explanation. What remains: the paper faceted the ACIS models itself",
        "(their tessellation is not in the repository, the files here are later exports whose",
        "fineness may differ), and it does not say how it classified a segment.",
        "",
    ]


def spearman(x, y) -> float:
    rx, ry = np.argsort(np.argsort(x)), np.argsort(np.argsort(y))
    return float(np.corrcoef(rx, ry)[0, 1])


def distances_table(lines: list[str], signatures: dict) -> dict:
    pairs = [p for p in PAPER_TABLE_2 if p[0] in MODELS and p[1] in MODELS]
    lines += [
        "## Table 2: distances between models",
        "",
        "The paper's scale differs from ours (its numbers look like ours times a constant), so",
        "each distance is also given as a ratio to the Boeing / Simple Boeing distance, the pair",
        "the paper calls most alike; and the six pairs' ordering is compared by Spearman's rank",
        "correlation. Cheese and Socket are not in the repository's surviving files.",
        "",
    ]
    agreement = {}
    for exporter in EXPORTERS:
        ours = {p: compare(signatures[exporter][p[0]], signatures[exporter][p[1]]) for p in pairs}
        base = pairs[0]
        lines += [f"### {exporter} files", "", "| pair | " + " | ".join(f"paper {m} | ours {m} | ratio paper / ours" for m in ("ALL", "AvgOf3", "AvgOf4", "Weighted")) + " |",
                  "|---|" + "---|---|---|" * 4]
        for p in pairs:
            cells = []
            for k, m in enumerate(PAPER_METRICS):
                paper_ratio = PAPER_TABLE_2[p][k] / PAPER_TABLE_2[base][k]
                our_ratio = ours[p][m] / ours[base][m]
                cells.append(f"{PAPER_TABLE_2[p][k]:.2f} | {ours[p][m]:.5f} | {paper_ratio:.2f} / {our_ratio:.2f}")
            lines.append(f"| {p[0]} - {p[1]} | " + " | ".join(cells) + " |")
        rho = {m: spearman([PAPER_TABLE_2[p][k] for p in pairs], [ours[p][m] for p in pairs]) for k, m in enumerate(PAPER_METRICS)}
        nearest = {m: min(pairs, key=lambda p: ours[p][m]) for m in PAPER_METRICS}
        agreement[exporter] = {"rho": rho, "nearest": nearest, "team_rank": {
            m: sorted(pairs, key=lambda p: ours[p][m]).index(("Team", "Team2")) + 1 for m in PAPER_METRICS}}
        lines += [
            "",
            "Spearman correlation of the six pairs' ordering, paper against ours: "
            + ", ".join(f"{m} {rho[m]:+.2f}" for m in PAPER_METRICS) + ".",
            "Nearest pair by each distance (the paper: Boeing - Simple Boeing by all four): "
            + ", ".join(f"{m}: {' - '.join(nearest[m])}" for m in PAPER_METRICS) + ".",
            "",
        ]
    return agreement


def figure_4(lines: list[str], signatures: dict, docs: Path) -> None:
    """The paper's Figure 4 (the four histograms of four parts), drawn by shapeidx plot's code."""
    from shapeidx.pictures.plot import plot_signatures

    exporter = "ACIS (Sat2Vrml)"
    picture = docs / "images" / "paper-figure-4.png"
    picture.parent.mkdir(parents=True, exist_ok=True)
    plot_signatures(list(signatures[exporter].items()), picture, f"Figure 4 on ndr: {exporter} files, 1024 points")
    files = " ".join(f"ndr/{MODELS[name]}{EXPORTERS[exporter]}" for name in MODELS)
    labels = " ".join(f"--label '{name}'" for name in MODELS)
    lines += [
        "## Figure 4: the four histograms of four parts",
        "",
        "The paper's Figure 4 shows the ALL, IN, OUT and MIXED histograms of the Boeing, Simple Boeing,",
        "Team and Team2 parts. Ours, drawn by `shapeidx plot` (probability against distance over the",
        "mean of each set, the scale the distances compare; each part's class fractions in the",
        "legends, the paper's four distances between every pair on top):",
        "",
        f"![Figure 4 reproduced]({picture.relative_to(docs).as_posix()})",
        "",
        f"The same figure from the shell (in `shared/data`): `shapeidx plot {files} {labels} -o figure-4.png`.",
        "",
    ]


def queries(lines: list[str], store: Path) -> dict:
    lines += [
        "## Figure 5: query by example on the whole ndr folder",
        "",
        "Of the paper's five queries only Query 5 (linkage arm 42, whose best answer in the",
        "paper is linkage arm 43 from the same spectrometer assembly) survives in ndr; goodpart3,",
        "the Socket, the simple bracket and the compressor housing do not. Linkage arm 42 is in",
        "our store, so it comes back first, at distance 0 (the paper's query was not in its",
        "database); what matters is what follows.",
        "",
    ]
    query_file = NDR / "CMU/spectrometer/linkage_arm_42.hh.sat.wrl"
    for metric in ("weighted", "combined"):
        hits = query_store(store, part=query_file, top=6, metric=metric)
        lines += [f"`shapeidx query {query_file.relative_to(NDR.parent)} --metric {metric} --top 6`:", "", "| rank | distance | part |", "|---|---|---|"]
        lines += [f"| {h['rank']} | {h['distance']:.5f} | {h['relative_path']} |" for h in hits]
        lines.append("")
    lines += [
        "### The same part from two CAD systems",
        "",
        "The paper's claim is that shape distributions find similar parts whatever system",
        "exported them. Each I-DEAS export, used as a query, and where its ACIS (Sat2Vrml) twin",
        "ranks among the other 15 parts (rank 1 is the query itself):",
        "",
        "| query (I-DEAS) | rank of its ACIS twin, weighted | combined | nearest other part (weighted) |",
        "|---|---|---|---|",
    ]
    twins = {}
    for name, stem in MODELS.items():
        twin = stem + EXPORTERS["ACIS (Sat2Vrml)"]
        ranks, nearest = {}, None
        for metric in ("weighted", "combined"):
            hits = query_store(store, part=NDR / (stem + ".wrl"), top=16, metric=metric)
            ranks[metric] = next(h["rank"] for h in hits if h["relative_path"] == twin)
            if metric == "weighted":
                nearest = next(h["relative_path"] for h in hits if h["relative_path"] not in (twin, stem + ".wrl"))
        lines.append(f"| {name} | {ranks['weighted']} | {ranks['combined']} | {nearest} |")
        twins[name] = ranks
    lines.append("")
    return twins


def summary(gaps: dict, agreement: dict, twins: dict) -> list[str]:
    """The findings in a few sentences, with the figures computed above."""
    def worst(name):
        return max(abs(gaps[(name, e)][0]) for e in EXPORTERS if (name, e) in gaps)

    acis = agreement["ACIS (Sat2Vrml)"]
    a, b = EXPORTERS
    between = max(float(np.abs(gaps[(name, a)] - gaps[(name, b)]).max()) for name in MODELS)
    return [
        "## In short",
        "",
        f"* **Class fractions (Table 1)** agree within {max(worst('Boeing'), worst('Simple Boeing')):.1f} points of IN on the two",
        f"  Boeing parts and within {max(worst('Team'), worst('Team2')):.1f} on the two TEAM parts, where ours have more IN",
        "  and less MIXED. The two exporters (ACIS through Sat2Vrml, SDRC I-DEAS) of each part",
        f"  agree with each other within {between:.1f} points in every class: the heterogeneity claim holds.",
        "* **Distances (Table 2)**: every distance finds Boeing - Simple Boeing the nearest pair, as",
        "  the paper does, and plain D2 orders the six pairs as the paper does (Spearman",
        f"  {acis['rho']['all']:+.2f} on the ACIS files). The classified distances do not follow the paper's",
        "  order: the paper's Table 2 puts Team - Team2 *farthest* by AvgOf3, AvgOf4 and Weighted,",
        "  against its own text and Figure 4 (\"resemblances are strong ... [between] the two TEAM",
        f"  parts\"); ours put it nearest after the Boeing pair (rank {acis['team_rank']['weighted']} of 6 by Weighted). We",
        "  cannot tell which of the paper's table and text is in error; ours side with the text.",
        "* **Query by example (Figure 5)**: the one surviving query, linkage arm 42, finds linkage",
        "  arm 43 first after itself, as in the paper.",
        "* **Same part, two CAD systems**: by Weighted the other system's file of the same part",
        f"  ranks right after the query for {sum(r['weighted'] == 2 for r in twins.values())} of {len(twins)} parts; by the combined metric",
        f"  for {sum(r['combined'] == 2 for r in twins.values())} of {len(twins)}.",
        "",
    ]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--store", type=Path, help="store of the ndr folder (default: a temporary one)")
    parser.add_argument("--output", type=Path, default=REPO / "docs" / "paper-reproduction.md")
    args = parser.parse_args(argv)
    keep_freed_memory()
    with tempfile.TemporaryDirectory() as tmp:
        store = args.store or Path(tmp) / "ndr.shapeidx"
        quiet_build(NDR, store)
        signatures = {
            exporter: {name: signature_of_solid(solid_of_file(NDR / (stem + suffix))) for name, stem in MODELS.items()}
            for exporter, suffix in EXPORTERS.items()
        }
        command = "python " + " ".join([Path(sys.argv[0]).relative_to(REPO).as_posix() if Path(sys.argv[0]).is_relative_to(REPO) else sys.argv[0]] + (argv if argv is not None else sys.argv[1:]))
        lines = [
            "# Reproducing Ip et al. (2002) on the National Design Repository",
            "",
            f"Produced by `{command}` on {datetime.date.today()}, shapeidx defaults (1024 points,",
            "bins of mean / 50). Data: `shared/data/ndr` (see its SOURCES.tsv). Nothing below is typed",
            "by hand except the paper's own figures.",
            "",
        ]
        summary_at = len(lines)
        gaps = fractions_table(lines)
        on_face_share(lines)
        agreement = distances_table(lines, signatures)
        figure_4(lines, signatures, args.output.parent)
        twins = queries(lines, store)
        lines[summary_at:summary_at] = summary(gaps, agreement, twins)
    args.output.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
