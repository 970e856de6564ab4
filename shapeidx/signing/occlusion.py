"""The ray-query backend: "is this segment blocked by the surface?" for many segments at once.

The classification rule (:mod:`shapeidx.signing.classify`) needs one question answered,
in bulk: does the open segment between two points cross any triangle? This module answers
it with Embree, one occlusion ray per segment, in two ways that give the same answers:

* :class:`NativeScene`, what every signature uses: the compiled pair pass of
  :mod:`shapeidx.signing._pairs`, which opens the Embree library that embreex loaded, lets
  it read the triangles in place and asks it about the pairs in packets of 16 while it
  classifies them (:func:`shapeidx.signing.classify.classify_pairs` says how);
* :class:`OcclusionScene`, through the ``embreex`` binding: where the extension is not
  built, or ``SHAPEIDX_NATIVE=0``, and as the floor that benchmarks measure against.

Another backend (a GPU ray tracer, say) would provide the same methods.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np


class OcclusionScene:
    """An Embree scene of triangles that answers "is this segment blocked?" for many segments."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        from embreex import mesh_construction, rtcore_scene

        self._scene = rtcore_scene.EmbreeScene(embree_device())
        self._mesh = mesh_construction.TriangleMesh(
            self._scene,
            np.ascontiguousarray(vertices, dtype=np.float32),
            np.ascontiguousarray(faces, dtype=np.int32),
        )

    def blocked(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """True where the segment from ``starts[k]`` to ``ends[k]`` meets a triangle."""
        if len(starts) == 0:
            return np.zeros(0, dtype=bool)
        starts = np.ascontiguousarray(starts, dtype=np.float32)
        directions = np.subtract(ends, starts, dtype=np.float32)
        reach = np.ones(len(starts), dtype=np.float32)  # direction is the whole segment
        return self._scene.run(starts, directions, dists=reach, query="OCCLUDED") != -1

    def blocked_between(self, points: np.ndarray, start_rows: np.ndarray, end_rows: np.ndarray, threads: int = 1):
        """:meth:`blocked` for segments ``points[start_rows[k]] -> points[end_rows[k]]``.

        With ``threads > 1`` the segments are split into that many chunks, gathered and
        queried concurrently (embreex releases the GIL; Embree queries are thread-safe).
        """
        def query(rows):  # np.take gathers rows about twice as fast as fancy indexing
            return self.blocked(np.take(points, start_rows[rows], axis=0), np.take(points, end_rows[rows], axis=0))

        if threads <= 1 or len(start_rows) < 10_000:
            return query(slice(None))
        self.blocked(points[:1], points[1:2])  # commit the scene once, before the threads race to
        chunks = [slice(c[0], c[-1] + 1) for c in np.array_split(np.arange(len(start_rows)), threads) if len(c)]
        return np.concatenate(list(thread_pool(threads).map(query, chunks)))


@lru_cache(maxsize=1)
def embree_device():
    """One Embree device per process: starting a device costs milliseconds, a scene does not."""
    from embreex import rtcore

    return rtcore.EmbreeDevice()


@lru_cache(maxsize=2)
def thread_pool(threads: int):
    """The process's pool of ``threads`` threads for Embree queries (kept: one per thread count)."""
    from concurrent.futures import ThreadPoolExecutor

    return ThreadPoolExecutor(max_workers=threads, thread_name_prefix="shapeidx-embree")


#: Embree's RTC_SCENE_FLAG_ROBUST.
ROBUST = 1 << 2


@lru_cache(maxsize=1)
def compiled_pairs():
    """The compiled pair passes (:mod:`shapeidx.signing._pairs`), or None.

    None when the extension was not built or ``SHAPEIDX_NATIVE=0`` asks for the numpy
    path (which gives the same results: tests/test_compiled_pairs.py).
    """
    import os

    if os.environ.get("SHAPEIDX_NATIVE", "1") == "0":
        return None
    try:
        from . import _pairs
    except ImportError:
        return None
    return _pairs


@lru_cache(maxsize=1)
def native_pairs():
    """:func:`compiled_pairs` with Embree opened for its scenes, or None (also when the
    library embreex loaded cannot be found in this process)."""
    compiled = compiled_pairs()
    library = _embree_library() if compiled is not None else None
    if library is None:
        return None
    try:
        compiled.open_embree(library, "")
    except (ImportError, RuntimeError):
        return None
    return compiled


def _embree_library() -> str | None:
    """The path of the libembree4 that embreex loaded into this process (Linux: /proc/self/maps)."""
    try:
        import embreex.rtcore  # noqa: F401 (loads the library)
    except ImportError:
        return None
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                path = line.rstrip("\n").split(maxsplit=5)[-1]
                if "libembree4" in path.rsplit("/", 1)[-1]:
                    return path
    except OSError:
        pass
    return None


class NativeScene:
    """The same questions as :class:`OcclusionScene`, from the compiled pass: Embree reads
    the triangles in place, and the pair pass runs in one loop (``classify``)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        native = native_pairs()
        # one float of padding after the last vertex: Embree reads vertices 16 bytes at a time
        self._vertices = np.zeros(3 * len(vertices) + 1, dtype=np.float32)
        self._vertices[:-1] = np.asarray(vertices, dtype=np.float32).ravel()
        self._faces = np.ascontiguousarray(faces, dtype=np.uint32)
        # embreex's scenes are robust (no ray slips between two triangles): so are these, for
        # the same answers on grazing rays
        self._scene = native.Scene(self._vertices, len(vertices), self._faces, len(self._faces), ROBUST)

    def blocked(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """True where the segment from ``starts[k]`` to ``ends[k]`` meets a triangle."""
        starts = np.ascontiguousarray(starts, dtype=np.float32)
        directions = np.ascontiguousarray(np.subtract(ends, starts, dtype=np.float32))
        hit = np.zeros(len(starts), dtype=bool)
        self._scene.blocked(starts, directions, hit.view(np.uint8))
        return hit

    def classify(self, *args):
        """Rows of the pair pass, written into the caller's arrays (see ``_pairs.c``)."""
        self._scene.classify(*args)
