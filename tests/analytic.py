"""Exact solids for tests: an independent answer to "what are this part's class fractions?".

Each solid is built from primitives with boolean operations, once as an exact description
(a signed distance function, negative inside, and area-uniform sampling of its exact surface)
and once as a triangle mesh through manifold3d. The reference classification samples the
exact surface and classifies each segment by evaluating the signed distance at many points
along it. It shares nothing with shapeidx's classification: no mesh, no normals, no rays.
"""

from __future__ import annotations

from dataclasses import dataclass

import manifold3d as mf
import numpy as np

SEGMENTS = 128  # circle tessellation of the meshes


# ------------------------------------------------------------------------------------
# primitives: sdf(points) and sample(count, rng) on the exact surface


@dataclass
class Box:
    lo: tuple
    hi: tuple

    def sdf(self, x):
        lo, hi = np.asarray(self.lo, float), np.asarray(self.hi, float)
        return np.max(np.maximum(lo - x, x - hi), axis=-1)

    @property
    def area(self):
        d = np.subtract(self.hi, self.lo)
        return 2 * (d[0] * d[1] + d[1] * d[2] + d[0] * d[2])

    def sample(self, count, rng):
        lo, hi = np.asarray(self.lo, float), np.asarray(self.hi, float)
        d = hi - lo
        face_area = np.array([d[1] * d[2], d[0] * d[2], d[0] * d[1]]).repeat(2)
        face = rng.choice(6, size=count, p=face_area / face_area.sum())
        p = lo + rng.random((count, 3)) * d
        axis, high = face // 2, face % 2 == 1
        p[np.arange(count), axis] = np.where(high, hi[axis], lo[axis])
        return p

    def mesh(self):
        lo = np.asarray(self.lo, float)
        return mf.Manifold.cube(tuple(np.subtract(self.hi, self.lo))).translate(tuple(lo))


@dataclass
class Cylinder:
    """Axis along z through (cx, cy), from z0 to z1."""

    cx: float
    cy: float
    r: float
    z0: float
    z1: float

    def sdf(self, x):
        rho = np.hypot(x[..., 0] - self.cx, x[..., 1] - self.cy)
        return np.maximum(rho - self.r, np.maximum(self.z0 - x[..., 2], x[..., 2] - self.z1))

    @property
    def area(self):
        return 2 * np.pi * self.r * (self.z1 - self.z0) + 2 * np.pi * self.r**2

    def sample(self, count, rng):
        h = self.z1 - self.z0
        side = 2 * np.pi * self.r * h
        on_side = rng.random(count) < side / self.area
        theta = rng.random(count) * 2 * np.pi
        rad = np.where(on_side, self.r, self.r * np.sqrt(rng.random(count)))
        z = np.where(on_side, self.z0 + h * rng.random(count), np.where(rng.random(count) < 0.5, self.z0, self.z1))
        return np.stack([self.cx + rad * np.cos(theta), self.cy + rad * np.sin(theta), z], axis=1)

    def mesh(self):
        return mf.Manifold.cylinder(self.z1 - self.z0, self.r, self.r, SEGMENTS).translate((self.cx, self.cy, self.z0))


@dataclass
class Sphere:
    c: tuple
    r: float

    def sdf(self, x):
        return np.linalg.norm(x - np.asarray(self.c, float), axis=-1) - self.r

    @property
    def area(self):
        return 4 * np.pi * self.r**2

    def sample(self, count, rng):
        v = rng.normal(size=(count, 3))
        return np.asarray(self.c, float) + self.r * v / np.linalg.norm(v, axis=1, keepdims=True)

    def mesh(self):
        return mf.Manifold.sphere(self.r, SEGMENTS).translate(tuple(self.c))


