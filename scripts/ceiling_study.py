#!/usr/bin/env python3
"""How far can a shape metric go? Ceilings of issue 24's three targets, from the parts' exact geometry.

    python scripts/ceiling_study.py --stores /work/stores/metric --pictures /tmp/ceiling \\
        --points2048 /tmp/ceiling/s2048 --markdown docs/unified.md

A miss is only a metric's fault when the right answer is the one that looks most like the query.
For every miss of today's best metric on each question, this script puts the part ranked first and
the right answer beside the query and measures, from the exact surface moments the stores keep
(shapeidx/signing/moments.py: principal radii, axis-aligned box, and the area of the cleaned solid
from the moments fingerprint), how far apart they are (:func:`gaps`: the largest relative mismatch
of the sorted box sides, the radii and the area, after the best uniform scale or at a given one):

1. **kicad6 kinds** (520 parts, 52 class folders): combined-angle with its weights cross-validated
   by class folds (deal 0 of :func:`shapeidx.evaluation.learn.cross_validated_distances`, as
   scripts/unified_study.py deals them); its NN misses and how far the part found is from the
   query. The ceiling (:func:`ceiling`): parts within a tolerance (:data:`TOLERANCES`) count as the
   same shape; a query whose same-shape parts are all of other classes is missed by any shape
   metric, and its first tier loses the slots they take. Scale-free (what D2 sees) and same size.
2. **xexp-dev twins** (KiCad 2017 export against 1,000 KiCad 6 parts, docs/twins.md): every one of
   the 69 kept pairs whose twin all-angle does not rank first, the part above it, the gaps, the
   twin's rank among the store by the exact gaps (the *oracle*), and a picture of the three
   (``--pictures``). Each miss gets a verdict (:data:`VERDICTS`, made by looking at the pictures).
3. **kicad6-step twins** (STEP against the 520 VRML parts, docs/step-twins.md): the same for the
   misses of combined and of all-angle.
4. **Sampling** (:func:`drawn_again`): the stores and the queries draw their points with one fixed
   seed. Today's queries signed with other seeds (:data:`SEEDS`), and exact copies of the right
   answers (their own files) signed with other seeds, ranked against the same stores; with
   ``--points2048`` also on stores signed with 2048 points (kicad6-2048.h5, and the twins' store
   built there, some 6 min).

Writes the section "How far can a shape metric go? (ceilings)" at the end of ``--markdown``
(replacing it when run again) and prints it. Exits 1 when a twin miss has no verdict (a new miss
after a change to the metrics: look at its picture and add it to :data:`VERDICTS`).
"""

from __future__ import annotations

import argparse
import datetime
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from _common import DATA, REPO, machine
import twin_study
from shapeidx.evaluation.evaluate import distance_matrices, labelled_features
from shapeidx.evaluation.learn import cross_validated_distances
from shapeidx.evaluation.retrieval import retrieval_scores
from shapeidx.search import Searcher
from shapeidx.search.distances import distances

BEGIN = "<!-- the ceilings section: written by scripts/ceiling_study.py; do not edit by hand -->"
END = "<!-- end of the ceilings section -->"
#: The unit factors a part's size may differ by between two exports (as scripts/twod_study.py's size gap).
UNITS = (1.0, 2.54, 1 / 2.54)
#: The seeds of the points drawn again (the stores use the fixed default seed).
SEEDS = (7, 8, 9)


# ---------------------------------------------------------------- geometry


class Facts:
    """The exact geometry a store keeps of each entry, by path."""

    def __init__(self, searcher: Searcher):
        self.paths = [str(p) for p in searcher.metadata_column("path")]
        self.row = {p: i for i, p in enumerate(self.paths)}
        bounds = np.asarray(searcher.column("entries/bounds"), dtype=np.float64)
        self.box = np.sort(bounds[:, 3:] - bounds[:, :3], axis=1)[:, ::-1]  # largest first
        self.radii = np.asarray(searcher.column("entries/extents"), dtype=np.float64)
        moments = np.asarray(searcher.column("entries/moments"), dtype=np.float64)
        # the area of the cleaned solid the signature samples (entries/area is the file's as read):
        # the moments fingerprint is area / (r1^2 + r2^2 + r3^2)
        self.area = moments[:, 0] * (self.radii**2).sum(axis=1)
        self.skew = moments[:, 1:]

    def of(self, path: str) -> dict:
        i = self.row[path]
        return {"box": self.box[i], "radii": self.radii[i], "area": self.area[i], "skew": self.skew[i]}


def gaps(a: dict, b: dict, scale: float | None = None) -> dict:
    """How far ``b`` is from ``a``: the largest relative mismatch of the sorted box sides, of the
    principal radii, of the area, and of the skewnesses (absolute), after scaling ``b`` by ``scale``
    (default: the best uniform scale, the median ratio of the sorted box sides, as
    twin_study.pair_facts; 1: the same size)."""
    if scale is None:
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = float(np.median(a["box"] / b["box"]))
    with np.errstate(divide="ignore", invalid="ignore"):
        box = float(np.nanmax(np.abs(a["box"] / (scale * b["box"]) - 1)))
        radii = float(np.nanmax(np.abs(a["radii"] / (scale * b["radii"]) - 1)))
        area = float(a["area"] / (scale**2 * b["area"]) - 1)
    skew = np.abs(a["skew"] - b["skew"])
    skew = float(np.nanmax(skew)) if np.isfinite(skew).any() else 0.0
    return {"scale": scale, "box": box, "radii": radii, "area": area, "skew": skew,
            "worst": max(box, radii, abs(area))}


def short(path: str) -> str:
    return Path(path).with_suffix("").name


# ---------------------------------------------------------------- 1. kicad6 kinds


#: The tolerances of the kinds ceiling table (largest gap of box sides, principal radii and area).
TOLERANCES = (0.01, 0.02, 0.05, 0.10)


