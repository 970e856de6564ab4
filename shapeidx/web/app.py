"""``shapeidx serve``: a local web page and JSON API over a store, the paper's query-by-example browsing.

Starlette (with uvicorn as the server): a small, well-kept ASGI toolkit that gives routing,
multipart uploads (python-multipart), static files and a test client, and nothing we do not
use (no ORM, no templates, no validation layer). The API is documented in docs/web.md.

The store is read once at start (:class:`StoreService`): the ok entries' histograms
(:class:`~shapeidx.ranking.SignatureTable`), paths, fractions and the failed entries with their
reasons stay in memory, so a query costs one vectorised ranking. The store is a snapshot:
restart the server to see a newer build.

Every request is treated as hostile:

* an ``id`` is looked up among the store's entries (exact match), never used as a path by
  itself; the file of an entry must resolve (symbolic links followed) to a place inside the
  store's root, or it is refused (403); the server never sends part files, only thumbnails;
* uploads need a Content-Length within :data:`MAX_UPLOAD` (413 beyond), are written to a
  private temporary file with the original name's suffix (so the loader picks the format),
  read, and deleted; a file that is not a usable part is a 422 with the loader's one-line
  reason;
* ``top`` and ``metric`` are checked (400); unknown ids are 404; nothing raises past a handler.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import threading
from collections import OrderedDict
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from ..distance import METRICS, compare
from ..errors import LoadError, ShapeidxError, StoreError
from ..pictures.similarity import SimilarityScale, signatures_of
from ..pictures.thumbcache import StoreThumbnails
from ..signing.histogram import Signature
from ..signing.parameters import HISTOGRAMS

#: Largest upload accepted, bytes (``serve --max-upload`` changes it).
MAX_UPLOAD = 64 * 1024 * 1024
#: Largest ``top`` a request may ask for.
MAX_TOP = 5000
#: Uploaded queries kept (signature and picture) so that their metric, k and compare view
#: can change without uploading again.
UPLOADS_KEPT = 64
#: Suffixes an upload may keep; any other name is sniffed from its content.
PART_SUFFIXES = (".stl", ".obj", ".off", ".ply", ".wrl", ".wrz", ".vrml")
UPLOAD_PREFIX = "upload:"


class RequestError(Exception):
    """A request that cannot be answered: HTTP status and a one-line message for the user."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


@dataclass
class Upload:
    """An uploaded part: its name, signature and thumbnail."""

    name: str
    signature: Signature
    png: bytes | None
    note: str


def _histograms_json(signature: Signature) -> dict:
    return {name: {"p": [round(float(v), 7) for v in signature.histograms[name].p], "mean": signature.histograms[name].mean}
            for name in HISTOGRAMS}


def _fractions_json(values) -> dict:
    return {"in": float(values[0]), "out": float(values[1]), "mixed": float(values[2])}


def upload_suffix(filename: str) -> str:
    """The suffix a temporary copy of an upload gets: its own when it names a part format."""
    name = os.path.basename(filename.replace("\\", "/")).lower()
    gz = name.endswith(".gz")
    stem = name[:-3] if gz else name
    suffix = os.path.splitext(stem)[1]
    if suffix in PART_SUFFIXES:
        return suffix + (".gz" if gz else "")
    return ".gz" if gz else ".part"


