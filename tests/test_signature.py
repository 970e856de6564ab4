"""Histograms and distances as Ip et al. (2002) define them, with our documented edge cases."""

from __future__ import annotations

import numpy as np
import pytest

import analytic as A
from shapeidx.signing.classify import pair_indices
from shapeidx.distance import ANGLE_METRICS, METRICS, MIN_AGREEMENT, compare, histogram_distance, metric_values
from shapeidx.signing.pipeline import signature_of_file, signature_of_solid, solid_of_file
from shapeidx.signing.sampling import sample_surface
from shapeidx.signing.histogram import Histogram, Signature


def signature_with(hist: dict, fractions: dict) -> Signature:
    """A Signature from probability lists and fractions (10,000 pairs), for arithmetic tests."""
    total = 10_000
    histograms = {}
    for name in ("all", "in", "out", "mixed"):
        share = 1.0 if name == "all" else fractions[name]
        counts = np.rint(np.asarray(hist[name], float) * share * total).astype(np.int64)
        histograms[name] = Histogram(counts, 1.0 if len(counts) else 0.0, 0.02 if len(counts) else 0.0)
    return Signature(points=100, seed=0, histograms=histograms)


class TestHistogram:
    def test_bins_are_a_fiftieth_of_the_mean_and_sum_to_one(self):
        d = np.random.default_rng(0).gamma(4.0, 2.0, size=50_000)
        h = Histogram.of(d)
        assert h.bin_width == pytest.approx(d.mean() / 50)
        assert h.p.sum() == pytest.approx(1.0)
        edges = np.arange(len(h.counts) + 1) * h.bin_width
        np.testing.assert_array_equal(h.counts, np.histogram(d, bins=edges)[0])

    def test_class_histograms_equal_histograms_of_each_class(self):
        rng = np.random.default_rng(2)
        d = rng.gamma(3.0, 1.0, size=20_000)
        classes = rng.choice(3, size=20_000, p=[0.6, 0.0, 0.4]).astype(np.uint8)  # no OUT pairs
        sig = Signature.from_pairs(d, classes, points=200, seed=0)
        for code, name in enumerate(("in", "out", "mixed")):
            alone = Histogram.of(d[classes == code])
            np.testing.assert_array_equal(sig.histograms[name].counts, alone.counts)
            assert sig.histograms[name].mean == pytest.approx(alone.mean)
            assert sig.histograms[name].bin_width == pytest.approx(alone.bin_width)

    def test_empty_class(self):
        h = Histogram.of(np.zeros(0))
        assert h.total == 0 and len(h.p) == 0 and h.mean == 0

    def test_signature_of_a_real_part(self, data_dir):
        sig = signature_of_file(data_dir / "mesh-wild/trimesh-models/plate_holes.STL", points=512)
        assert sig.histograms["all"].total == 512 * 511 // 2
        assert sum(sig.fractions.values()) == pytest.approx(1.0)
        assert sum(sig.histograms[c].total for c in ("in", "out", "mixed")) == 512 * 511 // 2
        for h in sig.histograms.values():  # a class with no pair (OUT here is rare) has no bins
            assert (h.p.sum() == pytest.approx(1.0) if h.total else len(h.p) == 0) and h.bin_width == pytest.approx(h.mean / 50)

    def test_histogram_bins_cover_the_longest_pair(self, tmp_path):
        v, f = A.mesh_arrays(A.catalogue()["l_bracket"])
        A.write_stl(tmp_path / "l.stl", v, f)
        solid = solid_of_file(tmp_path / "l.stl")
        sig = signature_of_solid(solid, points=256)
        points, _ = sample_surface(solid.vertices, solid.faces, 256)  # same seed: the same points
        i, j = pair_indices(256)
        longest = np.linalg.norm(points[i] - points[j], axis=1).max()
        h = sig.histograms["all"]
        assert (len(h.counts) - 1) * h.bin_width <= longest < len(h.counts) * h.bin_width


class TestDistances:
    def test_d_pads_the_shorter_histogram_and_divides_by_the_bin_count(self):
        assert histogram_distance(np.array([1.0]), np.array([0.0, 1.0])) == pytest.approx(2 / 2)
        assert histogram_distance(np.array([0.5, 0.5]), np.array([0.5, 0.25, 0.25])) == pytest.approx(0.5 / 3)
        assert histogram_distance(np.array([0.2, 0.8]), np.array([0.2, 0.8])) == 0

    def test_empty_histograms(self):
        assert histogram_distance(np.zeros(0), np.zeros(0)) == 0
        assert histogram_distance(np.zeros(0), np.array([0.25, 0.25, 0.5])) == pytest.approx(1 / 3)

    def test_the_four_distances_by_hand(self):
        a = signature_with({"all": [0.5, 0.5], "in": [1.0], "out": [0.5, 0.5], "mixed": [0.25, 0.75]}, {"in": 0.2, "out": 0.3, "mixed": 0.5})
        b = signature_with({"all": [0.5, 0.25, 0.25], "in": [0.5, 0.5], "out": [0.5, 0.5], "mixed": [0.75, 0.25]}, {"in": 0.4, "out": 0.3, "mixed": 0.3})
        d_all, d_in, d_out, d_mixed = 0.5 / 3, 1.0 / 2, 0.0, 1.0 / 2
        got = compare(a, b)
        assert got["all"] == pytest.approx(d_all)
        assert got["avg3"] == pytest.approx((d_in + d_out + d_mixed) / 3)
        assert got["avg4"] == pytest.approx((d_all + d_in + d_out + d_mixed) / 4)
        assert got["weighted"] == pytest.approx(d_in / (1 - 0.2) + d_out / (1 - 0.0) + d_mixed / (1 - 0.2))

    def test_no_distance_is_infinite_or_nan(self):
        # one part all IN, the other with no IN at all: Diff = 1 for the IN class
        a = signature_with({"all": [1.0], "in": [1.0], "out": [], "mixed": []}, {"in": 1.0, "out": 0.0, "mixed": 0.0})
        b = signature_with({"all": [0.5, 0.5], "in": [], "out": [0.5, 0.5], "mixed": [1.0]}, {"in": 0.0, "out": 0.5, "mixed": 0.5})
        got = compare(a, b)
        assert all(np.isfinite(v) for v in got.values())
        assert got["weighted"] == pytest.approx(1.0 / MIN_AGREEMENT + (1.0 / 2) / 0.5 + 1.0 / 0.5)
        # these signatures have no normal-angle histograms: the metrics needing them are left out
        assert compare(a, a) == {m: 0 for m in METRICS if m not in ANGLE_METRICS}

    def test_symmetric(self, data_dir):
        parts = data_dir / "mesh-wild/trimesh-models"
        a = signature_of_file(parts / "plate_holes.STL", points=256)
        b = signature_of_file(parts / "octagonal_pocket.stl", points=256)
        assert compare(a, b) == pytest.approx(compare(b, a))

    def test_paper_distances_work_on_arrays(self):
        features = {f"d_{h}": np.array([0.1, 0.2]) for h in ("all", "in", "out", "mixed")}
        features.update({f"gap_{c}": np.array([0.0, 0.5]) for c in ("in", "out", "mixed")})
        out = metric_values(features, ("all", "avg3", "avg4", "weighted"))
        np.testing.assert_allclose(out["weighted"], [0.3, 1.2])
        np.testing.assert_allclose(out["avg3"], [0.1, 0.2])
        np.testing.assert_allclose(out["avg4"], [0.1, 0.2])
