"""Result sheets: one self-contained HTML file of a query and its hits (``query --sheet``).

The file needs nothing but itself: thumbnails are PNG ``data:`` URIs, the histogram overlays
inline SVG, the style and the pager inline; it makes no network request and opens from disk.
Each hit shows its rank, thumbnail, distance, the similarity in words
(:mod:`shapeidx.pictures.similarity`), its path as an absolute ``file://`` link, its class
fractions and its four histograms over the query's.

Long answers stay usable: images are ``loading="lazy"``, hits are shown :data:`PAGE` at a
time by a few lines of script (all of them without script), the query's curves are written
once and reused by every hit (SVG ``<use>``), and thumbnails are made for the first
``thumbnails`` hits only (default :data:`DEFAULT_THUMBNAILS`; each new one costs a render).
"""

from __future__ import annotations

import base64
import datetime
import html
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..distance.metrics import default_metric, label as metric_label
from ..signing.histogram import Signature
from ..signing.parameters import BIN_DIVISOR, HISTOGRAMS

PAGE = 100
DEFAULT_THUMBNAILS = 200
#: The overlays show distance / mean from 0 to XMAX.
XMAX = 3.0
QUERY_COLOUR, HIT_COLOUR = "#1f77b4", "#d62728"
CLASS_COLOURS = {"in": "#4c9f70", "out": "#e0a030", "mixed": "#8a8fb8"}


@dataclass
class SheetPart:
    """A part on a sheet: what to call it, where it is, its signature and its picture.

    Attributes
    ----------
    label : str
    path : absolute path of the part file (or None)
    signature : Signature
    png : bytes or None
        The thumbnail; ``None`` shows ``note`` instead.
    note : str
        Why there is no picture.
    context_png : bytes or None
        A sub-part's: the picture of the whole file holding it, drawn small beside its own.
    """

    label: str
    path: Path | None
    signature: Signature
    png: bytes | None = None
    note: str = ""
    context_png: bytes | None = None


@dataclass
class SheetHit:
    part: SheetPart
    rank: int
    distance: float
    words: str = ""
    extra: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- pieces


def _esc(text) -> str:
    return html.escape(str(text), quote=True)


def data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _curve(histogram, width: float, height: float, y_top: float) -> str:
    """Polyline points of a histogram in a panel of ``width`` x ``height`` (y down)."""
    p = histogram.p
    if len(p) == 0 or y_top <= 0:
        return ""
    x = (np.arange(len(p)) + 0.5) / BIN_DIVISOR
    keep = x <= XMAX
    x, p = x[keep], p[keep]
    px = x / XMAX * width
    py = height - np.minimum(p / y_top, 1.0) * height
    return " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(px, py))


PANEL_W, PANEL_H, GAP, LABEL_H = 128, 46, 8, 12


