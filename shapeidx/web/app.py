"""``shapeidx serve``: a local web page and JSON API over a store, the paper's query-by-example browsing.

Starlette (with uvicorn as the server): a small, well-kept ASGI toolkit that gives routing,
multipart uploads (python-multipart), static files and a test client, and nothing we do not
use (no ORM, no templates, no validation layer). The API is documented in docs/web.md.

The store is opened once at start (:class:`StoreService`) and every query goes through the
one search road (:class:`~shapeidx.search.Searcher`): the same hits, distances and fields as
``shapeidx query`` and the Python API, with every metric of the registry and the ``where``
metadata filters. The store is a snapshot: restart the server to see a newer build.

Every request is treated as hostile:

* an ``id`` is looked up among the store's entries (exact match), never used as a path by
  itself; the file of an entry must resolve (symbolic links followed) to a place inside the
  store's root, or it is refused (403); the server never sends part files, only thumbnails;
* uploads need a Content-Length within :data:`MAX_UPLOAD` (413 beyond), are written to a
  private temporary file with the original name's suffix (so the loader picks the format),
  read, and deleted; a file that is not a usable part is a 422 with the loader's one-line
  reason;
* ``top``, ``metric``, ``where``, ``parts``, ``uses`` and ``same_part`` are checked (400); unknown ids are 404;
  nothing raises past a handler.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import threading
from collections import OrderedDict
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np

from ..distance import compare
from ..distance.metrics import METRICS, default_metric
from ..errors import LoadError, ShapeidxError, StoreError, UsageError
from ..pictures.similarity import SimilarityScale, closer_than
from ..pictures.thumbcache import StoreThumbnails
from ..signing.histogram import Signature
from ..signing.parameters import HISTOGRAMS

#: The metric of a search and of a where-used question that names none (the registry's defaults).
QUERY_METRIC, WHERE_USED_METRIC = default_metric("query"), default_metric("where-used")
#: Largest upload accepted, bytes (``serve --max-upload`` changes it).
MAX_UPLOAD = 64 * 1024 * 1024
#: Largest ``top`` a request may ask for.
MAX_TOP = 5000
#: Uploaded queries kept (signature and picture) so that their metric, k and compare view
#: can change without uploading again.
UPLOADS_KEPT = 64
UPLOAD_PREFIX = "upload:"
#: Uploads read and signed at the same time; one more is answered 503 at once (each may take
#: a core and, for a large part, a few GB while it is read).
MAX_UPLOADS_AT_ONCE = 2
#: Threads that read part files for thumbnails; the rest of the server never waits for them.
FILE_THREADS = 4
#: Longest wait for a thumbnail, seconds (queueing included): 503 beyond, the server goes on.
FILE_WAIT = 60.0


class RequestError(Exception):
    """A request that cannot be answered: HTTP status and a one-line message for the user."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


@dataclass
class Upload:
    """An uploaded part: its name, its query (signed with the store's parameters) and thumbnail."""

    name: str
    query: object
    png: bytes | None
    note: str


def _histograms_json(signature: Signature) -> dict:
    return {name: {"p": [round(float(v), 7) for v in signature.histograms[name].p], "mean": signature.histograms[name].mean}
            for name in HISTOGRAMS}


def _fractions_json(values) -> dict:
    return {"in": float(values[0]), "out": float(values[1]), "mixed": float(values[2])}


def upload_suffix(filename: str) -> str:
    """The suffix a temporary copy of an upload gets: its own when it names a part format."""
    from ..io.formats import PART_SUFFIXES

    name = os.path.basename(filename.replace("\\", "/")).lower()
    gz = name.endswith(".gz")
    stem = name[:-3] if gz else name
    suffix = os.path.splitext(stem)[1]
    if suffix in PART_SUFFIXES:
        return suffix + (".gz" if gz else "")
    return ".gz" if gz else ".part"


def _has_parts(store) -> bool:
    """Whether the store (every shard of a sharded one) has sub-parts (``build --parts``)."""
    from ..store.reader import member_stores

    try:
        member_stores(store, parts=True)
        return True
    except StoreError:
        return False


def _parts_searcher(store: Path):
    """The searcher of ``store``'s sub-parts; None while the first build with --parts has
    committed nothing (the page then has no sub-parts, as without them)."""
    from ..search import open_searcher
    from ..store.reader import StoreBeingCreated

    try:
        return open_searcher(store, parts=True)
    except StoreBeingCreated:
        return None


