"""Triangulation, merging and shell orientation (shapeidx.signing.mesh)."""

from __future__ import annotations

import numpy as np
import pytest

from shapeidx.io import load
from shapeidx.signing.mesh import (
    merge_vertices,
    orient_shells,
    remove_bad_faces,
    split_quads,
    triangle_areas,
    triangle_cross,
    triangulate_polygons,
)


def newell_area(points: np.ndarray) -> float:
    """Area of a planar polygon from its corners (Newell): independent of any triangulation."""
    return 0.5 * float(np.linalg.norm(np.cross(points, np.roll(points, -1, axis=0)).sum(axis=0)))


def place_in_3d(xy: np.ndarray, seed: int = 0) -> np.ndarray:
    """Put a 2-D polygon into a random plane of space."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return np.c_[xy, np.zeros(len(xy))] @ q.T + rng.normal(size=3) * 10


def assert_exact_cover(vertices, polygon, triangles):
    """Triangles cover the polygon exactly once, with its winding: their areas add up to the
    polygon's and every one faces the polygon's way (an overlap or a flip breaks one of these)."""
    normal = np.cross(vertices[polygon], np.roll(vertices[polygon], -1, axis=0)).sum(axis=0)
    cross = triangle_cross(vertices, triangles)
    assert np.all(cross @ normal > -1e-12)
    assert triangle_areas(vertices, triangles).sum() == pytest.approx(newell_area(vertices[polygon]), rel=1e-9)


class TestQuadrilaterals:
    def test_convex_quad_is_split_from_its_first_corner(self):
        # the paper's rule: from corner a the widest angle is b-a-d, so split along a-c
        v = np.array([[0, 0, 0], [2, 0, 0], [3, 2, 0], [0, 1, 0]], float)
        tri = split_quads(v, np.array([[0, 1, 2, 3]]))
        assert sorted(map(sorted, tri.tolist())) == [[0, 1, 2], [0, 2, 3]]

    def test_quad_reflex_at_first_corner_is_split_through_it(self):
        # corner a is reflex: the angles seen from it mislead the rule; b-d runs outside the
        # quad, a-c is the only diagonal inside
        v = np.array([[1, 1, 0], [0, 3, 0], [-3, -3, 0], [3, 0, 0]], float)
        quad = np.array([0, 1, 2, 3])
        tri = split_quads(v, quad[None])
        assert sorted(map(sorted, tri.tolist())) == [[0, 1, 2], [0, 2, 3]]
        assert_exact_cover(v, quad, tri)

    @pytest.mark.parametrize("start", range(4))
    def test_concave_quad_from_every_starting_corner(self, start):
        v = np.array([[1, 1, 0], [0, 3, 0], [-3, -3, 0], [3, 0, 0]], float)
        quad = np.roll(np.arange(4), start)
        assert_exact_cover(v, quad, split_quads(v, quad[None]))

    def test_quad_reflex_at_third_corner(self):
        v = np.array([[0, 0, 0], [4, 0, 0], [1, 1, 0], [0, 4, 0]], float)
        quad = np.array([0, 1, 2, 3])
        tri = split_quads(v, quad[None])
        assert_exact_cover(v, quad, tri)

    def test_non_planar_quad_follows_the_angle_rule(self):
        # folded quad: the rule, not the fold, decides; from a the widest angle is b-a-d
        v = np.array([[0, 0, 0], [1, 0, 0.3], [1, 1, 0], [0, 1, 0.3]], float)
        a, b, c, d = v
        def angle(x, y):
            return np.arccos(np.dot(x, y) / np.linalg.norm(x) / np.linalg.norm(y))
        assert angle(b - a, d - a) > max(angle(b - a, c - a), angle(c - a, d - a))
        tri = split_quads(v, np.array([[0, 1, 2, 3]]))
        assert sorted(map(sorted, tri.tolist())) == [[0, 1, 2], [0, 2, 3]]


class TestPolygons:
    @pytest.mark.parametrize(
        "xy",
        [
            [[0, 0], [4, 0], [4, 1], [1, 1], [1, 4], [0, 4]],  # L shape
            [[0, 0], [5, 0], [5, 3], [4, 3], [4, 1], [3, 1], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]],  # comb
            [[np.cos(t) * r, np.sin(t) * r] for t, r in zip(np.linspace(0, 2 * np.pi, 10, endpoint=False), [1, 0.4] * 5)],
        ],
        ids=["L", "comb", "star"],
    )
    def test_concave_polygon_in_any_plane(self, xy):
        v = place_in_3d(np.array(xy, float))
        polygon = np.arange(len(v))
        tri = triangulate_polygons(v, np.array([len(v)]), polygon)
        assert len(tri) == len(v) - 2
        assert_exact_cover(v, polygon, tri)

    def test_clockwise_polygon_keeps_its_winding(self):
        v = place_in_3d(np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 4], [0, 4]], float)[::-1], seed=3)
        polygon = np.arange(len(v))
        assert_exact_cover(v, polygon, triangulate_polygons(v, np.array([len(v)]), polygon))

    def test_mixed_sizes_keep_polygon_order(self):
        v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0], [3.5, 1, 0], [2.5, 2, 0], [2, 1, 0]], float)
        sizes = np.array([3, 5, 4])
        indices = np.array([0, 1, 2, 4, 5, 6, 7, 8, 0, 1, 2, 3])
        tri = triangulate_polygons(v, sizes, indices)
        assert len(tri) == 1 + 3 + 2
        assert tri[0].tolist() == [0, 1, 2]
        assert set(tri[1:4].ravel()) == {4, 5, 6, 7, 8}
        assert set(tri[4:].ravel()) == {0, 1, 2, 3}

    def test_real_concave_polygon_file(self, data_dir):
        mesh = load(data_dir / "mesh-wild/assimp-testmodels/usr/share/assimp/models/OBJ/concave_polygon.obj")
        assert mesh.face_sizes.max() > 4
        tri = triangulate_polygons(mesh.vertices, mesh.face_sizes, mesh.face_indices)
        start = 0
        for size in mesh.face_sizes:
            polygon = mesh.face_indices[start : start + size]
            start += size
            assert newell_area(mesh.vertices[polygon]) > 0
        # areas add up polygon by polygon: no fan across a reflex corner
        total = sum(
            newell_area(mesh.vertices[mesh.face_indices[s : s + n]])
            for s, n in zip(np.concatenate([[0], np.cumsum(mesh.face_sizes)[:-1]]), mesh.face_sizes)
        )
        assert triangle_areas(mesh.vertices, tri).sum() == pytest.approx(total, rel=1e-9)


def cubes_written_separately(cells, alternate_diagonals=False):
    """Unit cubes at integer cells, each written whole as a triangle soup; every square split
    along the diagonal from its smallest corner, so that where two cubes touch both write the
    same two triangles (as exporters that write each body on its own do). With
    ``alternate_diagonals`` every second cube splits its squares along the other diagonal."""
    triangles = []
    for k, c in enumerate(cells):
        corners = np.array(np.meshgrid(*[[x, x + 1] for x in c], indexing="ij")).reshape(3, -1).T.astype(float)
        for axis in range(3):
            for side in (c[axis], c[axis] + 1):
                square = corners[corners[:, axis] == side]
                square = square[np.lexsort(square.T[::-1])]  # smallest corner first, largest last
                if alternate_diagonals and k % 2:
                    triangles += [[square[1], square[0], square[2]], [square[1], square[3], square[2]]]
                else:
                    triangles += [[square[0], square[1], square[3]], [square[0], square[2], square[3]]]
    triangles = np.array(triangles)
    return triangles.reshape(-1, 3), np.arange(3 * len(triangles)).reshape(-1, 3)


def voxel_surface(cells):
    """Outward triangles of a union of unit cubes (integer cells), built face by face."""
    cells = set(map(tuple, cells))
    corners, triangles = {}, []

    def corner(p):
        return corners.setdefault(p, len(corners))

    for c in cells:
        for axis in range(3):
            for step in (-1, 1):
                n = list(c)
                n[axis] += step
                if tuple(n) in cells:
                    continue
                # the square between c and its empty neighbour, wound to face the neighbour
                u, w = [(axis + 1) % 3, (axis + 2) % 3]
                base = list(c)
                base[axis] += 1 if step > 0 else 0
                quad = []
                for du, dw in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    p = list(base)
                    p[u] += du
                    p[w] += dw
                    quad.append(corner(tuple(p)))
                if step < 0:
                    quad.reverse()
                triangles += [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
    vertices = np.zeros((len(corners), 3))
    for p, k in corners.items():
        vertices[k] = p
    return vertices, np.array(triangles)


class TestCleaning:
    def cube_soup(self):
        """A unit cube as an STL-style soup: 36 corners, one per triangle corner."""
        c = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T.astype(float)
        f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                      [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])  # fmt: skip
        return c[f].reshape(-1, 3), np.arange(36).reshape(-1, 3)

    def test_duplicate_points_are_merged(self):
        v, f = self.cube_soup()
        v2, f2 = merge_vertices(v, f)
        assert len(v2) == 8 and len(f2) == 12
        assert orient_shells(f2).closed.all()

    def test_points_within_rounding_are_merged(self):
        v, f = self.cube_soup()
        v = v + np.random.default_rng(0).normal(scale=1e-13, size=v.shape)
        assert len(merge_vertices(v, f)[0]) == 8

    def test_degenerate_and_duplicate_faces_are_dropped(self):
        v, f = merge_vertices(*self.cube_soup())
        faces = np.vstack([f, [[0, 0, 1]], f[:1], f[1:2, ::-1]])  # repeated corner, duplicate, reversed duplicate
        kept, degenerate, duplicate, flat, wall = remove_bad_faces(v, faces)
        assert (len(kept), degenerate, duplicate, flat, wall) == (12, 1, 2, 0, 0)
        np.testing.assert_array_equal(kept, f)

    def test_a_sliver_closing_a_t_junction_is_kept(self):
        # a square split as a fan from its centre (4 triangles), except that one side is
        # split at its midpoint m: the triangle on that side becomes two, and a zero-area
        # sliver (a, m, b) written below joins the long edge a-b of a second square glued
        # on. Dropping the sliver would leave a-m, m-b and a-b each with one triangle.
        v = np.array([[0, 0, 0], [2, 0, 0], [1, 0, 0], [1, 1, 0], [1, -1, 0]], float)  # a, b, m, top, bottom
        top = [[0, 2, 3], [2, 1, 3]]  # above the split edge
        bottom = [[1, 0, 4]]  # below the whole edge a-b
        sliver = [[0, 1, 2]]  # a, b, m: zero area, joins a-b with a-m and m-b
        faces = np.array(top + bottom + sliver)
        kept, degenerate, duplicate, flat, wall = remove_bad_faces(v, faces)
        assert (len(kept), degenerate, flat, wall) == (4, 0, 1, 0)
        u, w = kept.ravel(), kept[:, [1, 2, 0]].ravel()
        undirected = {tuple(sorted(e)) for e in zip(u, w)}
        counts = {e: sum(1 for x in zip(u, w) if tuple(sorted(x)) == e) for e in undirected}
        assert counts[(0, 1)] == 2 and counts[(0, 2)] == 2 and counts[(1, 2)] == 2

    @pytest.mark.parametrize("alternate_diagonals", [False, True], ids=["same-split", "other-split"])
    def test_walls_between_bodies_written_separately_are_dropped(self, alternate_diagonals):
        # three unit cubes in a row, each written whole (as KiCad's older libraries write a
        # capacitor's two caps and its body): the two faces where they touch are written twice
        # each, once per cube; the solid is the 3 x 1 x 1 box. The middle cube may split its
        # squares along the other diagonal, so that the touching faces share no triangle
        cells = [(0, 0, 0), (1, 0, 0), (2, 0, 0)]
        v, f = merge_vertices(*cubes_written_separately(cells, alternate_diagonals))
        kept, degenerate, duplicate, flat, wall = remove_bad_faces(v, f)
        assert (len(kept), degenerate, duplicate, wall) == (28, 0, 0, 8)
        # what is left is the box's surface: area 2 (3 + 3 + 1), every triangle on its boundary
        assert triangle_areas(v, kept).sum() == pytest.approx(14.0)
        on_boundary = (v[kept] == 0).all(axis=1) | (v[kept] == [3, 1, 1]).all(axis=1)
        assert on_boundary.any(axis=1).all()
        shells = orient_shells(kept)
        assert shells.count == 1 and shells.closed.all()
        from shapeidx.io.base import PolygonMesh
        from shapeidx.signing.solid import make_solid

        solid = make_solid(PolygonMesh.from_triangles(*cubes_written_separately(cells, alternate_diagonals), "test"))
        assert solid.watertight and solid.volume == pytest.approx(3.0)
        assert solid.describe()["solid"]["walls_removed"] == 8 and not solid.warnings

    def test_faces_written_twice_that_are_no_wall_keep_one_copy(self):
        v, f = merge_vertices(*self.cube_soup())
        # a side written twice inside one closed body: dropping it would open a hole
        kept, _, duplicate, _, wall = remove_bad_faces(v, np.vstack([f, f[:2]]))
        assert (len(kept), duplicate, wall) == (12, 2, 0)
        # a whole body written twice: nothing would be left of it
        kept, _, duplicate, _, wall = remove_bad_faces(v, np.vstack([f, f[:, ::-1]]))
        assert (len(kept), duplicate, wall) == (12, 12, 0)
        # a zero-thickness sheet written once per side
        sheet = np.array([[0, 1, 2], [1, 3, 2]])
        kept, _, duplicate, _, wall = remove_bad_faces(v, np.vstack([sheet, sheet[:, ::-1]]))
        assert (len(kept), duplicate, wall) == (2, 2, 0)
        # a wall written three times: an odd count does not cancel in a union
        vv, ff = merge_vertices(*cubes_written_separately([(0, 0, 0), (1, 0, 0)]))
        shared = [t for t in ff if np.all(vv[t][:, 0] == 1)]
        kept, _, duplicate, _, wall = remove_bad_faces(vv, np.vstack([ff, shared[:2]]))
        assert (wall, duplicate, len(kept)) == (0, 4, 22)

    def test_random_flips_are_made_consistent(self):
        v, f = merge_vertices(*self.cube_soup())
        rng = np.random.default_rng(1)
        flipped = np.where(rng.random(12)[:, None] < 0.5, f[:, ::-1], f)
        shells = orient_shells(flipped)
        assert shells.count == 1 and shells.closed.all()
        # consistent: every edge is used once in each direction
        edges = {tuple(e) for t in shells.faces for e in zip(t, np.roll(t, -1))}
        assert all((b, a) in edges for a, b in edges)

    def test_surface_pinched_along_an_edge_is_closed(self):
        # two cubes touching only along a vertical edge, joined through a slab above: the
        # edge has four faces, the surface still encloses a volume
        cells = [(0, 0, 0), (1, 1, 0), (0, 0, 1), (1, 0, 1), (0, 1, 1), (1, 1, 1)]
        v, f = voxel_surface(cells)
        shells = orient_shells(f)
        assert shells.count == 1 and shells.closed.all()
        from shapeidx.io.base import PolygonMesh
        from shapeidx.signing.solid import make_solid

        solid = make_solid(PolygonMesh.from_triangles(v, f[:, ::-1], "test"))  # wound inward on purpose
        assert solid.watertight and solid.volume == pytest.approx(6.0)

    def test_open_and_separate_shells(self):
        v, f = merge_vertices(*self.cube_soup())
        two = np.vstack([f, f[:-2] + len(v)])
        shells = orient_shells(two)
        assert shells.count == 2
        assert sorted(shells.closed.tolist()) == [False, True]


def test_the_fast_reductions_give_numpys_very_bits():
    """column_min / column_max, cross3 and shell_bounds (faster roads of the cleaning) against
    numpy's own reductions, bit for bit: signed zeros, NaN, ties, one row, many shells."""
    from shapeidx.io.base import column_max, column_min
    from shapeidx.signing.mesh import cross3
    from shapeidx.signing.solid import shell_bounds

    rng = np.random.default_rng(11)
    values = np.array([0.0, -0.0, 1.5, -2.0, 3.0, np.nan])
    for p in ([0.3, 0.3, 0.1, 0.1, 0.2, 0.0], [0.0, 0.0, 0.3, 0.3, 0.4, 0.0], [0.2, 0.2, 0.2, 0.2, 0.1, 0.1]):
        for rows in (1, 7, 5000):
            points = rng.choice(values, size=(rows, 3), p=p)
            assert column_min(points).tobytes() == points.min(axis=0).tobytes()
            assert column_max(points).tobytes() == points.max(axis=0).tobytes()
            a, b = rng.normal(size=(rows, 3)) * points, rng.normal(size=(rows, 3))
            assert cross3(a, b).tobytes() == np.cross(a, b).tobytes()
            faces = rng.integers(0, rows, size=(3 * rows, 3))
            shell = rng.integers(0, 9, size=3 * rows)
            lo, hi = shell_bounds(points, faces, shell, 10)
            c = points[faces]
            ref_lo, ref_hi = np.full((10, 3), np.inf), np.full((10, 3), -np.inf)
            np.minimum.at(ref_lo, shell, c.min(axis=1))
            np.maximum.at(ref_hi, shell, c.max(axis=1))
            assert lo.tobytes() == ref_lo.tobytes() and hi.tobytes() == ref_hi.tobytes()
