"""Thumbnails: pixels of known shapes against their analytic projections, and the disk cache."""

from __future__ import annotations

import io
import os

import analytic
import manifold3d as mf
import numpy as np
import pytest
from PIL import Image
from storetools import build, small_kicad

from shapeidx.pictures.render import DEFAULT_MARGIN, png_bytes, render_rgba
from shapeidx.pictures.thumbcache import StoreThumbnails, ThumbnailCache, cache_dir_of_store
from shapeidx.search import Searcher
from shapeidx.signing.pipeline import solid_of_file

SIZE = 200
# The image plane of a camera on the +x+y+z diagonal with +z up, written out independently.
RIGHT = np.array([-1.0, 1.0, 0.0]) / np.sqrt(2)
UP = np.array([-1.0, -1.0, 2.0]) / np.sqrt(6)


def coverage(picture):
    """Share of the frame the silhouette covers (partial pixels count partly)."""
    return picture[..., 3].astype(float).sum() / 255 / (picture.shape[0] * picture.shape[1])


def framed_scale(points_2d):
    """Pixels per model unit when the longer projected side spans the frame less its margins."""
    extent = np.ptp(points_2d, axis=0).max()
    return (1 - 2 * DEFAULT_MARGIN) * SIZE / extent


def box_mesh(a, b, c):
    return analytic.manifold_arrays(mf.Manifold.cube((a, b, c)))