class StoreService:
    """A store held open for the web page: queries through the one search road
    (:class:`~shapeidx.search.Searcher`), entries, thumbnails, uploads.

    Parameters
    ----------
    store : path of the store
    """

    def __init__(self, store: str | os.PathLike):
        from ..search import open_searcher

        self.searcher = open_searcher(store)
        self.store = self.searcher.store.absolute()
        self.reader = self.searcher.reader
        self.thumbs = StoreThumbnails(self.searcher)
        self.root = Path(self.searcher.root or ".")
        self.real_root = Path(os.path.realpath(self.root))
        self._lock = threading.Lock()  # one h5py reader shared by the request threads
        self._scales: dict = {}
        self._uploads: OrderedDict = OrderedDict()
        self._listing = None
        self.max_upload = MAX_UPLOAD
        self.scale(QUERY_METRIC)  # the default metric's calibration before the first query
        from ..search.blocks import WARM_MIN

        if len(self.searcher) >= WARM_MIN:  # a big store: every query prunes in blocks from the first
            self.searcher.warm()
        #: The store's sub-parts (``build --parts``; ``parts=1`` ranks them), or None.
        self.parts = _parts_searcher(self.store) if _has_parts(self.store) else None
        #: Their pictures (each drawn itself), cached with the files' in ``STORE/thumbs``.
        self.part_thumbs = StoreThumbnails(self.parts, folder=self.thumbs.cache.folder) if self.parts else None

    def close(self) -> None:
        self.searcher.close()
        if self.parts is not None:
            self.parts.close()

    # -- facts
    def info(self) -> dict:
        from ..distance.metrics import REGISTRY
        from ..io.formats import PART_SUFFIXES, SUFFIXES

        ok = len(self.searcher)  # the ranked entries: the ok ones
        entries = self._rows() if self._listing is None else len(self._listing["paths"])
        return {
            "store": str(self.store),
            "root": str(self.root),
            "entries": int(entries),
            "ok": int(ok),
            "failed": int(entries - ok),
            "metrics": [{"name": m.name, "label": m.label, "summary": m.summary} for m in REGISTRY.values()],
            "formats": {name: list(suffixes) for name, suffixes in SUFFIXES.items()},
            "suffixes": list(PART_SUFFIXES),
            "metadata_keys": list(self.searcher.metadata_keys()),
            "points": self.searcher.params.points,
            "max_upload": self.max_upload,
            "parts": self.parts is not None,
            "sub_parts": len(self.parts) if self.parts is not None else 0,
            "query_metric": QUERY_METRIC,
            "where_used_metric": WHERE_USED_METRIC,
        }

    def _rows(self) -> int:
        """Every entry of the store, failed ones too."""
        return len(self.reader.column("entries/status"))

    def _has_entry(self, entry: str) -> bool:
        """Whether ``entry`` names a whole-file entry of the store (ok or failed)."""
        return self.searcher.view.find(entry) is not None

    def _metadata_of(self, entry: str) -> dict:
        """The metadata of the ok entry ``entry`` (404 / 409 as :meth:`position_of`)."""
        with self._lock:
            return self.searcher.metadata_at(self.position_of(entry))

    def _fractions_of(self, searcher, entries) -> list:
        """The class fractions of each ranked entry named (called with the lock held)."""
        return [searcher.view.gather("fractions", np.array([searcher.view.position_of(
            searcher.view.find(entry))]))[0] for entry in entries]

    def listing(self) -> dict:
        """Every entry's path, status, reason, triangles and fractions (read once, on first use)."""
        from ..store import STATUS_OK

        with self._lock:
            if self._listing is None:
                status = self.reader.column("entries/status")
                self._listing = {"paths": self.reader.paths, "ok": status == STATUS_OK,
                                 "reasons": self.reader.column("entries/reason"),
                                 "triangles": self.reader.column("entries/triangles"),
                                 "fractions": self.reader.column("entries/fractions")}
            return self._listing

    def scale(self, metric: str, parts: bool = False) -> SimilarityScale:
        """The similarity words of ``metric``, calibrated on the files (or on the sub-parts)."""
        searcher = self.parts if parts else self.searcher
        with self._lock:
            if (metric, parts) not in self._scales:
                self._scales[metric, parts] = SimilarityScale.cached(searcher, metric, self.thumbs.cache.folder)
            return self._scales[metric, parts]

    def parts_searcher(self):
        """The searcher of the sub-parts, or 409 when the store was built without ``--parts``."""
        if self.parts is None:
            raise RequestError(409, f"the store {self.store} has no sub-parts: build it with 'shapeidx build DIR"
                                    f" --store {self.store} --parts' (docs/assemblies.md)")
        return self.parts

    def sub_entry(self, entry: str) -> dict | None:
        """What the page shows of a sub-entry ``FILE#n`` of an ok sub-part (``parent``,
        ``count``, ``metadata``: :meth:`~shapeidx.search.Searcher.sub_part_of`), else None."""
        if self.parts is None or "#" not in entry:
            return None
        with self._lock:
            return self.parts.sub_part_of(entry)

    def entries(self, offset: int, limit: int, status: str, contains: str) -> dict:
        listing = self.listing()
        paths, ok = listing["paths"], listing["ok"]
        picked = np.ones(len(paths), dtype=bool)
        if status == "ok":
            picked &= ok
        elif status == "failed":
            picked &= ~ok
        if contains:
            needle = contains.lower()
            picked &= np.array([needle in p.lower() for p in paths], dtype=bool)
        rows = np.flatnonzero(picked)
        page = rows[offset : offset + limit]
        return {
            "total": int(len(rows)),
            "offset": offset,
            "entries": [
                {
                    "id": str(paths[i]),
                    "status": "ok" if ok[i] else "failed",
                    "reason": str(listing["reasons"][i]),
                    "triangles": int(listing["triangles"][i]),
                    "fractions": _fractions_json(listing["fractions"][i]) if ok[i] else None,
                }
                for i in page
            ],
        }

    # -- ids: an entry's exact path (never a file path), or an upload's
    def position_of(self, entry: str) -> int:
        """The ranked position of an ok entry (404 for an unknown id, 409 for a failed one)."""
        found = self.searcher.view.find(entry)
        if found is None and self.sub_entry(entry) is not None:
            raise RequestError(409, f"{entry!r} is a sub-part: ask with parts=1")
        if found is None:
            raise RequestError(404, f"no entry {entry!r} in the store")
        position = self.searcher.view.position_of(found)
        if position is None:
            raise RequestError(409, f"entry {entry!r} failed to index: {self.searcher.view.status_of(found)[1]}")
        return position

    def file_of(self, entry: str) -> Path:
        """The entry's file, if it lies inside the store's root once links are followed (else 403)."""
        self.position_of(entry)  # a known entry or an error: the id is never a path by itself
        real = Path(os.path.realpath(self.root / entry))
        if not real.is_relative_to(self.real_root):
            raise RequestError(403, f"entry {entry!r} resolves outside the store's root; not served")
        return real

    def regular_file_of(self, entry: str) -> Path:
        """:meth:`file_of`, and the file must be a regular file: a FIFO, socket or device put
        under the entry's name is refused (404) without ever blocking on it."""
        from ..io.base import open_regular

        real = self.file_of(entry)
        try:
            with open_regular(real):
                pass
        except OSError as exc:
            raise RequestError(404, f"no picture of {entry!r}: {exc.strerror or exc}") from None
        return real

    def query_of(self, query_id: str):
        """The search query of an entry id or of a kept upload."""
        if query_id.startswith(UPLOAD_PREFIX):
            return self.upload(query_id).query
        if self.sub_entry(query_id) is not None and not self._has_entry(query_id):
            with self._lock:  # a sub-part FILE#n: its own signature, from the sub-parts
                return self.parts.query_of_entry(query_id)
        self.position_of(query_id)
        with self._lock:
            return self.searcher.query_of_entry(query_id)

    def upload(self, query_id: str) -> Upload:
        with self._lock:
            found = self._uploads.get(query_id)
            if found is None:
                raise RequestError(404, "unknown upload (uploads are kept while the server runs, the latest"
                                        f" {UPLOADS_KEPT}); upload the part again")
            self._uploads.move_to_end(query_id)
            return found

    # -- answers
    def describe(self, query_id: str, query=None) -> dict:
        """An entry or upload for the page: name, path, fractions, histograms, picture, metadata."""
        query = query or self.query_of(query_id)
        signature = query.signature
        out = {"id": query_id, "fractions": signature.fractions, "histograms": _histograms_json(signature)}
        if query_id.startswith(UPLOAD_PREFIX):
            upload = self.upload(query_id)
            out.update(name=upload.name, path=None, note=upload.note, metadata={},
                       thumbnail=f"/api/thumbnail?id={_quote(query_id)}" if upload.png else None)
        elif (sub := self.sub_entry(query_id)) is not None and not self._has_entry(query_id):
            out.update(name=query_id, path=str(self.root / sub["parent"]), metadata=sub["metadata"],
                       parent=sub["parent"], count=sub["count"], thumbnail=f"/api/thumbnail?id={_quote(query_id)}")
            if not sub["whole"]:
                out["parent_thumbnail"] = f"/api/thumbnail?id={_quote(sub['parent'])}"
        else:
            metadata = self._metadata_of(query_id)
            out.update(name=query_id, path=str(self.root / query_id), metadata=metadata,
                       thumbnail=f"/api/thumbnail?id={_quote(query_id)}")
        return out

    def query(self, query_id: str, top: int, metric: str, where=(), parts: bool = False,
              same_part: bool = False) -> dict:
        """Rank the store's files (or, ``parts``, its sub-parts: hits with ``parent`` and ``count``);
        ``same_part``: in the same-part order (``query --same-part``: hits with ``shape_gap``)."""
        from ..search import Filters, parse_where

        searcher = self.parts_searcher() if parts else self.searcher
        filters = Filters(where=parse_where(where), same_part=same_part)
        query = self.query_of(query_id)
        if parts != self._is_sub_entry(query.entry):
            query = replace(query, own=None)  # its own position is in the other store
        with self._lock:
            answer = searcher.search(query, top, metric, filters)
            fractions = self._fractions_of(searcher, [hit.relative_path for hit in answer.hits])
        scale = self.scale(metric, parts)
        hits = [self._hit_json(scale, hit.to_dict(), hit.relative_path, hit.distance, hit.parent, hit.count, f)
                for hit, f in zip(answer.hits, fractions)]
        return {"query": self.describe(query_id, query), "metric": metric, "top": top, "entries": answer.entries,
                "considered": answer.considered, "filters": answer.filters, "reason": answer.reason,
                "parts": parts, "calibration": scale.describe(), "hits": hits}

    def where_used(self, query_id: str, top: int, metric: str) -> dict:
        """The files holding a sub-part like the query, nearest first (``shapeidx where-used``):
        the answer of :meth:`query` with one hit per file, its nearest sub-part and its count.
        An id is asked as the command's ``--id`` is (:meth:`~shapeidx.search.searcher.Searcher.question_of_entry`)."""
        searcher = self.parts_searcher()
        if query_id.startswith(UPLOAD_PREFIX):
            query = self.query_of(query_id)
        else:
            if self.sub_entry(query_id) is None:
                self.position_of(query_id)  # 404 for an unknown id, 409 for a failed one
            with self._lock:
                query = searcher.question_of_entry(query_id, self.searcher)
        with self._lock:
            answer = searcher.where_used(query, top=top, metric=metric)
            fractions = self._fractions_of(searcher, [use.part for use in answer.uses])
            facts = [self.parts.sub_part_of(use.part) for use in answer.uses]
        scale = self.scale(metric, True)
        hits = [self._hit_json(scale, {"rank": use.rank, "distance": use.distance, "relative_path": use.part,
                                       "path": use.path, "title": use.title, "metadata": fact["metadata"]},
                               use.part, use.distance, use.relative_path, use.count, f, whole=fact["whole"])
                for use, fact, f in zip(answer.uses, facts, fractions)]
        return {"query": self.describe(query_id, query), "metric": metric, "top": top, "entries": answer.files,
                "considered": answer.files, "filters": [], "reason": answer.reason, "parts": True, "uses": True,
                "calibration": scale.describe(), "hits": hits}

    def _hit_json(self, scale, fields: dict, entry: str, distance: float, parent, count, fractions,
                  whole: bool | None = None) -> dict:
        """A hit for the page: ``fields`` with its id, words, share, fractions and pictures
        (a sub-part drawn itself, and the file holding it beside unless it is the whole file)."""
        share = scale.share(distance)
        out = {**fields, "id": entry, "words": scale.words(distance), "share": share,
               "closer_than": closer_than(share) if share is not None and distance > 0 else "",
               "fractions": _fractions_json(fractions), "thumbnail": f"/api/thumbnail?id={_quote(entry)}"}
        if parent is not None:  # a sub-part
            out.update(parent=parent, count=count)
            if whole is None:  # where-used has asked already; a query's hit is asked here
                whole = self.part_thumbs.is_whole_file(entry)
            if not whole:
                out["parent_thumbnail"] = f"/api/thumbnail?id={_quote(parent)}"
        return out

    def _is_sub_entry(self, entry) -> bool:
        """Whether ``entry`` names a sub-entry ``FILE#n`` (not a whole file whose name holds '#')."""
        return entry is not None and "#" in entry and not self._has_entry(entry)

    def query_upload(self, filename: str, data: bytes, top: int, metric: str, where=(), parts: bool = False,
                     uses: bool = False, same_part: bool = False) -> dict:
        """Sign an uploaded part file and rank the store against it (422 for a bad part);
        ``uses``: the files that use a part like it (:meth:`where_used`); ``same_part`` as :meth:`query`'s."""
        from ..pictures.render import render_solid_png
        from ..search.same_part import measures_of_solid

        name = os.path.basename((filename or "upload").replace("\\", "/")) or "upload"
        digest = hashlib.sha256(data).hexdigest()
        query_id = UPLOAD_PREFIX + digest[:32]
        with self._lock:
            known = self._uploads.get(query_id)
        if known is None:
            with tempfile.TemporaryDirectory(prefix="shapeidx-upload-") as folder:
                path = Path(folder) / ("part" + upload_suffix(name))
                path.write_bytes(data)
                try:
                    query = self.searcher.query_of_part(path, label=name)
                except LoadError as exc:
                    raise RequestError(422, f"{name}: {exc.reason}") from None
                query.path = query.entry = query.own = None  # a temporary file: not the store's
                # what where-used's same-size test and the same-part order read, once solid is gone
                query.measures = measures_of_solid(query.solid)
                try:
                    png, note = render_solid_png(query.solid), ""
                except Exception as exc:  # a picture is a nicety: the query still answers
                    png, note = None, f"no picture ({type(exc).__name__})"
                query.solid = None
            with self._lock:
                self._uploads[query_id] = Upload(name, query, png, note)
                while len(self._uploads) > UPLOADS_KEPT:
                    self._uploads.popitem(last=False)
        if uses:
            return self.where_used(query_id, top, metric)
        return self.query(query_id, top, metric, where, parts, same_part)

    def thumbnail(self, query_id: str) -> bytes:
        if query_id.startswith(UPLOAD_PREFIX):
            png = self.upload(query_id).png
            if png is None:
                raise RequestError(404, "no picture of this upload")
            return png
        if (sub := self.sub_entry(query_id)) is not None and not self._has_entry(query_id):
            self.regular_file_of(sub["parent"])  # a sub-part FILE#n: its file, a known entry inside the root
            try:  # drawn itself, from its file split again
                return self.part_thumbs.sub_part_png(query_id)
            except LoadError as exc:
                raise RequestError(404, f"no picture of {query_id!r}: {exc.reason}") from None
        self.regular_file_of(query_id)  # a known entry inside the root, a regular file, or an error
        try:
            return self.thumbs.png(query_id)
        except LoadError as exc:
            raise RequestError(404, f"no picture of {query_id!r}: {exc.reason}") from None

    def compare(self, a: str, b: str) -> dict:
        from ..distance.metrics import REGISTRY

        query_a, query_b = self.query_of(a), self.query_of(b)
        distances = compare(query_a.signature, query_b.signature)
        return {"a": self.describe(a, query_a), "b": self.describe(b, query_b), "distances": distances,
                "labels": {name: REGISTRY[name].label for name in distances}}


