"""VRML text to a tree of :class:`Node` objects (VRML 1.0 and 2.0, one generic parser).

The parser does not need to know every node type: a field's value is recognised by its
first token (``[`` a list, a number, a string, ``TRUE``/``FALSE``, a node, a word),
so nodes from extensions and exporters' private nodes are read and later skipped.

- ``DEF name node`` binds the name once the node is complete (so a node can never
  contain itself); ``USE name`` returns the same :class:`Node` object, which turns the
  tree into a directed acyclic graph that the traversal expands.
- ``PROTO`` bodies are parsed once as templates; each instance is a copy of the
  body's first node with ``IS`` references replaced by the instance's field values
  (subtrees without ``IS`` are shared, not copied). The number of nodes created this
  way is bounded, so nested PROTOs cannot blow up memory.
- ``EXTERNPROTO`` (a definition in another file) is skipped with a warning; its
  instances are read and ignored.
- ``ROUTE`` statements and ``Script`` field declarations are read and dropped.
- VRML 1.0 nodes have child nodes directly in their body (``Separator { Cube {} }``);
  those go to :attr:`Node.children`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...errors import LoadError
from .lexer import (
    ARRAY,
    BROKEN,
    END,
    NAME,
    NAME_START,
    NUMBER,
    PUNCT,
    STRING,
    Lexer,
    decode_string,
    describe,
    kind_of,
    number_value,
)

#: Deepest nesting of nodes and brackets accepted: far more than exporters write, and few
#: enough that hostile files cannot exhaust Python's stack.
MAX_NESTING = 120
#: Most nodes that PROTO expansion may create in one file (a PROTO bomb guard).
MAX_PROTO_NODES = 200_000

_INTERFACE_WITH_VALUE = {"field", "exposedField", "initializeOnly", "inputOutput"}
_INTERFACE_EVENT = {"eventIn", "eventOut", "inputOnly", "outputOnly"}
_BRACES = (b"{", b"}", b"[", b"]")
_STATEMENT_WORDS = frozenset((b"DEF", b"USE", b"PROTO", b"EXTERNPROTO", b"ROUTE"))
_NODE_WORDS = frozenset((b"DEF", b"USE", b"NULL"))
_VALUE_WORDS = _NODE_WORDS | {b"IS", b"TRUE", b"FALSE"}  # names that are not node types as values
_KEYWORDS = _STATEMENT_WORDS | _NODE_WORDS  # names that are not node types as statements
_DECLARATIONS = _INTERFACE_WITH_VALUE | _INTERFACE_EVENT
_NAME_START_BYTES = frozenset(bytes([c]) for c in NAME_START)  # tested on token[:1]
_NUMBER_START_BYTES = frozenset(bytes([c]) for c in b"0123456789+-.")  # '.' alone: punctuation
# First bytes of a token after a field name that node() leaves to _member: '{' (the name
# was a VRML 1.0 child node's type) and BROKEN's
_SLOW_STARTS = frozenset((b"{", BROKEN[:1]))
_HEADER = re.compile(rb"#(VRML|Inventor|X3D)\s*V?(\d+)?")


class Node:
    """One node as read: its type, its fields and (VRML 1.0) its child nodes.

    Field values are numpy float64 arrays (any numbers), lists of str (strings), bools,
    Nodes, lists of Nodes, ``None`` (``NULL``), tuples of words (VRML 1.0 enums and bit
    masks) or :class:`IsRef` inside PROTO templates.

    A plain class with slots: a CAD part makes thousands of nodes, and each costs less to
    make, and less for the garbage collector to look at, this way.

    Attributes
    ----------
    type : str
    token : int
        Index of the type name in its file's token list (for the line number).
    source : Lexer or None
        The file it was read from.
    fields : dict
    children : sequence of Node
        An empty tuple until a first child is added (VRML 2.0 nodes never have any).
    has_is : bool
        True when this node or a node below it holds an IS reference (PROTO templates).
    external : bool
        Set on EXTERNPROTO instances and node types nobody defined.
    name : str
        The name ``DEF`` gave the node, or "" (sub-parts are named after it).
    """

    __slots__ = ("children", "external", "fields", "has_is", "name", "source", "token", "type")

    def __init__(self, type: str, token: int, source: Lexer | None = None, external: bool = False):
        self.type = type
        self.token = token
        self.source = source
        self.fields: dict[str, Any] = {}
        self.children: list[Node] | tuple[()] = ()
        self.has_is = False
        self.external = external
        self.name = ""

    def __repr__(self) -> str:
        return f"Node({self.type!r}, line {self.line}, fields {sorted(self.fields)}, {len(self.children)} children)"

    def add_child(self, child: Node) -> None:
        if self.children:
            self.children.append(child)
        else:
            self.children = [child]
        self.has_is |= child.has_is

    @property
    def line(self) -> int | None:
        """Line of the node's type name in its file (counted on demand: messages only)."""
        return self.source.line_at(self.token) if self.source is not None else None


