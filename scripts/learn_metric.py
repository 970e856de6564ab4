#!/usr/bin/env python3
"""Learn the weights of a learned metric on a labelled collection; write them with their
cross-validated figures to its file in shapeidx/distance/ (combined_metric.json,
combined_angle_metric.json, combined_size_metric.json).

    python scripts/learn_metric.py ../shared/data/kicad6 --store kicad6.h5
    python scripts/learn_metric.py ../shared/data/kicad6 --store kicad6.h5 --metric combined-angle

The store is built (or updated) first, as ``shapeidx build`` would. The weights are learned
on every model of the collection; the figures recorded beside them are class-wise
cross-validated (each query ranked with weights that never saw its class; see
shapeidx/evaluation/learn.py), so they say what to expect on a collection of new classes.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path

from _common import REPO, quiet_build
from shapeidx.distance import LEARNED
from shapeidx.evaluation.evaluate import labelled_features
from shapeidx.evaluation.learn import cross_validate, fit_weights, weights_by_name
from shapeidx.system import keep_freed_memory
from shapeidx.signing.parameters import SIGNATURE_VERSION
from shapeidx.store import open_store

DISTANCE = REPO / "shapeidx" / "distance"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("collection", type=Path, help="labelled folder: its sub-folders are the classes")
    parser.add_argument("--store", type=Path, required=True)
    parser.add_argument("--folds", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--metric", choices=tuple(LEARNED), default="combined")
    parser.add_argument("--output", type=Path, help="default: the metric's file in shapeidx/distance/")
    args = parser.parse_args(argv)
    names, file = LEARNED[args.metric]
    output = args.output or DISTANCE / file

    keep_freed_memory()
    quiet_build(args.collection, args.store)
    with open_store(args.store) as reader:
        data = labelled_features(reader)
        points = reader.params.points
    missing = [name for name in names if name not in data.named()]
    if missing:
        sys.exit(f"{args.store}: its entries lack {', '.join(missing)} (built before the normal-angle histograms"
                 f" or the exact sizes); rebuild it to learn {args.metric}")
    features = data.learned_features(args.metric)
    cv = cross_validate(features, data.labels, folds=args.folds, repeats=args.repeats)
    weights = fit_weights(features, data.labels)
    command = "python " + " ".join([Path(sys.argv[0]).as_posix()] + (argv if argv is not None else sys.argv[1:]))
    record = {
        "weights": weights_by_name(weights, names),
        "trained_on": {"collection": args.collection.resolve().name, "models": int(len(data.labels)),
                       "classes": int(len(set(data.labels))), "points": points, "signature_version": SIGNATURE_VERSION},
        "cross_validation": cv,
        "command": command,
        "date": str(datetime.date.today()),
    }
    output.write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
