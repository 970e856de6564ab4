#!/usr/bin/env python3
"""How far the axial handedness ``h3`` of one part drifts between two tessellations: the
calibration of :data:`shapeidx.signing.chirality.AXIAL_CHIRAL_MIN` (docs/families.md).

    python scripts/chirality_twins.py [--data ../shared/data]

Each kicad6 VRML part and its STEP file in kicad6-step (faceted by OpenCASCADE) are one part
with other triangles. For the twins where both have ``h3`` (two principal radii coinciding),
prints how many agree in sign, and the largest ``|h3|`` that both reach with opposite signs:
a threshold below it would call such a part its own mirror image.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from _common import DATA, machine


def main(argv=None) -> int:
    from shapeidx.errors import ShapeidxError
    from shapeidx.signing.chirality import AXIAL_CHIRAL_MIN
    from shapeidx.signing.moments import shape_facts
    from shapeidx.signing.part import load_part

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(DATA))
    args = parser.parse_args(argv)
    from pathlib import Path

    data = Path(args.data)
    pairs = []
    for step in sorted((data / "kicad6-step").rglob("*.step")):
        vrml = data / "kicad6" / step.relative_to(data / "kicad6-step").with_suffix(".wrl")
        if not vrml.exists():
            continue
        try:
            h = [shape_facts(s.vertices, s.faces)["handedness"][2] for s in (load_part(vrml), load_part(step))]
        except ShapeidxError as exc:
            print(f"skipped {step.name}: {exc}", file=sys.stderr)
            continue
        pairs.append((vrml.relative_to(data / "kicad6").as_posix(), *h))
    both = [(name, a, b) for name, a, b in pairs if np.isfinite(a) and np.isfinite(b)]
    opposite = sorted(((min(abs(a), abs(b)), name, a, b) for name, a, b in both if np.sign(a) != np.sign(b)), reverse=True)
    print(f"{len(pairs)} twins; {len(both)} with h3 in both; {len(both) - len(opposite)} agree in sign")
    for reach, name, a, b in opposite[:5]:
        print(f"  opposite: {name}: {a:.3g} / {b:.3g} (both reach {reach:.3g})")
    flagged = sum(1 for reach, *_ in opposite if reach >= AXIAL_CHIRAL_MIN)
    print(f"AXIAL_CHIRAL_MIN {AXIAL_CHIRAL_MIN:g}: twins called mirror images {flagged}"
          + (f"; {AXIAL_CHIRAL_MIN / opposite[0][0]:.1f} x the largest opposite" if opposite else ""))
    print(machine())
    return 0


if __name__ == "__main__":
    sys.exit(main())
