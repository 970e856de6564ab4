#!/usr/bin/env python3
"""Parts of a kind beyond the scale-free metric: neighbourhood re-ranking and the exact sizes;
writes its section of docs/unified.md.

    python scripts/kinds_study.py --work /work/stores/kinds [--markdown docs/unified.md]

kicad6's cross-validated NN and FT (issue 33's targets: 0.76 and 0.45) with combined-angle's
features and, beside them, two families of levers, each scored as docs/results.md scores
combined-angle (its 52 classes dealt into 4 folds, 5 deals; every query ranked against all
519 other parts with weights learned without its class):

* **neighbourhood re-ranking** of the learned distance, which learns nothing and needs no
  label: local scaling (each distance divided by the geometric mean of the two parts' mean
  distance to their k nearest; Jegou et al., CVPR 2007, as the contextual dissimilarity
  measure), mutual proximity (Schnitzer et al., JMLR 2012: the probability that each part is
  the other's near neighbour, Gaussian per part), and the two together;
* **the exact sizes**: the store's principal radii (integrated from the surface, no sampling
  noise) as more learned features: ``Δr = |ln r - ln r'|`` of the largest (r1), the middle (r2)
  and the smallest (r3), or their square roots. kicad6's classes are in one unit (KiCad's VRML), and
  some are told apart by size alone (pin headers of 1.00, 2.00 and 2.54 mm pitch).

The check is on the four KiCad collections of other years and exporters (docs/results.md's
main table), which no weight has seen: weights learned on all of kicad6, with and without the
sizes.
"""

from __future__ import annotations

import argparse
import datetime
import sys
from pathlib import Path

import numpy as np
from scipy.special import ndtr

from _common import COLLECTIONS, DATA, REPO, machine, quiet_build
from shapeidx.distance import label
from shapeidx.evaluation.evaluate import labelled_features
from shapeidx.evaluation.learn import class_folds, fit_weights
from shapeidx.evaluation.retrieval import retrieval_scores
from shapeidx.search import Searcher
from shapeidx.search.same_part import radii_of_measures, size_gap

BEGIN = "<!-- the kinds section: written by scripts/kinds_study.py; do not edit by hand -->"
END = "<!-- end of the kinds section -->"
#: Where the section goes when the document has none yet: before the ceilings (which end the file).
BEFORE = "<!-- the ceilings section: written by scripts/ceiling_study.py; do not edit by hand -->"
FOLDS, DEALS = 4, 5
SHOWN = ("nn", "ft", "st", "dcg")
#: The sizes' variant that the product offers as ``--metric combined-size``.
BEST = "sqrt Δr2, sqrt Δr3"


INTRO = [
    "kicad6's cross-validated NN and FT (issue 33's targets: 0.76 and 0.45) with combined-angle's features and, beside",
    "them, two families of levers, each scored as docs/results.md scores combined-angle (its 52 classes dealt into 4",
    "folds, 5 deals; every query ranked against all 519 other parts with weights learned without its class):",
    "",
    "* *neighbourhood re-ranking* of the learned distance, which learns nothing and needs no label: local scaling",
    "  (each distance divided by the geometric mean of the two parts' mean distance to their k nearest; Jegou et al.,",
    "  CVPR 2007, the contextual dissimilarity measure), mutual proximity (Schnitzer et al., JMLR 2012: how likely",
    "  each part is the other's near neighbour, Gaussian per part), and the two together;",
    "* *the exact sizes*: the store's principal radii (integrated from the surface, no sampling noise) as more",
    "  learned features: Δr = the absolute difference of ln r of the largest (r1), the middle (r2) and the smallest",
    "  (r3) radius, or its square root. kicad6's classes are in one unit (KiCad's VRML), and some differ by size",
    "  alone (pin headers of 1.00, 2.00 and 2.54 mm pitch).",
    "",
    "The check is on the four KiCad collections of other years and exporters (docs/results.md's main table), which",
    "no weight has seen: weights learned on all of kicad6, with and without the sizes.",
]


def collection(work: Path, name: str):
    """(combined-angle's features (F, n, n), labels, ln principal radii (n, 3)) of a labelled collection."""
    store = quiet_build(COLLECTIONS[name], work / f"{name.replace('/', '-')}.shapeidx")
    with Searcher(store) as searcher:
        data = labelled_features(searcher)
    ln_r = np.log(radii_of_measures(data.measures))
    return data.learned_features("combined-angle"), np.asarray(data.labels).astype(str), ln_r


def apart(values: np.ndarray, modulo_units: bool = False) -> np.ndarray:
    """(n, n) ``|a - b|`` of per-part logs (modulo a unit factor: the smallest over them); 0 where unknown."""
    a, b = values[:, None], values[None, :]
    return np.nan_to_num(size_gap(a, b) if modulo_units else np.abs(a - b))


def nearest(M: np.ndarray, k: int) -> np.ndarray:
    d = M.copy()
    np.fill_diagonal(d, np.inf)
    return np.sort(d, axis=1)[:, :k]


