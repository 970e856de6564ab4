"""The signature's parameters and names, importable without the machinery that computes it.

Everything that stores, reads or compares signatures (the store, the distances, the
command line) needs these names, and none of it should pay for scipy or Embree to get them.
"""

#: Surface samples per part (the paper's m = 1024: 523,776 point pairs).
DEFAULT_POINTS = 1024
#: One fixed seed for every part (the store's ``seed_policy`` is ``fixed``): the same file gives
#: the same points, on every run and machine.
DEFAULT_SEED = 20020101
#: Bin width = mean distance of the set / BIN_DIVISOR (the paper's 1/50).
BIN_DIVISOR = 50
#: Raised whenever the same file and parameters could give a different signature (changes to
#: loading, cleaning, sampling or classification) of every format. A store records it and refuses
#: a mismatch ("rebuild it"). A change to one format's reader raises that reader's revision
#: instead (:attr:`shapeidx.io.base.Format.revision`): each entry records it, and a build signs
#: again only the entries an older revision read.
SIGNATURE_VERSION = 3  # 3: stratified sampling (signing.sampling); 2: walls between touching bodies dropped

#: Codes of the pair classes, as stored in class arrays.
IN, OUT, MIXED = 0, 1, 2
CLASS_NAMES = ("in", "out", "mixed")
#: Histogram names, in the order used everywhere (store, distances, JSON).
HISTOGRAMS = ("all",) + CLASS_NAMES
