"""``shapeidx cluster --plot OUT``: a picture of the clusters (matplotlib's Agg canvas).

Which picture follows the road :func:`~shapeidx.families.cluster.cluster_store` took:

* **matrix road** (Ward on the exact distance matrix, up to
  :data:`~shapeidx.families.cluster.MATRIX_LIMIT` entries): the dendrogram, root on the left,
  leaves on the right. Up to :data:`LEAF_LIMIT` entries every entry is a leaf, labelled with
  its file name. Above, the tree is drawn down to the cut only: one leaf per cluster
  (scipy's ``truncate_mode="lastp"``), labelled with the cluster's number, its size and its
  most central member, while there are at most :data:`CLUSTER_LEAF_LIMIT` clusters; with more,
  the :data:`CLUSTER_LEAF_LIMIT` last merged groups are the leaves, labelled by their size.
  Links below the cut take their cluster's colour (neighbouring clusters always differ),
  links above it are grey, and a dashed line marks the cut.
* **graph road** (larger stores; single linkage on the neighbour graph, no tree of every
  merge to draw): a 2-D embedding, one dot per entry coloured by its cluster. The plane is
  the first two principal axes of the candidate embedding of
  :func:`~shapeidx.store.candidates.embed` (whose Euclidean distances stand in for the
  metric near zero): principal components of those vectors are classical MDS of their
  distances, computed from a (dim, dim) covariance, so 10^6 entries cost seconds. The
  :data:`LABELLED_CLUSTERS` largest clusters carry their number at their median point.

The format follows the suffix of OUT: .png (150 dpi), .svg (text stays text) or .pdf.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

#: Up to this many entries the dendrogram shows (and names) every entry.
LEAF_LIMIT = 60
#: Above :data:`LEAF_LIMIT`, one leaf per cluster while there are at most this many.
CLUSTER_LEAF_LIMIT = 80
#: Clusters named by their number in the embedding picture (the largest).
LABELLED_CLUSTERS = 12
#: Dark enough for text on white, distinct side by side (matplotlib's tab10 without its grey).
PALETTE = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22")
GREY = "#9a9a9a"
#: Longest leaf label (characters; longer names keep their start, the part's family, and their
#: end, where KiCad names differ; the middle gives way).
LABEL_CHARS = 44


def plot_clusters(result: dict, table, output: str | os.PathLike, metric: str) -> str:
    """Write the picture of a :func:`~shapeidx.families.cluster.cluster_store` ``result``.

    Parameters
    ----------
    result : dict
        ``cluster_store``'s answer for ``table``; with a ``tree`` (the matrix road) the
        dendrogram is drawn, without one the embedding.
    table : FamilyTable
        The entries that were clustered (the embedding picture embeds them).
    output : path
        .png, .svg or .pdf (:func:`shapeidx.pictures.plot.check_format`).
    metric : str
        The distance the clusters were made with (titles, and the embedding's weights).

    Returns
    -------
    str
        What was drawn, in words ("dendrogram of 520 entries, one leaf per cluster", ...).
    """
    from ..pictures.plot import check_format

    output = check_format(output)
    if result.get("tree") is not None:
        fig, what = dendrogram_figure(result, metric)
    else:
        fig, what = embedding_figure(result, table, metric)
    _save(fig, output)
    return what


def cut_height(tree: np.ndarray, count: int) -> float:
    """A height between the merges that leave ``count`` clusters and the next (Ward's heights rise)."""
    n = len(tree) + 1
    heights = tree[:, 2]
    merged = n - count  # merges below the cut
    if merged <= 0:
        return float(heights[0]) / 2
    if merged >= n - 1:
        return float(heights[-1]) * 1.02
    return float(heights[merged - 1] + heights[merged]) / 2


def _leaf_representative(tree: np.ndarray) -> np.ndarray:
    """For every node of the tree (leaves, then merges), one entry below it."""
    n = len(tree) + 1
    rep = np.concatenate([np.arange(n), np.zeros(n - 1, dtype=np.int64)])
    for j, left in enumerate(tree[:, 0].astype(np.int64)):
        rep[n + j] = rep[left]
    return rep


def _clusters_below(tree: np.ndarray, cut: float) -> np.ndarray:
    """For every node of the tree, how many clusters of the cut at ``cut`` lie below it."""
    n = len(tree) + 1
    count = np.ones(2 * n - 1, dtype=np.int64)
    for j, (left, right, height, _) in enumerate(tree):
        count[n + j] = count[int(left)] + count[int(right)] if height >= cut else 1
    return count


def _short(path: str) -> str:
    name = Path(path).name
    from ..io.formats import PART_SUFFIXES

    for suffix in (".gz",) + PART_SUFFIXES:
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
    if len(name) <= LABEL_CHARS:
        return name
    head = (LABEL_CHARS - 3) // 2
    return name[:head] + "..." + name[-(LABEL_CHARS - 3 - head):]


def dendrogram_figure(result: dict, metric: str):
    """(Figure, words) of the Ward tree in ``result`` (see the module docstring)."""
    from scipy.cluster.hierarchy import dendrogram

    tree = np.asarray(result["tree"], dtype=np.float64)
    labels = np.asarray(result["clusters"])
    paths = [str(p) for p in result["paths"]]
    n, count = len(labels), int(result["count"])
    cut = cut_height(tree, count)
    rep = _leaf_representative(tree)
    medoid = {}
    for i in np.argsort(np.asarray(result["distances"]), kind="stable"):
        medoid.setdefault(int(labels[i]), i)
    sizes = np.bincount(labels)
    if n <= LEAF_LIMIT:
        mode, leaves, what = None, n, f"dendrogram of {n} entries, every entry a leaf"
    elif count <= CLUSTER_LEAF_LIMIT:
        mode, leaves, what = "lastp", count, f"dendrogram of {n} entries cut at {count} clusters, one leaf per cluster"
    else:
        mode, leaves, what = "lastp", CLUSTER_LEAF_LIMIT, (
            f"dendrogram of {n} entries down to {CLUSTER_LEAF_LIMIT} groups of its {count} clusters")
    # a first pass for the leaf order: colours go by position, so that neighbours differ
    shape = dendrogram(tree, truncate_mode=mode, p=leaves, no_plot=True, count_sort=False)
    clusters_in = _clusters_below(tree, cut)
    colour_of = {}
    for leaf in shape["leaves"]:
        # Ward's heights rise: each cluster is one subtree below the cut; a leaf that is a
        # group of several clusters takes no cluster's colour
        if clusters_in[leaf] == 1:
            colour_of.setdefault(int(labels[rep[leaf]]), PALETTE[len(colour_of) % len(PALETTE)])

    def link_colour(node: int) -> str:
        height = tree[node - n, 2]
        return colour_of.get(int(labels[rep[node]]), GREY) if height < cut else GREY

    def leaf_label(node: int) -> str:
        c = int(labels[rep[node]])
        if node < n and mode is None:
            return _short(paths[node])
        if node < n:
            return f"{c}: 1 part, {_short(paths[node])}"
        members = int(tree[node - n, 3])
        if clusters_in[node] == 1:  # a whole cluster
            return f"{c}: {members} parts, {_short(paths[medoid[c]])}"
        return f"{members} parts in {clusters_in[node]} clusters"

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    height = min(max(3.0, 0.19 * leaves + 1.3), 40.0)
    fig = Figure(figsize=(10.5, height))
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.04, 0.9 / height, 0.5, 1 - 1.5 / height))
    drawn = dendrogram(tree, truncate_mode=mode, p=leaves, orientation="left", count_sort=False,
                       link_color_func=link_colour, leaf_label_func=leaf_label, leaf_font_size=7.5,
                       above_threshold_color=GREY, ax=ax)
    for tick, leaf in zip(ax.get_yticklabels(), drawn["leaves"]):
        tick.set_color(colour_of.get(int(labels[rep[leaf]]), "#333333") if clusters_in[leaf] == 1 else "#333333")
    ax.axvline(cut, color="#444444", linestyle="--", linewidth=0.8)
    ax.annotate(f"cut {cut:.3g}", (cut, 0), xytext=(2, 2), textcoords="offset points", fontsize=7, color="#444444",
                xycoords=("data", "axes fraction"))
    # Ward's last merges are far higher than the ones near the cut: linear up to the cut, then
    # logarithmic, so that the merges just above the cut stay apart
    ax.set_xscale("symlog", linthresh=max(cut, 1e-12), linscale=0.6)
    ax.invert_xaxis() if not ax.xaxis_inverted() else None
    ax.yaxis.tick_right()
    ax.tick_params(axis="x", labelsize=7)
    for side in ("top", "left", "right"):
        ax.spines[side].set_visible(False)
    ax.set_xlabel(f"Ward merge height ({metric} distance and moments; linear to the dashed cut, then logarithmic)", fontsize=8)
    sizes_note = f"largest {sizes.max()}, {int((sizes[1:] == 1).sum())} of one entry"
    fig.suptitle(f"{n} entries in {count} clusters (Ward on the exact {metric} distances; {sizes_note})",
                 fontsize=9.5, y=1 - 0.25 / height)
    return fig, what