def local_scaling(M: np.ndarray, k: int) -> np.ndarray:
    r = nearest(M, k).mean(axis=1)
    return M / np.sqrt(r[:, None] * r[None, :])


def mutual_proximity(M: np.ndarray) -> np.ndarray:
    d = M.copy()
    np.fill_diagonal(d, np.nan)
    mu, sd = np.nanmean(d, axis=1), np.nanstd(d, axis=1)
    beyond_i = 1 - ndtr((M - mu[:, None]) / sd[:, None])
    beyond_j = 1 - ndtr((M - mu[None, :]) / sd[None, :])
    return 1 - beyond_i * beyond_j


RERANKINGS = {
    "none": lambda M: M,
    "local scaling, k = 10": lambda M: local_scaling(M, 10),
    "local scaling, k = 20": lambda M: local_scaling(M, 20),
    "mutual proximity": mutual_proximity,
    "local scaling (k = 20), then mutual proximity": lambda M: mutual_proximity(local_scaling(M, 20)),
}


def size_features(ln_r: np.ndarray) -> dict:
    """Name -> the extra (E, n, n) features of each size variant."""
    r1, r2, r3 = (apart(ln_r[:, i]) for i in range(3))
    return {
        "none": (),
        "Δr1 (the overall size)": (r1,),
        "Δr3": (r3,),
        "Δr2, Δr3": (r2, r3),
        "Δr3 modulo a unit factor": (apart(ln_r[:, 2], modulo_units=True),),
        "sqrt Δr3": (np.sqrt(r3),),
        "sqrt Δr2, sqrt Δr3": (np.sqrt(r2), np.sqrt(r3)),
    }


def with_sizes(features: np.ndarray, extra) -> np.ndarray:
    return np.concatenate([features] + [e[None] for e in extra]) if len(extra) else features


def cross_validated(features: np.ndarray, labels: np.ndarray, rerank=RERANKINGS["none"]) -> dict:
    """Scores over :data:`DEALS` deals: each fold's rows ranked by weights learned without its
    classes, the re-ranking applied to that fold's whole matrix (every part is in the store)."""
    runs = []
    for deal in range(DEALS):
        D = np.zeros(features.shape[1:])
        for fold in class_folds(labels, FOLDS, deal):
            held = np.isin(labels, fold)
            weights = fit_weights(features, labels, np.flatnonzero(~held))
            D[held] = rerank(np.tensordot(weights, features, axes=1))[held]
        runs.append(retrieval_scores(D, labels))
    return {s: float(np.mean([r[s] for r in runs])) for s in SHOWN} | {"std_nn": float(np.std([r["nn"] for r in runs]))}


def scores_row(label: str, s: dict) -> str:
    return f"| {label} | " + " | ".join(f"{s[k]:.3f}" for k in SHOWN) + " |"


def reading(reranked: dict, sized: dict, best: str, held_out: list) -> list:
    """What the tables say, from their own figures."""
    base = reranked["none"]
    top_rerank = max((s for name, s in reranked.items() if name != "none"), key=lambda s: s["nn"] + s["ft"])
    root3, units = sized["sqrt Δr3"], sized["Δr3 modulo a unit factor"]
    mean = {k: [float(np.mean([pair[i][k] for pair in held_out])) for i in (0, 1)] for k in ("nn", "ft")}
    return [
        f"* Re-ranking learns nothing and buys little: at best NN {top_rerank['nn'] - base['nn']:+.3f} and FT"
        f" {top_rerank['ft'] - base['ft']:+.3f} on combined-angle's {base['nn']:.3f} / {base['ft']:.3f}, short of the targets.",
        "* The smallest principal radius is what kicad6's classes of one kind and several pitches differ by (a 1.00 mm",
        "and a 2.54 mm pin header of one pin count have nearly one shape): with it NN and FT reach"
        f" {sized['Δr3']['nn']:.3f} / {sized['Δr3']['ft']:.3f}; its square root, which weighs the small"
        f" differences more, {root3['nn']:.3f} / {root3['ft']:.3f}, and with the middle radius's {sized[best]['nn']:.3f} /"
        f" {sized[best]['ft']:.3f}: issue 33's kicad6 targets (0.76 / 0.45), cross-validated. The overall size (r1, set by",
        f"the pin count) brings {sized['Δr1 (the overall size)']['nn'] - base['nn']:+.3f} NN. Taken modulo a unit"
        f" factor the size loses the FT gain ({units['ft']:.3f}): 2.54 is both KiCad's unit factor and the ratio of two pitches.",
        f"* On the four collections no weight has seen, the sizes move the mean NN from {mean['nn'][0]:.3f} to"
        f" {mean['nn'][1]:.3f} and the mean FT from {mean['ft'][0]:.3f} to {mean['ft'][1]:.3f} (each collection has a",
        "few dozen parts: one query is 0.014 to 0.025 of NN).",
        "",
    ]