def kinds(store: Path) -> dict:
    """kicad6: combined-angle cross-validated (one deal), its NN misses, and the exact-geometry gaps
    between every two parts, scale-free and at the same size."""
    with Searcher(store) as searcher:
        data = labelled_features(searcher)
        facts = Facts(searcher)
    paths = [str(p) for p in data.paths]
    labels = np.asarray(data.labels)
    n = len(paths)
    plain = distance_matrices(data, ("all-angle",))["all-angle"]
    cv = cross_validated_distances(data.learned_features("combined-angle"), labels, 4, 0)
    scores = retrieval_scores(cv, labels)
    f = [facts.of(p) for p in paths]
    free, sized = np.full((n, n), np.inf), np.full((n, n), np.inf)
    for i in range(n):
        for j in range(n):
            if i != j:
                free[i, j] = gaps(f[i], f[j])["worst"]
                sized[i, j] = gaps(f[i], f[j], 1.0)["worst"]
    other = labels[:, None] != labels[None, :]
    d = cv.copy()
    np.fill_diagonal(d, np.inf)
    nn = d.argmin(axis=1)
    misses = [i for i in range(n) if labels[nn[i]] != labels[i]]
    own_free = np.where(~other, free, np.inf).min(axis=1)
    rows = [{"query": paths[i], "first": paths[int(nn[i])], "gap": gaps(f[i], f[int(nn[i])]), "all_angle": float(plain[i, nn[i]]),
             "own": float(own_free[i])} for i in misses]
    exact = {}
    for name, gap in (("scale-free", free), ("same size", sized)):
        g = gap.copy()
        np.fill_diagonal(g, 0.0)
        exact[name] = retrieval_scores(g, labels)
    return {"n": n, "scores": scores, "misses": rows, "exact": exact, "labels": labels, "paths": paths, "free": free, "sized": sized,
            "other": other, "class_sizes": Counter(labels.tolist())}


def ceiling(labels, other, gap, tolerance) -> tuple[np.ndarray, np.ndarray]:
    """Per query, with parts within ``tolerance`` (``gap``) counted as the same shape: whether the NN
    is a forced miss (a same-shape part of another class and none of its own), and the best first
    tier when same-shape parts come first (ties broken the query's way) and the rest of its class next."""
    n = len(labels)
    same = gap <= tolerance
    np.fill_diagonal(same, False)
    forced, ft = np.zeros(n, dtype=bool), np.zeros(n)
    for i in range(n):
        c = int((~other[i]).sum()) - 1
        s_own = int((same[i] & ~other[i]).sum())
        s_other = int((same[i] & other[i]).sum())
        forced[i] = s_other > 0 and s_own == 0
        ft[i] = (s_own + max(0, c - s_own - s_other)) / c if c else 0.0
    return forced, ft


# ---------------------------------------------------------------- 2 and 3. twins


def twin_misses(query_store: Path, store: Path, twin_of, names, metrics) -> dict:
    """metric -> [row per query whose twin is not first], and the twins' ranks."""
    out = {m: [] for m in metrics}
    ranks = {m: {} for m in metrics}
    with Searcher(query_store) as queries, Searcher(store) as searcher:
        qf, sf = Facts(queries), Facts(searcher)
        where = sf.row
        for k, path in enumerate(queries.metadata_column("path")):
            path = str(path)
            if path not in names:
                continue
            twin = where[twin_of(path)]
            signature = queries.signature_at(k)
            for metric in metrics:
                d = distances(searcher.view, signature, metric)
                rank = int((d <= d[twin]).sum())
                ranks[metric][path] = rank
                if rank == 1:
                    continue
                order = np.argsort(d, kind="stable")
                above = [int(x) for x in order if x != twin and d[x] <= d[twin]]
                q = qf.of(path)
                first = sf.paths[above[0]]
                # the geometric oracle: the store's parts ordered by their exact-geometry gap to the query
                worst = np.array([gaps(q, sf.of(p))["worst"] for p in sf.paths])
                # the same with the size kept: the least gap over the unit factors (mm, tenths of an inch)
                sized = np.array([min(gaps(q, sf.of(p), u)["worst"] for u in UNITS) for p in sf.paths])
                out[metric].append({
                    "query": path, "twin": sf.paths[twin], "rank": rank, "first": first,
                    "d_twin": float(d[twin]), "d_first": float(d[above[0]]),
                    "g_twin": gaps(q, sf.of(sf.paths[twin])), "g_first": gaps(q, sf.of(first)),
                    "twin_vs_first": gaps(sf.of(sf.paths[twin]), sf.of(first)),
                    "oracle_rank": int((worst <= worst[twin]).sum()),
                    "oracle_first": sf.paths[int(np.argmin(worst))],
                    "oracle_sized": int((sized <= sized[twin]).sum()),
                    "above": [sf.paths[x] for x in above[:3]],
                })
    return out, ranks


def twin_gaps(query_store: Path, store: Path, twin_of) -> np.ndarray:
    """The largest exact-geometry gap between every query and its twin."""
    with Searcher(query_store) as queries, Searcher(store) as searcher:
        qf, sf = Facts(queries), Facts(searcher)
        return np.array([gaps(qf.of(p), sf.of(twin_of(p)))["worst"] for p in qf.paths])


