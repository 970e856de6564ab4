"""The one road of a query: resolve it, sign it with the store's parameters, build one
keep-mask, rank, return hits.

    with Searcher("parts.shapeidx") as searcher:
        query = searcher.query_of_part("bracket.stl")           # or query_of_entry("a/b.wrl")
        answer = searcher.search(query, top=5, metric="weighted",
                                 filters=Filters(where=parse_where(["material=steel"])))
        for hit in answer.hits:
            print(hit.rank, hit.distance, hit.path, hit.metadata)

The command line (``query``, ``classify``), the Python API (``shapeidx.query``), the web
page (``serve``) and result sheets all go through :class:`Searcher`, so that the same
question gets the same hits, distances and fields on every surface. A one-off command opens
a searcher for one question; a long-lived process (``serve``, a Python session) keeps it
open, and the arrays it gathers stay in memory between questions.

The keep-mask is every filter at once: ``--where`` metadata conditions, ``--scale
sensitive`` (the size band), ``--exclude-self``; ``--max-distance`` bounds the distances.
Filtered hits are exact: the same as ranking only the entries the filters keep.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..distance.metrics import default_metric
from ..errors import StoreError
from ..io.metadata import FILE_KEYS
from .distances import RANK_THREADS, nearest
from .hits import Answer, Hit, absolute
from .same_part import SAME_PART_CANDIDATES, SAME_PART_RANK, measures_of_solid, same_part_scores, shape_gap, shape_measures
from .where import Condition, keep_mask, parse_where
from .where_used import DEFAULT_METRIC as WHERE_USED_METRIC, SAME_SIZE


@dataclass(frozen=True)
class Filters:
    """What narrows or orders an answer besides ``top``.

    Attributes
    ----------
    exclude_self : bool
        Leave out the query's own entry (a part of the store's tree, or ``--id``).
    max_distance : float or None
        Leave out hits farther than this.
    scale : str
        ``"invariant"`` (the paper's) or ``"sensitive"``: leave out entries whose size differs
        from the query's by more than :data:`shapeidx.distance.scale.SIZE_BAND`.
    where : tuple of Condition (or their texts)
        Metadata conditions (:mod:`shapeidx.search.where`), all of which must hold.
    same_part : bool
        Order the hits for the same-part question: the metric's distance with the gap of the
        exact measures (size modulo a unit, proportions, area) added (:mod:`shapeidx.search.same_part`).
    """

    exclude_self: bool = False
    max_distance: float | None = None
    scale: str = "invariant"
    where: tuple = field(default_factory=tuple)
    same_part: bool = False

    def conditions(self) -> tuple:
        return tuple(c if isinstance(c, Condition) else parse_where([c])[0] for c in self.where)

    def described(self) -> list[str]:
        """The filters as a user gave them (``--where material=steel``, ...)."""
        out = [f"--where {c}" for c in self.conditions()]
        if self.scale != "invariant":
            out.append(f"--scale {self.scale}")
        if self.exclude_self:
            out.append("--exclude-self")
        if self.max_distance is not None:
            out.append(f"--max-distance {self.max_distance:g}")
        if self.same_part:
            out.append("--same-part")
        return out


@dataclass
class Query:
    """A query resolved and signed with the store's parameters.

    Attributes
    ----------
    label : str
        As the user gave it.
    signature : Signature
    own : int or None
        Position of the query's own entry among the store's ranked entries (it wins its ties).
    entry : str or None
        That entry's path relative to the store's root.
    path : str or None
        The query's file, absolute (None for standard input, arrays, entries).
    solid : Solid or None
        The part as loaded (when it was signed here), for its picture.
    measures : ndarray or None
        Its exact measures (:func:`shapeidx.search.same_part.shape_measures`: size, proportions,
        area, handedness), when known without ``solid`` or an entry of its own (a sharded
        store's question, a multi-part file asked where it is used, an upload whose part is let
        go): the same-part order and where-used's same-size test read them.
    """

    label: str
    signature: object
    own: int | None = None
    entry: str | None = None
    path: str | None = None
    solid: object = None
    measures: object = None


def entry_path_in(root, file) -> str | None:
    """The path of ``file`` relative to a store's ``root`` ('/'-separated), or None when it
    lies outside it (or there is no root).

    Tried as written (made absolute), with its folders' links followed but not its own, and
    wholly resolved, in that order: a build indexes a link to a file under the link's own
    path (a library tree of links, ``--follow-outside-links``), where resolving the link would
    leave the root.
    """
    if not root:
        return None
    try:
        named = Path(os.path.abspath(file))
        ways = (named, named.parent.resolve() / named.name, named.resolve())
    except (OSError, RuntimeError):
        return None
    for way in ways:
        try:
            return way.relative_to(root).as_posix()
        except ValueError:
            continue
    return None


#: What every searcher of a store offers (:class:`Searcher`, and
#: :class:`~shapeidx.search.sharded.ShardedSearcher` for a sharded store, both opened by
#: :func:`~shapeidx.search.sharded.open_searcher`): the methods the query road's surfaces call
#: (query, where-used, serve, check-new, classify, plot, sheets), with the same parameters, and
#: the attributes beside them. ``where_used`` and ``question_of_entry`` ask a searcher opened
#: with ``parts=True``.
QUERY_INTERFACE = ("search", "query_of_part", "query_of_entry", "query_measures", "entry_path_of", "resolve_entry", "signature_of",
                   "entry_paths", "metadata_keys", "present_metadata_keys", "warm", "close", "__enter__", "__exit__",
                   "where_used", "question_of_entry")
QUERY_ATTRIBUTES = ("store", "root", "params")


def sign_part(params, part, file_type: str | None = None, threads: int | None = None, seed: int | None = None):
    """``(signature, solid)`` of a part signed with a store's parameters ``params`` (faceted as
    the store's; ``seed``: its points drawn with this seed instead); a Signature is taken as it
    is when made with the store's points and seed (solid None)."""
    from ..signing.histogram import Signature

    if isinstance(part, Signature):
        if (part.points, part.seed) != (params.points, params.seed):
            raise StoreError(f"the signature was made with {part.points} points and seed {part.seed};"
                             f" the store's are {params.points} and {params.seed}")
        return part, None
    from ..io import LoadLimits
    from ..signing.part import load_part
    from ..signing.pipeline import signature_of_solid

    solid = load_part(part, file_type, LoadLimits(faceting=params.faceting))
    return signature_of_solid(solid, params.points, params.seed if seed is None else seed, params.bin_divisor,
                              threads or 1), solid


def _measures_of_columns(numbers) -> np.ndarray:
    """:func:`shapeidx.search.same_part.shape_measures` of the store's columns, ``numbers(name,
    width)`` giving each for the rows wanted."""
    from ..store.layout import SHAPE_COLUMNS, handedness_columns

    return shape_measures(numbers("entries/extents", 3), numbers("entries/moments", 4),
                          handedness_columns(lambda name: numbers(name, SHAPE_COLUMNS[name])))


def label_of(part, label: str | None = None) -> str:
    """What an answer calls its query: ``label``, else the path given, else the object's name."""
    if label is not None:
        return str(label)
    if isinstance(part, (str, os.PathLike)):
        return os.fspath(part)
    return str(getattr(part, "name", None) or type(part).__name__)


class Searcher:
    """A store opened to answer queries (see the module docstring).

    Raises
    ------
    StoreError
        No store, not a store, another signature version, no ranking arrays.
    StoreDamagedError
        A file of the store (a journal segment included) fails its checks.
    """

    def __init__(self, store: str | os.PathLike, parts: bool = False):
        from ..store import open_store
        from ..store.files import owner_of_parts
        from ..store.ranked import ranked_view
        from ..store.reader import member_stores

        self.store = Path(store)
        if parts:
            owner = owner_of_parts(self.store)
            if owner is not None:  # STORE/parts given for STORE: its own sub-parts would be STORE/parts/parts
                raise StoreError(f"the store {store} is the sub-parts store of {owner}: give --store {owner}")
            self.store = member_stores(store, parts=True)[0]
        #: Whether this searcher ranks the store's sub-entries (``build --parts``) instead of its
        #: files (also when opened on the sub-parts store itself, as each shard's is).
        self.parts = parts or owner_of_parts(self.store) is not None
        self.reader = open_store(self.store)
        try:
            check_usable(self.reader)
            self.view = ranked_view(self.reader)
        except BaseException:
            self.reader.close()
            raise
        self.params = self.reader.params
        self.root = self.reader.attrs.get("root") or ""
        self._columns: dict = {}  # metadata key -> its values for every ranked entry, once read
        self._cache: dict = {}  # the metadata table's row of every entry, the keys with a value
        self._blocks = None  # the BlockIndex of a long-lived searcher (shapeidx.search.blocks)
        self._searches = 0

    def __len__(self) -> int:
        return len(self.view)

    @property
    def table(self):
        """The store's metadata table (``build --metadata``), or None; read on first use."""
        if not hasattr(self, "_table"):
            from ..store.metadata import load_table

            self._table = load_table(self.store)
        return self._table

    # -- the store's entries, as StoreReader reads them (what shapeidx.open_store documents)
    @property
    def paths(self) -> np.ndarray:
        return self.reader.paths

    @property
    def attrs(self) -> dict:
        return self.reader.attrs

    def column(self, name: str) -> np.ndarray:
        return self.reader.column(name)

    def counts(self, name: str, rows=None):
        return self.reader.counts(name, rows)

    def signature(self, index: int):
        return self.reader.signature(index)

    def close(self) -> None:
        self._blocks = None
        self.reader.close()

    def warm(self):
        """Build the block index (:mod:`shapeidx.search.blocks`) now: what a long-lived process
        (``serve``, a Python session) does once so that every later query of a big store prunes
        in blocks instead of bounding every entry. A searcher of at least
        :data:`~shapeidx.search.blocks.WARM_MIN` entries builds it by itself on its second query."""
        from .blocks import BlockIndex

        if self._blocks is None and len(self.view):
            with self.view.checked(None):
                self._blocks = BlockIndex(self.view)
        return self._blocks

    def __enter__(self) -> "Searcher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- metadata, joined to the ranked entries by path key
    def metadata_keys(self) -> tuple:
        """Every key ``--where`` may name: ``path``, what files say themselves, the sidecar table's."""
        table_keys = tuple(self.table.columns) if self.table is not None else ()
        return ("path",) + tuple(k for k in FILE_KEYS if k not in table_keys) + table_keys

    def present_metadata_keys(self) -> tuple:
        """The metadata keys some entry has a value for (``path`` left out): the columns of a
        CSV answer."""
        if "present" not in self._cache:
            table_keys = tuple(self.table.columns) if self.table is not None else ()
            files = tuple(k for k in FILE_KEYS if k not in table_keys
                          and any(source.text_present(f"entries/{k}") for source in self.view.sources))
            self._cache["present"] = files + table_keys
        return self._cache["present"]

    def metadata_column(self, key: str, positions: np.ndarray | None = None) -> np.ndarray:
        """``key``'s value for the ranked entries at ``positions`` (default all), "" where none.
        A sidecar column of a key a file also gives wins where it has a value."""
        if positions is None and key in self._columns:
            return self._columns[key]
        if key == "path":
            values = self._file_column("entries/path", positions)
        else:
            values = self._file_column(f"entries/{key}", positions) if key in FILE_KEYS else None
            if self.table is not None and key in self.table.columns:
                table_values = self.table.column(key, self._table_rows(positions))
                values = table_values if values is None else np.where(table_values != "", table_values, values)
        if values is None:
            raise StoreError(f"no metadata {key!r} in {self.store}")
        if positions is None:
            self._columns[key] = values
        return values

    def metadata_at(self, position: int) -> dict:
        """Every key with a value for the entry at ``position`` (not ``path``): one row read of
        each (a hit of a store of a million entries reads its own rows, not the columns)."""
        i, row = self.view.locate(position)
        source = self.view.sources[i]
        found = {}
        for key in FILE_KEYS:
            value = self._columns[key][position] if key in self._columns else source.text_at(f"entries/{key}", row)
            if value != "":
                found[key] = str(value)
        if self.table is not None:
            table_row = self._table_rows(np.array([position]))[0]
            for key, values in self.table.columns.items():
                if table_row >= 0 and values[table_row] != "":
                    found[key] = str(values[table_row])
        return found

    def _file_column(self, name: str, positions) -> np.ndarray:
        from ..store.layout import object_array

        positions = np.arange(len(self.view)) if positions is None else np.asarray(positions, dtype=np.int64)
        out = object_array([""] * len(positions))
        for i, mine, rows in self.view.rows_of(positions):
            out[mine] = self.view.sources[i].column(name)[rows]
        return out

    def _table_rows(self, positions) -> np.ndarray:
        if "table_rows" not in self._cache and positions is not None and len(positions) <= 64:
            keys = np.zeros((len(positions), 2), dtype=np.uint64)
            for i, mine, rows in self.view.rows_of(np.asarray(positions, dtype=np.int64)):
                keys[mine] = self.view.sections[i].array("path_key")[rows]
            return self.table.rows_of(keys)  # a few hits: their keys alone, not every entry's
        if "table_rows" not in self._cache:
            keys = np.zeros((len(self.view), 2), dtype=np.uint64)
            for i, mine, rows in self.view.rows_of(np.arange(len(self.view))):
                keys[mine] = self.view.sections[i].array("path_key")[rows]
            self._cache["table_rows"] = self.table.rows_of(keys)
        rows = self._cache["table_rows"]
        return rows if positions is None else rows[np.asarray(positions, dtype=np.int64)]

    # -- what is asked
    def query_of_part(self, part, file_type: str | None = None, label: str | None = None,
                      threads: int | None = None, seed: int | None = None) -> Query:
        """A part (path, file object, arrays, trimesh, Solid, or a Signature with the store's
        parameters) signed with the store's parameters; its own entry found when it is a
        file of the store's tree. ``seed``: draw its points with this seed instead of the
        store's (a query whose points nothing in the store shares: the honest twin question)."""
        signature, solid = sign_part(self.params, part, file_type, threads, seed)
        path = os.path.abspath(part) if isinstance(part, (str, os.PathLike)) else None
        entry = self.entry_path_of(part) if path is not None else None
        found = self.view.find(entry) if entry is not None else None
        own = self.view.position_of(found) if found is not None else None
        return Query(label_of(part, label), signature, own, entry if own is not None else None, path, solid)

    def query_of_entry(self, entry: str | os.PathLike) -> Query:
        """An entry of the store (its path relative to the root, or a path of a file inside
        the root), with its stored signature.

        Raises
        ------
        StoreError
            No such entry, or its file failed to index (with the reason).
        """
        name = self.resolve_entry(entry)
        found = self.view.find(name)
        if found is None:
            raise StoreError(f"no entry {name!r} in {self.store} (give a path inside {self.root},"
                             " absolute or relative to it)")
        status, reason = self.view.status_of(found)
        if self.view.position_of(found) is None:
            raise StoreError(f"entry {name!r} failed to index: {reason}")
        return Query(os.fspath(entry), self.view.signature(found, self.params), self.view.position_of(found), name)

    def entry_path_of(self, file) -> str | None:
        """The relative path ``file`` has in the store when it lies inside the indexed root."""
        return entry_path_in(self.root, file)

    def resolve_entry(self, entry) -> str:
        """``entry`` if the store has it; else its path relative to the root when it names a
        file inside the root (absolute, or relative to the working directory)."""
        text = os.fspath(entry)
        if self.view.find(text) is not None:
            return text
        inside = self.entry_path_of(text)
        return inside if inside is not None and self.view.find(inside) is not None else text

    def signature_at(self, position: int):
        """The stored signature of the ranked entry at ``position``."""
        return self.view.signature(self.view.locate(position), self.params)

    def path_at(self, position: int) -> str:
        return self.view.path_at(position)

    def signature_of(self, entry: str):
        """The stored signature of the ranked entry named ``entry`` (a hit's relative path)."""
        return self.signature_at(self.view.position_of(self.view.find(entry)))

    # -- the answer
    def keep(self, query: Query, filters: Filters) -> tuple[np.ndarray | None, tuple[str, str] | None]:
        """The keep-mask of ``filters`` for ``query`` (None: every entry), and, when it keeps
        nothing, why: ``(kind, words)``, the kind one of :data:`~shapeidx.search.hits.NO_HIT`."""
        from ..distance.scale import within_band

        n = len(self.view)
        mask = keep_mask(filters.conditions(), self.metadata_column, self.metadata_keys())
        if mask is not None and not mask.any():
            return mask, ("where", f"no entry of the store matches {' and '.join(f'--where {c}' for c in filters.conditions())}")
        if filters.scale != "invariant":
            from ..distance.scale import check_scale

            check_scale(filters.scale)
            sizes = self.view.gather("means")[:, 0]
            band = within_band(query.signature.histograms["all"].mean, sizes)
            mask = band if mask is None else mask & band
            if not mask.any():
                return mask, ("scale", "no entry of the store (that matches the filters) is within the size band of"
                                       " --scale sensitive")
        if filters.exclude_self and query.own is not None:
            mask = np.ones(n, dtype=bool) if mask is None else mask.copy()
            mask[query.own] = False
            if not mask.any():
                return mask, ("exclude_self", "no entry but the query's own is left (--exclude-self)")
        return mask, None

    def search(self, query: Query, top: int = 10, metric: str = default_metric("query"), filters: Filters | None = None,
               threads: int = RANK_THREADS, among: Collection[str] | None = None, among_reason: str = "") -> Answer:
        """The ``top`` entries nearest to ``query`` by ``metric`` among those ``filters`` keep.

        Ties are broken by path, and the query's own entry wins its ties (so a part of the
        store comes before its identical twins). An answer with no hit says why
        (:attr:`Answer.reason`). ``among``: the entry paths (a set) that narrow them further
        (``classify``: the labelled voters), ``among_reason`` what to say when it leaves none.
        """
        from ..distance.metrics import metric as metric_record

        metric_record(metric)  # an unknown name: ValueError naming the known ones
        filters = filters or Filters()
        if top < 1:
            raise ValueError(f"top must be at least 1, not {top}")
        answer = Answer(query.label, query.path, query.entry, metric, str(self.store.resolve()), self.root, [],
                        considered=0, entries=len(self.view), filters=filters.described(), signature=query.signature)
        if len(self.view) == 0:
            answer.why, answer.reason = "empty", self.empty_reason()
            return answer
        keep, why = self.keep(query, filters)
        if among is not None and why is None:
            among = self._among_mask(among)
            keep = among if keep is None else keep & among
            if not keep.any():
                why = ("among", among_reason or "no entry is left to rank")
        answer.considered = len(self.view) if keep is None else int(keep.sum())
        if why is not None:
            answer.why, answer.reason = why
            return answer
        own = query.own if keep is None or query.own is None or keep[query.own] else None
        self.asked()
        gaps = None
        if filters.same_part:
            chosen, exact, gaps = self._same_part_candidates(query, metric, top, keep, own, filters.max_distance, threads)
            answer.nearest_distances = np.sort(exact[np.isfinite(exact)])[:SAME_PART_RANK].tolist()
        else:
            chosen, exact = self.rank(query.signature, metric, top, keep, own, filters.max_distance, threads)
        valid = np.isfinite(exact)
        if filters.max_distance is not None:
            valid &= exact <= filters.max_distance
        if not valid.any():
            nearest_at = float(np.min(exact)) if len(exact) else float("nan")
            answer.nearest = nearest_at if np.isfinite(nearest_at) else None
            answer.why, answer.reason = "max_distance", beyond_reason(filters.max_distance, answer.nearest)
            return answer
        chosen, exact = chosen[valid], exact[valid]
        if gaps is None:
            answer.hits = self._hits(chosen, exact, top, own)
        else:
            gaps = gaps[valid]
            answer.hits = self._hits(chosen, exact, top, own, same_part_scores(exact, gaps, answer.nearest_distances), gaps)
        return answer

    def _same_part_candidates(self, query: Query, metric: str, top: int, keep, own, max_distance, threads):
        """Positions, exact distances and exact-measure gaps of the candidates of
        :mod:`shapeidx.search.same_part`: the nearest by the metric and the nearest by the gap
        (gaps None: the query's measures are unknown)."""
        wanted = max(top, SAME_PART_CANDIDATES)
        chosen, exact = self.rank(query.signature, metric, wanted, keep, own, max_distance, threads)
        mine = self.query_measures(query)
        if mine is None:  # a bare signature: no measures to order by, the metric's order (hits without a gap)
            return chosen, exact, None
        gaps = shape_gap(mine, self.entry_measures())
        if keep is not None:
            gaps = np.where(keep, gaps, np.inf)
        by_gap = np.argpartition(gaps, min(wanted, len(gaps)) - 1)[:wanted]
        by_gap = by_gap[np.isfinite(gaps[by_gap]) & ~np.isin(by_gap, chosen)]
        if len(by_gap):
            mask = np.zeros(len(self.view), dtype=bool)
            mask[by_gap] = True
            more, more_exact = self.rank(query.signature, metric, len(by_gap), mask, threads=threads)
            chosen, exact = np.concatenate([chosen, more]), np.concatenate([exact, more_exact])
        return chosen, exact, gaps[chosen]

    def entry_measures(self) -> np.ndarray:
        """(N, 7): every ranked entry's exact measures (:func:`shapeidx.search.same_part.shape_measures`), read once."""
        if "measures" not in self._cache:
            self._cache["measures"] = _measures_of_columns(self.entry_numbers)
        return self._cache["measures"]

    def entry_numbers(self, name: str, width: int) -> np.ndarray:
        """(N, width) float64: a numeric per-entry column of every ranked entry (the store's
        ``entries/extents``, ``entries/moments``, ...), NaN where a file has none."""
        return self.view.numbers(name, width)

    def query_measures(self, query: Query) -> np.ndarray | None:
        """The query's exact measures: given, of its loaded part, or its own entry's (None: unknown)."""
        if query.measures is not None:
            return np.asarray(query.measures, dtype=np.float64)
        if query.solid is not None:
            return measures_of_solid(query.solid)
        if query.own is not None:
            if "measures" in self._cache:
                return self._cache["measures"][query.own]
            at, row = self.view.locate(query.own)
            column = self.view.sources[at].column
            return _measures_of_columns(lambda name, width: column(name)[row:row + 1])[0]
        return None

    def _among_mask(self, among) -> np.ndarray:
        """``among`` (entry paths) as a mask over the ranked entries; the last one is kept, as
        classify asks with one set of voters for every part."""
        held = self._cache.get("among")
        if held is None or held[0] is not among:
            mask = np.fromiter((p in among for p in self.metadata_column("path")), dtype=bool, count=len(self.view))
            held = self._cache["among"] = (among, mask)
        return held[1]

    def entry_paths(self) -> list:
        """The paths of the ranked (ok) entries, as the store names them."""
        return [str(p) for p in self.metadata_column("path")]

    def asked(self) -> None:
        """Count a question; the second one warms a big store (a long-lived searcher, whose
        next questions the block index serves)."""
        from .blocks import WARM_MIN

        self._searches += 1
        if self._blocks is None and self._searches > 1 and len(self.view) >= WARM_MIN:
            self.warm()

    def rank(self, signature, metric: str, top: int, keep: np.ndarray | None = None, first: int | None = None,
             max_distance: float | None = None, threads: int = RANK_THREADS):
        """Positions and exact distances of a set of entries holding every entry of the
        ``top``-nearest answer (the contract of :func:`shapeidx.search.distances.nearest`):
        by the block index where it is built and serves ``metric``, else entry by entry.
        Every question of this store (search, where-used) is ranked here."""
        if self._blocks is not None and self._blocks.serves(metric, signature):
            return self._blocks.nearest(signature, metric, top, keep, max_distance, threads)
        return nearest(self.view, signature, metric, top, keep, first, max_distance, threads)

    def _hits(self, positions: np.ndarray, distances: np.ndarray, top: int, first: int | None,
              scores: np.ndarray | None = None, gaps: np.ndarray | None = None) -> list:
        """The hits, nearest first by ``scores`` (default: the distances, which the hits carry;
        ``gaps``: their exact-measure gaps, for the same-part order)."""
        from ..store.layout import object_array

        scores = distances if scores is None else scores
        top = min(top, len(distances))
        threshold = np.partition(scores, top - 1)[top - 1]
        near = np.flatnonzero(scores <= threshold)  # every entry within the top-th score, ties included
        paths = object_array([self.view.path_at(int(p)) for p in positions[near]])
        not_first = positions[near] != first if first is not None else np.ones(len(near), dtype=bool)
        order = np.lexsort((paths, not_first, scores[near]))[:top]
        hits = []
        for rank, k in enumerate(order, start=1):
            position, relative = int(positions[near[k]]), str(paths[k])
            parent, count = self.parent_at(position) if self.parts else (None, None)
            hits.append(Hit(rank, float(distances[near[k]]), absolute(self.root, parent or relative), relative,
                            self.metadata_at(position), parent, count,
                            None if gaps is None else float(gaps[near[k]])))
        return hits

    def parent_at(self, position: int) -> tuple[str, int]:
        """The file (relative path) holding the sub-entry at ``position``, and how many times."""
        from ..store.layout import COUNT_COLUMN, PARENT_COLUMN

        i, row = self.view.locate(position)
        source = self.view.sources[i]
        return source.text_at(PARENT_COLUMN, row), int(source.value_at(COUNT_COLUMN, row))

    def sub_part_of(self, entry: str) -> dict | None:
        """What a page or picture of sub-entry ``entry`` (``FILE#n``) shows: its file
        (``parent``), how many times the file holds it (``count``), its ``metadata`` and
        ``title``, and whether it is the whole file (``whole``: a file that is one part, its
        ``FILE#1`` alone, once); None when the store has no such ok sub-entry."""
        found = self.view.find(entry) if "#" in entry else None
        position = self.view.position_of(found) if found is not None else None
        if position is None:
            return None
        parent, count = self.parent_at(position)
        whole = entry == f"{parent}#1" and count == 1 and self.view.find(f"{parent}#2") is None
        metadata = self.metadata_at(position)
        return {"parent": parent, "count": count, "metadata": metadata, "title": metadata.get("title") or None,
                "whole": whole}

    def parents(self) -> tuple[np.ndarray, np.ndarray]:
        """The file (relative path) and count of every ranked sub-entry (read once)."""
        from ..store.layout import COUNT_COLUMN, PARENT_COLUMN

        if "parents" not in self._cache:
            count = self._file_column(COUNT_COLUMN, None)
            self._cache["parents"] = (self._file_column(PARENT_COLUMN, None), count.astype(np.int64))
        return self._cache["parents"]

    # -- where-used (a searcher of a store's sub-parts)
    def where_used(self, query: Query, top: int = 10, metric: str = WHERE_USED_METRIC, max_distance: float | None = None,
                   scale: str = "sensitive", same_size: float | None = SAME_SIZE, threads: int = RANK_THREADS):
        """The ``top`` files holding a sub-part nearest to ``query``, nearest first.

        Parameters
        ----------
        query : Query
            Of this searcher (:meth:`query_of_part`, :meth:`question_of_entry`).
        top : int
            Files wanted.
        metric : str
            A metric's name (default: where-used's, :data:`shapeidx.search.where_used.DEFAULT_METRIC`).
        max_distance : float or None
            Every file with a sub-part within it, each counting all of them.
        scale : str
            ``"sensitive"``: only sub-parts of the query's size; ``"invariant"``: any size.
        same_size : float or None
            With ``"sensitive"``: the largest relative difference of principal radii (None: the size band only).

        Returns
        -------
        WhereUsed
            :func:`shapeidx.search.where_used.uses_in_store`'s answer; with no file, why.
        """
        from .where_used import uses_in_store

        return uses_in_store(self, query, top, metric, Filters(max_distance=max_distance, scale=scale), same_size,
                             threads)

    def question_of_entry(self, entry, files=None) -> Query:
        """Where-used's question for an entry of the store (``--id``; the web page's ids).

        A sub-entry ``FILE#n`` is asked as stored; a file that is one part is its ``FILE#1``
        (the same entry). A file of several parts is asked whole: its signature from the
        whole-file store ``files`` (a :class:`Searcher` of the store whose sub-parts this
        searcher ranks, opened here when None), with its exact measures, so that the
        same-size test holds for it too (a file that holds the same assembly fused into one
        solid is where it is used).
        """
        name = self.resolve_entry(entry)
        if self.view.find(name) is not None:
            return self.query_of_entry(name)
        for whole in dict.fromkeys(w for w in (name, self.entry_path_of(entry)) if w):
            if self.view.find(f"{whole}#1") is not None and self.view.find(f"{whole}#2") is None:
                return self.query_of_entry(f"{whole}#1")
        if files is None:
            with Searcher(Path(self.store).parent) as files:  # the sub-parts' store is STORE/parts
                return self.question_of_entry(entry, files)
        query = files.query_of_entry(entry)  # an unknown or failed entry: StoreError, in words
        query.measures = files.query_measures(query)
        query.own = None  # its position is in the whole-file store
        return query

    def empty_reason(self) -> str:
        """Why this store has nothing to rank (:func:`empty_store_reason`)."""
        from ..store.lock import read_build_state

        return empty_store_reason(self.store, len(self.reader), read_build_state(self.store))


def empty_store_reason(store, rows: int, state: dict | None, sharded: bool = False) -> str:
    """Why a store has nothing to rank, in words: the one text of every searcher.

    Parameters
    ----------
    store : path
        The store as opened (a sharded store's own folder, not a shard's).
    rows : int
        Its entries, failed ones too.
    state : dict or None
        Its last build's record (:func:`shapeidx.store.lock.read_build_state`; a sharded
        store's: a running shard's, else a stopped one's).
    sharded : bool
        A sharded store, which its build command names (``--shards N``).
    """
    if rows:
        return (f"none of the store's {rows} entries could be indexed ('shapeidx stats --failed --store"
                f" {store}' lists why)")
    state = state or {}
    if state.get("state") == "running":
        return (f"the store has no entry yet: a build is running (pid {state.get('pid')} on {state.get('host')},"
                f" since {state.get('started')}); its first commit comes within --commit-interval")
    if state.get("state") in ("stopped", "interrupted"):
        return f"the store has no entry: its last build {state['state']} before its first commit; run it again"
    return f"the store has no entry yet (run 'shapeidx build DIR{' --shards N' if sharded else ''}' first)"


def beyond_reason(max_distance: float, nearest: float | None) -> str:
    """Why no hit is within ``max_distance``: the words, with the nearest distance when there was one."""
    nearest_at = f" (the nearest is at {nearest:.6g})" if nearest is not None else ""
    return f"no hit within --max-distance {max_distance:g}{nearest_at}"


def check_usable(reader) -> None:
    """Refuse, in one line, a store whose signatures another version of shapeidx made."""
    from ..signing.parameters import SIGNATURE_VERSION

    version = reader.params.signature_version
    if version != SIGNATURE_VERSION:
        from ..store.files import build_command
        from ..store.layout import as_text

        if version < SIGNATURE_VERSION:
            way = (f"its next build signs every entry again:"
                   f" {build_command(reader.path, as_text(reader.attrs.get('root', '')) or None)}")
        else:
            way = "a newer shapeidx made it: upgrade shapeidx to read it"
        raise StoreError(f"store {reader.path} holds signatures of version {version}, this shapeidx"
                         f" makes version {SIGNATURE_VERSION}: {way}")
