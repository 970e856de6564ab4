"""Decoding text files of unknown encoding."""

from __future__ import annotations


def decode_text(data: bytes) -> str:
    """Bytes to str: UTF-16 with a byte-order mark, else UTF-8, else Latin-1 (never fails)."""
    if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return data.decode("utf-16", errors="replace")
    if data[:3] == b"\xef\xbb\xbf":
        data = data[3:]
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")
