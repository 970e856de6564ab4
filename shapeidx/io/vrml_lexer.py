"""VRML tokens: names, numbers, strings and punctuation, plus number arrays read in bulk.

VRML 1.0 and 2.0 share one lexical grammar: white space and commas separate tokens,
``#`` starts a comment that runs to the end of the line, and tokens need no white space
between them (``Shape{geometry Box{}}``, ``point[0 0 0]``). Names may not start with a
digit, ``+``, ``-`` or ``.``, so ``1-2`` is the two numbers 1 and -2.

Most of a CAD export is numbers inside brackets (``point [ ... ]``, ``coordIndex
[ ... ]``). Tokenising those one by one in Python would be the whole run time, so
:meth:`Lexer.numbers_in_brackets` finds the closing bracket and converts the span with
one numpy call.
"""

from __future__ import annotations

import re
import warnings
from typing import NamedTuple

import numpy as np

from ..errors import LoadError

# Token kinds
NAME = "name"
NUMBER = "number"
STRING = "string"
PUNCT = "punct"  # one of [ ] { } ( ) . |
END = "end"

# Names: the first character may not be a digit, '+', '-' or '.'; '(' ')' '|' may appear
# inside a name (CAD exporters write DEF names like ``Part(2)``) but not at its start,
# where they are VRML 1.0 bit-mask punctuation.
_TOKEN = re.compile(
    rb"""
    (?:[\s,]|\#[^\n\r]*+)*+                      # white space, commas, comments (possessive:
                                                 # a failed token must not re-split them)
    (?:
        (?P<number>[+-]?(?:0[xX][0-9a-fA-F]+|(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?))
      | (?P<name>[^\x00-\x20"\#'+,\-.0-9\[\\\]{}()|\x7f][^\x00-\x20"\#',.\[\\\]{}\x7f]*)
      | (?P<string>"(?:[^"\\]|\\.)*")
      | (?P<punct>[\[\]{}().|])
      | (?P<end>\Z)
    )
    """,
    re.VERBOSE | re.DOTALL,
)
_SKIP = re.compile(rb"(?:[\s,]|\#[^\n\r]*+)*+")
_NUMBER_TEXT = re.compile(rb"[+-]?(?:0[xX][0-9a-fA-F]+|(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)")
_RAW_WORD = re.compile(rb"[^\s{}\[\]]+")
_COMMENT = re.compile(rb"\#[^\n\r]*")
_SMALL_SPAN = 4096  # bytes; below this splitting in Python is faster than np.fromstring
_COMMAS_TO_SPACES = bytes.maketrans(b",", b" ")
_STRING_ESCAPE = re.compile(r"\\(.)", re.DOTALL)


class Token(NamedTuple):
    kind: str
    text: bytes
    start: int  # byte offset of the token's first character
    end: int  # byte offset just past it


