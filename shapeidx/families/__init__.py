"""The whole store at once: the paper's first task (categories, clusters) and duplicates.

(``--scale invariant | sensitive`` is :mod:`shapeidx.distance.scale`: query uses it too; the
candidate step, FAISS over fixed-length embeddings, is :mod:`shapeidx.store.candidates`.)

    table.py       the ok entries laid out for pair work: exact distances of chosen pairs
    labels.py      labels of entries: folders or a CSV
    classify.py    distance-weighted k-NN vote            (shapeidx classify)
    cluster.py     Ward on the exact matrix, or the graph (shapeidx cluster)
    duplicates.py  identical / same / near tiers           (shapeidx duplicates)
    checkin.py     is a new part already in the store?    (shapeidx check-new)
    cluster_plot.py  a picture of the clusters             (shapeidx cluster --plot)
    agreement.py   NMI and ARI; scores.py: the figures of shapeidx evaluate
"""