def overlay_svg(query: Signature, hit: Signature) -> str:
    """Four small panels (ALL, IN, OUT, MIXED): the hit's curves (red) over the query's (blue)."""
    width = 2 * PANEL_W + GAP
    height = 2 * (PANEL_H + LABEL_H) + GAP
    body = []
    for k, name in enumerate(HISTOGRAMS):
        x0 = (k % 2) * (PANEL_W + GAP)
        y0 = (k // 2) * (PANEL_H + LABEL_H + GAP) + LABEL_H
        hq, hh = query.histograms[name], hit.histograms[name]
        q_peak = float(hq.p.max()) if len(hq.p) else 0.0
        h_peak = float(hh.p.max()) if len(hh.p) else 0.0
        top = max(q_peak, h_peak) * 1.05
        body.append(f'<text x="{x0}" y="{y0 - 3}" font-size="9" fill="#444">{name.upper()}</text>')
        body.append(f'<rect x="{x0}" y="{y0}" width="{PANEL_W}" height="{PANEL_H}" fill="#fafafa" stroke="#ddd"/>')
        if q_peak:
            # the query's curve is drawn at height 1 per its peak: scale it to this panel's top
            body.append(f'<use href="#q-{name}" transform="translate({x0},{y0 + PANEL_H}) scale(1,{-PANEL_H * q_peak / top:.4f})"/>')
        if h_peak:
            body.append(
                f'<polyline transform="translate({x0},{y0})" points="{_curve(hh, PANEL_W, PANEL_H, top)}" fill="none"'
                f' stroke="{HIT_COLOUR}" stroke-width="1.1"/>'
            )
    return (
        f'<svg class="overlay" width="{width}" height="{height}" viewBox="0 0 {width} {height}" role="img"'
        ' aria-label="histograms of the query (blue) and the hit (red)">' + "".join(body) + "</svg>"
    )


def query_symbols(query: Signature) -> str:
    """A hidden SVG defining the query's four curves once, y up from 0 to its own peak 1 (every <use> scales them)."""
    parts = []
    for name in HISTOGRAMS:
        h = query.histograms[name]
        p = h.p
        points = ""
        if len(p):
            x = (np.arange(len(p)) + 0.5) / BIN_DIVISOR
            keep = x <= XMAX
            px, py = x[keep] / XMAX * PANEL_W, p[keep] / p.max()
            points = " ".join(f"{a:.1f},{b:.4f}" for a, b in zip(px, py))
        parts.append(
            f'<g id="q-{name}"><polyline points="{points}" fill="none" stroke="{QUERY_COLOUR}" stroke-width="1.4"'
            ' vector-effect="non-scaling-stroke"/></g>'
        )
    return '<svg width="0" height="0" style="position:absolute" aria-hidden="true"><defs>' + "".join(parts) + "</defs></svg>"


def fractions_html(signature: Signature) -> str:
    """The class fractions as words and as a stacked bar."""
    f = signature.fractions
    bar = "".join(
        f'<span style="width:{100 * f[c]:.2f}%;background:{CLASS_COLOURS[c]}" title="{c.upper()} {100 * f[c]:.2f}%"></span>'
        for c in ("in", "out", "mixed")
    )
    words = " · ".join(f"{c.upper()} {100 * f[c]:.1f}%" for c in ("in", "out", "mixed"))
    return f'<div class="fractions">{words}<div class="bar">{bar}</div></div>'


def _picture(part: SheetPart, size: int, lazy: bool) -> str:
    loading = ' loading="lazy" decoding="async"' if lazy else ""
    if part.png is None:
        picture = f'<div class="nopic" style="width:{size}px;height:{size}px">{_esc(part.note or "no picture")}</div>'
    else:
        picture = (f'<img class="thumb" src="{data_uri(part.png)}" width="{size}" height="{size}"'
                   f' alt="{_esc(part.label)}"{loading}>')
    if part.context_png is None:
        return picture
    small = size * 3 // 8
    return (f'<div class="pictures">{picture}<figure class="context"><img class="context-thumb"'
            f' src="{data_uri(part.context_png)}" width="{small}" height="{small}" alt="the whole file"{loading}>'
            f'<figcaption>whole file</figcaption></figure></div>')


def _metadata_html(metadata: dict | None) -> str:
    if not metadata:
        return ""
    return '<div class="metadata">' + " · ".join(f"<b>{_esc(k)}</b> {_esc(v)}" for k, v in metadata.items()) + "</div>"


def _times(count) -> str:
    count = count or 1
    return "once" if count == 1 else f"{count} times"


def _sub_part_html(extra: dict) -> str:
    """A sub-part's line (``query --parts``): which file holds it and how many times."""
    parent = extra.get("parent")
    if not parent:
        return ""
    title = extra.get("title")
    named = f" ({_esc(title)})" if title else ""
    return (f'<div class="subpart">sub-part{named} in <b class="parent">{_esc(parent)}</b>, {_times(extra.get("count"))}</div>')


def _link(part: SheetPart) -> str:
    if part.path is None:
        return f'<span class="path">{_esc(part.label)}</span>'
    path = Path(part.path).absolute()
    return f'<a class="path" href="{_esc(path.as_uri())}" title="{_esc(path)}">{_esc(part.label)}</a>'


STYLE = """
body{font:14px/1.4 system-ui,-apple-system,'Segoe UI',sans-serif;margin:0;background:#f3f4f6;color:#222}
header{background:#fff;border-bottom:1px solid #ddd;padding:16px 24px;display:flex;gap:24px;align-items:flex-start}
header h1{font-size:20px;margin:0 0 6px}
header .thumb,header .nopic{margin:0;flex:none}
.meta{color:#555;font-size:13px;max-width:70em}
.hits{display:grid;grid-template-columns:repeat(auto-fill,minmax(300px,1fr));gap:14px;padding:18px 24px}
.hit{background:#fff;border:1px solid #ddd;border-radius:6px;padding:10px;display:flex;flex-direction:column;gap:4px}
.hit .top{display:flex;justify-content:space-between;align-items:baseline}
.rank{font-weight:700;font-size:18px}
.distance{font-variant-numeric:tabular-nums;color:#333}
.words{font-weight:600;color:#1a5e3a}
.words.far{color:#8a4b00}
.share{font-weight:400;color:#555;font-size:12px}
details{font-size:12px;color:#555;margin-top:4px}
.thumb{display:block;margin:0 auto;background:#fff}
.pictures{display:flex;align-items:flex-end;justify-content:center;gap:6px}
.pictures .thumb{margin:0}
.context{margin:0;text-align:center;font-size:11px;color:#666}
.context-thumb{display:block;background:#fff;border:1px solid #ddd;border-radius:3px}
.nopic{display:flex;align-items:center;justify-content:center;margin:0 auto;color:#888;font-size:12px;text-align:center;border:1px dashed #ccc}
.path{word-break:break-all;font-size:12.5px}
.fractions{font-size:12px;color:#444}
.metadata{font-size:12px;color:#333;word-break:break-word}
.subpart{font-size:12.5px;color:#333;word-break:break-all}
.bar{display:flex;height:6px;margin-top:2px;border-radius:3px;overflow:hidden}
.bar span{display:block;height:6px}
.legend{font-size:12px;color:#555}
.legend b.q{color:%s}.legend b.h{color:%s}
nav.pages{padding:0 24px 24px;display:flex;gap:6px;flex-wrap:wrap}
nav.pages button{border:1px solid #bbb;background:#fff;border-radius:4px;padding:3px 9px;cursor:pointer}
nav.pages button.on{background:#1f77b4;color:#fff;border-color:#1f77b4}
""" % (QUERY_COLOUR, HIT_COLOUR)

PAGER = """
(function(){var hits=document.querySelectorAll('.hit[data-page]');var n=0;hits.forEach(function(h){n=Math.max(n,+h.dataset.page)});
if(n<1)return;var nav=document.createElement('nav');nav.className='pages';document.body.appendChild(nav);
function show(p){hits.forEach(function(h){h.style.display=(+h.dataset.page===p)?'':'none'});
nav.querySelectorAll('button').forEach(function(b){b.className=(+b.dataset.page===p)?'on':''});window.scrollTo(0,0)}
for(var p=0;p<=n;p++){var b=document.createElement('button');b.textContent=(p*%d+1)+'-'+Math.min((p+1)*%d,hits.length);
b.dataset.page=p;b.onclick=function(){show(+this.dataset.page)};nav.appendChild(b)}show(0)})();
""" % (PAGE, PAGE)


def sheet_html(title: str, query: SheetPart, hits: list[SheetHit], meta: list[str], calibration: str = "") -> str:
    """The whole sheet as one HTML string."""
    cards = []
    for k, hit in enumerate(hits):
        far = " far" if hit.words in ("weakly similar", "not similar") else ""
        cards.append(
            f'<article class="hit" data-page="{k // PAGE}" data-rank="{hit.rank}" data-path="{_esc(hit.part.label)}">'
            f'<div class="top"><span class="rank">#{hit.rank}</span><span class="distance">distance {hit.distance:.4g}</span></div>'
            + (f'<div class="words{far}">{_esc(hit.words)} <span class="share">{_esc(hit.extra.get("share", ""))}</span></div>'
               if hit.words else "")
            + _picture(hit.part, 160, lazy=k >= 12)
            + _link(hit.part)
            + _sub_part_html(hit.extra)
            + _metadata_html(hit.extra.get("metadata"))
            + fractions_html(hit.part.signature)
            + overlay_svg(query.signature, hit.part.signature)
            + "</article>"
        )
    meta_html = "".join(f"<div>{line}</div>" for line in meta)
    if calibration:
        meta_html += f"<details><summary>How the similarity words are calibrated</summary>{_esc(calibration)}</details>"
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<meta name=\"viewport\" content=\"width=device-width,initial-scale=1\"><title>{_esc(title)}</title>"
        "<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; img-src data:; style-src 'unsafe-inline';"
        " script-src 'unsafe-inline'\">"
        f"<style>{STYLE}</style></head><body>"
        + query_symbols(query.signature)
        + "<header>"
        + _picture(query, 200, lazy=False)
        + f'<div><h1>{_esc(title)}</h1><div class="query">{_link(query)}</div>{fractions_html(query.signature)}'
        f'<div class="meta">{meta_html}</div>'
        f'<div class="legend">Histograms: distance / mean of the set from 0 to {XMAX:g}; <b class="q">query</b> and'
        f' <b class="h">hit</b>.</div></div></header>'
        f'<main class="hits">{"".join(cards)}</main>'
        + (f"<script>{PAGER}</script>" if len(hits) > PAGE else "")
        + "</body></html>\n"
    )


