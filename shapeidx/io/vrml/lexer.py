"""VRML tokens: names, numbers, strings and punctuation, plus number arrays read in bulk.

VRML 1.0 and 2.0 share one lexical grammar: white space and commas separate tokens,
``#`` starts a comment that runs to the end of the line, and tokens need no white space
between them (``Shape{geometry Box{}}``, ``point[0 0 0]``). Names may not start with a
digit, ``+``, ``-`` or ``.``, so ``1-2`` is the two numbers 1 and -2.

The whole file is split into tokens by one ``re.findall``: the per-token work happens in
C, and the parser walks the resulting list of token texts by index. CAD exporters write
one node per face (a KiCad part holds a thousand Shapes), so the cost per token, not per
byte, is what decides the speed on such files.

Most of a CAD export's bytes are numbers inside brackets (``point [ ... ]``, ``coordIndex
[ ... ]``). The tokenising expression takes a ``[`` followed by a number, and everything
up to its ``]``, as one token (an *array*), which :meth:`Lexer.array_numbers` converts with
one numpy call.

A token's kind is told by its first byte (:func:`kind_of`); its byte offset, needed only
for the line number of a message, is found on demand by a second pass
(:meth:`Lexer.start`). Two things keep that list faithful to a one-token-at-a-time
reading:

- A character no token can start with ends the list: the rest of the file becomes one
  *broken* token, replaced by :data:`BROKEN`, whose error ("unexpected character",
  "unterminated string") is raised when the parser reaches it, as reading one token at a
  time would have. An array without its ``]`` also runs to the end of the file. So a
  string or an array that never closes is looked for once, not again from every later
  quote or bracket: a hostile file cannot make tokenising quadratic.
- Two things are known only when the parser gets there: a VRML 1.0 string written
  without quotes (:meth:`Lexer.raw_word`) may end inside what the list holds as a string
  or a comment, and a comment inside an array may hold the ``]`` the array token ended
  at. The list is then rebuilt from there, in windows that grow while they are used
  (:meth:`Lexer.refill`), so that repeated rebuilds cost no more than the text they cover.
"""

from __future__ import annotations

import re
import sys
import warnings
from itertools import islice

import numpy as np

from ...errors import LoadError

# Token kinds (see kind_of)
NAME = "name"
NUMBER = "number"
STRING = "string"
PUNCT = "punct"  # one of [ ] { } ( ) . |
ARRAY = "array"  # '[' + numbers + ']' as one token
END = "end"
BAD = "bad"  # the broken rest of the file

