"""What a part file says about itself: its title and product id, read from the text.

These become the entry's metadata (``shapeidx build``), beside the sidecar table a user gives
(``--metadata``), and ``--where title~*usb*`` filters on them:

* STEP: the first ``PRODUCT('id', 'name', 'description', ...)`` entity: ``title`` is its
  name, ``product_id`` its id (ISO 10303-21 strings: ``''`` is a quote, ``\\X2\\...\\X0\\``
  escapes are kept as written);
* IGES: the global section's product identification (parameter 4, a Hollerith string) as
  ``title``;
* VRML 2.0: ``WorldInfo { title "..." }``; VRML 1.0: the first ``Info { string "..." }``.

Only the first :data:`SCAN_BYTES` of the text are looked at, with patterns that cannot
backtrack far, so a hostile file costs at most a few milliseconds; nothing here can fail a
read (what cannot be found is simply absent).
"""

from __future__ import annotations

import re

#: Keys a file can give (the store keeps a column for each).
FILE_KEYS = ("title", "product_id")
#: Bytes of a file's text looked at.
SCAN_BYTES = 1 << 20
#: Longest value kept (characters).
MAX_VALUE = 500

_STEP_STRING = r"'((?:[^']|'')*)'"
_STEP_PRODUCT = re.compile(rb"PRODUCT\s*\(\s*" + _STEP_STRING.encode() + rb"\s*,\s*" + _STEP_STRING.encode(), re.IGNORECASE)
_VRML2_TITLE = re.compile(rb'WorldInfo\s*\{[^}]{0,4000}?\btitle\s+"((?:[^"\\]|\\.){0,2000})"')
_VRML1_INFO = re.compile(rb'\bInfo\s*\{[^}]{0,4000}?\bstring\s+"((?:[^"\\]|\\.){0,2000})"')


def file_metadata(data: bytes, format_name: str) -> dict:
    """``{"title": ..., "product_id": ...}`` (the keys found) from a file's (uncompressed) content."""
    head = data[:SCAN_BYTES]
    try:
        if format_name in ("step",):
            return _step(head)
        if format_name in ("iges",):
            return _iges(head)
        if format_name.startswith("vrml"):
            return _vrml(head)
    except (ValueError, IndexError, UnicodeError):
        pass
    return {}


def _clean(raw: bytes) -> str:
    text = raw.decode("utf-8", "replace")
    text = " ".join(text.split())  # one line
    return text[:MAX_VALUE]


def _step(head: bytes) -> dict:
    match = _STEP_PRODUCT.search(head)
    if not match:
        return {}
    product_id, name = (_clean(g.replace(b"''", b"'")) for g in match.groups())
    found = {}
    if name:
        found["title"] = name
    if product_id:
        found["product_id"] = product_id
    return found


def _iges(head: bytes) -> dict:
    """Parameter 3 of the global section (lines with 'G' in column 73): the product
    identification of the sending system."""
    lines = head.split(b"\n")
    text = b"".join(line[:72] for line in lines if len(line) >= 73 and line[72:73] == b"G").decode("latin-1")
    values = _global_parameters(text, 3)
    return {"title": values[2]} if len(values) > 2 and values[2] else {}


def _global_parameters(text: str, count: int) -> list:
    """The first ``count`` parameters of an IGES global section, Hollerith strings decoded.
    The first two name the parameter and record delimiters (default ',' and ';')."""
    delimiter, record = ",", ";"
    values, at = [], 0
    while len(values) < count and at < len(text):
        match = re.match(r"\s*(\d+)H", text[at:])
        if match:  # a Hollerith string: nH then n characters
            start = at + match.end()
            n = int(match.group(1))
            value = text[start : start + n]
            at = start + n
        else:
            ends = [i for i in (text.find(delimiter, at), text.find(record, at)) if i >= 0]
            end = min(ends) if ends else len(text)
            value, at = text[at:end].strip(), end
        if len(values) == 0 and len(value) == 1:
            delimiter = value
        elif len(values) == 1 and len(value) == 1:
            record = value
        values.append(_clean(value.encode("latin-1")))
        if at < len(text) and text[at] == record:
            break
        at += 1  # the delimiter after the value
    return values


def _vrml(head: bytes) -> dict:
    match = _VRML2_TITLE.search(head) or _VRML1_INFO.search(head)
    if not match:
        return {}
    title = _clean(re.sub(rb"\\(.)", rb"\1", match.group(1)))
    return {"title": title} if title else {}