def rotation_taking_z_to(direction):
    """A rotation matrix that maps +z onto ``direction`` (Rodrigues)."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(z, d), np.dot(z, d)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


class TestKnownShapes:
    def test_box_silhouette_is_its_projected_area(self):
        """A box a x b x c seen along (1,1,1) covers (ab + bc + ca) / sqrt(3), scaled to the frame."""
        a, b, c = 3.0, 2.0, 1.0
        vertices, faces = box_mesh(a, b, c)
        picture = render_rgba(vertices, faces, SIZE)
        corners = np.array([[x, y, z] for x in (0, a) for y in (0, b) for z in (0, c)])
        scale = framed_scale(np.stack([corners @ RIGHT, corners @ UP], axis=1))
        expected = (a * b + b * c + c * a) / np.sqrt(3) * scale**2 / SIZE**2
        assert coverage(picture) == pytest.approx(expected, rel=0.01)

    def test_box_fills_the_frame_centred(self):
        vertices, faces = box_mesh(3.0, 2.0, 1.0)
        alpha = render_rgba(vertices, faces, SIZE)[..., 3] > 0
        rows, cols = np.flatnonzero(alpha.any(axis=1)), np.flatnonzero(alpha.any(axis=0))
        width, height = cols[-1] - cols[0] + 1, rows[-1] - rows[0] + 1
        assert max(width, height) == pytest.approx((1 - 2 * DEFAULT_MARGIN) * SIZE, abs=2)
        assert (cols[0] + cols[-1]) / 2 == pytest.approx(SIZE / 2 - 0.5, abs=1.5)
        assert (rows[0] + rows[-1]) / 2 == pytest.approx(SIZE / 2 - 0.5, abs=1.5)

    def test_box_shows_three_faces_in_three_shades_and_nothing_else(self):
        """Three visible faces, each one flat shade, different from each other; the rest empty."""
        vertices, faces = box_mesh(3.0, 2.0, 1.0)
        picture = render_rgba(vertices, faces, SIZE, supersample=1)
        solid = picture[..., 3] == 255
        assert set(np.unique(picture[..., 3])) == {0, 255}  # no supersampling: in or out
        shades = {tuple(c) for c in picture[solid][:, :3]}
        assert len(shades) == 3
        assert np.all(picture[~solid][:, :3] == 255)

    def test_tube_along_the_view_is_an_annulus_with_an_empty_hole(self):
        """A tube whose axis points at the camera shows a ring; the background shows through the hole."""
        outer, inner, segments = 2.0, 1.2, 256
        tube = mf.Manifold.cylinder(4.0, outer, outer, segments) - mf.Manifold.cylinder(6.0, inner, inner, segments).translate((0, 0, -1))
        vertices, faces = analytic.manifold_arrays(tube)
        vertices = vertices @ rotation_taking_z_to([1, 1, 1]).T
        picture = render_rgba(vertices, faces, SIZE)
        polygon_area = segments / 2 * np.sin(2 * np.pi / segments) * (outer**2 - inner**2)
        scale = (1 - 2 * DEFAULT_MARGIN) * SIZE / (2 * outer)
        assert coverage(picture) == pytest.approx(polygon_area * scale**2 / SIZE**2, rel=0.01)
        centre = picture[SIZE // 2 - 10 : SIZE // 2 + 10, SIZE // 2 - 10 : SIZE // 2 + 10]
        assert np.all(centre[..., 3] == 0)
        assert np.all(picture[:3, :, 3] == 0) and np.all(picture[:, :3, 3] == 0)  # the margins

    def test_size_does_not_change_the_framing(self):
        """Twice the pixels: the same share of the frame (the part is framed, not the units)."""
        vertices, faces = box_mesh(30.0, 20.0, 10.0)
        small, large = render_rgba(vertices, faces, 100), render_rgba(vertices, faces, 300)
        assert coverage(small) == pytest.approx(coverage(large), rel=0.02)

    def test_empty_mesh_is_an_empty_picture(self):
        picture = render_rgba(np.zeros((0, 3)), np.zeros((0, 3), int), 32)
        assert picture.shape == (32, 32, 4) and not picture[..., 3].any()


class TestRealParts:
    def test_different_parts_differ_and_a_part_renders_the_same_twice(self, data_dir):
        kicad = data_dir / "kicad6"
        a = solid_of_file(kicad / "Battery" / "BatteryHolder_Keystone_500.wrl")
        b = solid_of_file(kicad / "LED_SMD" / sorted(p.name for p in (kicad / "LED_SMD").glob("*.wrl"))[0])
        pa, pa2, pb = render_rgba(a.vertices, a.faces, 128), render_rgba(a.vertices, a.faces, 128), render_rgba(b.vertices, b.faces, 128)
        assert np.array_equal(pa, pa2)
        silhouette_a, silhouette_b = pa[..., 3] > 127, pb[..., 3] > 127
        assert (silhouette_a ^ silhouette_b).mean() > 0.05
        assert 0.1 < silhouette_a.mean() < 0.9

    def test_png_round_trip(self, data_dir):
        solid = solid_of_file(data_dir / "kicad6" / "Battery" / "BatteryHolder_Keystone_500.wrl")
        picture = render_rgba(solid.vertices, solid.faces, 96)
        decoded = np.asarray(Image.open(io.BytesIO(png_bytes(picture))))
        assert decoded.shape == (96, 96, 4) and np.array_equal(decoded, picture)


class TestCache:
    def test_second_request_is_read_not_rendered_and_a_changed_file_is_rendered_again(self, tmp_path):
        part = tmp_path / "box.stl"
        analytic.write_stl(part, *box_mesh(3.0, 2.0, 1.0))
        cache = ThumbnailCache(tmp_path / "thumbs", 64)
        first = cache.png(part)
        assert cache.png(part) == first and cache.rendered == 1
        assert [p.suffix for p in (tmp_path / "thumbs").iterdir()] == [".png"]  # no temporary left
        analytic.write_stl(part, *box_mesh(1.0, 1.0, 5.0))
        changed = cache.png(part)
        assert cache.rendered == 2 and changed != first

    def test_an_unwritable_cache_still_gives_the_picture(self, tmp_path):
        part = tmp_path / "box.stl"
        analytic.write_stl(part, *box_mesh(3.0, 2.0, 1.0))
        blocker = tmp_path / "not-a-folder"
        blocker.write_text("x")
        data = ThumbnailCache(blocker / "thumbs", 64).png(part)
        assert Image.open(io.BytesIO(data)).size == (64, 64)

    def test_store_thumbnails_live_beside_the_store_and_follow_file_changes(self, data_dir, tmp_path):
        tree = small_kicad(data_dir, tmp_path, ("LED_SMD",))
        store = tmp_path / "s.h5"
        assert build(tree, store).exit_code == 0
        with Searcher(store) as searcher:
            thumbs = StoreThumbnails(searcher, 64)
            entry = str(searcher.paths[0])
            first = thumbs.png(entry)
            assert thumbs.png(entry) == first and thumbs.cache.rendered == 1
        assert cache_dir_of_store(store) == store / "thumbs" and any((store / "thumbs").iterdir())
        # the store is untouched by the cache and still opens
        with Searcher(store) as searcher:
            assert len(searcher) == 10
            # the file is replaced by another part after the build: its picture follows
            other = tree / str(searcher.paths[1])
            os.replace(other, tree / entry)
            thumbs = StoreThumbnails(searcher, 64)
            assert thumbs.png(entry) != first and thumbs.cache.rendered == 1