# White space, commas, comments (possessive: a failed token must not re-split them). A
# comment runs to the end of its line, so no comment follows another directly.
_SKIP_TEXT = rb"[\s,]*+(?:\#[^\n\r]*+[\s,]*+)*+"
_NUMBER_TEXT_RE = rb"[+-]?(?:0[xX][0-9a-fA-F]+|(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)"
# Names: the first character may not be a digit, '+', '-' or '.'; '(' ')' '|' may appear
# inside a name (CAD exporters write DEF names like ``Part(2)``) but not at its start,
# where they are VRML 1.0 bit-mask punctuation.
_NAME_RE = rb"[^\x00-\x20\"\#'+,\-.0-9\[\\\]{}()|\x7f][^\x00-\x20\"\#',.\[\\\]{}\x7f]*+"
_STRING_RE = rb'"(?:[^"\\]++|\\.)*+"'
# '[' whose next token is a number: up to the next ']', or to the end of the file when there
# is none (reported when the parser reaches it). A single negated character is what the
# regular expression engine scans fastest (the bulk of a CAD file is in these spans); a
# comment inside that holds a ']' ends this too early, which array_numbers() corrects.
_ARRAY_RE = rb"\[" + _SKIP_TEXT + rb"(?=[+-]?\.?\d)[^\]]*+(?:\]|\Z)"
# The same with comments skipped: what the array really spans
_EXACT_ARRAY = re.compile(rb"\[(?:[^\]\#]++|\#[^\n\r]*+)*+(?:\]|\Z)")
# Alternatives are told apart by their first byte, except '[' (array before punctuation)
# and '.' (a number like .5 before the punctuation).
_ALTERNATIVES = (
    _ARRAY_RE + rb"|" + _NAME_RE + rb"|[\[\]{}()|]|" + _NUMBER_TEXT_RE + rb"|\.|" + _STRING_RE
)
_TOKEN = re.compile(_SKIP_TEXT + rb"(" + _ALTERNATIVES + rb"|\Z|.+)", re.DOTALL)
_VALID = re.compile(_ALTERNATIVES, re.DOTALL)  # a token that is not the broken rest
_SKIP = re.compile(_SKIP_TEXT)
_NUMBER_TEXT = re.compile(_NUMBER_TEXT_RE)
_RAW_WORD = re.compile(rb"[^\s{}\[\]]+")
_COMMENT = re.compile(rb"\#[^\n\r]*")
_CLOSED_ARRAY = re.compile(rb"\[(?:[^\]\#]++|\#[^\n\r]*+)*+\]")
_SMALL_SPAN = 4096  # bytes; below this splitting in Python is faster than np.fromstring
_COMMAS_TO_SPACES = bytes.maketrans(b",", b" ")
_STRING_ESCAPE = re.compile(r"\\(.)", re.DOTALL)

#: Stands for the broken rest of a file in the token list. Its first byte is no token's,
#: so every test the parser makes on a token's text fails on it.
BROKEN = b"\x00broken"
#: Tokens the parser may look at beyond the current one between two calls of
#: :meth:`Lexer.refill` (the longest fixed sequence is ``ROUTE a . b TO c . d``).
LOOKAHEAD = 16
_END_PADDING = [b""] * LOOKAHEAD
_NUMBER_START = frozenset(b"0123456789+-.")
NAME_START = frozenset(bytes(_c for _c in range(256) if re.fullmatch(_NAME_RE, bytes([_c]))))
_FIRST_WINDOW = 32  # tokens read after a rebuild (more than LOOKAHEAD); doubled for each next window


def kind_of(token: bytes) -> str:
    """The kind of a token text: NAME, NUMBER, STRING, PUNCT, ARRAY, END or BAD."""
    if not token:
        return END
    first = token[0]
    if first in NAME_START:
        return NAME
    if first == 0x5B:  # '['
        return PUNCT if len(token) == 1 else ARRAY
    if first in _NUMBER_START:
        if len(token) > 1 or 0x30 <= first <= 0x39:
            return NUMBER
        return PUNCT if first == 0x2E else BAD  # '+' or '-' alone is no token
    if first == 0x22 and len(token) > 1:  # '"'
        return STRING
    if len(token) == 1 and token in b"]{}()|":
        return PUNCT
    return BAD


