"""Searching a store: the one road every query takes (CLI, Python API, web page, sheets, classify).

    searcher.py   Searcher: resolve the query (file, stdin, entry, signature), sign it with the
                  store's parameters, build one keep-mask, rank, return hits (Filters, Query)
    where.py      --where: metadata conditions (KEY=VALUE, KEY>=N, KEY~GLOB) and their keep-mask
    distances.py  the distances from a query to the store's entries: the one place they are
                  computed (lower bounds, exact distances, the candidate step)
    hits.py       Hit and Answer: the same fields on every surface
    same_part.py  --same-part: the hits ordered with the gap of the exact measures (size in any
                  unit, proportions, area) added to the metric's distance
    blocks.py     the block bounds a long-lived process (serve, a held Searcher) prunes with
    sharded.py    a sharded store: every shard's exact top k (here or on Dask workers), merged
    where_used.py the files holding a sub-part like a given one, nearest first

Names load on first use.
"""

from .._lazy import attach

_NAMES = {
    **dict.fromkeys(["Searcher", "Filters", "Query", "check_usable"], ".searcher"),
    **dict.fromkeys(["Condition", "parse_where", "parse_condition"], ".where"),
    **dict.fromkeys(["Hit", "Answer"], ".hits"),
    **dict.fromkeys(["ShardedSearcher", "open_searcher"], ".sharded"),
    **dict.fromkeys(["distances", "nearest", "entry_features"], ".distances"),
}
__all__ = sorted(_NAMES)
__getattr__, __dir__ = attach(__name__, _NAMES)