class ShardedStoreService(StoreService):
    """:class:`StoreService` over a sharded store (:mod:`shapeidx.search.sharded`): queries go to
    every shard (each on a worker of ``scheduler``, else here) and their exact top k are merged;
    an entry's facts come from the one shard its path key names; the words are calibrated on the
    first shard; its sub-parts (``build --shards N --parts``) are ranked as its files are."""

    def __init__(self, store: str | os.PathLike, scheduler: str | None = None):
        from ..search import open_searcher

        self.searcher = open_searcher(store, scheduler)
        self.store = self.searcher.store.absolute()
        self.reader = None
        self.thumbs = StoreThumbnails(self.searcher)
        self.root = Path(self.searcher.root or ".")
        self.real_root = Path(os.path.realpath(self.root))
        self._lock = threading.Lock()
        self._scales: dict = {}
        self._uploads: OrderedDict = OrderedDict()
        self._listing = None
        self.max_upload = MAX_UPLOAD
        self.parts = self.part_thumbs = None
        if _has_parts(store):  # build --shards N --parts: every shard's sub-parts ranked alike
            self.parts = open_searcher(store, scheduler, parts=True)
            self.part_thumbs = StoreThumbnails(self.parts, folder=self.thumbs.cache.folder)
        self.scale(QUERY_METRIC)
        self.searcher.warm()  # each big shard builds its block index where it is

    def info(self) -> dict:
        return {**super().info(), "shards": len(self.searcher.shards)}

    def _rows(self) -> int:
        return self.searcher.rows

    def _facts(self, entry: str) -> dict | None:
        with self._lock:
            return self.searcher.entry_facts(entry)

    def _has_entry(self, entry: str) -> bool:
        return self._facts(entry) is not None

    def position_of(self, entry: str) -> int:
        """0 for an ok entry of its shard (404 for an unknown id, 409 for a failed one)."""
        facts = self._facts(entry)
        if facts is None and self.sub_entry(entry) is not None:
            raise RequestError(409, f"{entry!r} is a sub-part: ask with parts=1")
        if facts is None:
            raise RequestError(404, f"no entry {entry!r} in the store")
        if not facts["ok"]:
            raise RequestError(409, f"entry {entry!r} failed to index: {facts['reason']}")
        return 0

    def _metadata_of(self, entry: str) -> dict:
        self.position_of(entry)
        return self._facts(entry)["metadata"]

    def _fractions_of(self, searcher, entries) -> list:
        return [searcher.entry_facts(entry)["fractions"] for entry in entries]

    def listing(self) -> dict:
        with self._lock:
            if self._listing is None:
                self._listing = self.searcher.listing()
            return self._listing

    def scale(self, metric: str, parts: bool = False) -> SimilarityScale:
        from ..pictures.similarity import shard_scale

        searcher = self.parts if parts else self.searcher
        with self._lock:
            if (metric, parts) not in self._scales:
                self._scales[metric, parts] = searcher.on_shard(0, shard_scale, metric, 0, len(searcher.shards))
            return self._scales[metric, parts]