class StoreService:
    """A store held in memory for the web page: ranking, entries, thumbnails, uploads.

    Parameters
    ----------
    store : path of the store
    """

    def __init__(self, store: str | os.PathLike):
        from ..signing.parameters import SIGNATURE_VERSION
        from ..ranking import SignatureTable
        from ..store import STATUS_OK, open_store

        self.store = Path(store).absolute()
        self.reader = open_store(self.store)
        if self.reader.params.signature_version != SIGNATURE_VERSION:
            raise StoreError(f"store {self.store} holds signatures of version {self.reader.params.signature_version},"
                             f" this shapeidx makes version {SIGNATURE_VERSION}: rebuild it")
        self.table = SignatureTable.load(self.reader)
        self.thumbs = StoreThumbnails(self.reader)
        self.root = Path(self.reader.attrs.get("root") or ".")
        self.real_root = Path(os.path.realpath(self.root))
        status = self.reader.column("entries/status")
        self.all_paths = self.reader.paths
        self.ok = status == STATUS_OK
        self.reasons = self.reader.column("entries/reason")
        self.triangles = self.reader.column("entries/triangles")
        self.all_fractions = self.reader.column("entries/fractions")
        self._lock = threading.Lock()  # one h5py reader shared by the request threads
        self._scales: dict = {}
        self._uploads: OrderedDict = OrderedDict()
        self.max_upload = MAX_UPLOAD
        self.scale("weighted")  # the default metric's calibration before the first query

    def close(self) -> None:
        self.reader.close()

    # -- facts
    def info(self) -> dict:
        return {
            "store": str(self.store),
            "root": str(self.root),
            "entries": int(len(self.all_paths)),
            "ok": int(self.ok.sum()),
            "failed": int((~self.ok).sum()),
            "metrics": list(METRICS),
            "points": self.reader.params.points,
            "max_upload": self.max_upload,
        }

    def scale(self, metric: str) -> SimilarityScale:
        with self._lock:
            if metric not in self._scales:
                self._scales[metric] = SimilarityScale.cached(self.reader, self.table, metric, self.thumbs.cache.folder)
            return self._scales[metric]

    def entries(self, offset: int, limit: int, status: str, contains: str) -> dict:
        picked = np.ones(len(self.all_paths), dtype=bool)
        if status == "ok":
            picked &= self.ok
        elif status == "failed":
            picked &= ~self.ok
        if contains:
            needle = contains.lower()
            picked &= np.array([needle in p.lower() for p in self.all_paths], dtype=bool)
        rows = np.flatnonzero(picked)
        page = rows[offset : offset + limit]
        fractions = self.all_fractions
        return {
            "total": int(len(rows)),
            "offset": offset,
            "entries": [
                {
                    "id": str(self.all_paths[i]),
                    "status": "ok" if self.ok[i] else "failed",
                    "reason": str(self.reasons[i]),
                    "triangles": int(self.triangles[i]),
                    "fractions": _fractions_json(fractions[i]) if self.ok[i] else None,
                }
                for i in page
            ],
        }

    # -- ids
    def table_index(self, entry: str) -> int:
        """Position of an ok entry in the table (404 for an unknown id, 409 for a failed one)."""
        i = self.table.index_of(entry)
        if i is not None:
            return i
        j = self.reader.index_of(entry, self.all_paths)
        if j is None:
            raise RequestError(404, f"no entry {entry!r} in the store")
        raise RequestError(409, f"entry {entry!r} failed to index: {self.reasons[j]}")

    def file_of(self, entry: str) -> Path:
        """The entry's file, if it lies inside the store's root once links are followed (else 403)."""
        self.table_index(entry)  # a known entry or an error: the id is never a path by itself
        real = Path(os.path.realpath(self.root / entry))
        if not real.is_relative_to(self.real_root):
            raise RequestError(403, f"entry {entry!r} resolves outside the store's root; not served")
        return real

    def signature_of(self, query_id: str) -> tuple[Signature, int | None]:
        """The signature of an entry or of a kept upload, and its table index (None for uploads)."""
        if query_id.startswith(UPLOAD_PREFIX):
            return self.upload(query_id).signature, None
        i = self.table_index(query_id)
        with self._lock:
            return signatures_of(self.reader, self.table.rows[[i]])[0], i

    def upload(self, query_id: str) -> Upload:
        with self._lock:
            found = self._uploads.get(query_id)
            if found is None:
                raise RequestError(404, "unknown upload (uploads are kept while the server runs, the latest"
                                        f" {UPLOADS_KEPT}); upload the part again")
            self._uploads.move_to_end(query_id)
            return found

    # -- answers
    def describe(self, query_id: str, known: tuple | None = None) -> dict:
        """An entry or upload for the page: name, path, fractions, histograms, picture.

        ``known`` is ``signature_of(query_id)`` when the caller has it already.
        """
        signature, i = known or self.signature_of(query_id)
        out = {"id": query_id, "fractions": signature.fractions, "histograms": _histograms_json(signature)}
        if i is None:
            upload = self.upload(query_id)
            out.update(name=upload.name, path=None, note=upload.note,
                       thumbnail=f"/api/thumbnail?id={_quote(query_id)}" if upload.png else None)
        else:
            out.update(name=query_id, path=str(self.root / query_id), thumbnail=f"/api/thumbnail?id={_quote(query_id)}")
        return out

    def query(self, query_id: str, top: int, metric: str) -> dict:
        signature, first = self.signature_of(query_id)
        return self._answer(query_id, signature, first, top, metric)

    def _answer(self, query_id, signature, first, top, metric) -> dict:
        from ..ranking import top_hits

        query = self.describe(query_id, (signature, first))
        distances = self.table.distances(signature, metric)
        hits = top_hits(distances, self.table.paths, top, first)
        scale = self.scale(metric)
        for hit in hits:
            i = self.table.index_of(hit["path"])
            share = scale.share(hit["distance"])
            hit.update(
                id=hit.pop("path"),
                words=scale.words(hit["distance"]),
                share=share,
                fractions=_fractions_json(self.table.fractions[i]),
            )
            hit["thumbnail"] = f"/api/thumbnail?id={_quote(hit['id'])}"
        return {"query": query, "metric": metric, "top": top, "entries": len(self.table),
                "calibration": scale.describe(), "hits": hits}

    def query_upload(self, filename: str, data: bytes, top: int, metric: str) -> dict:
        """Sign an uploaded part file and rank the store against it (LoadError for a bad part)."""
        from ..pictures.render import render_solid_png
        from ..api import load
        from ..io import LoadLimits
        from ..signing.pipeline import signature_of_solid

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
                    params = self.reader.params
                    solid = load(path, limits=LoadLimits(faceting=params.faceting))
                    signature = signature_of_solid(solid, params.points, params.seed, params.bin_divisor)
                except LoadError as exc:
                    raise RequestError(422, f"{name}: {exc.reason}") from None
                try:
                    png, note = render_solid_png(solid), ""
                except Exception as exc:  # a picture is a nicety: the query still answers
                    png, note = None, f"no picture ({type(exc).__name__})"
            with self._lock:
                self._uploads[query_id] = Upload(name, signature, png, note)
                while len(self._uploads) > UPLOADS_KEPT:
                    self._uploads.popitem(last=False)
        return self.query(query_id, top, metric)

    def thumbnail(self, query_id: str) -> bytes:
        if query_id.startswith(UPLOAD_PREFIX):
            png = self.upload(query_id).png
            if png is None:
                raise RequestError(404, "no picture of this upload")
            return png
        self.file_of(query_id)  # a known entry inside the root, or an error
        try:
            return self.thumbs.png(query_id)
        except LoadError as exc:
            raise RequestError(404, f"no picture of {query_id!r}: {exc.reason}") from None

    def compare(self, a: str, b: str) -> dict:
        sig_a, _ = self.signature_of(a)
        sig_b, _ = self.signature_of(b)
        return {"a": self.describe(a), "b": self.describe(b), "distances": compare(sig_a, sig_b)}


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


