"""The whole store at once: the paper's first task (categories, clusters) and duplicates.

    table.py       the ok entries laid out for pair work: exact distances of chosen pairs
    candidates.py  the approximate step: fixed-length embeddings searched with FAISS
    chirality.py   size, principal radii, handedness and moments of a surface (build time)
    labels.py      labels of entries: folders or a CSV
    scale.py       --scale invariant | sensitive
    classify.py    distance-weighted k-NN vote            (shapeidx classify)
    cluster.py     Ward on the exact matrix, or the graph (shapeidx cluster)
    duplicates.py  identical / same / near tiers           (shapeidx duplicates)
    agreement.py   NMI and ARI; scores.py: the figures of shapeidx evaluate
"""
