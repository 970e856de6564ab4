"""Headless shaded thumbnails of parts: primary rays cast with Embree, no display, no GPU.

The view is fixed so that every thumbnail is comparable with every other:

* **view direction** :data:`VIEW`: the camera sits on the +x +y +z diagonal and looks at the
  part's centre (an isometric view; +z points up in the picture);
* **orthographic** projection: sizes along the picture are true to the part, so a flat
  face seen edge-on vanishes and parallel edges stay parallel;
* **framing**: the part's projected outline is centred and its longer side spans
  ``1 - 2 * margin`` of the frame, whatever the part's size;
* **lighting**: a key light from the upper left of the camera and a weaker fill light from
  its lower right, plus ambient; faces are lit from whichever side faces the camera (many
  exported parts are not consistently oriented), so the same face of two parts gets the same
  shade;
* **background**: transparent (alpha 0), shown white by anything that displays the PNG.

Anti-aliasing by supersampling: ``supersample**2`` rays per pixel, averaged.
"""

from __future__ import annotations

import io

import numpy as np

#: The camera looks along -VIEW: from the +x +y +z diagonal towards the part.
VIEW = np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0)
#: What points up in the picture (projected onto the image plane).
UP = np.array([0.0, 0.0, 1.0])
#: Lights in camera coordinates (right, up, towards the camera), and their strengths.
KEY_LIGHT = np.array([-0.45, 0.65, 0.62])
FILL_LIGHT = np.array([0.55, -0.35, 0.76])
KEY, FILL, AMBIENT = 0.62, 0.25, 0.22
#: The part's colour (RGB, 0-1): a light steel blue that shading keeps readable.
COLOUR = np.array([0.70, 0.79, 0.92])
DEFAULT_SIZE = 256
DEFAULT_MARGIN = 0.05
#: Raised whenever a picture of the same part would change (view, lights, colour, framing).
RENDER_VERSION = 1


