"""The same solid gives the same signature whichever way it is written.

An L-shaped block (hand-written fixtures in tests/data/vrml) as ASCII STL, as VRML 2.0
inside a rotated and scaled Transform (concave caps marked convex), the same gzipped, and
as VRML 1.0 made of quadrilaterals listed clockwise: all within the method's own noise of
the STL (1.5 times the largest distance between the STL and five reseeds of it, as in
test_invariance.py), with class fractions within 3 percentage points. Two blocks written
once and placed twice with DEF/USE give the signature of the two blocks written out.

2048 points rather than the default 1024: with 1024 the reseed noise of so small a part is
wide enough to let the block stretched by 40 % along one axis pass for the same.
"""

from __future__ import annotations

import gzip

import numpy as np

import pytest

from shapeidx.distance import compare
from shapeidx.signing.pipeline import signature_of_file, signature_of_solid, solid_of_file
from test_vrml_support import FIXTURES

POINTS = 2048
L_BLOCK_VARIANTS = ["l_block_rotated_scaled.wrl", "l_block_rotated_scaled.wrz", "l_block_v1_quads.wrl"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("vrml_signature")
    for name in (
        "l_block.stl",
        "l_block_rotated_scaled.wrl",
        "l_block_v1_quads.wrl",
        "two_blocks_def_use.wrl",
        "two_blocks_explicit.wrl",
    ):
        (folder / name).write_bytes((FIXTURES / name).read_bytes())
    (folder / "l_block_rotated_scaled.wrz").write_bytes(
        gzip.compress((FIXTURES / "l_block_rotated_scaled.wrl").read_bytes())
    )
    return folder


def noise_of(path) -> float:
    """The largest weighted distance between a file's signature and five reseeds."""
    solid = solid_of_file(path)
    reference = signature_of_solid(solid, points=POINTS)
    return max(compare(reference, signature_of_solid(solid, POINTS, seed))["weighted"] for seed in range(1, 6))


@pytest.fixture(scope="module")
def l_block_noise(files):
    return noise_of(files / "l_block.stl")


@pytest.mark.parametrize("variant", L_BLOCK_VARIANTS)
def test_the_l_block_has_one_signature_in_every_format(files, l_block_noise, variant):
    reference = signature_of_file(files / "l_block.stl", POINTS)
    signature = signature_of_file(files / variant, POINTS)
    assert compare(reference, signature)["weighted"] <= 1.5 * l_block_noise
    for name, share in reference.fractions.items():
        assert signature.fractions[name] == pytest.approx(share, abs=0.03), name


def test_def_use_gives_the_signature_of_two_blocks(files):
    two_blocks = signature_of_file(files / "two_blocks_explicit.wrl", POINTS)
    placed_twice = signature_of_file(files / "two_blocks_def_use.wrl", POINTS)
    one_block = signature_of_file(files / "l_block.stl", POINTS)
    noise = noise_of(files / "two_blocks_explicit.wrl")
    assert compare(two_blocks, placed_twice)["weighted"] <= 1.5 * noise
    assert compare(one_block, placed_twice)["weighted"] > 1.5 * noise  # not just any shape
    for name, share in two_blocks.fractions.items():
        assert placed_twice.fractions[name] == pytest.approx(share, abs=0.03), name


@pytest.mark.parametrize("name", ["Capacitor_SMD.3dshapes/C_0805_2012Metric.wrz", "Capacitor_SMD.3dshapes/C_1206_3216Metric.wrz"])
def test_a_box_written_as_three_touching_bodies_is_one_convex_solid(data_dir, name):
    # KiCad's older capacitors: the body and two end caps written face by face, each body
    # writing the face where it touches the next. Their union is one rectangular box: its
    # volume is the product of its sides, and, being convex, every pair of its points is IN
    # (Ip et al. 2002, 3.2.3). Kept as a wall, the touching faces made most pairs MIXED.
    solid = solid_of_file(data_dir / "vrml-wild" / "kicad-wrz" / name)
    lo, hi = solid.bounds
    assert solid.watertight and solid.describe()["solid"]["walls_removed"] == 8
    assert solid.volume == pytest.approx(float(np.prod(hi - lo)), rel=1e-6)
    fractions = signature_of_solid(solid).fractions
    assert fractions["in"] >= 0.999 and fractions["mixed"] <= 0.001