def _metric(params) -> str:
    metric = params.get("metric") or "weighted"
    if metric not in METRICS:
        raise RequestError(400, f"unknown metric {str(metric)[:40]!r}; expected one of {', '.join(METRICS)}")
    return metric


def _id(params, name: str = "id") -> str:
    value = params.get(name)
    if not value:
        raise RequestError(400, f"missing {name}")
    return str(value)


def create_app(service: StoreService, max_upload: int = MAX_UPLOAD):
    """The Starlette application serving ``service``'s store."""
    from starlette.applications import Starlette
    from starlette.middleware import Middleware
    from starlette.concurrency import run_in_threadpool
    from starlette.responses import FileResponse, JSONResponse, Response
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    static = Path(str(resources.files("shapeidx.web").joinpath("static")))
    service.max_upload = max_upload

    def guarded(handler):
        async def endpoint(request):
            try:
                return await handler(request)
            except RequestError as exc:
                return JSONResponse({"error": exc.message}, status_code=exc.status)
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
        result = await run_in_threadpool(service.query, _id(q), _int(q, "top", 10, 1, MAX_TOP), _metric(q))
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
        if "multipart/form-data" not in request.headers.get("content-type", ""):
            raise RequestError(415, "send the part as multipart/form-data with the field 'file'")
        try:
            form = await request.form(max_files=1, max_fields=10, max_part_size=max_upload)
        except Exception as exc:  # malformed multipart
            raise RequestError(400, f"cannot read the upload ({exc})") from None
        try:
            upload = form.get("file")
            if upload is None or isinstance(upload, str):
                raise RequestError(400, "no file in the upload (multipart field 'file')")
            data = await upload.read()
            if len(data) > max_upload:
                raise RequestError(413, f"upload is over the limit of {max_upload:,} bytes")
            if not data:
                raise RequestError(422, f"{upload.filename or 'upload'}: the file is empty")
            top, metric = _int(form, "top", 10, 1, MAX_TOP), _metric(form)
            result = await run_in_threadpool(service.query_upload, upload.filename or "upload", data, top, metric)
        finally:
            await form.close()
        return JSONResponse(result)

    async def thumbnail(request):
        png = await run_in_threadpool(service.thumbnail, _id(request.query_params))
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

    return Starlette(routes=routes, middleware=[Middleware(SecurityHeaders)])


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