def camera_axes(view: np.ndarray = VIEW, up: np.ndarray = UP) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit vectors (right, up, towards camera) of the image plane for a view direction."""
    back = np.asarray(view, float) / np.linalg.norm(view)
    up = np.asarray(up, float)
    if abs(np.dot(up, back)) > 0.999:  # looking straight along the up vector: pick another
        up = np.array([0.0, 1.0, 0.0])
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    return right, np.cross(back, right), back


def render_rgba(
    vertices: np.ndarray,
    faces: np.ndarray,
    size: int = DEFAULT_SIZE,
    margin: float = DEFAULT_MARGIN,
    view: np.ndarray = VIEW,
    supersample: int = 2,
) -> np.ndarray:
    """A shaded picture of a triangle mesh, as an RGBA image.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (k, 3) int
    size : pixels of the square picture's side
    margin : empty border on each side, as a fraction of ``size``
    view : direction from the part towards the camera (default :data:`VIEW`)
    supersample : rays per pixel along each axis

    Returns
    -------
    (size, size, 4) uint8
        Row 0 is the top of the picture; alpha 0 where no ray meets the part.
    """
    from embreex import mesh_construction, rtcore_scene

    from ..signing.occlusion import embree_device

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    picture = np.zeros((size, size, 4), dtype=np.uint8)
    if len(faces) == 0 or len(vertices) == 0:
        return picture
    right, up, back = camera_axes(view)
    in_use = np.zeros(len(vertices), dtype=bool)
    in_use[faces.ravel()] = True  # frame what is drawn, not stray points
    used = vertices[in_use]
    u, v, w = used @ right, used @ up, used @ back
    centre_u, centre_v = (u.min() + u.max()) / 2, (v.min() + v.max()) / 2
    span = max(u.max() - u.min(), v.max() - v.min())
    if not np.isfinite(span) or span <= 0:
        return picture
    n = size * supersample
    pixel = span / ((1 - 2 * margin) * n)  # model units per sample
    # Embree works in float32: centre the part so that large coordinates keep their precision
    centre = used.mean(axis=0)
    offsets = (np.arange(n) + 0.5 - n / 2) * pixel  # sample centres across the frame
    grid_u = np.broadcast_to(centre_u - centre @ right + offsets, (n, n))
    grid_v = np.broadcast_to((centre_v - centre @ up - offsets)[:, None], (n, n))  # row 0 at the top
    depth = w.max() - centre @ back + span  # start the rays in front of the part
    origins = np.empty((n * n, 3), dtype=np.float32)
    for k in range(3):
        origins[:, k] = (grid_u * right[k] + grid_v * up[k] + depth * back[k]).reshape(-1)
    directions = np.empty_like(origins)
    directions[:] = -back

    scene = rtcore_scene.EmbreeScene(embree_device())
    mesh_construction.TriangleMesh(
        scene, np.ascontiguousarray(vertices - centre, dtype=np.float32), np.ascontiguousarray(faces, dtype=np.int32)
    )
    # Rays end behind the part. Embree's packet queries have been seen to report hits far
    # beyond any triangle for rays parallel to edge-on faces: only hits within reach count.
    reach = (w.max() - w.min()) + span  # from the start to the far side of the part
    limit = np.full(n * n, reach * 1.01, dtype=np.float32)
    result = scene.run(origins, directions, dists=limit, output=1)
    distance = np.asarray(result["tfar"]).reshape(-1)
    hit = (np.asarray(result["primID"]).reshape(-1) >= 0) & (distance <= reach * 1.01)

    light = np.zeros(n * n, dtype=np.float32)
    if hit.any():
        normals = np.asarray(result["Ng"], dtype=np.float64).reshape(-1, 3)[hit]
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
        # two-sided: the side facing the camera is the one we see
        camera = normals @ np.stack([right, up, back], axis=1)
        camera *= np.where(camera[:, 2:3] < 0, -1.0, 1.0)
        key = np.clip(camera @ (KEY_LIGHT / np.linalg.norm(KEY_LIGHT)), 0, None)
        fill = np.clip(camera @ (FILL_LIGHT / np.linalg.norm(FILL_LIGHT)), 0, None)
        light[hit] = AMBIENT + KEY * key + FILL * fill
    # average each pixel's samples; the light over the samples that hit (premultiplied)
    s = supersample
    light = light.reshape(size, s, size, s).sum(axis=3).sum(axis=1)
    alpha = hit.reshape(size, s, size, s).sum(axis=3, dtype=np.int32).sum(axis=1)
    colour = np.clip((light / np.maximum(alpha, 1))[..., None] * COLOUR, 0, 1)
    picture[..., :3] = np.rint(colour * 255).astype(np.uint8)
    picture[..., 3] = np.rint(alpha / (s * s) * 255).astype(np.uint8)
    picture[picture[..., 3] == 0, :3] = 255  # white under transparent: looks right anywhere
    return picture


def png_bytes(picture: np.ndarray) -> bytes:
    """An RGBA (or RGB) uint8 image as PNG file bytes."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(picture).save(buffer, format="PNG", optimize=False, compress_level=6)
    return buffer.getvalue()


def render_solid_png(solid, size: int = DEFAULT_SIZE) -> bytes:
    """The PNG thumbnail of a :class:`~shapeidx.signing.solid.Solid` (or anything with vertices and faces)."""
    return png_bytes(render_rgba(solid.vertices, solid.faces, size))


def render_file_png(path, size: int = DEFAULT_SIZE) -> bytes:
    """The PNG thumbnail of a part file (raises :class:`~shapeidx.errors.LoadError`)."""
    from ..signing.part import load_part

    return render_solid_png(load_part(path), size)


def render_sub_part_png(path, number: int, size: int = DEFAULT_SIZE, count: int | None = None,
                        title: str | None = None) -> bytes:
    """The PNG thumbnail of sub-part ``number`` (``FILE#number`` of ``build --parts``) of a
    part file, drawn in its own frame (the frame it is signed in).

    ``count`` and ``title``: what the store says of the sub-part; a file that splits
    otherwise now (changed rules: :data:`~shapeidx.io.parts.PARTS_VERSION`) is refused
    rather than drawn as another sub-part. A file that is one part is its own ``FILE#1``.
    Raises :class:`~shapeidx.errors.LoadError`.
    """
    from ..errors import LoadError
    from ..io.parts import split_parts
    from ..signing.solid import make_solid

    parts = split_parts(path)
    if parts is None and number == 1:
        return render_file_png(path, size)
    if parts is None or not 1 <= number <= len(parts):
        raise LoadError(path, f"has no sub-part #{number} now (the split changed since the build: build --parts again)")
    part = parts[number - 1]
    if (count is not None and part.count != count) or (title and part.name and part.name != title):
        raise LoadError(path, f"splits otherwise than when sub-part #{number} was signed (build --parts again)")
    return render_solid_png(make_solid(part.mesh, path), size)