@dataclass
class Torus:
    """Around the z axis through the origin."""

    R: float
    r: float

    def sdf(self, x):
        rho = np.hypot(x[..., 0], x[..., 1])
        return np.hypot(rho - self.R, x[..., 2]) - self.r

    @property
    def area(self):
        return 4 * np.pi**2 * self.R * self.r

    def sample(self, count, rng):
        out = np.empty((0, 3))
        while len(out) < count:  # area element is proportional to R + r cos(phi)
            phi = rng.random(4 * count) * 2 * np.pi
            keep = rng.random(4 * count) * (self.R + self.r) < self.R + self.r * np.cos(phi)
            phi = phi[keep]
            theta = rng.random(len(phi)) * 2 * np.pi
            rho = self.R + self.r * np.cos(phi)
            out = np.concatenate([out, np.stack([rho * np.cos(theta), rho * np.sin(theta), self.r * np.sin(phi)], 1)])
        return out[:count]

    def mesh(self):
        circle = mf.CrossSection.circle(self.r, SEGMENTS // 2).translate((self.R, 0))
        return mf.Manifold.revolve(circle, SEGMENTS)


# ------------------------------------------------------------------------------------
# booleans


@dataclass
class Union:
    parts: list

    def sdf(self, x):
        return np.min([p.sdf(x) for p in self.parts], axis=0)

    @property
    def area(self):  # area of the children's surfaces (an upper bound of the union's)
        return sum(p.area for p in self.parts)

    def sample(self, count, rng):
        return _sample_boundary(self, count, rng)

    def raw_sample(self, count, rng):
        return _raw_children(self.parts, count, rng)

    def on_boundary(self, x, tol):
        return np.abs(self.sdf(x)) <= tol

    def mesh(self):
        return mf.Manifold.batch_boolean([p.mesh() for p in self.parts], mf.OpType.Add)


@dataclass
class Difference:
    base: object
    holes: list

    def sdf(self, x):
        return np.max([self.base.sdf(x)] + [-h.sdf(x) for h in self.holes], axis=0)

    @property
    def area(self):
        return self.base.area + sum(h.area for h in self.holes)

    def sample(self, count, rng):
        return _sample_boundary(self, count, rng)

    def raw_sample(self, count, rng):
        return _raw_children([self.base] + list(self.holes), count, rng)

    def on_boundary(self, x, tol):
        return np.abs(self.sdf(x)) <= tol

    def mesh(self):
        return mf.Manifold.batch_boolean([self.base.mesh()] + [h.mesh() for h in self.holes], mf.OpType.Subtract)


def _raw_children(parts, count, rng):
    areas = np.array([p.area for p in parts])
    counts = rng.multinomial(count, areas / areas.sum())
    return np.concatenate([p.sample(n, rng) for p, n in zip(parts, counts)])


def _sample_boundary(solid, count, rng):
    """Uniform points on a boolean's boundary: uniform on all children's surfaces, keep those
    on the result's boundary (|sdf| ~ 0), shuffle, take ``count``."""
    tol = 1e-9 * extent(solid)
    out = np.empty((0, 3))
    while len(out) < count:
        raw = solid.raw_sample(4 * count, rng)
        out = np.concatenate([out, raw[solid.on_boundary(raw, tol)]])
    return out[rng.permutation(len(out))[:count]]


def extent(solid) -> float:
    """Bounding-box diagonal of the solid's mesh."""
    lo, hi = np.array(solid.mesh().bounding_box()).reshape(2, 3)
    return float(np.linalg.norm(hi - lo))


# ------------------------------------------------------------------------------------
# the reference classification


def reference_fractions(solid, points=1024, pairs=25_000, steps=500, seed=7):
    """Class fractions (in, out, mixed) of the exact solid, by brute force.

    ``points`` exact surface samples; ``pairs`` random pairs of them; each segment is IN when
    the signed distance is <= tol at every one of ``steps`` interior points, OUT when no
    point farther than 0.1% of the size from both ends is in the closed solid, MIXED
    otherwise. (The margin keeps an OUT segment's first steps, still within rounding of the
    surface, from counting as inside; a wider margin turns MIXED segments that clip material
    near an end into OUT ones.)
    """
    rng = np.random.default_rng(seed)
    p = solid.sample(points, rng)
    i = rng.integers(0, points, pairs)
    j = rng.integers(0, points, pairs)
    keep = i != j
    i, j = i[keep], j[keep]
    size = extent(solid)
    tol, margin = 1e-9 * size, 0.001 * size
    t = (np.arange(steps) + 0.5) / steps
    classes = np.empty(len(i), dtype=np.uint8)
    for start in range(0, len(i), 5000):
        a, b = p[i[start : start + 5000]], p[j[start : start + 5000]]
        along = a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]
        inside = solid.sdf(along) <= tol
        length = np.linalg.norm(b - a, axis=1)[:, None]
        away = (t[None, :] * length >= margin) & ((1 - t[None, :]) * length >= margin)
        all_in = inside.all(axis=1)
        none_in = ~(inside & away).any(axis=1)
        classes[start : start + 5000] = np.where(all_in, 0, np.where(none_in, 1, 2))
    return np.bincount(classes, minlength=3) / len(classes)


