"""Parts of many separate shells cost about linear time, not the square of the shell count.

The class of input the attack used: a small VRML whose DEF/USE groups, each used twice with
a translation, expand to thousands of separate closed tetrahedra (2^14 from 1.4 kB). The
shell-nesting test compared every shell's box with every other's (16,000 shells: 32 s).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from shapeidx.io import load
from shapeidx.signing.solid import make_solid


def tetrahedra_vrml(levels: int, axes: str = "xyz") -> str:
    """2**levels tetrahedra by DEF/USE doubling, each copy moved along the next of ``axes``."""
    lines = ["DEF L0 Shape { geometry IndexedFaceSet { coord Coordinate { point [0 0 0, 1 0 0, 0 1 0, 0 0 1] }"
             " coordIndex [0 2 1 -1 0 1 3 -1 0 3 2 -1 1 2 3 -1] } }"]
    for k in range(1, levels + 1):
        axis = "xyz".index(axes[(k - 1) % len(axes)])
        offset = [0, 0, 0]
        offset[axis] = 3 * 2 ** ((k - 1) // len(axes))
        lines.append(f"DEF L{k} Group {{ children [ USE L{k - 1} Transform {{ translation {offset[0]} {offset[1]} "
                     f"{offset[2]} children USE L{k - 1} }} ] }}")
    return "#VRML V2.0 utf8\nSwitch { whichChoice -1 choice [\n" + "\n".join(lines) + "\n] }\n" + f"USE L{levels}\n"


def _solid_seconds(path):
    mesh = load(path)
    started = time.process_time()
    solid = make_solid(mesh, path)
    return time.process_time() - started, solid


@pytest.mark.parametrize("axes", ["xyz", "y"], ids=["grid", "row"])
def test_many_separate_shells_take_about_linear_time(tmp_path, axes):
    times = {}
    for levels in (12, 14):
        path = tmp_path / f"t{levels}.wrl"
        path.write_text(tetrahedra_vrml(levels, axes))
        times[levels], solid = _solid_seconds(path)
        assert solid.shells == 2**levels and solid.watertight
        assert solid.volume == pytest.approx(2**levels / 6, rel=1e-9)  # analytic: 1/6 each
        assert solid.report["cavities"] == 0
    # four times the shells: about four times the time (the square would be sixteen)
    assert times[14] < 8 * max(times[12], 0.05), times
    assert times[14] < 20, times


def test_touching_pairs_are_every_pair_a_direct_comparison_finds():
    from shapeidx.signing.solid import touching_pairs

    rng = np.random.default_rng(3)
    for n, spread in ((300, 10.0), (300, 1.0), (50, 0.1)):
        lo = rng.uniform(0, spread, (n, 3))
        hi = lo + rng.exponential(0.3, (n, 3)) * (rng.uniform(size=(n, 1)) < 0.9) + (rng.uniform(size=(n, 1)) < 0.05) * 5
        i, j = touching_pairs(lo, hi)
        found = set(zip(i.tolist(), j.tolist()))
        a, b = np.triu_indices(n, 1)
        touch = np.all(lo[a] <= hi[b], axis=1) & np.all(lo[b] <= hi[a], axis=1)
        assert found == set(zip(a[touch].tolist(), b[touch].tolist()))


def test_nested_shells_still_make_cavities(tmp_path):
    """Cubes of sides 6, 4 and 2 about one centre, and a separate cube: the middle one is a
    cavity; volume 6^3 - 4^3 + 2^3 + 1 (analytic)."""
    def cube(side, at=(0, 0, 0)):
        h = side / 2
        pts = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)]
        pts = " , ".join(f"{x + at[0]} {y + at[1]} {z + at[2]}" for x, y, z in pts)
        quads = "0 1 3 2 -1 4 6 7 5 -1 0 4 5 1 -1 2 3 7 6 -1 0 2 6 4 -1 1 5 7 3 -1"
        return f"Shape {{ geometry IndexedFaceSet {{ coord Coordinate {{ point [{pts}] }} coordIndex [{quads}] }} }}"
    path = tmp_path / "nested.wrl"
    path.write_text("#VRML V2.0 utf8\n" + "\n".join([cube(6), cube(4), cube(2), cube(1, (10, 0, 0))]) + "\n")
    _, solid = _solid_seconds(path)
    assert solid.report["cavities"] == 1
    assert solid.volume == pytest.approx(216 - 64 + 8 + 1, rel=1e-9)