def write_sheet(output: str | os.PathLike, title: str, query: SheetPart, hits: list[SheetHit], meta: list[str],
                calibration: str = "") -> Path:
    """Write the sheet to ``output`` (atomically: a temporary file renamed into place)."""
    return _write_html(output, sheet_html(title, query, hits, meta, calibration))


def check_sheet_folder(output: str | os.PathLike) -> None:
    """Raise StoreError when ``output``'s folder does not exist (asked before any work)."""
    from ..errors import StoreError

    folder = Path(output).absolute().parent
    if not folder.is_dir():
        raise StoreError(f"{output}: no folder {folder} to write the sheet in")


def _write_html(output: str | os.PathLike, text: str) -> Path:
    """``text`` written to ``output`` atomically (a temporary file renamed into place)."""
    from ..errors import ShapeidxError

    output = Path(output)
    temporary = output.with_name(f".{output.name}.tmp-{os.getpid()}")
    try:
        temporary.write_text(text, encoding="utf-8")
        os.replace(temporary, output)
    except OSError as exc:
        temporary.unlink(missing_ok=True) if temporary.parent.is_dir() else None
        raise ShapeidxError(f"{output}: cannot write the sheet ({exc.strerror or exc})") from None
    return output


# ----------------------------------------------------------------------------- sheets of the commands