@dataclass(frozen=True)
class IsRef:
    """``field IS name`` inside a PROTO body: replaced when the PROTO is instantiated."""

    name: str


@dataclass
class ProtoDef:
    name: str
    defaults: dict[str, Any]
    body: list[Node]


@dataclass
class Scene:
    """A parsed file: its VRML version (1 or 2) and its top-level nodes."""

    path: Any
    version: int
    nodes: list[Node]
    warnings: list[str]
    #: Every node read or made by PROTO expansion, in order, for passes that want them
    #: all at once rather than by traversal.
    all_nodes: list[Node] = field(default_factory=list)


def read_header(data: bytes, path) -> tuple[int, list[str]]:
    """The VRML version from the ``#VRML V1.0``/``#VRML V2.0`` header.

    Returns
    -------
    version : int
        1 or 2. A file without a header is read as VRML 2.0 (with a warning).
    warnings : list of str

    Raises
    ------
    LoadError
        For Open Inventor and X3D files, which look like VRML but are other formats.
    """
    head = data.lstrip(b"\xef\xbb\xbf \t\r\n")[:64]
    match = _HEADER.match(head)
    if match is None:
        return 2, ["no '#VRML V2.0' header: read as VRML 2.0"]
    kind, major = match.group(1), match.group(2)
    if kind == b"Inventor":
        raise LoadError(path, "Open Inventor file ('#Inventor' header), not VRML: not supported", 1)
    if kind == b"X3D":
        raise LoadError(path, "X3D file ('#X3D' header): only VRML 1.0 and 2.0 are supported", 1)
    if major == b"1":
        return 1, []
    if major == b"2":
        return 2, []
    version = major.decode() if major else "?"
    return 2, [f"unknown VRML version {version!r} in the header: read as VRML 2.0"]


def parse_vrml(data: bytes, path) -> Scene:
    """Parse a whole VRML file.

    Raises
    ------
    LoadError
        On anything that is not VRML syntax, with the line it was found on.
    """
    version, warnings = read_header(data, path)
    parser = _Parser(Lexer(data, path), warnings, version)
    nodes = parser.statements(until_close=None)
    return Scene(path, version, nodes, warnings, parser.created)


class _Scope:
    """Names visible while parsing: a file, or one PROTO body, has its own."""

    def __init__(self, protos: dict[str, ProtoDef | None]):
        self.defs: dict[str, Node] = {}
        # Known PROTO names; None marks an EXTERNPROTO (declared, not loaded).
        self.protos = protos