def open_service(store: str | os.PathLike, scheduler: str | None = None) -> StoreService:
    """The service of an ordinary store, or of a sharded one (``scheduler``: its shards ranked
    on that Dask cluster's workers); ``scheduler`` with an ordinary store is refused in one line."""
    from ..store.shards import is_sharded

    if is_sharded(store):
        return ShardedStoreService(store, scheduler)
    if scheduler:
        from ..errors import StoreError

        raise StoreError(f"{store} is not a sharded store: --scheduler serves a store built with --shards")
    return StoreService(store)


def _quote(text: str) -> str:
    from urllib.parse import quote

    return quote(text, safe="")


# ----------------------------------------------------------------------------- the app


def _int(params, name: str, default: int, lo: int, hi: int) -> int:
    raw = params.get(name)
    if raw in (None, ""):
        return default
    try:
        value = int(raw)
    except (TypeError, ValueError):
        raise RequestError(400, f"{name} must be a whole number, not {str(raw)[:40]!r}") from None
    if not lo <= value <= hi:
        raise RequestError(400, f"{name} must be between {lo} and {hi}")
    return value


def _uses(params) -> bool:
    """``uses=1``: where used (the files holding a sub-part like the query); it takes no ``where``
    and no ``same_part`` and ranks sub-parts, so ``parts`` is checked but says nothing more."""
    uses = _flag(params, "uses")
    _flag(params, "parts")
    if uses and any(condition.strip() for condition in _where(params)):
        raise RequestError(400, "where used takes no 'where' conditions (they select files, not sub-parts)")
    if uses and _flag(params, "same_part"):
        raise RequestError(400, "where used takes no 'same_part' (it keeps sub-parts of the query's size already)")
    return uses


