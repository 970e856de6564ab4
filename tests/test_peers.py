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


def test_the_cache_answers_a_second_run_without_describing_again(tmp_path, monkeypatch):
    files = sorted((KICAD6 / "Battery").glob("*.wrl"))[:3]
    cache = peers.DescriptorCache(tmp_path / "descriptors")
    first = peers.describe(files, seeds=(3, 4), cache=cache, sign=True)
    assert first.banks[("shd", 3)].shape == (3, peers.SPHERES * (peers.BANDS + 1)) and not first.missing["shd"]
    assert not np.array_equal(first.banks[("shd", 3)], first.banks[("shd", 4)])  # another seed, other points

    def refuse(*args, **kwargs):
        raise AssertionError("described again")

    monkeypatch.setattr(peers, "shd_descriptor", refuse)
    monkeypatch.setattr("shapeidx.signing.pipeline.signature_of_solid", refuse)
    again = peers.describe(files, seeds=(3, 4), cache=cache, sign=True)
    for key, bank in first.banks.items():
        assert np.array_equal(bank, again.banks[key])
    for a, b in zip(first.signatures[4], again.signatures[4]):
        assert np.array_equal(a.fractions, b.fractions)
    assert again.seconds["shd"] == pytest.approx(first.seconds["shd"])  # the times are kept with them
    bad = tmp_path / "bad.wrl"
    bad.write_text("junk\n")
    missed = peers.describe([files[0], bad], seeds=(3,), cache=cache)  # the first from the cache
    assert missed.missing["shd"] == {1} and not missed.banks[("shd", 3)][1].any()
    assert np.array_equal(missed.banks[("shd", 3)][0], first.banks[("shd", 3)][0])


def test_a_part_the_peer_cannot_describe_is_never_found_and_finds_nothing():
    from shapeidx.evaluation.retrieval import retrieval_scores

    labels = ["a", "a", "b", "b"]
    bank = np.array([[0.0], [0.1], [5.0], [5.1]], dtype=np.float32)
    described = peers.Described([None] * 4, {("shd", peers.GALLERY_SEED): bank}, {"shd": {1}}, {}, {})
    d = peers.peer_matrix(described, "shd", labels)
    assert np.isinf(d[0, 1]) and d[1, 0] == np.inf and d[1, 2] == 1.0
    per = retrieval_scores(d, labels, per_query=True)["per_query"]
    nn = dict(zip(per["index"].tolist(), per["nn"].tolist()))
    assert nn == {0: 0.0, 1: 0.0, 2: 1.0, 3: 1.0}


def test_the_kinds_question_scores_the_peer_as_evaluate_scores_shapeidx(tmp_path):
    """On a small real collection: the parts evaluate scores, and the peer's NN equal to the
    share of parts whose L2-nearest other part is of their folder, computed here by hand."""
    folder = peers.COLLECTIONS["kicad-2017/freecad-coin"]
    if not folder.is_dir():
        pytest.skip(f"no {folder}")
    out = {"lightfield": None, "cache": peers.DescriptorCache(tmp_path / "descriptors")}
    peers.kinds(tmp_path, out, "kicad-2017/freecad-coin", folder)
    k = out["kinds"]["kicad-2017/freecad-coin"]
    assert k["parts"] == 40 and k["classes"] == 7 and k["missing"] == {"shd": 0}
    described, _ = out["gallery"]["kicad-2017/freecad-coin"]
    bank = described.bank("shd")
    labels = [str(p.relative_to(folder)).split("/")[0] for p in described.paths]
    d = np.sqrt(((bank[:, None, :] - bank[None, :, :]) ** 2).sum(axis=2))
    np.fill_diagonal(d, np.inf)
    by_hand = np.mean([labels[int(np.argmin(row))] == labels[q] for q, row in enumerate(d)
                       if labels.count(labels[q]) > 1])
    assert k["peers"]["shd"]["nn"] == pytest.approx(by_hand)
    assert 0 < k["weighted"]["nn"] <= 1 and k["best"][1]["ft"] >= k["weighted"]["ft"]
