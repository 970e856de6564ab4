#!/usr/bin/env python3
"""2-D histograms (pair distance x normal angle) for one metric for every question (issue 24).

    python scripts/twod_study.py extract --cache /tmp/metric2      # sign every part again, keep fine 2-D counts
    python scripts/twod_study.py study --cache /tmp/metric2 --markdown /tmp/metric2/twod.md

``extract`` re-signs the parts of the stores the unified study ranks (kicad6, the 1,000-part twin
store and the KiCad 2017 queries of scripts/twin_study.py, kicad6-step) with the store's points and
seed, and keeps, per part, fine joint counts of its pairs (cached per collection, one ``.npz``):

* ``dist_angle`` (3, DIST_BINS, ANGLE_BINS): class x distance (in units of the part's mean pair
  distance, bins of 1/DIST_PER_MEAN, the last bin holding everything beyond) x the angle between
  the two normals (the 17 bins of shapeidx.signing.angles);
* ``dist_end`` (3, DIST_BINS, END_BINS): class x distance x the cosine between a point's normal and
  the segment to the other point, counted at both ends (END_BINS equal bins over [-1, 1]).

The 1-D angle histograms these sum to are the stored ones (checked for every part: the same
samples, another implementation). ``study`` derives coarser 2-D signature parts from the counts and
measures each, alone and with today's metrics, on the questions of scripts/unified_study.py.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from _common import DATA

from shapeidx.search import Searcher
from shapeidx.signing.angles import ANGLE_BINS, angle_bins
from shapeidx.signing.classify import classify_pairs, pair_indices
from shapeidx.signing.parameters import DEFAULT_POINTS, DEFAULT_SEED
from shapeidx.signing.part import load_part
from shapeidx.signing.sampling import sample_surface

DIST_PER_MEAN = 16
DIST_BINS = 64  # distances up to 4 x the mean; beyond, the last bin
END_BINS = 8

STORES = Path("/work/stores/metric")
#: collection -> (store, the folder its paths are relative to)
COLLECTIONS = {
    "kicad6": (STORES / "kicad6-1024.h5", DATA / "kicad6"),
    "kicad2017": (STORES / "twins" / "kicad2017.h5", DATA / "xexp-dev" / "kicad2017"),
    "store1000": (STORES / "twins" / "store1000.h5", STORES / "twins" / "parts"),
    "kicad6-step": (STORES / "kicad6-step.h5", DATA / "kicad6-step"),
}


def part_counts(path: Path):
    """(dist_angle, dist_end, angle histogram of all pairs) of one part, at the store's points and seed."""
    solid = load_part(path)
    samples, face_index = sample_surface(solid.vertices, solid.faces, DEFAULT_POINTS, DEFAULT_SEED)
    normals = []
    distances, classes = classify_pairs(solid.vertices, solid.faces, samples, face_index, solid.watertight,
                                        normals_out=normals)
    n = normals[0]
    i, j = pair_indices(len(n))
    cos = np.einsum("ij,ij->i", n[i], n[j])
    theta = angle_bins(cos)
    mean = distances.mean()
    dbin = np.minimum((distances / mean * DIST_PER_MEAN).astype(np.int64), DIST_BINS - 1)
    cls = classes.astype(np.int64)
    key = (cls * DIST_BINS + dbin)
    dist_angle = np.bincount(key * ANGLE_BINS + theta, minlength=3 * DIST_BINS * ANGLE_BINS)
    # the segment from i to j in the normalised frame classify used (directions only)
    lo, hi = solid.vertices.min(axis=0), solid.vertices.max(axis=0)
    p = (samples - (lo + hi) / 2)
    u = p[j] - p[i]
    length = np.linalg.norm(u, axis=1)
    u /= np.where(length > 0, length, 1.0)[:, None]
    ends = []
    for c in (np.einsum("ij,ij->i", n[i], u), -np.einsum("ij,ij->i", n[j], u)):
        ends.append(np.minimum(((np.clip(c, -1, 1) + 1) * (END_BINS / 2)).astype(np.int64), END_BINS - 1))
    dist_end = sum(np.bincount(key * END_BINS + e, minlength=3 * DIST_BINS * END_BINS) for e in ends)
    return (dist_angle.reshape(3, DIST_BINS, ANGLE_BINS), dist_end.reshape(3, DIST_BINS, END_BINS),
            np.bincount(theta, minlength=ANGLE_BINS))