class Lexer:
    """The tokens of one VRML file, as a list of texts the parser reads by index.

    Parameters
    ----------
    data : bytes
        The whole (decompressed) file.
    path : path-like
        Named in error messages.

    Attributes
    ----------
    tokens : list of bytes
        Token texts, the broken rest of the file (if any) replaced by :data:`BROKEN`,
        then :data:`LOOKAHEAD` empty texts (end of file), so that looking a few tokens
        ahead never runs off the list.
    refill_at : int
        Before reading token ``i >= refill_at`` the parser calls :meth:`refill` (only
        after a rebuild does the list stop short of the end of the file).
    """

    def __init__(self, data: bytes, path):
        self.data = data
        self.path = path
        self.tokens: list[bytes] = _TOKEN.findall(data)
        self._starts: list[int] | None = None  # byte offset of each token, when needed
        self._broken_at = -1  # byte offset of the broken rest of the file
        self._mark_broken(len(self.tokens) - 2)  # the last token before the empty end match
        self.tokens += _END_PADDING
        self.refill_at = sys.maxsize
        self._rest = None  # after a rebuild: the matches still to read
        self._window = _FIRST_WINDOW
        # Old Mac files end lines with CR only; count those when there is no LF at all.
        self._newline = b"\n" if b"\n" in data or b"\r" not in data else b"\r"

    def _mark_broken(self, index: int) -> None:
        """Replace token ``index`` by BROKEN if it is the broken rest of the file."""
        if index >= 0 and self.tokens[index] and not _VALID.fullmatch(self.tokens[index]):
            self._broken_at = len(self.data) - len(self.tokens[index])
            self.tokens[index] = BROKEN

    # -- positions and errors -------------------------------------------------------------

    def start(self, index: int) -> int:
        """Byte offset of token ``index`` (computed for the whole list on first use)."""
        if self._starts is None:
            # the same expression from the same place gives the same tokens
            starts = [match.start(1) for match in _TOKEN.finditer(self.data)]
            self._starts = starts + [len(self.data)] * LOOKAHEAD
        return self._starts[index]

    def line_of(self, offset: int) -> int:
        """1-based line number of a byte offset (computed only when needed: messages)."""
        return self.data.count(self._newline, 0, offset) + 1

    def line_at(self, index: int) -> int:
        """1-based line number of token ``index``."""
        return self.line_of(self.start(index))

    def error(self, reason: str, index: int, at: int | None = None) -> LoadError:
        """A LoadError about token ``index``, on the line of token ``at`` (default: the same).

        When token ``index`` is the broken rest of the file, the lexical error is the one
        reported: reading one token at a time would have stopped there.
        """
        if self.tokens[index] is BROKEN:
            return self.broken_error()
        return LoadError(self.path, reason, self.line_at(index if at is None else at))

    def error_at_offset(self, reason: str, offset: int) -> LoadError:
        return LoadError(self.path, reason, self.line_of(offset))

    def broken_error(self) -> LoadError:
        """The error of the broken rest of the file: its first character."""
        start = self._broken_at
        char = self.data[start : start + 1]
        if char == b'"':
            return LoadError(self.path, "unterminated string (no closing '\"')", self.line_of(start))
        return LoadError(self.path, f"unexpected character {_show(char)}", self.line_of(start))

    # -- bulk reading ---------------------------------------------------------------------

    def array_numbers(self, index: int) -> np.ndarray:
        """The numbers of the array token ``index`` (``[`` + numbers + ``]``), as float64.

        Raises
        ------
        LoadError
            "unterminated '['" when the file ends first; "expected a number" for other
            text inside the brackets, on the line of the first number.
        """
        token = self.tokens[index]
        if b"#" in token:  # comments (which may hold ']') inside: the careful way
            token = self._exact_array(index)
            if not _CLOSED_ARRAY.fullmatch(token):
                raise self.error_at_offset("unterminated '[' (file ends before its ']')", self.start(index))
            text = token[1:-1]
            text = _COMMENT.sub(b" ", text[_SKIP.match(text).end() :]).translate(_COMMAS_TO_SPACES)
        elif token[-1] != 0x5D:  # no ']'
            raise self.error_at_offset("unterminated '[' (file ends before its ']')", self.start(index))
        else:
            # from the first number on, as parse_numbers expects (its span's length matters)
            text = token[1:-1].translate(_COMMAS_TO_SPACES).lstrip()
        if len(text) < _SMALL_SPAN:
            try:  # parse_numbers' first step, inlined: thousands of small arrays in a CAD part
                return np.array(text.split(), dtype=np.float64)
            except ValueError:
                pass
        return parse_numbers(text, lambda reason: self._array_error(index, reason))

    def _exact_array(self, index: int) -> bytes:
        """The text of array token ``index`` with its comments skipped. When a comment held
        the ``]`` the token ended at, the array goes on, and the tokens after it are
        rebuilt from its real end."""
        start = self.start(index)
        exact = _EXACT_ARRAY.match(self.data, start).group()
        if len(exact) != len(self.tokens[index]):
            self.tokens[index] = exact
            self._rebuild(index + 1, start + len(exact))
        return exact

    def _array_error(self, index: int, reason: str) -> LoadError:
        first_number = _SKIP.match(self.data, self.start(index) + 1).end()
        return self.error_at_offset(reason, first_number)

    def first_in_array(self, index: int) -> tuple[bytes, int]:
        """The first token inside array token ``index`` and its byte offset, for where an
        array is not allowed and the message names what follows the ``[``."""
        offset = _SKIP.match(self.data, self.start(index) + 1).end()
        return _TOKEN.match(self.data, offset).group(1), offset

    def raw_word(self, index: int) -> tuple[bytes, int]:
        """The text from token ``index`` up to the next white space or brace, whatever it
        holds, and the index of the token after it.

        VRML 1.0 (like Open Inventor) allows a string without quotes when it has no white
        space: ``filename ../textures/wood.jpg``. When the word ends inside a token or a
        comment of the list (it holds a ``"`` or a ``#``), the list is rebuilt from there.
        """
        start = self.start(index)
        match = _RAW_WORD.match(self.data, start)
        if match is None:
            raise self.error("expected a value", index)
        end = match.end()
        resume = _SKIP.match(self.data, end).end()
        starts = self._starts
        following = index + 1
        while following < len(starts) and starts[following] < resume:
            following += 1
        if following >= len(starts) or starts[following] != resume:
            following = self._rebuild(index, end)
        elif following >= self.refill_at:
            self.refill()
        return match.group(), following

    # -- rebuilding ------------------------------------------------------------------------

    def _rebuild(self, index: int, offset: int) -> int:
        """Tokens from byte ``offset`` on replace those from ``index`` on; returns ``index``."""
        del self.tokens[index:]
        del self._starts[index:]
        self._rest = _TOKEN.finditer(self.data, offset)
        self._window = _FIRST_WINDOW
        self.refill()
        return index

    def refill(self) -> None:
        """Read the next window of tokens after a rebuild.

        Each window is twice the last, so what a later rebuild throws away is never more
        than what was read and used before it.
        """
        if self._rest is None:
            return
        tokens, starts, size = self.tokens, self._starts, len(self.data)
        for match in islice(self._rest, self._window):
            tokens.append(match.group(1))
            starts.append(match.start(1))
            if match.end() == size and tokens[-1]:  # reaches the end: may be the broken rest
                self._mark_broken(len(tokens) - 1)
        self._window *= 2
        if tokens[-1]:
            self.refill_at = len(tokens) - LOOKAHEAD
        else:  # the empty match at the end of the file: no more windows
            self._rest = None
            self.refill_at = sys.maxsize
            tokens += _END_PADDING
            starts += [size] * LOOKAHEAD


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


def number_value(token: bytes) -> float:
    """One number token (decimal or hexadecimal) as a float."""
    return float(int(token, 16)) if b"x" in token or b"X" in token else float(token)


def decode_string(token: bytes) -> str:
    """The text of a quoted string token, escapes (``\\"``, ``\\\\``) resolved."""
    inner = token[1:-1].decode("utf-8", errors="replace")
    return _STRING_ESCAPE.sub(r"\1", inner) if "\\" in inner else inner


def describe(token: bytes) -> str:
    """A token as shown in an error message."""
    kind = kind_of(token)
    if kind == END:
        return "end of file"
    if kind == STRING:
        return "a string"
    if kind == ARRAY:
        return "'['"  # reading one token at a time, the message names the bracket
    return _show(token[:40])


def _show(text: bytes) -> str:
    from ...errors import quoted_bytes

    return quoted_bytes(text) if text else "end of file"