def _picture_of(render, label: str) -> tuple[bytes | None, str]:
    from ..errors import ShapeidxError

    try:
        return render(), ""
    except ShapeidxError as exc:
        return None, f"no picture: {exc}"
    except OSError as exc:
        return None, f"no picture: {exc.strerror or exc}"


def _thumbnails_of(searcher):
    """The thumbnails of a searcher's entries; a sub-entry ``FILE#n``'s (drawn from its file
    split again) are cached with the whole store's (``STORE/thumbs``)."""
    from .thumbcache import StoreThumbnails, cache_dir_of_store

    sub_parts = bool(getattr(searcher, "parts", False))
    # a store's sub-parts searcher has STORE/parts for its store; a sharded store's, STORE itself
    whole = searcher.store if hasattr(searcher, "shards") else searcher.store.parent
    return StoreThumbnails(searcher, folder=cache_dir_of_store(whole) if sub_parts else None)


def _sub_part_pictures(thumbs, entry: str, parent: str) -> tuple[bytes | None, str, bytes | None]:
    """A sub-part's own picture (or why none), and its file's (None when it is the same: a
    file that is one part)."""
    png, note = _picture_of(lambda: thumbs.sub_part_png(entry), entry)
    whole, _ = _picture_of(lambda: thumbs.png(parent, record=entry), parent)
    return png, note, (None if whole == png else whole)