def extract(cache: Path, names) -> None:
    cache.mkdir(parents=True, exist_ok=True)
    for name in names:
        out = cache / f"{name}.npz"
        if out.exists():
            print(f"{name}: cached", flush=True)
            continue
        store, root = COLLECTIONS[name]
        with Searcher(store) as searcher:
            paths = [str(p) for p in searcher.metadata_column("path")]
            stored = [searcher.signature_at(k).angles for k in range(len(paths))]
        da, de, ok = [], [], []
        start = time.time()
        mismatch = 0
        for k, rel in enumerate(paths):
            try:
                a, e, angle_all = part_counts(root / rel)
            except Exception as error:  # noqa: BLE001 - a study: note and go on
                print(f"  {rel}: {error}", flush=True)
                a, e, angle_all = np.zeros((3, DIST_BINS, ANGLE_BINS), np.int64), np.zeros((3, DIST_BINS, END_BINS), np.int64), None
            if angle_all is not None and stored[k] is not None and not np.array_equal(angle_all, stored[k][0]):
                mismatch += 1
            da.append(a)
            de.append(e)
            ok.append(angle_all is not None)
            if k % 50 == 0:
                print(f"  {name} {k}/{len(paths)} {time.time() - start:.0f} s", flush=True)
        np.savez_compressed(out, paths=np.array(paths), dist_angle=np.array(da, np.int32), dist_end=np.array(de, np.int32),
                            ok=np.array(ok))
        print(f"{name}: {len(paths)} parts, {time.time() - start:.0f} s; angle histograms differing from the store's: "
              f"{mismatch}", flush=True)


def base(cache: Path) -> None:
    """Today's per-pair features (FEATURES + ANGLE_FEATURES) through the search road, cached:
    kicad6 labelled (sorted by path, as the evaluation), the KiCad 2017 queries against the
    1,000-part store, kicad6-step against kicad6."""
    from shapeidx.distance.combined import ANGLE_FEATURES, FEATURES
    from shapeidx.evaluation.evaluate import labelled_features
    from shapeidx.search.distances import entry_features
    from shapeidx.signing.parameters import HISTOGRAMS

    out = cache / "base.npz"
    if out.exists():
        return
    names = FEATURES + ANGLE_FEATURES
    with Searcher(COLLECTIONS["kicad6"][0]) as searcher:
        data = labelled_features(searcher)
    saved = dict(names=np.array(names), k6_paths=data.paths.astype(str), k6_labels=data.labels.astype(str),
                 k6=np.stack([data.named()[n] for n in names]).astype(np.float32))
    for key, queries, store in (("xexp", "kicad2017", "store1000"), ("step", "kicad6-step", "kicad6")):
        with Searcher(COLLECTIONS[queries][0]) as q, Searcher(COLLECTIONS[store][0]) as s:
            rows = []
            for k in range(len(q)):
                values = entry_features(s.view, q.signature_at(k), HISTOGRAMS, None, True)
                rows.append([values[n] for n in names])
            saved[key] = np.array(rows, dtype=np.float32).transpose(1, 0, 2)
            saved[key + "_queries"] = np.array([str(p) for p in q.metadata_column("path")])
            saved[key + "_store"] = np.array([str(p) for p in s.metadata_column("path")])
    np.savez_compressed(out, **saved)


# ---------------------------------------------------------------- the study


class Data:
    """Everything the study ranks, aligned: kicad6 (sorted by path, as the evaluation), the
    xexp queries against the 1,000-part store, the STEP queries against kicad6."""

    def __init__(self, cache: Path):
        import twin_study

        b = np.load(cache / "base.npz")
        self.names = [str(n) for n in b["names"]]
        self.labels = b["k6_labels"]
        self.k6 = dict(zip(self.names, b["k6"].astype(np.float64)))
        self.counts = {name: np.load(cache / f"{name}.npz") for name in COLLECTIONS}
        order = {name: {str(p): i for i, p in enumerate(c["paths"])} for name, c in self.counts.items()}
        self.k6_rows = np.array([order["kicad6"][str(p)] for p in b["k6_paths"]])  # counts row of each sorted part
        # xexp: the kept pairs, halves A / B
        queries = [str(p) for p in b["xexp_queries"]]
        store = {str(p): i for i, p in enumerate(b["xexp_store"])}
        kept = [n for n in queries if n not in twin_study.EXCLUDED and f"twins/{n}" in store]
        self.half_a, self.half_b = twin_study.halves(kept)
        self.x_names = queries
        self.x_twin = np.array([store.get(f"twins/{n}", -1) for n in queries])
        self.x = dict(zip(self.names, b["xexp"].astype(np.float64)))
        self.x_qrows = np.array([order["kicad2017"][n] for n in queries])
        self.x_srows = np.array([order["store1000"][str(p)] for p in b["xexp_store"]])
        # step
        squeries = [str(p) for p in b["step_queries"]]
        sstore = {str(p): i for i, p in enumerate(b["step_store"])}
        self.s_names = squeries
        self.s_twin = np.array([sstore.get(str(Path(n).with_suffix(".wrl")), -1) for n in squeries])
        self.s = dict(zip(self.names, b["step"].astype(np.float64)))
        self.s_qrows = np.array([order["kicad6-step"][n] for n in squeries])
        self.s_srows = np.array([order["kicad6"][str(p)] for p in b["step_store"]])


