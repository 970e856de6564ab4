"""shapeidx: find CAD parts that look alike, by their IN/OUT/MIXED D2 shape distributions.

The data flows one way::

    file --io.load--> PolygonMesh --mesh.make_solid--> Solid
         --sampling.sample_surface--> points --classify.classify_pairs--> distances, classes
         --signature.Signature.from_pairs--> Signature --store--> HDF5

and a query runs the same road, then ranks the store with :mod:`shapeidx.distance`.
"""

__version__ = "0.1.0"