class Lexer:
    """Tokens of one VRML file, read on demand with one token of look-ahead.

    Parameters
    ----------
    data : bytes
        The whole (decompressed) file.
    path : path-like
        Named in error messages.
    """

    def __init__(self, data: bytes, path):
        self.data = data
        self.path = path
        self.pos = 0  # where scanning continues: just past the last buffered token
        self._ahead: list[Token] = []  # tokens scanned but not consumed yet
        # Old Mac files end lines with CR only; count those when there is no LF at all.
        self._newline = b"\n" if b"\n" in data or b"\r" not in data else b"\r"

    # -- errors -------------------------------------------------------------------------

    def line_of(self, offset: int) -> int:
        """1-based line number of a byte offset (computed only when needed: errors)."""
        return self.data.count(self._newline, 0, offset) + 1

    def error(self, reason: str, offset: int | None = None) -> LoadError:
        """A LoadError naming this file and the line of ``offset`` (default: the next token)."""
        if offset is None:
            offset = self.peek().start
        return LoadError(self.path, reason, self.line_of(offset))

    # -- tokens -------------------------------------------------------------------------

    def peek(self, ahead: int = 0) -> Token:
        """The next token (``ahead=1``: the one after it), without consuming it."""
        buffered = self._ahead
        if len(buffered) > ahead:  # the common case, kept short: this runs per token
            return buffered[ahead]
        while len(buffered) <= ahead:
            token = self._scan()
            buffered.append(token)
            self.pos = token.end
        return buffered[ahead]

    def next(self) -> Token:
        """Consume and return the next token."""
        buffered = self._ahead
        if buffered:
            return buffered.pop(0)
        token = self._scan()
        self.pos = token.end
        return token

    def _rewind_to_next_token(self) -> int:
        """Forget the look-ahead; bulk readers restart at the next token's first byte."""
        start = self.peek().start
        self._ahead.clear()
        return start

    def _scan(self) -> Token:
        match = _TOKEN.match(self.data, self.pos)
        if match is None:
            start = _SKIP.match(self.data, self.pos).end()
            char = self.data[start : start + 1]
            if char == b'"':
                raise LoadError(self.path, "unterminated string (no closing '\"')", self.line_of(start))
            raise LoadError(self.path, f"unexpected character {_show(char)}", self.line_of(start))
        kind = match.lastgroup
        start, end = match.span(kind)
        return Token(kind, self.data[start:end], start, end)

    def expect(self, text: bytes, where: str) -> Token:
        """Consume a punctuation token or raise 'expected X' naming ``where``."""
        token = self.next()
        if token.text != text or token.kind != PUNCT:
            raise self.error(f"expected '{text.decode()}' {where}, found {describe(token)}", token.start)
        return token

    # -- bulk reading -------------------------------------------------------------------

    def numbers_in_brackets(self, opened_at: int) -> np.ndarray:
        """Read every number up to the next ``]`` in one go; the ``[`` was already consumed.

        Parameters
        ----------
        opened_at : int
            Byte offset of the ``[``, for the message when there is no ``]``.

        Returns
        -------
        (k,) float64
        """
        start = self._rewind_to_next_token()
        close, has_comment = self._closing_bracket(start, opened_at)
        span = self.data[start:close]
        if has_comment:
            span = _COMMENT.sub(b" ", span)
        self.pos = close + 1
        return parse_numbers(span, lambda reason: self.error(reason, start))

    def _closing_bracket(self, start: int, opened_at: int) -> tuple[int, bool]:
        """Offset of the ``]`` that ends a number list, skipping comments (which may hold ']')."""
        data = self.data
        search_from = start
        has_comment = False
        while True:
            close = data.find(b"]", search_from)
            comment = data.find(b"#", search_from, close if close >= 0 else len(data))
            if comment < 0:
                break
            has_comment = True
            search_from = _end_of_line(data, comment)
        if close < 0:
            raise LoadError(self.path, "unterminated '[' (file ends before its ']')", self.line_of(opened_at))
        return close, has_comment

    def raw_word(self) -> bytes:
        """The text up to the next white space or brace, whatever it holds.

        VRML 1.0 (like Open Inventor) allows a string without quotes when it has no white
        space: ``filename ../textures/wood.jpg``.
        """
        start = self._rewind_to_next_token()
        match = _RAW_WORD.match(self.data, start)
        if match is None:
            raise self.error("expected a value", start)
        self.pos = match.end()
        return match.group()

    def at_close(self, close: bytes, opened_at: int, what: str) -> bool:
        """Consume the next token and say True when it is ``close``; False (nothing
        consumed) for any other token; an error naming ``what`` at the end of the file."""
        token = self.peek()
        if token.kind == PUNCT and token.text == close:
            self.next()
            return True
        if token.kind == END:
            raise self.error(f"{what} is never closed (file ends first)", opened_at)
        return False


def parse_numbers(span: bytes, fail) -> np.ndarray:
    """Numbers separated by white space and commas, as float64, in one numpy call.

    ``np.fromstring`` (C ``strtod``) does the work; spans it cannot read to the end
    (numbers written without a separator, like ``1-2``, or hexadecimal integers) are
    re-read with a regular expression that must account for every character.
    ``fail(reason)`` builds the exception raised for text that is not numbers.
    """
    text = span.translate(_COMMAS_TO_SPACES)
    try:
        if len(text) < _SMALL_SPAN:
            # Python's float() per word: cheaper than np.fromstring's set-up for a few numbers
            return np.array(text.split(), dtype=np.float64)
        if not text.strip():
            return np.zeros(0)  # np.fromstring reads blank text as [-1.0]
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # partial reads are a DeprecationWarning
            return np.fromstring(text, dtype=np.float64, sep=" ")
    except (ValueError, DeprecationWarning):
        pass
    pieces = _NUMBER_TEXT.findall(text)
    if len(b"".join(pieces)) + len(re.findall(rb"\s", text)) != len(text):
        bad = re.sub(rb"[\s]+", b" ", text).strip()
        first_bad = next((w for w in bad.split() if not _NUMBER_TEXT.fullmatch(w)), bad[:20])
        raise fail(f"expected a number, found {_show(first_bad[:30])}")
    return np.array([int(p, 16) if b"x" in p.lower() else float(p) for p in pieces], dtype=np.float64)


def decode_string(token: Token) -> str:
    """The text of a quoted string token, escapes (``\\"``, ``\\\\``) resolved."""
    inner = token.text[1:-1].decode("utf-8", errors="replace")
    return _STRING_ESCAPE.sub(r"\1", inner) if "\\" in inner else inner


def describe(token: Token) -> str:
    """A token as shown in an error message."""
    if token.kind == END:
        return "end of file"
    if token.kind == STRING:
        return "a string"
    return _show(token.text[:40])


def _show(text: bytes) -> str:
    return repr(text.decode("utf-8", errors="replace")) if text else "end of file"


def _end_of_line(data: bytes, offset: int) -> int:
    ends = [e for e in (data.find(b"\n", offset), data.find(b"\r", offset)) if e >= 0]
    return min(ends) if ends else len(data)