def _query_part(searcher, thumbs, query, signature) -> tuple[SheetPart, dict]:
    """The query of a sheet, with its picture; and, for a sub-entry, its ``parent`` and ``count``."""
    from .thumbcache import ThumbnailCache

    sub_parts = bool(getattr(searcher, "parts", False))
    header_extra: dict = {}
    if query.entry is not None:
        shown, context = query.entry, None
        found = searcher.view.find(query.entry) if sub_parts else None
        if found is not None:  # a sub-entry FILE#n: drawn itself, its file beside it
            parent, count = searcher.parent_at(searcher.view.position_of(found))
            shown = parent or query.entry
            header_extra = {"parent": parent, "count": count}
            png, note, context = _sub_part_pictures(thumbs, query.entry, shown)
        else:
            png, note = _picture_of(lambda: thumbs.png(shown, record=query.entry), query.entry)
        part = SheetPart(query.entry, thumbs.file_of(shown), signature, png, note, context)
    else:
        from .render import render_solid_png

        cache = ThumbnailCache(thumbs.cache.folder)
        source = query.path
        if query.solid is not None and source is not None:
            png, note = _picture_of(lambda: cache.png(source, solid=query.solid), query.label)
        elif query.solid is not None:  # standard input, arrays: no file to cache the picture by
            png, note = _picture_of(lambda: render_solid_png(query.solid), query.label)
        else:
            png, note = None, "no picture (the query was a signature)"
        part = SheetPart(query.label, Path(source) if source else None, signature, png, note)
    return part, header_extra


def answer_sheet(searcher, answer, query, output: str | os.PathLike, thumbnails: int = DEFAULT_THUMBNAILS) -> Path:
    """Write the sheet of a search's answer (:class:`~shapeidx.search.Answer` of ``query`` by
    ``searcher``): the very hits, distances and metadata the command line printed, drawn.

    Raises StoreError when ``output``'s folder does not exist.
    """
    from .similarity import closer_than

    thumbs, part, header_extra, scale = _sheet_start(searcher, output, query, answer.signature, answer.metric)
    sub_parts = bool(getattr(searcher, "parts", False))
    sheet_hits = []
    for k, hit in enumerate(answer.hits):
        shown = hit.parent or hit.relative_path  # a sub-part: the link opens the whole file holding it
        context = None
        if k >= thumbnails:
            png, note = None, f"no picture beyond the first {thumbnails} hits (--thumbnails)"
        elif hit.parent is not None:  # a sub-part: drawn itself, its file small beside it
            png, note, context = _sub_part_pictures(thumbs, hit.relative_path, hit.parent)
        else:
            png, note = _picture_of(lambda: thumbs.png(shown, record=hit.relative_path), hit.relative_path)
        words = scale.words(hit.distance)
        share = scale.share(hit.distance)
        extra = {"share": closer_than(share)} if share is not None and hit.distance > 0 else {}
        extra["metadata"] = hit.metadata
        if hit.parent is not None:
            extra.update(parent=hit.parent, count=hit.count, title=hit.metadata.get("title", ""))
        hit_part = SheetPart(hit.relative_path, thumbs.file_of(shown), searcher.signature_of(hit.relative_path), png, note,
                             context)
        sheet_hits.append(SheetHit(hit_part, hit.rank, hit.distance, words, extra))
    filters = "; ".join(answer.filters)
    what = "sub-parts" if sub_parts else "parts"
    meta = [
        f"Store <code>{_esc(answer.store)}</code>: {answer.entries:,} {what} (root <code>{_esc(answer.root)}</code>).",
        f"Metric {_esc(metric_label(answer.metric))}, top {len(answer.hits)}"
        + (f", filters {_esc(filters)} ({answer.considered:,} {what} left)" if filters else "")
        + f". Made {datetime.datetime.now():%Y-%m-%d %H:%M}.",
    ]
    if sub_parts:
        meta.append("Sub-parts of the files (<code>build --parts</code>): each is drawn in its own frame, the picture"
                    " of the whole file that holds it small beside it."
                    + (f" The query is a sub-part of <b>{_esc(header_extra['parent'])}</b>,"
                       f" {_times(header_extra['count'])} there." if header_extra.get("parent") else ""))
    if answer.reason:
        meta.append(f"No hit: {_esc(answer.reason)}.")
    title = f"{'Sub-parts' if sub_parts else 'Parts'} nearest to {Path(part.label).name}"
    return write_sheet(output, title, part, sheet_hits, meta, scale.describe())


