"""The signature's pair work as it was before it was made faster (session 4, issue 13).

A frozen copy, so that tests/test_signing_unchanged.py can show on real parts that the
faster code gives the same classes, histograms and angle counts, bit for bit. Do not
"improve" this file: it is the reference.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import pdist

from shapeidx.signing.angles import ANGLE_BINS
from shapeidx.signing.classify import OFFSET, TANGENT, _orient_by_winding, normalise, pair_flat_indices, pair_indices
from shapeidx.signing.histogram import Histogram
from shapeidx.signing.mesh import unit_normals
from shapeidx.signing.occlusion import OcclusionScene
from shapeidx.signing.parameters import BIN_DIVISOR, CLASS_NAMES, IN, MIXED, OUT


def classify_pairs(vertices, faces, points, face_index, watertight):
    """Distances, classes and the samples' normals, as classify.classify_pairs computed them."""
    vertices, points, scale = normalise(np.asarray(vertices, float), np.asarray(points, float))
    normals = unit_normals(vertices, faces[face_index])
    scene = OcclusionScene(vertices, faces)
    if not watertight:
        normals = _orient_by_winding(points, normals, vertices, faces)
    m = len(points)
    first, second = pair_indices(m)
    upper, lower = pair_flat_indices(m)
    distance = pdist(points)
    p32, n32 = points.astype(np.float32), normals.astype(np.float32)
    rise = np.multiply.outer(p32[:, 0], n32[:, 0])
    rise += np.multiply.outer(p32[:, 1], n32[:, 1])
    rise += np.multiply.outer(p32[:, 2], n32[:, 2])
    rise -= np.einsum("ij,ij->i", p32, n32)[None, :]
    rise = rise.ravel()
    threshold = (TANGENT * distance).astype(np.float32)
    leaves_second = rise[upper] > threshold
    leaves_first = rise[lower] > threshold
    classes = np.full(len(distance), MIXED, dtype=np.uint8)
    agree = np.flatnonzero(leaves_first == leaves_second)
    outward = leaves_first[agree]
    shifted = np.concatenate([points - OFFSET * normals, points + OFFSET * normals]).astype(np.float32)
    row_shift = m * outward
    clear = ~scene.blocked_between(shifted, first[agree] + row_shift, second[agree] + row_shift)
    classes[agree[clear]] = np.where(outward[clear], OUT, IN)
    return distance / scale, classes, normals


def angle_histograms(normals, classes):
    n = np.asarray(normals, dtype=np.float64)
    upper, _ = pair_flat_indices(len(n))
    cos = (n @ n.T).ravel()[upper]
    np.clip(cos, -1.0, 1.0, out=cos)
    bins = np.minimum((np.arccos(cos) * (ANGLE_BINS / np.pi)).astype(np.int64), ANGLE_BINS - 1)
    per_class = np.bincount(np.asarray(classes, dtype=np.int64) * ANGLE_BINS + bins, minlength=len(CLASS_NAMES) * ANGLE_BINS)
    per_class = per_class[: len(CLASS_NAMES) * ANGLE_BINS].reshape(len(CLASS_NAMES), ANGLE_BINS)
    return np.vstack([per_class.sum(axis=0), per_class]).astype(np.int64)


def histograms(distances, classes, divisor=BIN_DIVISOR):
    """{name: Histogram}, as Signature.from_pairs built them."""
    out = {"all": Histogram.of(distances, divisor)}
    n_classes = len(CLASS_NAMES)
    sizes = np.bincount(classes, minlength=n_classes)
    means = np.bincount(classes, weights=distances, minlength=n_classes) / np.maximum(sizes, 1)
    widths = means / divisor
    bins = (distances / np.where(widths > 0, widths, 1.0)[classes]).astype(np.int64)
    stride = int(bins.max()) + 1 if len(bins) else 1
    key = classes.astype(np.int64) * stride + bins
    table = np.bincount(key, minlength=n_classes * stride).reshape(n_classes, stride)
    for code, name in enumerate(CLASS_NAMES):
        used = np.flatnonzero(table[code])
        counts = table[code, : used[-1] + 1] if len(used) else np.zeros(0, dtype=np.int64)
        out[name] = Histogram(counts, float(means[code]), float(widths[code]))
    return out