def metric_reading(ndr: dict, files: int) -> list:
    """The product's metric, from its own figures on ndr."""
    return [
        f"### The metric: `--metric combined-size` ({BEST}, the weights of `combined_size_metric.json`)",
        "",
        "The variant above is what the product offers as `combined-size` (checked here: its features, through the search",
        "road, are these). Every other metric is scale-invariant, as the paper's are; this one is not (a part and its",
        "copy at twice the size differ), so it serves a library kept in one unit and hurts one that mixes units. On",
        "ndr, whose exporters differ by a factor of about 1,000 (as scripts/unified_study.py measures it: of the files",
        "that share their folder with another, the share whose nearest other file is from that folder):",
        "",
        "| metric | ndr same folder |",
        "|---|---|",
    ] + [f"| {label(name)} | {rate:.3f} ({round(rate * files)} of {files}) |" for name, rate in ndr.items()] + [
        "",
        "So no task uses it unasked (the defaults stay scale-invariant); name it for a library of one unit.",
    ]


def product_features(work: Path, extra) -> None:
    """Refuse to write a section whose study variant is not the product's ``combined-size`` features."""
    store = quiet_build(COLLECTIONS["kicad6"], work / "kicad6.shapeidx")
    with Searcher(store) as searcher:
        product = labelled_features(searcher).learned_features("combined-size")
    if not np.allclose(product[-len(extra):], np.stack(extra), rtol=0, atol=1e-12):
        raise SystemExit(f"combined-size's size features are not the study's {BEST}")


def ndr_same_folder(work: Path) -> dict:
    """The ndr same-folder rate (scripts/unified_study.py's) of the scale-invariant metrics and combined-size."""
    from shapeidx.evaluation.evaluate import distance_matrices
    from unified_study import same_folder_rate

    store = quiet_build(DATA / "ndr", work / "ndr.shapeidx")
    with Searcher(store) as searcher:
        data = labelled_features(searcher)
    matrices = distance_matrices(data, ("weighted", "combined-angle", "combined-size"))
    return {name: same_folder_rate(d, data.paths) for name, d in matrices.items()} | {"files": len(data.paths)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", type=Path, required=True, help="folder for the stores (reused)")
    parser.add_argument("--markdown", type=Path, default=REPO / "docs" / "unified.md")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    features, labels, ln_r = collection(args.work, "kicad6")
    sizes = size_features(ln_r)
    head = ["| variant | NN | FT | ST | DCG |", "|---|---|---|---|---|"]
    L = [BEGIN, "", "## Parts of a kind: neighbourhood re-ranking and the exact sizes", ""]
    L += INTRO
    L += ["", "### Neighbourhood re-ranking of combined-angle (kicad6, cross-validated)", ""] + head
    reranked = {}
    for name, rerank in RERANKINGS.items():
        reranked[name] = cross_validated(features, labels, rerank)
        L.append(scores_row(name, reranked[name]))
        print(L[-1], flush=True)
    L += ["", "### The exact sizes as learned features beside combined-angle's (kicad6, cross-validated)", ""] + head
    sized = {}
    for name, extra in sizes.items():
        sized[name] = cross_validated(with_sizes(features, extra), labels)
        L.append(scores_row(name, sized[name]))
        print(L[-1], f"(NN spread over the deals {sized[name]['std_nn']:.3f})", flush=True)
    best = BEST
    L.append(scores_row(f"{best}, then local scaling (k = 20)",
                        cross_validated(with_sizes(features, sizes[best]), labels, RERANKINGS["local scaling, k = 20"])))
    print(L[-1], flush=True)
    L += ["", f"### Collections no weight has seen: weights learned on all of kicad6, without and with {best}", "",
          "| collection | models | NN | FT | NN with the sizes | FT with the sizes |", "|---|---|---|---|---|---|"]
    plain_w = fit_weights(features, labels)
    sized_w = fit_weights(with_sizes(features, sizes[best]), labels)
    held_out = []
    for name in list(COLLECTIONS)[1:]:
        f, lab, r = collection(args.work, name)
        plain = retrieval_scores(np.tensordot(plain_w, f, axes=1), lab)
        with_size = retrieval_scores(np.tensordot(sized_w, with_sizes(f, size_features(r)[best]), axes=1), lab)
        held_out.append((plain, with_size))
        L.append(f"| {name} | {len(lab)} | {plain['nn']:.3f} | {plain['ft']:.3f} | {with_size['nn']:.3f} | {with_size['ft']:.3f} |")
        print(L[-1], flush=True)
    L += [""] + reading(reranked, sized, best, held_out)
    product_features(args.work, sizes[best])
    ndr = ndr_same_folder(args.work)
    L += metric_reading(ndr, ndr.pop("files"))
    command = "python scripts/kinds_study.py " + " ".join(argv if argv is not None else sys.argv[1:])
    L += ["", f"Command: `{command}`; {datetime.date.today()}; {machine()}.", "", END]
    section = "\n".join(L) + "\n"
    text = args.markdown.read_text()
    if BEGIN in text:
        text = text[: text.index(BEGIN)] + section + text[text.index(END) + len(END) + 1:]
    else:
        at = text.index(BEFORE)
        text = text[:at] + section + "\n" + text[at:]
    args.markdown.write_text(text)
    print(f"wrote the kinds section of {args.markdown}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