def _flag(params, name: str) -> bool:
    """A yes/no parameter: 1/true/yes/on or 0/false/no/off/absent (else 400)."""
    value = str(params.get(name) or "0").strip().lower()
    if value in ("1", "true", "yes", "on"):
        return True
    if value in ("0", "false", "no", "off", ""):
        return False
    raise RequestError(400, f"{name} must be 1 or 0, not {value[:40]!r}")


def _metric(params, default: str = QUERY_METRIC) -> str:
    """The metric asked for; absent: ``query``'s default (the paper's Weighted), or where-used's."""
    metric = params.get("metric") or default
    if metric not in METRICS:
        raise RequestError(400, f"unknown metric {str(metric)[:40]!r}; expected one of {', '.join(METRICS)}")
    return metric


#: ``where`` conditions a request may carry at most.
MAX_WHERE = 20


def _where(params) -> list:
    values = [str(v)[:500] for v in params.getlist("where")] if hasattr(params, "getlist") else []
    if len(values) > MAX_WHERE:
        raise RequestError(400, f"at most {MAX_WHERE} where conditions")
    return values


def _id(params, name: str = "id") -> str:
    value = params.get(name)
    if not value:
        raise RequestError(400, f"missing {name}")
    return str(value)


def create_app(service: StoreService, max_upload: int = MAX_UPLOAD, host: str = "127.0.0.1",
               uploads_at_once: int = MAX_UPLOADS_AT_ONCE, file_threads: int = FILE_THREADS,
               file_wait: float = FILE_WAIT, body_idle: float | None = None, body_total: float | None = None):
    """The Starlette application serving ``service``'s store.

    ``host`` is the address the server is bound to: the ``Host`` header must name it (or
    localhost); see :mod:`shapeidx.web.guard`. ``uploads_at_once`` uploads are read at the same
    time (503 beyond); thumbnails are read by ``file_threads`` threads of their own, and a
    request waits at most ``file_wait`` seconds for one (503). ``body_idle`` and ``body_total``
    bound a request body's arrival (408).
    """
    import anyio
    from starlette.applications import Starlette
    from starlette.middleware import Middleware
    from starlette.concurrency import run_in_threadpool
    from starlette.requests import Request
    from starlette.responses import FileResponse, JSONResponse, Response
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    from .guard import BODY_IDLE_TIMEOUT, BODY_TIMEOUT, BodyTimedOut, BodyTimeout, HostOriginGuard, allowed_hosts

    static = Path(str(resources.files("shapeidx.web").joinpath("static")))
    service.max_upload = max_upload
    uploads = anyio.CapacityLimiter(uploads_at_once)
    file_readers = anyio.CapacityLimiter(file_threads)

    async def in_file_thread(function, *args):
        """Run a call that reads part files on the thumbnail threads, waiting at most ``file_wait``."""
        try:
            with anyio.fail_after(file_wait):
                return await anyio.to_thread.run_sync(function, *args, limiter=file_readers, abandon_on_cancel=True)
        except TimeoutError:
            raise RequestError(503, f"reading the part took more than {file_wait:g} s (the server is busy"
                                    " or the file is slow to read); try again later") from None

    def guarded(handler):
        async def endpoint(request):
            try:
                return await handler(request)
            except RequestError as exc:
                headers = {"Retry-After": "5"} if exc.status == 503 else None
                return JSONResponse({"error": exc.message}, status_code=exc.status, headers=headers)
            except BodyTimedOut as exc:
                return JSONResponse({"error": str(exc)}, status_code=408, headers={"Connection": "close"})
            except UsageError as exc:
                return JSONResponse({"error": str(exc)}, status_code=400)
            except ShapeidxError as exc:
                return JSONResponse({"error": str(exc)}, status_code=422)
            except Exception as exc:  # a bug: a one-line 500, the server keeps running
                return JSONResponse({"error": f"internal error: {type(exc).__name__}: {exc}"}, status_code=500)

        return endpoint

    async def index(request):
        return FileResponse(static / "index.html", headers={"Cache-Control": "no-cache"})

    async def info(request):
        return JSONResponse(service.info())

    async def entries(request):
        q = request.query_params
        status = q.get("status") or "all"
        if status not in ("all", "ok", "failed"):
            raise RequestError(400, "status must be all, ok or failed")
        result = await run_in_threadpool(service.entries, _int(q, "offset", 0, 0, 10**9), _int(q, "limit", 100, 1, 1000),
                                         status, (q.get("q") or "")[:200])
        return JSONResponse(result)

    async def entry(request):
        return JSONResponse(await run_in_threadpool(service.describe, _id(request.query_params)))

    async def query_get(request):
        q = request.query_params
        if _uses(q):
            result = await run_in_threadpool(service.where_used, _id(q), _int(q, "top", 10, 1, MAX_TOP),
                                             _metric(q, WHERE_USED_METRIC))
        else:
            result = await run_in_threadpool(service.query, _id(q), _int(q, "top", 10, 1, MAX_TOP), _metric(q),
                                             _where(q), _flag(q, "parts"), _flag(q, "same_part"))
        return JSONResponse(result)

    async def query_post(request):
        length = request.headers.get("content-length")
        if length is None:
            raise RequestError(411, "the upload needs a Content-Length")
        try:
            length = int(length)
        except ValueError:
            raise RequestError(400, "bad Content-Length") from None
        if length > max_upload:
            raise RequestError(413, f"upload of {length:,} bytes is over the limit of {max_upload:,} bytes")
        boundary = _multipart_boundary(request.headers.get("content-type", ""))
        try:
            uploads.acquire_nowait()
        except anyio.WouldBlock:
            raise RequestError(503, f"the server is already reading {uploads_at_once} uploads; try again shortly") from None
        try:
            body = await _read_body(request, max_upload)
            if not _multipart_is_whole(body, boundary):
                raise RequestError(400, "the upload is cut short (the multipart body does not end with its closing"
                                        " boundary); send it again")

            async def replay():
                return {"type": "http.request", "body": body, "more_body": False}

            try:
                form = await Request(request.scope, replay).form(max_files=1, max_fields=12, max_part_size=max_upload)
            except Exception as exc:  # malformed multipart
                raise RequestError(400, f"cannot read the upload ({getattr(exc, 'detail', None) or exc})") from None
            try:
                upload = form.get("file")
                if upload is None or isinstance(upload, str):
                    raise RequestError(400, "no file in the upload (multipart field 'file')")
                data = await upload.read()
                if len(data) > max_upload:
                    raise RequestError(413, f"upload is over the limit of {max_upload:,} bytes")
                if not data:
                    raise RequestError(422, f"{upload.filename or 'upload'}: the file is empty")
                uses = _uses(form)
                top, metric, parts, same_part = (_int(form, "top", 10, 1, MAX_TOP),
                                                 _metric(form, WHERE_USED_METRIC if uses else QUERY_METRIC),
                                                 _flag(form, "parts"), _flag(form, "same_part"))
                if parts or uses:
                    service.parts_searcher()  # 409 before signing, when the store has no sub-parts
                result = await anyio.to_thread.run_sync(service.query_upload, upload.filename or "upload", data, top,
                                                        metric, _where(form), parts, uses, same_part)
            finally:
                await form.close()
        finally:
            uploads.release()
        return JSONResponse(result)

    async def thumbnail(request):
        png = await in_file_thread(service.thumbnail, _id(request.query_params))
        return Response(png, media_type="image/png", headers={"Cache-Control": "max-age=3600"})

    async def compare_view(request):
        q = request.query_params
        return JSONResponse(await run_in_threadpool(service.compare, _id(q, "a"), _id(q, "b")))

    async def not_found(request):
        return JSONResponse({"error": f"no such API: {request.url.path}"}, status_code=404)

    routes = [
        Route("/", index),
        Route("/favicon.ico", lambda request: Response(status_code=204)),
        Route("/api/store", guarded(info)),
        Route("/api/entries", guarded(entries)),
        Route("/api/entry", guarded(entry)),
        Route("/api/query", guarded(query_get), methods=["GET"]),
        Route("/api/query", guarded(query_post), methods=["POST"]),
        Route("/api/thumbnail", guarded(thumbnail)),
        Route("/api/compare", guarded(compare_view)),
        Route("/api/{rest:path}", not_found, methods=["GET", "POST", "PUT", "DELETE", "PATCH"]),
        Mount("/static", StaticFiles(directory=static), name="static"),
    ]

    body_limits = dict(idle=BODY_IDLE_TIMEOUT if body_idle is None else body_idle,
                       total=BODY_TIMEOUT if body_total is None else body_total)
    return Starlette(routes=routes, middleware=[Middleware(SecurityHeaders),
                                                Middleware(HostOriginGuard, hosts=allowed_hosts(host)),
                                                Middleware(BodyTimeout, **body_limits)])