def signature_part(counts, kind: str = "angle", dist_factor: int = 4, top: int = DIST_BINS, angle_groups=None,
                   per_class: bool = False, weights_by_fraction: bool = False):
    """Probabilities (n, H, B) of a 2-D signature part from the fine counts: distance bins merged by
    ``dist_factor`` (up to ``top`` fine bins), angle bins merged by ``angle_groups`` (start indices);
    one histogram of all pairs, or one per class (each normalised on its own)."""
    c = counts["dist_angle" if kind == "angle" else "dist_end"].astype(np.float64)  # (n, 3, D, A)
    c = c[:, :, :top]
    n, _, d, a = c.shape
    c = c.reshape(n, 3, d // dist_factor, dist_factor, a).sum(axis=3)
    if angle_groups is not None:
        c = np.add.reduceat(c, angle_groups, axis=3)
    c = c.reshape(n, 3, -1)
    h = c if per_class else c.sum(axis=1, keepdims=True)
    total = h.sum(axis=2, keepdims=True)
    return np.divide(h, total, out=np.zeros_like(h), where=total > 0)


def pair_distance(a, b, how: str = "hellinger"):
    """(n, m) distances between probability arrays a (n, H, B) and b (m, H, B), summed over H."""
    out = np.zeros((len(a), len(b)))
    for hh in range(a.shape[1]):
        x, y = a[:, hh], b[:, hh]
        if how == "hellinger":
            out += np.sqrt(np.maximum(0.0, 1 - np.sqrt(x) @ np.sqrt(y).T))
        else:
            for start in range(0, len(x), 64):
                xs = x[start:start + 64, None, :]
                if how == "l1":
                    out[start:start + 64] += np.abs(xs - y[None]).sum(axis=2)
                elif how == "chi2":
                    s = xs + y[None]
                    out[start:start + 64] += (np.divide((xs - y[None]) ** 2, s, out=np.zeros(np.broadcast_shapes(xs.shape, y[None].shape)), where=s > 0)).sum(axis=2) / 2
    return out


def twod_matrices(data: "Data", how: str, **part) -> tuple:
    """The 2-D distance on the three questions: kicad6 (n, n) sorted, xexp (80, 1000), step (336, 520)."""
    k6 = signature_part(data.counts["kicad6"], **part)
    k = k6[data.k6_rows]
    x = pair_distance(signature_part(data.counts["kicad2017"], **part)[data.x_qrows],
                      signature_part(data.counts["store1000"], **part)[data.x_srows], how)
    st = pair_distance(signature_part(data.counts["kicad6-step"], **part)[data.s_qrows], k6[data.s_srows], how)
    return pair_distance(k, k, how), x, st


def twin_first(d: np.ndarray, twins: np.ndarray, rows) -> float:
    """Share of query ``rows`` whose twin comes first (ties against it)."""
    return float(np.mean([int((d[r] <= d[r, twins[r]]).sum()) == 1 for r in rows]))


def scores(data: "Data", k6, x, st, cv_folds=None) -> dict:
    """NN/FT on kicad6 (mean over the folds' matrices when ``k6`` is a list), xexp A/B, step rank 1."""
    from shapeidx.evaluation.retrieval import retrieval_scores

    mats = k6 if isinstance(k6, list) else [k6]
    r = [retrieval_scores(m, data.labels) for m in mats]
    xa = [data.x_names.index(n) for n in data.half_a]
    xb = [data.x_names.index(n) for n in data.half_b]
    srows = [i for i in range(len(data.s_names)) if data.s_twin[i] >= 0]
    return {"nn": float(np.mean([v["nn"] for v in r])), "ft": float(np.mean([v["ft"] for v in r])),
            "A": twin_first(x, data.x_twin, xa), "B": twin_first(x, data.x_twin, xb),
            "step": twin_first(st, data.s_twin, srows)}


def fmt(name, s) -> str:
    return f"| {name} | {s['nn']:.3f} | {s['ft']:.3f} | {s['A']:.3f} | {s['B']:.3f} | {s['step']:.3f} |"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    e = sub.add_parser("extract")
    e.add_argument("--cache", type=Path, required=True)
    e.add_argument("collections", nargs="*", default=list(COLLECTIONS))
    b = sub.add_parser("base")
    b.add_argument("--cache", type=Path, required=True)
    args = parser.parse_args(argv)
    if args.command == "extract":
        extract(args.cache, args.collections)
    elif args.command == "base":
        base(args.cache)
    return 0


if __name__ == "__main__":
    sys.exit(main())
