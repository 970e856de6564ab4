"""scripts/peers.py's harness on a few kicad6 parts: the reimplemented spherical-harmonic descriptor.

Skips, with the reason, where the shared data or scipy's sph_harm_y is absent. The product never
imports scripts/peers.py.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
peers = pytest.importorskip("peers", reason="scripts/peers.py does not import here")
pytest.importorskip("scipy.special", reason="scipy is absent")
if not hasattr(__import__("scipy.special").special, "sph_harm_y"):
    pytest.skip("scipy has no sph_harm_y (scipy >= 1.15 needed)", allow_module_level=True)

KICAD6 = peers.DATA / "kicad6"


@pytest.fixture(scope="module")
def parts():
    if not KICAD6.is_dir():
        pytest.skip(f"no shared data at {KICAD6}")
    from shapeidx.signing.pipeline import solid_of_file

    folders = sorted(p for p in KICAD6.iterdir() if p.is_dir())[:2]
    chosen = [(f.name, sorted(f.glob("*.wrl"))[k]) for f in folders for k in range(3)]
    return [(label, solid_of_file(path)) for label, path in chosen]


def test_descriptor_shape_and_nearest_is_itself(parts):
    bank = np.array([peers.shd_descriptor(s.vertices, s.faces).ravel() for _, s in parts])
    assert bank.shape == (6, peers.SPHERES * (peers.BANDS + 1))
    d = np.array([peers.l2_to_many(bank, row) for row in bank])
    assert np.allclose(np.diag(d), 0)
    assert (np.argmin(d + np.eye(6) * 0, axis=1) == np.arange(6)).all()


def test_rotation_and_scale_move_it_less_than_another_part(parts):
    from scipy.spatial.transform import Rotation

    _, solid = parts[0]
    a = peers.shd_descriptor(solid.vertices, solid.faces)
    moved = Rotation.from_euler("xyz", [0.3, 1.1, -0.7]).apply(solid.vertices) * 3.7 + 5.0
    b = peers.shd_descriptor(moved, solid.faces)
    others = [peers.shd_descriptor(s.vertices, s.faces) for label, s in parts if label != parts[0][0]]
    assert np.linalg.norm(a - b) < min(np.linalg.norm(a - o) for o in others)


def test_deterministic_given_seed(parts):
    _, solid = parts[1]
    assert np.array_equal(peers.shd_descriptor(solid.vertices, solid.faces, 3), peers.shd_descriptor(solid.vertices, solid.faces, 3))
