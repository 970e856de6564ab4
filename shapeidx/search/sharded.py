"""Searching a sharded store (:mod:`shapeidx.store.shards`): every shard's exact top k, merged.

    with open_searcher("parts.shapeidx", scheduler="tcp://10.0.0.5:8786") as searcher:
        query = searcher.query_of_part("bracket.stl")
        answer = searcher.search(query, top=5, metric="weighted")

The query is signed once, here, with the shards' parameters; its signature (a few KB) goes
to every shard, which ranks its own entries by the one search road (:class:`Searcher`:
the same filters, metrics, bounds and tie rules) and returns its ``top`` nearest, ties broken
as a store breaks them: by distance, then the query's own entry first, then by path. The
client merges the lists by the same key and keeps the first ``top``. Every hit of the global
top ``top`` is among its shard's top ``top`` under that one total order, so the merged answer
is exactly that of one store holding every entry: the same hits in the same order, with the
same distances (tests/test_shards.py compares them on a real Dask cluster).

Without a scheduler the shards are ranked here, one after the other. With one
(``--scheduler``), shard ``k`` is ranked on the cluster's worker ``k mod W`` (workers sorted
by address), which keeps the shard open between queries, so a long-lived cluster answers
from mapped, resident arrays; the shard's store must be visible to that worker at the same
path. The query's own entry (``--id``, or a file of the tree) is looked up in the one shard
its path key names.

With ``parts=True`` (a store built with ``--shards N --parts``) each shard's sub-parts store
is ranked the same way, and where-used (:meth:`ShardedSearcher.where_used`) asks every shard
for its top files and merges them: a file and its sub-parts share the file's path key, so
they live in one shard, and each file's nearest sub-part and count are its shard's.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..distance.metrics import default_metric
from ..errors import StoreError
from ..store.shards import shard_of_paths
from .hits import NO_HIT, Answer, Hit, absolute
from .same_part import SAME_PART_CANDIDATES, measures_of_solid, same_part_scores
from .searcher import Filters, Query, Searcher, beyond_reason, empty_store_reason, entry_path_in, label_of, sign_part
from .where_used import DEFAULT_METRIC as WHERE_USED_METRIC, SAME_SIZE


def open_searcher(store, scheduler: str | None = None, parts: bool = False):
    """A :class:`Searcher` of an ordinary store, a :class:`ShardedSearcher` of a sharded one
    (``scheduler``: ranked on that Dask cluster's workers); ``parts``: ranking the sub-entries
    (``build --parts``). ``scheduler`` with an ordinary store is refused in one line, and so is
    a sub-parts store ``OWNER/parts`` asked for files (its owner answers with ``parts``)."""
    from ..store.files import owner_of_parts
    from ..store.shards import is_sharded

    owner = None if parts else owner_of_parts(store)
    if owner is not None:  # its hits would read as whole files, without their file and count
        raise StoreError(f"the store {store} is the sub-parts store of {owner}: give --store {owner} --parts")
    if is_sharded(store):
        return ShardedSearcher(store, scheduler, parts=parts)
    if scheduler:
        raise StoreError(f"{store} is not a sharded store: --scheduler queries a store built with --shards")
    return Searcher(store, parts=parts)


#: Per process (a Dask worker's, or this one's): the shards kept open, by path, with what their
#: files were when opened (a build's commit since then opens the shard again).
_OPEN: dict = {}


def _state(path: str):
    from ..store.files import main_file, read_committed

    try:
        main = main_file(Path(path)).stat()
        return read_committed(Path(path)), main.st_ino, main.st_mtime_ns
    except OSError:
        return None


def held_searcher(path: str) -> Searcher:
    """The shard at ``path`` as this process holds it open (opened again after a commit)."""
    return _searcher(path)


def _searcher(path: str) -> Searcher:
    state = _state(path)
    held = _OPEN.get(path)
    if held is not None and held[1] == state and state is not None:
        return held[0]
    if held is not None:
        held[0].close()
        del _OPEN[path]
    searcher = Searcher(path)
    _OPEN[path] = (searcher, state)
    return searcher


def close_shards() -> None:
    """Close every shard this process holds open."""
    while _OPEN:
        _OPEN.popitem()[1][0].close()


def shard_info(path: str) -> dict:
    """A shard's parameters, root and ok entries (run where the shard is)."""
    searcher = _searcher(path)
    return {"params": searcher.params, "root": searcher.root, "entries": len(searcher), "rows": len(searcher.paths),
            "metadata_keys": searcher.metadata_keys()}


def shard_facts(path: str, entry: str) -> dict | None:
    """What a page shows of ``entry`` (run where its shard is): ok or not, the reason, its
    metadata and class fractions; None when the shard has no such entry."""
    searcher = _searcher(path)
    found = searcher.view.find(entry)
    if found is None:
        return None
    position = searcher.view.position_of(found)
    if position is None:
        return {"ok": False, "reason": searcher.view.status_of(found)[1], "metadata": {}, "fractions": None}
    return {"ok": True, "reason": "", "metadata": searcher.metadata_at(position),
            "fractions": searcher.view.gather("fractions", np.array([position]))[0]}


def shard_listing(path: str) -> dict:
    """Every entry of the shard, failed ones too: path, ok, reason, triangles, fractions."""
    from ..store import STATUS_OK

    reader = _searcher(path).reader
    return {"paths": np.asarray(reader.paths), "ok": reader.column("entries/status") == STATUS_OK,
            "reasons": reader.column("entries/reason"), "triangles": reader.column("entries/triangles"),
            "fractions": reader.column("entries/fractions")}


def warm_shard(path: str) -> None:
    """Build the shard's block index where it is, if it is big enough to want one."""
    from .blocks import WARM_MIN

    searcher = _searcher(path)
    if len(searcher) >= WARM_MIN:
        searcher.warm()


def shard_build_state(path: str) -> dict | None:
    """The shard's last build's record (:func:`shapeidx.store.lock.read_build_state`)."""
    from ..store.lock import read_build_state

    return read_build_state(Path(path))


def shard_entry(path: str, entry: str) -> tuple:
    """The stored signature and exact measures of ``entry`` in the shard (StoreError as
    :meth:`Searcher.query_of_entry`)."""
    searcher = _searcher(path)
    query = searcher.query_of_entry(entry)
    return query.signature, searcher.query_measures(query)


def shard_entry_paths(path: str) -> list:
    """The paths of the shard's ranked entries."""
    return _searcher(path).entry_paths()


def shard_question(path: str, entry: str) -> tuple:
    """Where-used's question for ``entry`` in the shard whose sub-parts are at ``path``: its
    signature, the entry it is (a sub-entry wins its ties), whether that is a sub-entry, its
    exact measures."""
    parts = _searcher(path)
    query = parts.question_of_entry(entry, _searcher(str(Path(path).parent)))
    return query.signature, query.entry, query.own is not None, parts.query_measures(query)


def where_used_shard(path: str, signature, entry: str | None, measures, top: int, metric: str,
                     max_distance: float | None, scale: str, same_size: float | None):
    """The shard's where-used answer (run where the shard is; ``path``: its sub-parts;
    ``measures``: the query's exact measures, for the same-size test in every shard)."""
    searcher = _searcher(path)
    query = replace(_shard_query(searcher, signature, entry), measures=measures)
    return searcher.where_used(query, top, metric, max_distance, scale, same_size)


def _shard_query(searcher: Searcher, signature, entry: str | None) -> Query:
    """The query as the shard asks it: ``entry``'s own position when the shard holds it."""
    found = searcher.view.find(entry) if entry is not None else None
    own = searcher.view.position_of(found) if found is not None else None
    return Query(entry or "", signature, own, entry if own is not None else None)


def shard_sub_part(path: str, entry: str) -> dict | None:
    """:meth:`Searcher.sub_part_of` in the shard whose sub-parts are at ``path``."""
    return _searcher(path).sub_part_of(entry)


def search_shard(path: str, signature, entry: str | None, top: int, metric: str, filters: Filters,
                 among=None, among_reason: str = "", measures=None) -> dict:
    """The shard's exact top ``top`` (run where the shard is): each hit as (distance, not the
    query's own entry, relative path, metadata, its file and count when it is a sub-entry, its
    exact-measure gap), in the store's order; the counts; why none (``why``: its kind, one of
    :data:`~shapeidx.search.hits.NO_HIT`, and ``reason``: its words). With the same-part order
    (``measures``: the query's exact measures) the shard's top :data:`SAME_PART_CANDIDATES` and
    its nearest distances, for the merge to order them with the scale of the whole store."""
    import time

    started = time.perf_counter()
    searcher = _searcher(path)
    query = replace(_shard_query(searcher, signature, entry), measures=measures)
    own = query.own
    asked = max(top, SAME_PART_CANDIDATES) if filters.same_part else top
    answer = searcher.search(query, asked, metric, filters, among=among, among_reason=among_reason)
    return {"hits": [(hit.distance, hit.relative_path != query.entry, hit.relative_path, hit.metadata, hit.parent,
                      hit.count, hit.shape_gap) for hit in answer.hits],
            "considered": answer.considered, "entries": answer.entries, "why": answer.why, "reason": answer.reason,
            "nearest": answer.nearest, "nearest_distances": answer.nearest_distances, "own": own is not None,
            "seconds": time.perf_counter() - started}


class ShardedSearcher:
    """A sharded store opened to answer queries; the query interface of :class:`Searcher`."""

    def __init__(self, store, scheduler: str | None = None, parts: bool = False):
        from ..store.reader import member_stores

        self.store = Path(store)
        #: Whether this searcher ranks the sub-entries of each shard (``build --parts``).
        self.parts = parts
        self.shards = [str(p.resolve()) for p in member_stores(self.store, parts)]
        self.scheduler = scheduler
        self.client = None
        self._workers: list = []
        if scheduler:
            from ..index.dask_pool import dask_client

            self.client = dask_client(scheduler)
            self._workers = sorted(self.client.scheduler_info()["workers"])
        infos = self._each(shard_info, [(path,) for path in self.shards])
        self.params, self.root = infos[0]["params"], infos[0]["root"]
        for path, info in zip(self.shards, infos):
            if info["params"] != self.params or info["root"] != self.root:
                raise StoreError(f"shard {path} was built with other parameters or another root than {self.shards[0]}")
        self.entries = sum(info["entries"] for info in infos)
        self.rows = sum(info["rows"] for info in infos)  # failed entries too
        self._metadata_keys = tuple(dict.fromkeys(k for info in infos for k in info["metadata_keys"]))

    def __len__(self) -> int:
        return self.entries

    def _each(self, function, arguments: list, shards=None) -> list:
        """``function(*arguments[i])`` for each shard ``shards[i]`` (default all), where the shard is."""
        shards = range(len(self.shards)) if shards is None else shards
        if self.client is None:
            return [function(*args) for args in arguments]
        futures = [self.client.submit(function, *args, pure=False,
                                      workers=[self._workers[k % len(self._workers)]] if self._workers else None,
                                      allow_other_workers=True)
                   for k, args in zip(shards, arguments)]
        return self.client.gather(futures)

    def close(self) -> None:
        if self.client is None:
            close_shards()
        else:
            self.client.close(timeout=5)
            self.client = None

    def __enter__(self) -> "ShardedSearcher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def shard_of(self, entry: str) -> int:
        """The shard that holds ``entry`` (a sub-entry ``FILE#n`` lives in its file's)."""
        if self.parts and "#" in entry:
            entry = entry.rsplit("#", 1)[0]
        return int(shard_of_paths([entry], len(self.shards))[0])

    def metadata_keys(self) -> tuple:
        return self._metadata_keys

    def warm(self) -> None:
        """Each big shard's block index, built where the shard is (as :meth:`Searcher.warm`)."""
        self._each(warm_shard, [(path,) for path in self.shards])

    def entry_facts(self, entry: str) -> dict | None:
        """:func:`shard_facts` of ``entry`` from the shard its path key names."""
        return self.on_shard(self.shard_of(entry), shard_facts, entry)

    def listing(self) -> dict:
        """Every shard's :func:`shard_listing`, in one list sorted by path."""
        parts = self._each(shard_listing, [(path,) for path in self.shards])
        joined = {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}
        order = np.argsort(joined["paths"], kind="stable")
        return {key: values[order] for key, values in joined.items()}

    def present_metadata_keys(self) -> tuple:
        if self.client is not None:
            return ()
        keys = []
        for path in self.shards:
            keys += [k for k in _searcher(path).present_metadata_keys() if k not in keys]
        return tuple(keys)

    def entry_path_of(self, file) -> str | None:
        return entry_path_in(self.root, file)

    def resolve_entry(self, entry) -> str:
        """``entry`` as the store names it: a path relative to the root is taken as it is; a file
        inside the root (absolute, or relative to here) becomes its path relative to the root."""
        text = os.fspath(entry)
        inside = self.entry_path_of(text) if os.path.exists(text) else None
        return inside if inside is not None else text

    def query_of_entry(self, entry) -> Query:
        name = self.resolve_entry(entry)
        k = self.shard_of(name)
        signature, measures = self._each(shard_entry, [(self.shards[k], name)], [k])[0]
        return Query(os.fspath(entry), signature, None, name, measures=measures)

    def query_measures(self, query: Query):
        """The query's exact measures: given (an entry's, from its shard) or of its loaded part;
        a file of the tree, from the shard that holds it (None: unknown)."""
        if query.measures is not None:
            return query.measures
        if query.solid is not None:
            return measures_of_solid(query.solid)
        if query.entry is not None:
            return self.on_shard(self.shard_of(query.entry), shard_entry, query.entry)[1]
        return None

    def signature_of(self, entry: str):
        """The stored signature of the entry named ``entry`` (its path relative to the root)."""
        return self.query_of_entry(entry).signature

    def entry_paths(self) -> list:
        """The paths of every shard's ranked entries, sorted."""
        return sorted(p for paths in self._each(shard_entry_paths, [(path,) for path in self.shards]) for p in paths)

    def question_of_entry(self, entry, files=None) -> Query:
        """Where-used's question for an entry (:meth:`Searcher.question_of_entry`), made in the
        shard that holds its file, with its exact measures for every shard (``files``: unused,
        each shard asks its own whole-file store, where it is)."""
        name = self.resolve_entry(entry)
        signature, asked, sub_entry, measures = self.on_shard(self.shard_of(name), shard_question, name)
        # labelled as one store's question is: a sub-entry by its name, a whole file as given
        return Query(asked if sub_entry else os.fspath(entry), signature, None, asked, measures=measures)

    def where_used(self, query: Query, top: int = 10, metric: str = WHERE_USED_METRIC,
                   max_distance: float | None = None, scale: str = "sensitive", same_size: float | None = SAME_SIZE,
                   threads: int | None = None):
        """Every shard's :meth:`Searcher.where_used`, merged: a file and its sub-parts live in one
        shard, so the top ``top`` files are among the shards' top ``top`` (ties broken by path, as
        one store's answer is ordered); the parameters are :meth:`Searcher.where_used`'s."""
        from .where_used import NO_USE, WhereUsed, check_question, no_use_reason

        check_question(top, metric)
        measures = self.query_measures(query)
        answers = self._each(where_used_shard, [(path, query.signature, query.entry, measures, top, metric,
                                                 max_distance, scale, same_size) for path in self.shards])
        answer = WhereUsed(query.label, query.entry, metric, str(self.store.resolve()), self.root,
                           sum(a.sub_entries for a in answers), sum(a.files for a in answers), [], max_distance)
        answer.uses = sorted((use for a in answers for use in a.uses), key=lambda u: (u.distance, u.relative_path))[:top]
        for rank, use in enumerate(answer.uses, start=1):
            use.rank = rank
        if not answer.uses:
            # as one store says it: where-used checks in the order of NO_USE, and the whole store
            # passes a check where any shard does (as in search's merge)
            nearest = [a.nearest for a in answers if a.nearest is not None]
            answer.nearest = min(nearest) if nearest else None
            answer.why = max((a.why for a in answers if a.why is not None), key=NO_USE.index)
            answer.reason = (self.empty_reason() if answer.why == "empty"
                             else no_use_reason(max_distance, answer.nearest) if answer.why == "max_distance"
                             else next(a.reason for a in answers if a.why == answer.why))
        return answer

    def sub_part_of(self, entry: str) -> dict | None:
        """:meth:`Searcher.sub_part_of`, asked of the shard that holds the sub-entry's file."""
        return self.on_shard(self.shard_of(entry), shard_sub_part, entry) if self.parts and "#" in entry else None

    def on_shard(self, k: int, function, *arguments):
        """``function(shard k's path, *arguments)``, where shard ``k`` is."""
        return self._each(function, [(self.shards[k], *arguments)], [k])[0]

    def query_of_part(self, part, file_type: str | None = None, label: str | None = None,
                      threads: int | None = None, seed: int | None = None) -> Query:
        """As :meth:`Searcher.query_of_part` (its own entry looked up by the shard that holds it)."""
        signature, solid = sign_part(self.params, part, file_type, threads, seed)
        path = os.path.abspath(part) if isinstance(part, (str, os.PathLike)) else None
        # a file of the tree is its shard's own entry; never a sub-entry (those are FILE#n)
        entry = self.entry_path_of(part) if path is not None and not self.parts else None
        return Query(label_of(part, label), signature, None, entry, path, solid)

    def search(self, query: Query, top: int = 10, metric: str = default_metric("query"), filters: Filters | None = None,
               threads: int | None = None, among=None, among_reason: str = "") -> Answer:
        """Every shard's exact top ``top``, merged (see the module docstring); ``among`` and
        ``among_reason`` as :meth:`Searcher.search`'s, asked of every shard."""
        from ..distance.metrics import metric as metric_record

        metric_record(metric)
        filters = filters or Filters()
        if top < 1:
            raise ValueError(f"top must be at least 1, not {top}")
        measures = self.query_measures(query) if filters.same_part else None
        answers = self._each(search_shard, [(path, query.signature, query.entry, top, metric, filters, among,
                                             among_reason, measures) for path in self.shards])
        self.last_seconds = [a["seconds"] for a in answers]  # each shard's own time (benchmarks)
        found = [hit for answer in answers for hit in answer["hits"]]
        if filters.same_part and found:
            # ordered as one store orders them: the scale from the whole store's nearest distances
            nearest = [d for a in answers for d in (a["nearest_distances"] or ())]
            scores = same_part_scores([hit[0] for hit in found], [hit[6] or 0.0 for hit in found], nearest)
            order = sorted(range(len(found)), key=lambda k: (scores[k], found[k][1], found[k][2]))
            found = [found[k] for k in order]
        else:
            found.sort(key=lambda hit: hit[:3])
        own = any(a["own"] for a in answers)
        answer = Answer(query.label, query.path, query.entry if own else None, metric, str(self.store.resolve()),
                        self.root, [], considered=sum(a["considered"] for a in answers),
                        entries=sum(a["entries"] for a in answers), filters=filters.described(),
                        signature=query.signature)
        answer.hits = [Hit(rank, float(distance), absolute(self.root, parent or relative), relative, metadata, parent, count, gap)
                       for rank, (distance, _, relative, metadata, parent, count, gap) in enumerate(found[:top], start=1)]
        if not answer.hits:
            answer.why, answer.reason = self._no_hit(answers, filters)
        return answer

    def _no_hit(self, answers: list, filters: Filters) -> tuple[str, str]:
        """Why no shard has a hit, as one store of every entry says it: the road checks in the
        order of :data:`~shapeidx.search.hits.NO_HIT`, and the whole store passes a check where
        any shard does, so it stops at the latest check a shard stopped at."""
        why = max((a["why"] for a in answers if a["why"] is not None), key=NO_HIT.index)  # each shard says why it has none
        if why == "empty":
            return why, self.empty_reason()
        if why == "max_distance":
            nearest = [a["nearest"] for a in answers if a["nearest"] is not None]
            return why, beyond_reason(filters.max_distance, min(nearest) if nearest else None)
        # the other words name the filters only, the same in every shard
        return why, next(a["reason"] for a in answers if a["why"] == why)

    def empty_reason(self) -> str:
        """Why the store has nothing to rank (:func:`~shapeidx.search.searcher.empty_store_reason`):
        a running shard's build first, else a stopped one's."""
        states = [s for s in self._each(shard_build_state, [(path,) for path in self.shards]) if s]
        state = next((s for s in states if s.get("state") == "running"), None) or next(
            (s for s in states if s.get("state") in ("stopped", "interrupted")), None)
        return empty_store_reason(self.store, self.rows, state, sharded=True)