def picture(files: list, titles: list, output: Path) -> None:
    """The parts side by side (shapeidx.pictures.render's fixed isometric view), titled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from shapeidx.pictures.render import render_rgba
    from shapeidx.signing.part import load_part

    fig, axes = plt.subplots(1, len(files), figsize=(4.2 * len(files), 4.6))
    for ax, file, title in zip(axes, files, titles):
        solid = load_part(file)
        ax.imshow(render_rgba(solid.vertices, solid.faces, 320))
        ax.set_title(title, fontsize=8, wrap=True)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(output, dpi=80)
    plt.close(fig)


def drawn_again(store: Path, files: dict, metrics, seeds=SEEDS) -> dict:
    """Each query file (``files``: right answer's entry in ``store`` -> the file to sign) signed with
    each of ``seeds`` (the store's number of points) and ranked against ``store``: metric -> {entry:
    [the right answer's rank, one per seed]}. With the right answer's own file, an **exact copy**
    whose points are drawn independently of the stored ones: the rank-1 rate this gives is the most
    a metric on these signatures can be expected to reach for a real twin whose points are not
    drawn with the stored part's seed."""
    from shapeidx.signing.pipeline import signature_of_solid, solid_of_file

    out = {m: {} for m in metrics}
    with Searcher(store) as searcher:
        where = {str(p): i for i, p in enumerate(searcher.metadata_column("path"))}
        for entry, file in files.items():
            solid = solid_of_file(file)
            own = where[entry]
            for seed in seeds:
                signature = signature_of_solid(solid, points=searcher.params.points, seed=seed)
                for m in metrics:
                    d = distances(searcher.view, signature, m)
                    out[m].setdefault(entry, []).append(int((d <= d[own]).sum()))
    return out


def first_rate(ranks: dict, entries) -> float:
    """Share of rank 1 over ``entries`` and seeds."""
    return float(np.mean([r == 1 for e in entries for r in ranks[e]]))


# ---------------------------------------------------------------- verdicts (made on the pictures)

FAILURE, SIBLING, REMODELLED, DUPLICATE = "metric failure", "series sibling", "twin remodelled", "duplicate"
#: Each twin miss, by (query, part ranked first) file stems: (verdict, what the pictures and figures show).
#: Made by looking at --pictures' three views (query, twin, part ranked first) beside the gaps.
VERDICTS = {
    # xexp-dev, all-angle
    ("CP_Axial_L55.0mm_D26.0mm_P60.00mm_Horizontal", "CP_Axial_L67.0mm_D32.0mm_P75.00mm_Horizontal"):
        (SIBLING, "a larger can of the series with the twin's proportions (1% apart); the 2017 can has grooves and marks the twin lacks"),
    ("CP_Axial_L55.0mm_D32.0mm_P60.00mm_Horizontal", "TerminalBlock_Phoenix_MKDS-1,5-4_1x04_P5.00mm_Horizontal"):
        (FAILURE, "a terminal block above a can that looks like the query"),
    ("CP_Axial_L80.0mm_D35.0mm_P85.00mm_Horizontal", "Mounting_Wuerth_WA-SMSR-M3_H9.6mm_9775096360"):
        (FAILURE, "a standoff above a can that looks like the query"),
    ("CP_Radial_D10.0mm_P2.50mm_P5.00mm", "CP_Elec_10x10"):
        (REMODELLED, "the 2017 can is hollow and open at the top (its inner wall shows), the twin closed with a vent cross: 23% more surface; other cans as near"),
    ("CP_Radial_D10.0mm_P3.50mm", "CP_Elec_10x10"):
        (REMODELLED, "as above: hollow open 2017 can against a closed twin, 24% more surface"),
    ("CP_Radial_D14.0mm_P7.50mm", "CP_Elec_10x10"):
        (REMODELLED, "as above: hollow open 2017 can against a closed twin, 24% more surface"),
    ("C_Disc_D10.5mm_W5.0mm_P7.50mm", "C_Disc_D10.5mm_W5.0mm_P10.00mm"):
        (SIBLING, "the same disc at another pitch (one lead bent); the 2017 leads reach 1.2 mm lower than the twin's (height +10%)"),
    ("C_Disc_D11.0mm_W5.0mm_P5.00mm", "C_Disc_D10.5mm_W5.0mm_P10.00mm"):
        (SIBLING, "a 5% smaller disc at another pitch; the 2017 leads reach 1.2 mm lower than the twin's (height +9%)"),
    ("C_Disc_D8.0mm_W2.5mm_P5.00mm", "C_Disc_D7.5mm_W2.5mm_P5.00mm"):
        (SIBLING, "a 6% smaller disc at the same pitch, nearer the query in box and area than the twin (the 2017 leads reach 1.2 mm lower: height +12%)"),
    ("C_Rect_L11.5mm_W6.4mm_P10.00mm_MKT", "C_Rect_L11.5mm_W6.6mm_P10.00mm_MKT"):
        (SIBLING, "the same box 3% wider; the 2017 leads reach 0.9 mm lower than the twin's (height +8%)"),
    ("C_Rect_L9.0mm_W3.9mm_P7.50mm_MKT", "C_Rect_L9.0mm_W4.0mm_P7.50mm_MKT"):
        (SIBLING, "the same box 2.5% wider; the 2017 leads reach 0.9 mm lower than the twin's (height +9%)"),
    ("Crystal_HC49-U_Horizontal_1EP_style2", "Crystal_HC18-U_Horizontal_1EP_style1"):
        (DUPLICATE, "KiCad 6's HC18-U model is the twin's geometry (0.0% apart): a tie at best"),
    ("LED_D8.0mm", "D_P600_R-6_P7.62mm_Vertical_KathodeUp"):
        (FAILURE, "a vertical diode above an LED that looks like the query"),
    # kicad6-step, combined and all-angle
    ("C_2816_7142Metric", "L_2816_7142Metric"): (DUPLICATE, "KiCad's C_2816 and L_2816 are one model (0.0% apart)"),
    ("L_2816_7142Metric", "C_2816_7142Metric"): (DUPLICATE, "KiCad's C_2816 and L_2816 are one model (0.0% apart)"),
    ("C_Rect_L41.5mm_W15.0mm_P37.50mm_MKS4", "UFBGA-144_7x7mm_Layout12x12_P0.5mm"):
        (FAILURE, "a flat BGA above a box capacitor; the twin is the query's geometry"),
    ("TE_1-84952-0_1x10-1MP_P1.0mm_Horizontal", "TE_1-84953-0_1x10-1MP_P1.0mm_Horizontal"):
        (FAILURE, "the twin looks like the query; the part above has slots on top (the twin's VRML has 8% less surface, none visible)"),
    ("PhoenixContact_GMSTBVA_2,5_8-G-7,62_1x08_P7.62mm_Vertical", "PhoenixContact_GMSTBA_2,5_8-G_1x08_P7.50mm_Horizontal"):
        (FAILURE, "the horizontal header (box 30% apart) above the vertical one"),
    ("L_Radial_D24.4mm_P23.90mm_muRATA_1400series", "SW_DIP_SPSTx02_Slide_KingTek_DSHP02TS_W7.62mm_P1.27mm"):
        (FAILURE, "a DIP switch above a radial inductor"),
    ("LED_Rectangular_W7.62mm_H4.55mm_P5.08mm_R3", "DIP-5-6_W7.62mm_Socket"):
        (FAILURE, "the twin looks like the query (its VRML has 14% less surface, none visible); the DIP does not"),
    ("LED_Rectangular_W7.62mm_H4.55mm_P5.08mm_R3", "SW_Tactile_SPST_Angled_PTS645Vx39-2LFS"):
        (FAILURE, "as above, a tactile switch above it"),
    ("R_LDR_D6.4mm_P3.4mm_Vertical", "BatteryHolder_Keystone_3000_1x12mm"):
        (FAILURE, "a battery holder above a photoresistor"),
    ("RV_Disc_D21.5mm_W5.3mm_P10mm", "RV_Disc_D21.5mm_W5.6mm_P10mm"):
        (SIBLING, "the same disc 5% thicker"),
    ("RV_Disc_D21.5mm_W5.6mm_P10mm", "RV_Disc_D21.5mm_W5.3mm_P10mm"):
        (SIBLING, "the same disc 5% thinner"),
    ("RV_Disc_D21.5mm_W6.8mm_P10mm", "RV_Disc_D15.5mm_W5.2mm_P7.5mm"):
        (SIBLING, "a smaller disc of the series, proportions 5% apart"),
    ("CP_Elec_10x7.7", "CP_Elec_8x6.2"): (SIBLING, "a smaller can of the series, proportions 2% apart"),
    ("Molex_502250-2191_2Rows-21Pins-1MP_P0.60mm_Horizontal", "NHD-0420H1Z"): (FAILURE, "a display module above a connector"),
    ("TE_1-84953-0_1x10-1MP_P1.0mm_Horizontal", "TE_1-84952-0_1x10-1MP_P1.0mm_Horizontal"):
        (SIBLING, "the same connector without the top slots, 8% less surface"),
    ("JST_EH_S6B-EH_1x06_P2.50mm_Horizontal", "Molex_PicoBlade_53261-0671_1x06-1MP_P1.25mm_Horizontal"):
        (FAILURE, "another maker's connector, box 38% apart"),
    ("Molex_PicoBlade_53261-0671_1x06-1MP_P1.25mm_Horizontal",
     "PhoenixContact_MC_1,5_5-GF-3.5_1x05_P3.50mm_Horizontal_ThreadedFlange_MountHole"):
        (FAILURE, "a terminal header above a connector; the twin looks like the query (its VRML has 9% less surface)"),
    ("PhoenixContact_GMSTBA_2,5_8-G_1x08_P7.50mm_Horizontal", "PhoenixContact_GMSTBVA_2,5_8-G-7,62_1x08_P7.62mm_Vertical"):
        (FAILURE, "the vertical header (box 42% apart) above the horizontal one"),
    ("PhoenixContact_GMSTBVA_2,5_8-G-7,62_1x08_P7.62mm_Vertical", "PhoenixContact_MSTBVA_2,5_12-G_1x12_P5.00mm_Vertical"):
        (SIBLING, "a 12-pin header of the smaller series, box 2% and surface 5% apart"),
    ("CA56-12SEKWA", "Crystal_SMD_MicroCrystal_CC4V-T1A-2Pin_5.0x1.9mm"): (FAILURE, "a crystal box above a display"),
    ("UFBGA-132_7x7mm_P0.5mm", "UFBGA-144_7x7mm_Layout12x12_P0.5mm"):
        (SIBLING, "the same body with 12 more balls underneath: box, radii and surface within 0.5%"),
    ("Potentiometer_Bourns_3009Y_Horizontal", "Potentiometer_Bourns_3009P_Horizontal"):
        (SIBLING, "the same body with its pins placed otherwise, within 1%"),
    ("Relay_DPST_Schrack-RT2-FormA_RM5mm", "Relay_DPDT_Schrack-RT2-FormC_RM5mm"):
        (SIBLING, "the same relay with one more pin, 1.4% more surface"),
    ("Transformer_Breve_TEZ-38x45", "Transformer_CHK_EI54-12VA_Neutral"):
        (SIBLING, "another maker's transformer of the same form, box 8% apart"),
    ("Transformer_CHK_EI38-3VA_Neutral", "Transformer_CHK_EI38-3VA_1xSec"):
        (SIBLING, "the same transformer with other pins, box 5% apart"),
}


def verdict(row: dict) -> tuple[str, str, bool]:
    """(verdict, reason, reachable by a perfect shape metric): a metric failure is; a sibling is
    when the twin is the query's nearest part in exact geometry (oracle rank 1), else the sibling
    is at least as near; a remodelled twin or a duplicate is not."""
    key = (short(row["query"]), short(row["first"]))
    if key not in VERDICTS:
        return "?", "no verdict yet: look at the picture", False
    kind, reason = VERDICTS[key]
    return kind, reason, kind == FAILURE or (kind == SIBLING and row["oracle_rank"] == 1)


def pct(x: float) -> str:
    return f"{100 * x:+.1f}%" if np.isfinite(x) else "n/a"


def worst(g: dict) -> str:
    return f"{100 * g['worst']:.1f}%"


# ---------------------------------------------------------------- main


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--stores", type=Path, default=Path("/work/stores/metric"),
                        help="scripts/unified_study.py's --work folder (kicad6-1024.h5, kicad6-2048.h5, kicad6-step.h5, twins/)")
    parser.add_argument("--pictures", type=Path, help="write a picture of every twin miss here (query, twin, part first)")
    parser.add_argument("--points2048", type=Path,
                        help="folder for the twin stores signed with 2048 points (built there if missing, some 10 min)")
    parser.add_argument("--markdown", type=Path, default=REPO / "docs" / "unified.md")
    args = parser.parse_args(argv)
    stores = args.stores
    print("kicad6 ...", file=sys.stderr)
    k = kinds(stores / "kicad6-1024.h5")

    print("xexp-dev ...", file=sys.stderr)
    old, store = stores / "twins" / "kicad2017.h5", stores / "twins" / "store1000.h5"
    with Searcher(old) as q:
        names = [str(p) for p in q.metadata_column("path")]
    kept = [n for n in names if n not in twin_study.EXCLUDED]
    half_a, half_b = twin_study.halves(kept)
    xexp, _ = twin_misses(old, store, lambda p: f"twins/{p}", set(kept), ("all-angle",))
    xall = twin_study.twin_ranks(old, store, lambda p: f"twins/{p}")
    print("kicad6-step ...", file=sys.stderr)
    step_store, vrml = stores / "kicad6-step.h5", stores / "kicad6-1024.h5"
    with Searcher(step_store) as q:
        steps = [str(p) for p in q.metadata_column("path")]
    wrl = lambda p: str(Path(p).with_suffix(".wrl"))  # noqa: E731
    step, _ = twin_misses(step_store, vrml, wrl, set(steps), ("combined", "all-angle"))
    sall = twin_study.twin_ranks(step_store, vrml, wrl)
    step_gaps = twin_gaps(step_store, vrml, wrl)

    print("points drawn again ...", file=sys.stderr)
    metrics = ("all-angle", "combined", "unified")
    twin_files = stores / "twins" / "parts" / "twins"
    x_entry = {f"twins/{q}": q for q in kept}
    s_entry = {wrl(p): p for p in steps}
    drawn = {
        # today's queries with their points drawn with other seeds
        ("xexp", "query"): drawn_again(store, {e: DATA / "xexp-dev" / "kicad2017" / q for e, q in x_entry.items()}, metrics),
        ("step", "query"): drawn_again(vrml, {e: DATA / "kicad6-step" / p for e, p in s_entry.items()}, metrics),
        # exact copies of the right answers
        ("xexp", "copy"): drawn_again(store, {e: twin_files / q for e, q in x_entry.items()}, metrics),
        ("step", "copy"): drawn_again(vrml, {e: DATA / "kicad6" / e for e in s_entry}, metrics),
    }
    if (stores / "kicad6-2048.h5").exists():
        drawn[("step", "copy 2048")] = drawn_again(stores / "kicad6-2048.h5", {e: DATA / "kicad6" / e for e in s_entry}, metrics,
                                                   seeds=SEEDS[:1])
    if args.points2048:
        from _common import quiet_build

        args.points2048.mkdir(parents=True, exist_ok=True)
        s2 = quiet_build(stores / "twins" / "parts", args.points2048 / "store1000-2048.h5", points=2048, workers=1,
                         follow_outside_links=True)
        o2 = quiet_build(DATA / "xexp-dev" / "kicad2017", args.points2048 / "kicad2017-2048.h5", points=2048, workers=1)
        ranks = twin_study.twin_ranks(o2, s2, lambda p: f"twins/{p}", metrics)
        drawn[("xexp", "query 2048, stored seed")] = {m: {e: [ranks[q][m]] for e, q in x_entry.items()} for m in metrics}
        drawn[("xexp", "copy 2048")] = drawn_again(s2, {e: twin_files / q for e, q in x_entry.items()}, metrics, seeds=SEEDS[:1])

    if args.pictures:
        args.pictures.mkdir(parents=True, exist_ok=True)
        for tag, rows, qroot, sroot in (("xexp", xexp["all-angle"], DATA / "xexp-dev" / "kicad2017", stores / "twins" / "parts"),
                                        ("step-combined", step["combined"], DATA / "kicad6-step", DATA / "kicad6"),
                                        ("step-all-angle", step["all-angle"], DATA / "kicad6-step", DATA / "kicad6")):
            for r in rows:
                out = args.pictures / f"{tag}-{short(r['query'])}.png"
                if not out.exists():
                    picture([qroot / r["query"], sroot / r["twin"], sroot / r["first"]],
                            [f"query {short(r['query'])}",
                             f"twin (rank {r['rank']}) {short(r['twin'])}\nbox {pct(r['g_twin']['box'])} area {pct(r['g_twin']['area'])}",
                             f"first {short(r['first'])}\nbox {pct(r['g_first']['box'])} area {pct(r['g_first']['area'])}"], out)
    lines = report(k, xexp, xall, half_a, half_b, step, sall, steps, drawn, step_gaps)
    command = "python scripts/ceiling_study.py " + " ".join(argv if argv is not None else sys.argv[1:])
    lines += ["", f"Command: `{command}`; {datetime.date.today()}; {machine()}.", "", END, ""]
    text = "\n".join(lines)
    print(text)
    old_text = args.markdown.read_text() if args.markdown.exists() else ""
    if BEGIN in old_text:
        old_text = old_text[: old_text.index(BEGIN)]
    args.markdown.write_text(old_text.rstrip("\n") + "\n\n" + text)
    unknown = [r["query"] for rows in (xexp, step) for m in rows for r in rows[m] if verdict(r)[0] == "?"]
    if unknown:
        print(f"no verdict for {unknown}: look at their pictures and add them to VERDICTS", file=sys.stderr)
        return 1
    return 0


# ---------------------------------------------------------------- the section


def report(k, xexp, xall, half_a, half_b, step, sall, steps, drawn, step_gaps) -> list:
    labels, paths, n = k["labels"], k["paths"], k["n"]
    L = [BEGIN, "", "## How far can a shape metric go? (ceilings)", ""]
    L += [
        "Issue 24's targets ask today's best figures to rise: kicad6 cross-validated NN 0.728 to 0.80 and FT 0.424 to",
        "0.50, xexp-dev rank 1 0.824 / 0.800 to 0.90, kicad6-step rank 1 0.970 to 0.98. This section asks of every miss",
        "whether *any* shape metric could have got it right. It measures, from the exact surface moments each store",
        "keeps (shapeidx/signing/moments.py, integrated exactly, not sampled), how far apart the query, the right answer",
        "and the part ranked first are: the largest mismatch of the sorted bounding-box sides, of the principal radii",
        "and of the surface area of the cleaned solid (the surface the signature samples), after the best uniform",
        "scale (the median ratio of the box sides, as docs/twins.md) unless said *same size*. Every twin miss was also",
        "looked at: a picture of the query, its twin and the part ranked first (`--pictures`), and a verdict:",
        "",
        f"* **{FAILURE}**: the twin looks like the query and the part above does not: a better metric could find it;",
        f"* **{SIBLING}**: the part above is another size, pitch or variant of the twin's family and nearly the",
        "  twin's geometry; a perfect shape metric finds the twin only when the twin is the query's nearest part in",
        "  exact geometry (the *oracle rank* below is 1), else the sibling is at least as near as the twin;",
        f"* **{REMODELLED}**: the two exports are different models (the box/area table of docs/twins.md) and other",
        "  parts are as near; **duplicate**: the part above has the twin's geometry (a tie at best).",
        "",
        "Beside the geometry, sampling. Every store draws its points with one fixed seed, and so does a query: a twin",
        "meshed alike (a STEP part and its VRML export; a KiCad 2017 and a KiCad 6 export of one model) gets points",
        "at much the same places as its stored twin, and a twin's distance is smaller than two independent drawings",
        f"of the same part would give. Two checks, each with the seeds {', '.join(map(str, SEEDS))} (the stores keep theirs):",
        "the queries of today signed with another seed (*query drawn again*), and an **exact copy** of each right",
        "answer (its own file) signed with another seed and ranked against the same store. No metric on these",
        "signatures can be expected to find a real twin drawn independently more often than the exact copy.",
        "",
    ]
    # ---- the summary
    kc = {t: ceiling(labels, k["other"], k["free"], t) for t in TOLERANCES}
    ks = {t: ceiling(labels, k["other"], k["sized"], t) for t in TOLERANCES}
    halves = {"A": half_a, "B": half_b}
    xmiss = {r["query"]: r for r in xexp["all-angle"]}

    def x_ceiling(half, optimistic=False, sized=False):
        """Rank-1 share a perfect shape metric reaches on a half: today's hits, the metric failures and the
        siblings whose twin is the query's nearest part in exact geometry (scale-free, or with the size
        kept: ``sized``); ``optimistic``: every sibling."""
        names = halves[half]
        ok = 0
        for q in names:
            if q not in xmiss:
                ok += 1
                continue
            kind, _, reach = verdict(xmiss[q])
            ok += reach or (kind == SIBLING and (optimistic or (sized and xmiss[q]["oracle_sized"] == 1)))
        return ok / len(names)

    smiss = {}
    for m in ("combined", "all-angle"):
        for r in step[m]:
            smiss.setdefault(r["query"], []).append((m, r))

    def s_reachable(q, optimistic=False):
        if any(sall[q][m] == 1 for m in sall[q]):
            return True  # some metric of today ranks the twin first
        return all(verdict(r)[2] or (optimistic and verdict(r)[0] == SIBLING) for _, r in smiss[q])

    s_ceiling = np.mean([s_reachable(q) for q in steps])
    s_opt = np.mean([s_reachable(q, True) for q in steps])
    any_x = {h: np.mean([min(xall[q].values()) == 1 for q in halves[h]]) for h in halves}
    x_e = {h: [f"twins/{q}" for q in names] for h, names in halves.items()}
    s_e = [str(Path(p).with_suffix(".wrl")) for p in steps]

    def best(key, entries):
        got = drawn.get(key)
        if not got:
            return "n/a"
        rates = {m: first_rate(got[m], entries) for m in got}
        m = max(rates, key=rates.get)
        return f"{rates[m]:.3f} ({m})"

    L += [
        "### In short",
        "",
        "| question (target) | best today | perfect shape metric: at most (strict; every sibling found) | today's metrics, query drawn again | an exact copy drawn again |",
        "|---|---|---|---|---|",
        f"| kicad6 NN (0.80) | 0.728 | {1 - kc[0.02][0].mean():.3f} (same shape = within 2%); {1 - kc[0.05][0].mean():.3f} (5%); "
        f"{1 - kc[0.10][0].mean():.3f} (10%) | | |",
        f"| kicad6 FT (0.50) | 0.424 | {kc[0.02][1].mean():.3f} (2%); {kc[0.10][1].mean():.3f} (10%) | | |",
        f"| xexp-dev rank 1, A (0.90) | 0.824 | {x_ceiling('A'):.3f}; {x_ceiling('A', True):.3f} (size kept: {x_ceiling('A', sized=True):.3f}) | {best(('xexp', 'query'), x_e['A'])} |"
        f" {best(('xexp', 'copy'), x_e['A'])} |",
        f"| xexp-dev rank 1, B (0.90) | 0.800 | {x_ceiling('B'):.3f}; {x_ceiling('B', True):.3f} (size kept: {x_ceiling('B', sized=True):.3f}) | {best(('xexp', 'query'), x_e['B'])} |"
        f" {best(('xexp', 'copy'), x_e['B'])} |",
        f"| kicad6-step rank 1 (0.98) | 0.970 | {s_ceiling:.3f}; {s_opt:.3f} | {best(('step', 'query'), s_e)} | {best(('step', 'copy'), s_e)};"
        f" 2048 points: {best(('step', 'copy 2048'), s_e)} |",
        "",
        "(*best today*: the figures of the table at the top; *query drawn again* and *exact copy*: the best of all-angle,",
        "combined and unified, rank 1 averaged over the seeds.)",
        "",
    ]

    def sampling(kind, groups) -> list:
        keys = [key for key in drawn if key[0] == kind]
        out = ["| " + " | ".join(["metric"] + [f"{g}: {key[1]}" for g in groups for key in [(kind, 'stored seed')] + keys]) + " |",
               "|---|" + "---|" * (len(groups) * (len(keys) + 1))]
        for m in drawn[keys[0]]:
            cells = []
            for g, entries in groups.items():
                today = sall if kind == "step" else xall
                names = [e.removeprefix("twins/") for e in entries] if kind == "xexp" else [
                    next(p for p in steps if str(Path(p).with_suffix(".wrl")) == e) for e in entries]
                cells.append(f"{np.mean([today[n][m] == 1 for n in names]):.3f}")
                cells += [f"{first_rate(drawn[key][m], entries):.3f}" for key in keys]
            out.append(f"| {m} | " + " | ".join(cells) + " |")
        return out

    # ---- 1. kinds
    misses = k["misses"]
    wg = np.array([r["gap"]["worst"] for r in misses])
    L += [
        "### kicad6 kinds",
        "",
        f"combined-angle, its weights learned without the query's class (class folds, 4 folds, deal 0 of",
        f"scripts/unified_study.py's five): NN {k['scores']['nn']:.3f}, FT {k['scores']['ft']:.3f}, {len(misses)} NN misses of {n}.",
        f"The part a miss finds first is rarely the query's shape: the largest gap of box, radii and area between",
        f"the query and it is {np.percentile(wg, 25):.0%} / {np.median(wg):.0%} / {np.percentile(wg, 75):.0%} (quartiles),",
        f"within 2% for {(wg <= 0.02).sum()}, within 5% for {(wg <= 0.05).sum()}, within 10% for {(wg <= 0.10).sum()} of the {len(misses)};",
        f"for {sum(r['own'] < r['gap']['worst'] for r in misses)} of them a part of the query's own class is nearer in these",
        "exact measures than the part found. Those measures are no metric of kinds themselves: ranked by them alone",
        f"(the largest gap as a distance) kicad6 gets NN {k['exact']['scale-free']['nn']:.3f} / FT {k['exact']['scale-free']['ft']:.3f}"
        f" scale-free, {k['exact']['same size']['nn']:.3f} / {k['exact']['same size']['ft']:.3f} at the same size.",
        "",
        "The ceiling: a query whose nearest parts in exact geometry (within the tolerance) are all of another class",
        "is missed by any shape metric (a *forced* miss); its first tier loses the slots those parts take. Over all",
        f"{n} queries (not only today's misses):",
        "",
        "| same shape when within | forced misses, scale-free | NN ceiling, scale-free | FT ceiling, scale-free | forced misses, same size | NN ceiling, same size | FT ceiling, same size |",
        "|---|---|---|---|---|---|---|",
    ]
    for t in TOLERANCES:
        L.append(f"| {t:.0%} | {kc[t][0].sum()} | {1 - kc[t][0].mean():.3f} | {kc[t][1].mean():.3f} | {ks[t][0].sum()} |"
                 f" {1 - ks[t][0].mean():.3f} | {ks[t][1].mean():.3f} |")
    L += ["", "Class pairs that share shapes (scale-free, parts of two classes within the tolerance; pairs of parts, an example):", "",
          "| classes | pairs within 2% | within 5% | within 10% | example (gap) |", "|---|---|---|---|---|"]
    pairs = {t: Counter() for t in (0.02, 0.05, 0.10)}
    example = {}
    for i in range(n):
        for j in range(i + 1, n):
            if k["other"][i, j]:
                g = min(k["free"][i, j], k["free"][j, i])
                key = tuple(sorted((labels[i], labels[j])))
                for t in pairs:
                    if g <= t:
                        pairs[t][key] += 1
                if g <= 0.10 and (key not in example or g < example[key][2]):
                    example[key] = (paths[i], paths[j], g)
    shown = sorted(pairs[0.10], key=lambda c: (-pairs[0.02][c], -pairs[0.05][c], -pairs[0.10][c], c))
    for key in shown[:25]:
        a, b, g = example[key]
        L.append(f"| {key[0]} / {key[1]} | {pairs[0.02][key]} | {pairs[0.05][key]} | {pairs[0.10][key]} | `{short(a)}` / `{short(b)}` ({g:.1%}) |")
    L.append(f"\n{len(pairs[0.10])} class pairs share a shape within 10%, {len(pairs[0.05])} within 5%, {len(pairs[0.02])} within 2%"
             f" (the 25 first above).")
    confusion = Counter((labels[paths.index(r["query"])], r["first"].split("/")[0]) for r in misses)
    L += ["", "Where the misses go (query's class -> class of the part found first; the 15 most frequent):", "",
          "| query class | found class | misses | median gap |", "|---|---|---|---|"]
    for (a, b), c in confusion.most_common(15):
        g = np.median([r["gap"]["worst"] for r in misses if r["query"].split("/")[0] == a and r["first"].split("/")[0] == b])
        L.append(f"| {a} | {b} | {c} | {g:.0%} |")
    L += ["", "<details><summary>Every NN miss (query, part found first, scale, gaps, all-angle distance, nearest part of its own class)</summary>", "",
          "| query | found first | scale | box | radii | area | worst | all-angle | nearest own class (worst) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(misses, key=lambda r: r["gap"]["worst"]):
        g = r["gap"]
        L.append(f"| `{r['query']}` | `{r['first']}` | {g['scale']:.2f} | {pct(g['box'])} | {pct(g['radii'])} | {pct(g['area'])} |"
                 f" {g['worst']:.1%} | {r['all_angle']:.5f} | {r['own']:.1%} |")
    L += ["", "</details>", ""]

    # ---- 2. xexp-dev
    L += ["### xexp-dev twins (KiCad 2017 against 1,000 KiCad 6 parts), all-angle's misses", "",
          "*twin* and *first*: the query's gaps to its twin and to the part ranked first (box, area); *twin/first*: the",
          "largest gap between those two; *oracle*: the twin's rank among the 1,000 parts by the largest gap to the",
          "query (box, radii, area: 1 = the twin is the query's nearest part in exact geometry); *first by*: today's",
          "metrics that rank the twin first.", "",
          "| half | query | rank | part first | twin: box, area | first: box, area | twin/first | oracle (size kept) | first by | verdict | reachable |",
          "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(xexp["all-angle"], key=lambda r: ("A" if r["query"] in half_a else "B", r["query"])):
        kind, reason, reach = verdict(r)
        by = ", ".join(m for m, v in xall[r["query"]].items() if v == 1) or "none"
        L.append(f"| {'A' if r['query'] in half_a else 'B'} | `{short(r['query'])}` | {r['rank']} | `{short(r['first'])}` |"
                 f" {pct(r['g_twin']['box'])}, {pct(r['g_twin']['area'])} | {pct(r['g_first']['box'])}, {pct(r['g_first']['area'])} |"
                 f" {worst(r['twin_vs_first'])} | {r['oracle_rank']} ({r['oracle_sized']}) | {by} | {kind}: {reason} | {'yes' if reach else 'no'} |")
    L += ["", "| half | pairs | all-angle rank 1 | misses: metric failure | series sibling | twin remodelled | duplicate |"
          " perfect shape metric (siblings lost / found) | ranked first by one of today's 8 metrics |",
          "|---|---|---|---|---|---|---|---|---|"]
    for h, names in halves.items():
        rows = [r for r in xexp["all-angle"] if r["query"] in names]
        kinds_ = Counter(verdict(r)[0] for r in rows)
        L.append(f"| {h} | {len(names)} | {1 - len(rows) / len(names):.3f} | {kinds_[FAILURE]} | {kinds_[SIBLING]} |"
                 f" {kinds_[REMODELLED]} | {kinds_[DUPLICATE]} | {x_ceiling(h):.3f} / {x_ceiling(h, True):.3f} | {any_x[h]:.3f} |")
    L += ["", "Rank 1 with the points drawn again (seeds as above; *2048*: today's metrics, weights set at 1024 points,"
          " on stores signed with 2048 points):", ""]
    L += sampling("xexp", x_e) + [""]

    # ---- 3. kicad6-step
    L += ["### kicad6-step twins (STEP against the 520 VRML parts), the misses of combined and all-angle", "",
          "| metric | STEP part | rank | part first | twin: box, area | first: box, area | twin/first | oracle | first by | verdict | reachable |",
          "|---|---|---|---|---|---|---|---|---|---|---|"]
    for m in ("combined", "all-angle"):
        for r in step[m]:
            kind, reason, reach = verdict(r)
            by = ", ".join(x for x, v in sall[r["query"]].items() if v == 1) or "none"
            L.append(f"| {m} | `{short(r['query'])}` | {r['rank']} | `{short(r['first'])}` | {pct(r['g_twin']['box'])}, {pct(r['g_twin']['area'])} |"
                     f" {pct(r['g_first']['box'])}, {pct(r['g_first']['area'])} | {worst(r['twin_vs_first'])} | {r['oracle_rank']} | {by} |"
                     f" {kind}: {reason} | {'yes' if reach else 'no'} |")
    L += ["", "| metric | rank 1 | misses: metric failure | series sibling | duplicate |", "|---|---|---|---|---|"]
    for m in ("combined", "all-angle"):
        kinds_ = Counter(verdict(r)[0] for r in step[m])
        L.append(f"| {m} | {1 - len(step[m]) / len(steps):.3f} | {kinds_[FAILURE]} | {kinds_[SIBLING]} | {kinds_[DUPLICATE]} |")
    L += ["", "Rank 1 with the points drawn again:", ""] + sampling("step", {"all": s_e})
    L += ["", f"A perfect shape metric: {s_ceiling:.3f} of the {len(steps)} STEP parts ({s_opt:.3f} if it also tells every sibling"
          " apart): a twin is lost only when no metric of today finds it and its misses are duplicates or siblings as near as it.", ""]

    # ---- the judgement
    same_misses = int((wg <= 0.02).sum())
    missed = {r["query"] for r in misses}
    forced_hit = sum(1 for i in np.flatnonzero(kc[0.02][0]) if paths[i] not in missed)
    xr_ = {h: Counter(verdict(r)[0] for r in xexp["all-angle"] if r["query"] in halves[h]) for h in halves}
    sc = Counter(verdict(r)[0] for r in step["combined"])

    def rate_of(key, entries, m):
        return first_rate(drawn[key][m], entries) if key in drawn else float("nan")

    L += [
        "### Can issue 24's targets be met by a shape metric?",
        "",
        f"* **kicad6 NN >= 0.80, FT >= 0.50: not ruled out by the geometry.** Only {kc[0.02][0].sum()} of the {n} parts have a part of",
        f"  another class within 2% of their shape and none of their own (among them C_2816 / L_2816, one model, and",
        f"  D_ / R_MicroMELF, 0.9% apart): NN {1 - kc[0.02][0].mean():.3f}, FT {kc[0.02][1].mean():.3f} at most. Of today's {len(misses)} misses",
        f"  {same_misses} are such look-alikes; the median miss finds a part {np.median(wg):.0%} off the query in box, radii or area, and",
        f"  for {sum(r['own'] < r['gap']['worst'] for r in misses)} a part of the query's own class is nearer in exact geometry: these are",
        "  metric failures, not impossible questions. The catch is resolution: counting parts within 10% as the same",
        f"  shape, {kc[0.10][0].sum()} queries have only other classes that near and the NN ceiling falls to {1 - kc[0.10][0].mean():.3f}"
        f" (scale-free; {1 - ks[0.10][0].mean():.3f} with the size kept).",
        "  A scale-free metric reaches 0.80 only by telling apart shapes a few percent apart across class boundaries",
        "  (SMD passives and packages of one size, one maker's terminal-block series, BGA against QFN: the class pairs",
        "  above), which the 1,024-point histograms resolve poorly: their sampling noise alone makes an exact copy drawn",
        "  again lose to another part in 6-22% of the twin queries below. The target is a metric problem, at the limit",
        "  of D2 at 1,024 points.",
        f"* **xexp-dev rank 1 >= 0.90 on the held-out half: out of reach of a scale-free metric, and of D2 at 1,024 points.**",
        f"  A perfect scale-free shape metric reaches",
        f"  {x_ceiling('A'):.3f} on A and {x_ceiling('B'):.3f} on B: of all-angle's misses, {xr_['A'][REMODELLED] + xr_['B'][REMODELLED]}"
        f" twins were remodelled (the hollow, open 2017 cans of CP_Radial),",
        f"  {xr_['A'][DUPLICATE] + xr_['B'][DUPLICATE]} has a duplicate (Crystal_HC18-U is the HC49-U twin's geometry), and"
        f" {xr_['A'][SIBLING] + xr_['B'][SIBLING]} lose to a sibling of the series",
        "  (another pitch, 2.5-6% in one size) that is as near the 2017 export as the twin is, because the 2017 leads",
        f"  reach about 1 mm lower (8-12% of the height); only {xr_['A'][FAILURE] + xr_['B'][FAILURE]} are metric failures. Finding every sibling as well would give"
        f" {x_ceiling('A', True):.3f} / {x_ceiling('B', True):.3f}; with the size kept",
        f"  (units 1, 2.54) {x_ceiling('A', sized=True):.3f} / {x_ceiling('B', sized=True):.3f}: B's target then holds with no"
        " more than three misses, A's not at all. Today's eight metrics together rank"
        f" {any_x['A']:.3f} / {any_x['B']:.3f} first, above the strict ceiling on A: among near-equal",
        "  candidates (the siblings, the crystal's duplicate) some metric wins by chance, which no single metric can be",
        "  expected to do. And sampling caps D2 metrics lower: an exact copy of the twin,"
        f" its points drawn again, is first for all-angle only",
        f"  {rate_of(('xexp', 'copy'), x_e['A'], 'all-angle'):.3f} (A) / {rate_of(('xexp', 'copy'), x_e['B'], 'all-angle'):.3f} (B) of the time among"
        " the 1,000 parts; today's 0.824 / 0.800 owe part of their hits to the query",
        f"  being drawn with the store's seed (with other seeds: {rate_of(('xexp', 'query'), x_e['A'], 'all-angle'):.3f} /"
        f" {rate_of(('xexp', 'query'), x_e['B'], 'all-angle'):.3f}).",
        f"* **kicad6-step rank 1 >= 0.98: reachable by geometry, at the edge of sampling.** The STEP part and its VRML",
        f"  export are one model (box, radii and area within 1% for {(step_gaps <= 0.01).sum()} of the {len(step_gaps)}, median"
        f" {np.median(step_gaps):.2%}; the {(step_gaps > 0.05).sum()} beyond 5% differ in",
        f"  surface the pictures do not show); of combined's {len(step['combined'])} misses {sc[FAILURE]} are metric failures,"
        f" {sc[SIBLING]} siblings the exact geometry tells",
        f"  apart and {sc[DUPLICATE]} the C_2816 / L_2816 duplicate: a perfect shape metric reaches {s_ceiling:.3f}. Exact geometry does it (the",
        "  proportions detector of the 2-D section: 0.982), D2 hardly: an exact copy drawn again is first"
        f" {rate_of(('step', 'copy'), s_e, 'combined'):.3f} (combined) /",
        f"  {rate_of(('step', 'copy'), s_e, 'unified'):.3f} (unified) at 1,024 points and"
        f" {rate_of(('step', 'copy 2048'), s_e, 'unified'):.3f} (unified) at 2,048; today's 0.970 needs the shared seed"
        f" (other seeds: {rate_of(('step', 'query'), s_e, 'combined'):.3f}).",
        "",
        "So: one target (xexp-dev 0.90) is beyond any scale-free shape metric on these pairs, because the 2017 models",
        "differ from their twins by more than the series siblings differ from the twins (with the size kept, half B",
        "leaves three misses of margin, half A none); one (kicad6-step 0.98) needs exact",
        "geometry, which the sampled histograms cannot carry at 1,024 points; kicad6's are not ruled out by the data but",
        "need a discrimination of a few percent between classes that D2 histograms of 1,024 points do not have. The",
        "ceilings rest on the stores' exact moments (box, principal radii, area) and on the pictures, and are",
        "estimates, not proofs: two shapes can share those measures and still differ (pin layouts: combined-angle",
        f"finds a part of its own class first for {forced_hit} of the {kc[0.02][0].sum()} parts counted lost at 2%), and"
        " parts a few percent apart may be as good as",
        "identical to a metric that samples 1,024 points (the 10% row); each sibling verdict is a judgement on a",
        "2.5-8% difference, made on the pictures.",
        "",
    ]
    return L


if __name__ == "__main__":
    sys.exit(main())
