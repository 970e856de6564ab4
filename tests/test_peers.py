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


@pytest.fixture(scope="module")
def lightfield():
    """The Light Field Descriptor's own programs (pip install -e '.[peers]', the Debian packages
    of peers.LFD_DEBIAN, python scripts/peers.py --build-lfd); skipped where they are not."""
    programs = peers.lfd_programs()
    if programs is None:
        pytest.skip(f"no Light Field Descriptor built in {peers.LFD_HOME} (or no Xvfb): see scripts/peers.py")
    field = peers.LightField(programs)
    yield field
    field.close()


def test_light_field_distance_is_the_programs_own(parts, lightfield, tmp_path):
    """lfd_to_many (numpy) gives exactly what the package's Distance program prints, on real parts
    (the program never reads its second part's eccentricity: zeroed here to match it)."""
    import subprocess

    bank = np.array([lightfield.describe(s.vertices, s.faces) for _, s in parts[:4]])
    assert bank.shape == (4, 10, 10, 47) and bank.dtype == np.uint8
    for k, descriptor in enumerate(bank):
        for suffix, values in (("art", descriptor[..., :35]), ("fd", descriptor[..., 35:45]),
                               ("cir", descriptor[..., 45]), ("ecc", descriptor[..., 46])):
            values.tofile(tmp_path / f"p{k}_q8_v1.8.{suffix}")
    programs = peers.lfd_programs()
    for a in range(4):
        for b in range(4):
            printed = subprocess.run([str(programs / "Distance"), str(tmp_path / f"p{a}"), str(tmp_path / f"p{b}")],
                                     cwd=programs, capture_output=True).stdout  # its main is void: no status
            query = bank[b].copy()
            query[..., 46] = 0
            assert peers.lfd_to_many(bank[a:a + 1], query)[0] == int(printed.split(b"SIMILARITY:")[1].split()[0])
    d = np.array([peers.lfd_to_many(bank, row) for row in bank])
    assert np.array_equal(np.diag(d), np.zeros(4)) and (d + np.eye(4) * 1e9 > 0).all()


def test_light_field_of_a_rotated_copy_is_nearer_than_another_part(parts, lightfield):
    from scipy.spatial.transform import Rotation

    _, solid = parts[0]
    a = lightfield.describe(solid.vertices, solid.faces)
    moved = Rotation.from_euler("xyz", [0.3, 1.1, -0.7]).apply(solid.vertices) * 3.7 + 5.0
    b = lightfield.describe(moved, solid.faces)
    others = np.array([lightfield.describe(s.vertices, s.faces) for label, s in parts if label != parts[0][0]])
    assert peers.lfd_to_many(b[None], a)[0] < peers.lfd_to_many(others, a).min()