# ------------------------------------------------------------------------------------
# the solids the tests use


def catalogue() -> dict:
    """Name -> exact solid, the shapes named in issue 2."""
    return {
        "box": Box((0, 0, 0), (2, 3, 4)),
        "cylinder": Cylinder(0, 0, 1, 0, 3),
        "tube": Difference(Cylinder(0, 0, 1, 0, 3), [Cylinder(0, 0, 0.5, -1, 4)]),
        "torus": Torus(2, 0.5),
        "plate_with_holes": Difference(
            Box((0, 0, 0), (6, 4, 0.5)),
            [Cylinder(1.5, 2, 0.6, -1, 1), Cylinder(3, 2, 0.6, -1, 1), Cylinder(4.5, 2, 0.6, -1, 1)],
        ),
        # a box minus a box: no coincident faces, so exact sampling stays uniform
        "l_bracket": Difference(Box((0, 0, 0), (4, 3, 3)), [Box((-1, 1, 1), (5, 4, 4))]),
        "hollow_box": Difference(Box((0, 0, 0), (3, 3, 3)), [Box((0.7, 0.7, 0.7), (2.3, 2.3, 2.3))]),
        "two_blocks": Union([Box((0, 0, 0), (1, 1, 1)), Box((2, 0, 0), (3, 1, 1))]),
        "pin_in_block": Union([Box((0, 0, 0), (3, 3, 1)), Cylinder(1.5, 1.5, 0.4, 0.5, 2.5)]),
        "drilled_block": Difference(
            Box((0, 0, 0), (4, 3, 2)),
            [
                Cylinder(1, 1.5, 0.4, -1, 3),  # through hole
                Cylinder(3, 0.8, 0.3, 1, 3),  # blind hole from the top
                Sphere((2.6, 2.0, 1.0), 0.5),  # closed cavities
                Box((1.8, 0.5, 0.4), (2.4, 1.2, 0.9)),
            ],
        ),
    }


def mesh_arrays(solid):
    """(vertices, faces) of the solid's manifold3d mesh."""
    return manifold_arrays(solid.mesh())


def manifold_arrays(manifold):
    """(vertices, faces) of a manifold3d Manifold."""
    m = manifold.to_mesh64()
    return np.asarray(m.vert_properties[:, :3], float), np.asarray(m.tri_verts, np.int64)


def separate_shells(parts):
    """(vertices, faces) of several solids put side by side in one mesh, not united."""
    vertices, faces, offset = [], [], 0
    for part in parts:
        v, f = manifold_arrays(part.mesh())
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces)


def write_stl(path, vertices, faces) -> None:
    """Binary STL, written here so that tests do not depend on another library's writer."""
    tri = vertices[faces].astype("<f4")
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    record = np.zeros(len(faces), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    record["n"], record["v"] = normals, tri
    with open(path, "wb") as f:
        f.write(b"shapeidx test solid".ljust(80, b" "))
        f.write(np.uint32(len(faces)).tobytes())
        f.write(record.tobytes())


def write_obj(path, vertices, faces) -> None:
    """Wavefront OBJ with full float64 precision (STL would round to float32)."""
    with open(path, "w") as f:
        f.write("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in vertices.tolist()))
        f.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces.tolist()))


def random_rotation(rng) -> np.ndarray:
    """A uniformly random proper rotation matrix."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q
