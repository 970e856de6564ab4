"""shapeidx: find CAD parts that look alike, by their IN/OUT/MIXED D2 shape distributions.

Ip, Lapadat, Sieger & Regli, "Using Shape Distributions to Compare Solid Models" (ACM Solid
Modeling 2002). The data flows one way, a package per stage::

    io/          file -> PolygonMesh               (a reader per format, load())
    signing/     -> Solid -> points -> classified pairs -> Signature
    distance/    Signature x Signature -> distances (the metric registry: the paper's four, ours)
    store/       Signatures of a tree -> a store directory of HDF5 files (crash-safe, journalled)
    index/       a directory tree -> the store (``shapeidx build``)
    search/      a part -> the store's nearest entries (the one road of every query)
    families/    the whole store at once: classify, cluster, duplicates
    evaluation/  a labelled collection -> retrieval figures

The public API (:mod:`shapeidx.api`)::

    import shapeidx
    part = shapeidx.load("bracket.stl")              # a clean, oriented triangle mesh
    sig = shapeidx.signature(part)                   # or a path, file object, arrays, trimesh
    shapeidx.compare("a.wrl", "b.wrl")["weighted"]   # the paper's distances, and combined
    shapeidx.query("parts.shapeidx", "bracket.stl", top=5, where=["material=steel"])  # nearest entries

Names load on first use, so ``import shapeidx`` costs almost nothing.
"""

from ._lazy import attach

__version__ = "0.1.0"

_NAMES = {
    **dict.fromkeys(["load", "signature", "compare", "open_store", "query"], ".api"),
    **dict.fromkeys(["ShapeidxError", "LoadError", "StoreError"], ".errors"),
    "Signature": ".signing.histogram",
    "Solid": ".signing.solid",
    **dict.fromkeys(["METRICS", "SIZE_METRICS"], ".distance.metrics"),
}
__all__ = sorted(_NAMES)
__getattr__, __dir__ = attach(__name__, _NAMES)