class _Parser:
    """Walks the lexer's token list; ``self.i`` is the index of the next token.

    Every loop over a node body or a list starts by calling :meth:`Lexer.refill` when the
    list runs short (only after a rebuild, see :mod:`.lexer`); what one turn of a loop
    reads before the next loop starts stays within ``LOOKAHEAD`` tokens.

    The checks follow a parser that scans one token at a time with one token of
    look-ahead: where that one would have scanned the broken rest of the file (and
    stopped with its lexical error), this one raises that error too, even when the token
    it was looking at would have allowed something else.
    """

    def __init__(self, lexer: Lexer, warnings: list[str], version: int):
        self.lx = lexer
        self.tokens = lexer.tokens  # the lexer changes this list in place only
        self.i = 0
        self.version = version
        self.warnings = warnings
        self.scope = _Scope({})
        self.depth = 0
        self.proto_nodes_created = 0
        self._warned: set[str] = set()
        self._names: dict[bytes, str] = {}  # decoded names: a file repeats a few hundred
        # Names read as a field name (neither a statement nor a declaration keyword)
        self._field_names: dict[bytes, str] = {}
        self.created: list[Node] = []  # every node made, for Scene.all_nodes

    def warn_once(self, message: str) -> None:
        if message not in self._warned:
            self._warned.add(message)
            self.warnings.append(message)

    def _decode(self, token: bytes) -> str:
        name = self._names.get(token)
        if name is None:
            name = self._names[token] = token.decode("utf-8", errors="replace")
        return name

    def _error(self, reason: str, index: int | None = None, at: int | None = None) -> LoadError:
        """LoadError about token ``index`` (default: the next), on the line of ``at``."""
        return self.lx.error(reason, self.i if index is None else index, at)

    # -- statements ---------------------------------------------------------------------

    def statements(self, until_close: int | None) -> list[Node]:
        """Nodes up to the end of file, or up to the ``}`` matching the ``{`` at token
        index ``until_close``."""
        nodes = []
        tokens, lx = self.tokens, self.lx
        while True:
            if self.i >= lx.refill_at:
                lx.refill()
            token = tokens[self.i]
            if until_close is None:
                if not token:
                    return nodes
            elif token == b"}":
                self.i += 1
                return nodes
            elif not token:
                raise self._error("'{' of a PROTO body is never closed (file ends first)", at=until_close)
            if token[:1] in _NAME_START_BYTES and token not in _KEYWORDS and tokens[self.i + 1] == b"{":
                node = self.node(self.i)  # a plain node, as statement() would read it
            else:
                node = self.statement()
            if node is not None:
                nodes.append(node)

    def statement(self) -> Node | None:
        """One node, PROTO, EXTERNPROTO or ROUTE; returns the node or None."""
        token = self.tokens[self.i]
        if kind_of(token) == NAME:
            if token == b"PROTO":
                self.proto()
                return None
            if token == b"EXTERNPROTO":
                self.externproto()
                return None
            if token == b"ROUTE":
                self.route()
                return None
            return self.node_statement()
        raise self._error(f"expected a node, found {describe(token)}")

    def route(self) -> None:
        """``ROUTE a.field TO b.field``: events do not change geometry; read and drop."""
        start = self.i
        for offset, expected in enumerate((NAME, b".", NAME, b"TO", NAME, b".", NAME), 1):
            token = self.tokens[start + offset]
            if (kind_of(token) if expected == NAME else token) != expected:
                raise self._error(f"malformed ROUTE: unexpected {describe(token)}", start + offset, at=start)
        self.i = start + 8

    # -- nodes ----------------------------------------------------------------------------

    def node_statement(self) -> Node | None:
        """``DEF name node``, ``USE name``, ``NULL`` or a plain node."""
        start = self.i
        token = self.tokens[start]
        if token == b"USE":
            return self.use()
        if token == b"DEF":
            name = self._name_after("DEF")
            type_index = self.i
            if kind_of(self.tokens[type_index]) != NAME:
                type_token = self.tokens[type_index]
                raise self._error(f"expected a node type after DEF {name}, found {describe(type_token)}")
            node = self.node(type_index)
            if node is not None:
                self.scope.defs[name] = node
                if not node.name:  # the first DEF name a node gets (a shared PROTO body keeps its own)
                    node.name = name
            return node
        if token == b"NULL":
            self.i += 1
            return None
        return self.node(start)

    def use(self) -> Node | None:
        """``USE name`` (the next tokens): the node DEF bound to the name, or None."""
        start = self.i
        name = self._name_after("USE")
        node = self.scope.defs.get(name)
        if node is None:
            self.warnings.append(f"line {self.lx.line_at(start)}: USE of undefined name {name!r} ignored")
        return node

    def _name_after(self, what: str) -> str:
        """The name that must follow the keyword ``what`` (DEF, USE, IS, PROTO...), which
        is the next token; leaves ``self.i`` after the name."""
        index = self.i + 1
        token = self.tokens[index]
        if token[:1] not in _NAME_START_BYTES:
            raise self._error(f"expected a name after {what}, found {describe(token)}", index)
        self.i = index + 1
        return self._names.get(token) or self._decode(token)

    def node(self, type_index: int) -> Node:
        """The node whose type name is token ``type_index``: its ``{ body }`` of fields
        and (VRML 1.0) child nodes, PROTOs expanded.

        The hot loop of the reader: a CAD part has a few fields per node and thousands of
        nodes. A field name seen before (``self._field_names``) followed by the commonest
        values (a number array, a node, ``USE``) is read here with a few tests; anything
        else goes to :meth:`_member`, which reads one member of a body the general way.
        """
        tokens, lx = self.tokens, self.lx
        type_token = tokens[type_index]
        type_name = self._names.get(type_token) or self._decode(type_token)
        brace = type_index + 1
        if tokens[brace] != b"{":
            found = describe(tokens[brace])
            raise self._error(f"expected '{{' after node type {type_name!r}, found {found}", brace)
        node = Node(type_name, type_index, lx)
        self.created.append(node)
        self.depth += 1
        if self.depth > MAX_NESTING:
            raise self._error(f"nodes or lists nested deeper than {MAX_NESTING} levels", brace)
        fields, field_names = node.fields, self._field_names
        i = brace + 1
        while True:
            if i >= lx.refill_at:
                lx.refill()
            token = tokens[i]
            following = tokens[i + 1]
            name = field_names.get(token)
            start = following[:1]
            if name is None or start in _SLOW_STARTS:  # '}', a new name, a child node, broken
                if token == b"}":
                    break
                self.i = i
                self._member(node, brace)
            elif start == b"[" and len(following) > 1:  # a number array
                fields[name] = lx.array_numbers(i + 1)
                i += 2
                continue
            elif start in _NAME_START_BYTES and following not in _VALUE_WORDS and tokens[i + 2] == b"{":
                child = fields[name] = self.node(i + 1)
                node.has_is |= child.has_is
            elif following == b"USE":
                self.i = i + 1
                fields[name] = self.use()
            elif start in _NUMBER_START_BYTES and following != b".":  # numbers without [ ]
                after = tokens[i + 2]
                if after[:1] in _NUMBER_START_BYTES and after != b".":
                    self.i = i + 1
                    fields[name] = self.numbers()
                else:  # one number (creaseAngle 0.5): what numbers() gives, without its loop
                    fields[name] = np.array([number_value(following)], dtype=np.float64)
                    i += 2
                    continue
            else:
                self.i = i + 1
                value = fields[name] = self.field_value(name, node)
                if value.__class__ is not np.ndarray and _holds_is(value):
                    node.has_is = True
            i = self.i
        self.i = i + 1
        self.depth -= 1
        if type_name in self.scope.protos:
            return self.instantiate(node, self.scope.protos[type_name])
        return node

    def _member(self, node: Node, brace: int) -> None:
        """One field, child node or statement of the body opened by token ``brace``."""
        i = self.i
        token = self.tokens[i]
        if not token or token[0] not in NAME_START:
            if not token:
                raise self._error(f"'{{' of {node.type} is never closed (file ends first)", i, at=brace)
            raise self._error(f"expected a field name or '}}' in {node.type}, found {describe(token)}", i)
        if token in _STATEMENT_WORDS:
            self._add_child(node, self.statement())
            return
        if self._starts_node(i):  # VRML 1.0 child node
            self._add_child(node, self.node(i))
            return
        name = self._decode(token)
        self.i = i + 1
        if name in _DECLARATIONS:
            self.declaration(node, name)  # Script and PROTO-like field declarations
            return
        self._field_names[token] = name  # a plain field name: node() reads the next one
        value = node.fields[name] = self.field_value(name, node)
        if value.__class__ is not np.ndarray and _holds_is(value):
            node.has_is = True

    def _enter(self, index: int) -> None:
        self.depth += 1
        if self.depth > MAX_NESTING:
            raise self._error(f"nodes or lists nested deeper than {MAX_NESTING} levels", index)

    @staticmethod
    def _add_child(node: Node, child: Node | None) -> None:
        if child is not None:
            node.add_child(child)

    def declaration(self, node: Node, keyword: str) -> None:
        """``field TYPE name value`` / ``eventIn TYPE name`` inside a Script node."""
        type_index = self.i
        type_token, name_token, after = self.tokens[type_index : type_index + 3]
        if type_token is BROKEN or name_token is BROKEN:
            raise self.lx.broken_error()
        if kind_of(type_token) != NAME or kind_of(name_token) != NAME:
            raise self._error(f"malformed '{keyword}' declaration in {node.type}", type_index)
        if after is BROKEN:  # scanned as the look-ahead for IS
            raise self.lx.broken_error()
        name = self._decode(name_token)
        self.i = type_index + 2
        if after == b"IS":
            node.fields[name] = IsRef(self._name_after("IS"))
            node.has_is = True
        elif keyword in _INTERFACE_WITH_VALUE:
            node.fields[name] = self.typed_value(type_index, name)

    # -- values ---------------------------------------------------------------------------

    def field_value(self, name: str, node: Node):
        """The value of field ``name``: decided by its first token."""
        i = self.i
        token = self.tokens[i]
        kind = kind_of(token)
        if kind == ARRAY:  # '[' and numbers: the common case
            self.i = i + 1
            return self.lx.array_numbers(i)
        if kind == NAME:
            if token == b"IS":
                return IsRef(self._name_after("IS"))
            if token == b"TRUE" or token == b"FALSE":
                self.i = i + 1
                return token == b"TRUE"
            if token in _NODE_WORDS:
                return self.node_statement()
            if self._starts_node(i):
                return self.node(i)
        elif kind == NUMBER:
            return self.numbers()
        elif kind == STRING:
            self.i = i + 1
            return [decode_string(token)]
        elif token == b"[":
            return self.bracketed_list()
        elif token == b"(":
            return self.bit_mask()
        if self.version == 1 and kind in (NAME, PUNCT) and token not in _BRACES:
            # an enum (``vertexOrdering CLOCKWISE``) or a string without quotes
            word, self.i = self.lx.raw_word(i)
            return tuple(word.decode("utf-8", errors="replace").split("|"))
        if kind == NAME:
            self.i = i + 1
            return (self._decode(token),)
        raise self._error(f"expected a value for field '{name}' of {node.type}, found {describe(token)}", i)

    def numbers(self) -> np.ndarray:
        """Numbers written without brackets (``translation 1 2 3``), token by token: few."""
        tokens, lx = self.tokens, self.lx
        values = []
        while True:
            if self.i >= lx.refill_at:
                lx.refill()
            token = tokens[self.i]
            if token[:1] not in _NUMBER_START_BYTES or token == b".":  # not a number
                return np.array(values, dtype=np.float64)
            values.append(number_value(token))
            self.i += 1

    def bracketed_list(self):
        """``[ ... ]`` of strings, nodes or words, one by one (a ``[`` followed by a number
        is an array token, read in bulk)."""
        tokens, lx = self.tokens, self.lx
        opening = self.i
        if tokens[opening + 1] is BROKEN:  # scanned to see whether numbers follow
            raise lx.broken_error()
        self._enter(opening)
        self.i = opening + 1
        items: list = []
        while True:
            if self.i >= lx.refill_at:
                lx.refill()
            token = tokens[self.i]
            if token == b"]":
                self.i += 1
                break
            kind = kind_of(token)
            if kind == END:
                raise self._error("'[' is never closed (file ends first)", at=opening)
            if kind == STRING:
                items.append(decode_string(token))
                self.i += 1
            elif kind == NUMBER:
                items.extend(self.numbers().tolist())
            elif kind == NAME and token in (b"ROUTE", b"PROTO", b"EXTERNPROTO"):
                self.statement()
            elif kind == NAME:
                items.append(self._list_item())
            else:
                raise self._error(f"unexpected {describe(token)} in a '[ ]' list")
        self.depth -= 1
        return [item for item in items if item is not None]

    def _list_item(self):
        """A node in an MFNode list, or a word (VRML 1.0 ``fields [ SFFloat size ]``)."""
        i = self.i
        token = self.tokens[i]
        if token in _NODE_WORDS:
            return self.node_statement()
        if self._starts_node(i):
            return self.node(i)
        self.i = i + 1
        return token.decode("utf-8", errors="replace")

    def _starts_node(self, i: int) -> bool:
        """Is the name at token ``i`` a node type, followed by ``{``? Looking at the next
        token scans it: when it is the broken rest of the file, its error is raised."""
        following = self.tokens[i + 1]
        if following is BROKEN:
            raise self.lx.broken_error()
        return following == b"{"

    def bit_mask(self) -> tuple[str, ...]:
        """VRML 1.0 ``(SIDES | TOP)``: the words between the parentheses."""
        tokens, lx = self.tokens, self.lx
        opening = self.i
        self.i += 1
        words = []
        while True:
            if self.i >= lx.refill_at:
                lx.refill()
            i = self.i
            token = tokens[i]
            self.i = i + 1
            if token == b")":
                return tuple(words)
            kind = kind_of(token)
            if kind == NAME:
                words.extend(w for w in token.decode("utf-8", errors="replace").replace(")", "|").split("|") if w)
                if token.endswith(b")"):
                    return tuple(words)
            elif token != b"|":
                raise self._error(f"unexpected {describe(token)} in a '( | )' bit mask", i, at=opening)

    def typed_value(self, type_index: int, name: str):
        """A value whose type is declared (PROTO interface, Script field); the type name
        is token ``type_index``."""
        type_name = self.tokens[type_index]
        token = self.tokens[self.i]
        if type_name == b"SFNode":
            if kind_of(token) == NAME:
                return self.node_statement() if token in _NODE_WORDS else self.node(self.i)
            raise self._error(f"expected a node or NULL for SFNode field '{name}', found {describe(token)}")
        if type_name == b"MFNode" and kind_of(token) == NAME:
            node = self.node_statement() if token in _NODE_WORDS else self.node(self.i)
            return [node] if node is not None else []
        return self.field_value(name, Node("declaration", type_index, self.lx))

    # -- PROTO ----------------------------------------------------------------------------

    def proto(self) -> None:
        """``PROTO Name [ interface ] { body }``: remembered as a template."""
        name = self._name_after("PROTO")
        opening = self._expect(b"[", f"after PROTO {name}")
        defaults = self.interface(opening, with_values=True)
        brace = self._expect(b"{", f"to open the body of PROTO {name}")
        outer = self.scope
        self.scope = _Scope(dict(outer.protos))  # the body has its own DEF names
        self._enter(brace)
        try:
            body = self.statements(until_close=brace)
        finally:
            self.scope = outer
            self.depth -= 1
        outer.protos[name] = ProtoDef(name, defaults, body)

    def _expect(self, text: bytes, where: str) -> int:
        """Consume the punctuation ``text`` (the next token); returns its index."""
        index = self.i
        token = self.tokens[index]
        if token != text:
            if text == b"[" and kind_of(token) == ARRAY:
                # '[' followed by numbers: an interface holds declarations, not numbers
                first, offset = self.lx.first_in_array(index)
                expected = "expected field, exposedField, eventIn or eventOut"
                raise self.lx.error_at_offset(f"{expected}, found {describe(first)}", offset)
            raise self._error(f"expected '{text.decode()}' {where}, found {describe(token)}", index)
        self.i = index + 1
        return index

    def externproto(self) -> None:
        """``EXTERNPROTO Name [ interface ] "url"``: not loaded; its instances are skipped."""
        keyword = self.i
        name = self._name_after("EXTERNPROTO")
        opening = self._expect(b"[", f"after EXTERNPROTO {name}")
        self.interface(opening, with_values=False)
        url = self.field_value("url", Node("EXTERNPROTO", keyword, self.lx))
        if not isinstance(url, list) or not all(isinstance(u, str) for u in url):
            raise self._error(f"expected the url string(s) of EXTERNPROTO {name}", keyword)
        self.scope.protos[name] = None
        self.warn_once(f"EXTERNPROTO {name} is defined in another file and is not loaded: its instances are skipped")

    def interface(self, opening: int, with_values: bool) -> dict[str, Any]:
        """A PROTO/EXTERNPROTO interface after the ``[`` at token ``opening``; returns the
        default value of each field."""
        tokens, lx = self.tokens, self.lx
        defaults: dict[str, Any] = {}
        while True:
            if self.i >= lx.refill_at:
                lx.refill()
            start = self.i
            token = tokens[start]
            if token == b"]":
                self.i = start + 1
                return defaults
            if not token:
                raise self._error("'[' of a PROTO interface is never closed (file ends first)", at=opening)
            keyword = token.decode("utf-8", errors="replace")
            if kind_of(token) != NAME or keyword not in _INTERFACE_WITH_VALUE | _INTERFACE_EVENT:
                raise self._error(f"expected field, exposedField, eventIn or eventOut, found {describe(token)}")
            type_token, name_token = tokens[start + 1 : start + 3]
            if type_token is BROKEN or name_token is BROKEN:
                raise lx.broken_error()
            if kind_of(type_token) != NAME or kind_of(name_token) != NAME:
                raise self._error(f"malformed '{keyword}' declaration", start)
            self.i = start + 3
            if with_values and keyword in _INTERFACE_WITH_VALUE:
                name = self._decode(name_token)
                defaults[name] = self.typed_value(start + 1, name)

    def instantiate(self, instance: Node, proto: ProtoDef | None) -> Node:
        """The node a PROTO instance stands for: its body's first node, IS replaced."""
        if proto is None:  # EXTERNPROTO
            instance.external = True
            return instance
        first = next((n for n in proto.body if n is not None), None)
        if first is None:
            return Node(f"{proto.name} (empty PROTO)", instance.token, instance.source)
        values = dict(proto.defaults)
        values.update(instance.fields)
        return self._copy(first, values, {})

    def _copy(self, template: Node, values: dict[str, Any], memo: dict[int, Node]) -> Node:
        if not template.has_is:
            return template  # nothing to substitute: share it
        copied = memo.get(id(template))
        if copied is not None:
            return copied
        self.proto_nodes_created += 1
        if self.proto_nodes_created > MAX_PROTO_NODES:
            # on the line of the token after the instance, as a one-token reader reports it
            raise self._error(f"PROTO expansion creates more than {MAX_PROTO_NODES:,} nodes (refused as a possible bomb)")
        copy = Node(template.type, template.token, template.source, external=template.external)
        self.created.append(copy)
        memo[id(template)] = copy
        for name, value in template.fields.items():
            copy.fields[name] = self._substitute(value, values, memo)
            copy.has_is |= _holds_is(copy.fields[name])
        copy.children = [self._copy(child, values, memo) for child in template.children]
        copy.has_is |= any(child.has_is for child in copy.children)
        return copy

    def _substitute(self, value, values: dict[str, Any], memo: dict[int, Node]):
        if isinstance(value, IsRef):
            return values.get(value.name)
        if isinstance(value, Node):
            return self._copy(value, values, memo)
        if isinstance(value, list) and value and isinstance(value[0], Node):
            return [self._copy(item, values, memo) for item in value]
        return value


def _holds_is(value) -> bool:
    if isinstance(value, IsRef):
        return True
    if isinstance(value, Node):
        return value.has_is
    if isinstance(value, list) and value and isinstance(value[0], Node):
        return any(isinstance(item, Node) and item.has_is for item in value)
    return False