def _sheet_start(searcher, output, query, signature, metric: str):
    """What both sheets of a searcher begin with: ``output``'s folder checked (StoreError when
    it does not exist), the store's thumbnails, the query's part and header, the metric's
    similarity scale."""
    check_sheet_folder(output)
    thumbs = _thumbnails_of(searcher)
    part, header_extra = _query_part(searcher, thumbs, query, signature)
    return thumbs, part, header_extra, _similarity_scale(searcher, metric, thumbs)


def _similarity_scale(searcher, metric: str, thumbs):
    """The metric's similarity scale of the searcher's store (a sharded store's: calibrated on
    its first shard, where it is)."""
    from .similarity import SimilarityScale

    if hasattr(searcher, "shards"):
        from .similarity import shard_scale

        return searcher.on_shard(0, shard_scale, metric, 0, len(searcher.shards))
    return SimilarityScale.cached(searcher, metric, thumbs.cache.folder)


def where_used_sheet(searcher, answer, query, output: str | os.PathLike, thumbnails: int = DEFAULT_THUMBNAILS) -> Path:
    """Write the sheet of ``where-used`` (:class:`~shapeidx.search.where_used.WhereUsed` of
    ``query`` by ``searcher``, opened with ``parts=True``): one card per file holding a
    sub-part like the query, with the file's picture, its nearest sub-part (whose histograms
    are drawn over the query's) and how many times the file holds it.

    Raises StoreError when ``output``'s folder does not exist.
    """
    from .similarity import closer_than

    thumbs, part, header_extra, scale = _sheet_start(searcher, output, query, query.signature, answer.metric)
    cards = []
    for k, use in enumerate(answer.uses):
        if k < thumbnails:  # the sub-part itself, the file small beside it
            png, note, context = _sub_part_pictures(thumbs, use.part, use.relative_path)
        else:
            png, note, context = None, f"no picture beyond the first {thumbnails} files", None
        share = scale.share(use.distance)
        extra = {"share": closer_than(share)} if share is not None and use.distance > 0 else {}
        extra.update(parent=use.relative_path, count=use.count, title=use.title, part=use.part)
        cards.append(SheetHit(SheetPart(use.part, Path(use.path), searcher.signature_of(use.part), png, note, context),
                              use.rank, use.distance, scale.words(use.distance), extra))
    meta = [
        f"Store <code>{_esc(answer.store)}</code>: {answer.sub_entries:,} sub-parts of {answer.files:,} files"
        f" (root <code>{_esc(answer.root)}</code>).",
        f"Metric {_esc(metric_label(answer.metric))}, the {len(answer.uses)} nearest files"
        + (f" within {answer.max_distance:g}" if answer.max_distance is not None else "")
        + f"; each card: the file's nearest sub-part (drawn in its own frame, the whole file small beside it)"
        f" and how many times the file holds it (its histograms over the query's). Made {datetime.datetime.now():%Y-%m-%d %H:%M}.",
    ]
    if header_extra.get("parent"):
        meta.append(f"The query is a sub-part of <b>{_esc(header_extra['parent'])}</b>,"
                    f" {_times(header_extra['count'])} there.")
    if answer.reason:
        meta.append(f"No file: {_esc(answer.reason)}.")
    return write_sheet(output, f"Where {Path(part.label).name} is used", part, cards, meta, scale.describe())