def _multipart_boundary(content_type: str) -> bytes:
    """The boundary of a ``multipart/form-data`` Content-Type (415 or 400 otherwise)."""
    from email.message import Message

    message = Message()
    message["content-type"] = content_type
    if message.get_content_type() != "multipart/form-data":
        raise RequestError(415, "send the part as multipart/form-data with the field 'file'")
    boundary = message.get_param("boundary")
    if not isinstance(boundary, str) or not 0 < len(boundary) <= 200:
        raise RequestError(400, "the multipart Content-Type has no boundary")
    try:
        return boundary.encode("ascii")
    except UnicodeEncodeError:
        raise RequestError(400, "the multipart boundary is not ASCII") from None


async def _read_body(request, limit: int) -> bytes:
    """The whole request body, refused (413) as soon as it passes ``limit`` bytes."""
    from starlette.requests import ClientDisconnect

    chunks, total = [], 0
    try:
        async for chunk in request.stream():
            total += len(chunk)
            if total > limit:
                raise RequestError(413, f"upload is over the limit of {limit:,} bytes")
            chunks.append(chunk)
    except ClientDisconnect:
        raise RequestError(400, "the client went away before the upload was whole") from None
    return b"".join(chunks)


def _multipart_is_whole(body: bytes, boundary: bytes) -> bool:
    """Whether a multipart body ends with its closing boundary (``--B--``, then at most line ends).

    python-multipart reads a body cut short as if it were whole (the last part simply ends),
    which would rank a truncated part file; such an upload is refused instead."""
    return body.rstrip(b"\r\n").endswith(b"--" + boundary + b"--")


class SecurityHeaders:
    """ASGI middleware: headers that keep the page from loading anything but its own files."""

    HEADERS = [
        (b"x-content-type-options", b"nosniff"),
        (b"content-security-policy", b"default-src 'self'; img-src 'self' data:; style-src 'self'; object-src 'none'"),
        (b"referrer-policy", b"no-referrer"),
        (b"x-frame-options", b"DENY"),
    ]

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                message.setdefault("headers", [])
                message["headers"] = list(message["headers"]) + self.HEADERS
            await send(message)

        await self.app(scope, receive, send_with_headers)
