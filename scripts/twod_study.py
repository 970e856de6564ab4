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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    e = sub.add_parser("extract")
    e.add_argument("--cache", type=Path, required=True)
    e.add_argument("collections", nargs="*", default=list(COLLECTIONS))
    args = parser.parse_args(argv)
    if args.command == "extract":
        extract(args.cache, args.collections)
    return 0


if __name__ == "__main__":
    sys.exit(main())