def compare_sheet(output, a, b, sig_a: Signature, sig_b: Signature, distances: dict, metric: str = default_metric("compare")) -> Path:
    """The sheet of ``shapeidx compare A B``: A as the query, B as the one hit."""
    from .thumbcache import ThumbnailCache, default_cache_dir

    cache = ThumbnailCache(default_cache_dir())
    png_a, note_a = _picture_of(lambda: cache.png(a), str(a))
    png_b, note_b = _picture_of(lambda: cache.png(b), str(b))
    query = SheetPart(str(a), Path(a).absolute(), sig_a, png_a, note_a)
    hit = SheetHit(SheetPart(str(b), Path(b).absolute(), sig_b, png_b, note_b), 1, distances[metric])
    meta = ["Distances: " + ", ".join(f"{metric_label(m)} {distances[m]:.4g}" for m in distances),
            f"Made {datetime.datetime.now():%Y-%m-%d %H:%M}. No store: no similarity words (they are calibrated on a store;"
            " see <code>shapeidx query --sheet</code>)."]
    return write_sheet(output, f"{Path(a).name} against {Path(b).name}", query, [hit], meta)


CHECK_STYLE = """
section.new{background:#fff;border-bottom:1px solid #ddd;margin:0 0 8px}
section.new>header{border:0}
.status{font-weight:700;font-size:15px}
.status.duplicate{color:#b00020}.status.new{color:#1a5e3a}.status.unchanged,.status.error{color:#555}
.hit.dup{border-color:#b00020;box-shadow:inset 4px 0 0 #b00020}
.kind{font-size:12px;text-transform:uppercase;letter-spacing:.04em;color:#666}
.hit.dup .kind{color:#b00020;font-weight:700}
.facts{font-size:12.5px;color:#333}
"""


def _check_card(thumbs, scale, hit: dict, kind: str, k: int, thumbnails: int, drawn: list) -> str:
    from .similarity import closer_than

    if drawn[0] < thumbnails:
        png, note = _picture_of(lambda: thumbs.png(hit["relative_path"]), hit["relative_path"])
        drawn[0] += 1
    else:
        png, note = None, f"no picture beyond the first {thumbnails}"
    part = SheetPart(hit["relative_path"], Path(hit["path"]), None, png, note)
    size = "size ?" if hit["size_ratio"] is None else f"size x{hit['size_ratio']:.4g}"
    if hit.get("unit"):
        size += f" (unit factor {hit['unit']:.4g})"
    facts = [size] + (["mirrored"] if hit["mirrored"] else [])
    dup = kind == "duplicate"
    share = scale.share(hit["distance"])
    words = hit["words"] if hit["tier"] != "look-alike" else scale.words(hit["distance"])  # a plain neighbour: how near
    far = " far" if words in ("weakly similar", "not similar") else ""
    return (f'<article class="hit{" dup" if dup else ""}" data-kind="{kind}" data-tier="{_esc(hit["tier"])}"'
            f' data-path="{_esc(hit["relative_path"])}">'
            f'<div class="top"><span class="kind">{kind}{"" if hit["tier"] == kind else ": " + _esc(hit["tier"])}</span>'
            f'<span class="distance">distance {hit["distance"]:.4g}</span></div>'
            f'<div class="words{far}">{_esc(words)}'
            + (f' <span class="share">{_esc(closer_than(share))}</span>' if share is not None and hit["distance"] > 0 else "")
            + "</div>"
            + _picture(part, 160, lazy=k >= 12) + _link(part)
            + f'<div class="facts">{_esc(", ".join(facts))}</div></article>')