def embedding_figure(result: dict, table, metric: str):
    """(Figure, words) of the entries on the first two principal axes of their embedding."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..store.candidates import embed

    labels = np.asarray(result["clusters"])
    n, count = len(labels), int(result["count"])
    xy, share = principal_plane(embed(table, metric))
    fig = Figure(figsize=(9.0, 8.0))
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.08, 0.07, 0.88, 0.84))
    colours = np.array(PALETTE)[(labels - 1) % len(PALETTE)]
    dot = float(np.clip(4000.0 / max(n, 1), 1.0, 12.0))
    # the largest clusters last, so that they are not hidden under the many small ones
    order = np.argsort(-labels, kind="stable")
    ax.scatter(xy[order, 0], xy[order, 1], s=dot, c=colours[order], linewidths=0, alpha=0.8, rasterized=True)
    sizes = np.bincount(labels)
    for c in range(1, min(count, LABELLED_CLUSTERS) + 1):
        at = np.median(xy[labels == c], axis=0)
        ax.annotate(f"{c} ({sizes[c]})", at, fontsize=8, fontweight="bold", ha="center", va="center",
                    color=PALETTE[(c - 1) % len(PALETTE)],
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.75})
    ax.set_xlabel(f"first principal axis of the {metric} embedding ({100 * share[0]:.0f}% of its variance)", fontsize=8)
    ax.set_ylabel(f"second principal axis ({100 * share[1]:.0f}%)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.2)
    entries = "1 entry" if n == 1 else f"{n} entries"
    clusters = "1 cluster" if count == 1 else f"{count} clusters"
    how = f"single linkage on the {metric} neighbour graph" if result.get("road") == "graph" else metric
    ax.set_title(f"{entries} in {clusters} ({how}); numbered: the {min(count, LABELLED_CLUSTERS)} largest (their sizes)",
                 fontsize=9)
    return fig, f"embedding of {entries} in {clusters} on two principal axes"


def principal_plane(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) coordinates on the two first principal axes, and their shares of the variance."""
    x = np.asarray(vectors, dtype=np.float64)
    if x.shape[1] < 2:  # a one-dimensional embedding: its second axis is zero
        x = np.concatenate([x, np.zeros((len(x), 2 - x.shape[1]))], axis=1)
    x = x - x.mean(axis=0)
    covariance = x.T @ x / max(len(x) - 1, 1)
    values, axes = np.linalg.eigh(covariance)
    top = np.argsort(values)[::-1][:2]
    axes, values = axes[:, top], values[top]
    total = float(np.clip(np.trace(covariance), 1e-300, None))
    xy = x @ axes
    # a sign per axis so that the picture does not flip between runs of LAPACK
    xy *= np.where(np.abs(xy.max(axis=0)) >= np.abs(xy.min(axis=0)), 1.0, -1.0)
    return xy, values / total


def _save(fig, output: Path) -> None:
    from matplotlib import rc_context

    from ..errors import ShapeidxError
    from ..pictures.plot import stable_metadata

    try:
        with rc_context({"svg.fonttype": "none", "svg.hashsalt": "shapeidx"}):
            fig.savefig(output, dpi=150, format=output.suffix.lower()[1:], metadata=stable_metadata(output))
    except OSError as exc:
        raise ShapeidxError(f"{output}: cannot write the figure ({exc.strerror or exc})") from None
