"""Which entries of two stores of the same tree have different signatures.

After a reader changes (a format's revision raised), a build signs that format's files
again; this tells which of them came out otherwise, by comparing every entry's class
fractions, triangle count, area and the counts of its four histograms, bit for bit.
``--expect`` names a file listing the paths that should differ (one per line): the script
then says which differ unexpectedly and which expected ones did not.

Run::

    python scripts/store_diff.py BEFORE.shapeidx AFTER.shapeidx --expect affected.txt
"""

from __future__ import annotations

import argparse

import numpy as np

from shapeidx.signing.parameters import HISTOGRAMS
from shapeidx.store import open_store


def differing_paths(before, after) -> list[str]:
    """Paths whose signatures differ between the two stores (which hold the same paths)."""
    with open_store(before) as a, open_store(after) as b:
        paths = np.asarray(a.paths)
        if list(paths) != list(b.paths):
            raise SystemExit(f"{before} and {after} do not hold the same paths")
        n = len(paths)
        differ = np.zeros(n, dtype=bool)
        for column in ("entries/fractions", "entries/triangles", "entries/area"):
            x, y = np.asarray(a.column(column)).reshape(n, -1), np.asarray(b.column(column)).reshape(n, -1)
            differ |= ~np.all((x == y) | (np.isnan(x) & np.isnan(y)) if x.dtype.kind == "f" else x == y, axis=1)
        rows = np.arange(n)
        for name in HISTOGRAMS:
            (flat_a, len_a), (flat_b, len_b) = a.counts(name, rows), b.counts(name, rows)
            ends_a, ends_b = np.cumsum(len_a), np.cumsum(len_b)
            for i in np.flatnonzero(len_a == len_b).tolist():
                if not np.array_equal(flat_a[ends_a[i] - len_a[i]:ends_a[i]], flat_b[ends_b[i] - len_b[i]:ends_b[i]]):
                    differ[i] = True
            differ |= len_a != len_b
        return sorted(str(p) for p in paths[differ])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before")
    parser.add_argument("after")
    parser.add_argument("--expect", help="a file of the paths that should differ, one per line")
    args = parser.parse_args()
    changed = differing_paths(args.before, args.after)
    with open_store(args.after) as reader:
        total = len(reader)
    print(f"{len(changed)} of {total} entries differ")
    for path in changed:
        print(f"  {path}")
    if args.expect:
        with open(args.expect, encoding="utf-8") as f:
            expected = {line.strip() for line in f if line.strip()}
        print(f"expected: {len(expected)}; differ unexpectedly: {sorted(set(changed) - expected)};"
              f" expected but the same: {sorted(expected - set(changed))}")


if __name__ == "__main__":
    main()