def check_new_sheet(searcher, reports: list, output: str | os.PathLike, metric: str,
                    thumbnails: int = DEFAULT_THUMBNAILS) -> Path:
    """Write the sheet of ``check-new`` for the reviewer of a merge request: per new file, its
    picture and status, then the store's parts that are the same part (duplicates, marked, with
    tier, size ratio, unit factor and mirror flag) and its nearest look-alikes, each drawn.

    ``reports``: :meth:`shapeidx.families.checkin.Checker.check`'s dicts (an ``error`` one
    carries ``reason``). Raises StoreError when ``output``'s folder does not exist.
    """
    from .thumbcache import ThumbnailCache

    check_sheet_folder(output)
    thumbs = _thumbnails_of(searcher)
    files = ThumbnailCache(thumbs.cache.folder)
    scale = _similarity_scale(searcher, metric, thumbs)
    drawn = [0]
    sections = []
    counts = {"duplicate": 0, "new": 0, "unchanged": 0, "error": 0}
    order = ("duplicate", "error", "new", "unchanged")  # what a reviewer must look at first
    for r in sorted(reports, key=lambda r: order.index(r["status"]) if r["status"] in order else len(order)):
        status = r["status"]
        counts[status] = counts.get(status, 0) + 1
        checked = status in ("duplicate", "new")
        png, note = _picture_of(lambda: files.png(r["file"]), str(r["file"])) if checked else (None, "")
        part = SheetPart(str(r["file"]), Path(r["file"]).absolute(), None, png, note)
        said = {"duplicate": f"ALREADY IN THE LIBRARY: {len(r['duplicates'])} duplicate(s)",
                "new": "new: no duplicate in the store", "unchanged": "unchanged (the store holds it under this path)",
                "error": f"error: {r.get('reason', '')}"}.get(status, status)
        cards = [_check_card(thumbs, scale, h, "duplicate", k, thumbnails, drawn) for k, h in enumerate(r["duplicates"])]
        cards += [_check_card(thumbs, scale, h, "look-alike", len(cards) + k, thumbnails, drawn)
                  for k, h in enumerate(r["look_alikes"])]
        sections.append(
            f'<section class="new" data-status="{_esc(status)}" data-file="{_esc(r["file"])}"><header>'
            + (_picture(part, 200, lazy=len(sections) >= 4) if checked else "")
            + f'<div><h1>{_esc(Path(str(r["file"])).name)}</h1><div class="query">{_link(part)}</div>'
            f'<div class="status {_esc(status)}">{_esc(said)}</div></div></header>'
            + (f'<main class="hits">{"".join(cards)}</main>' if cards else "") + "</section>")
    title = f"check-new: {counts['duplicate']} of {len(reports)} file(s) already in the library"
    summary = ", ".join(f"{n} {s}" for s, n in counts.items() if n)
    head = (f'<header><div><h1>{_esc(title)}</h1><div class="meta"><div>Store <code>{_esc(searcher.store)}</code>:'
            f' {len(searcher):,} parts (root <code>{_esc(searcher.root)}</code>). Metric {_esc(metric_label(metric))};'
            f' {_esc(summary)}. Made {datetime.datetime.now():%Y-%m-%d %H:%M}.</div>'
            "<div>Duplicates (tiers identical, same, converted: docs/duplicates.md) are marked in red; look-alikes"
            " are parts worth reusing, not duplicates.</div></div></div></header>")
    text = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<meta name=\"viewport\" content=\"width=device-width,initial-scale=1\"><title>{_esc(title)}</title>"
            "<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; img-src data:; style-src 'unsafe-inline'\">"
            f"<style>{STYLE}{CHECK_STYLE}</style></head><body>{head}{''.join(sections)}</body></html>\n")
    return _write_html(output, text)
