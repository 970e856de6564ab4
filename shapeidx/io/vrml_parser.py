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

from ..errors import LoadError
from .vrml_lexer import END, NAME, NUMBER, PUNCT, STRING, Lexer, Token, decode_string, describe

#: Deepest nesting of nodes and brackets accepted: far more than exporters write, and few
#: enough that hostile files cannot exhaust Python's stack.
MAX_NESTING = 120
#: Most nodes that PROTO expansion may create in one file (a PROTO bomb guard).
MAX_PROTO_NODES = 200_000

_INTERFACE_WITH_VALUE = {"field", "exposedField", "initializeOnly", "inputOutput"}
_INTERFACE_EVENT = {"eventIn", "eventOut", "inputOnly", "outputOnly"}
_BRACES = (b"{", b"}", b"[", b"]")
_HEADER = re.compile(rb"#(VRML|Inventor|X3D)\s*V?(\d+)?")


@dataclass(eq=False)
class Node:
    """One node as read: its type, its fields and (VRML 1.0) its child nodes.

    Field values are numpy float64 arrays (any numbers), lists of str (strings), bools,
    Nodes, lists of Nodes, ``None`` (``NULL``), tuples of words (VRML 1.0 enums and bit
    masks) or :class:`IsRef` inside PROTO templates.
    """

    type: str
    offset: int  # byte offset of the type name in its file
    source: Lexer | None = None  # the file it was read from (for line numbers)
    fields: dict[str, Any] = field(default_factory=dict)
    children: list["Node"] = field(default_factory=list)
    #: True when this node or a node below it holds an IS reference (PROTO templates).
    has_is: bool = False
    #: Set on EXTERNPROTO instances and node types nobody defined.
    external: bool = False

    @property
    def line(self) -> int | None:
        """Line of the node's type name in its file (counted on demand: messages only)."""
        return self.source.line_of(self.offset) if self.source is not None else None


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
    return Scene(path, version, nodes, warnings)


class _Scope:
    """Names visible while parsing: a file, or one PROTO body, has its own."""

    def __init__(self, protos: dict[str, ProtoDef | None]):
        self.defs: dict[str, Node] = {}
        # Known PROTO names; None marks an EXTERNPROTO (declared, not loaded).
        self.protos = protos


class _Parser:
    def __init__(self, lexer: Lexer, warnings: list[str], version: int):
        self.lx = lexer
        self.version = version
        self.warnings = warnings
        self.scope = _Scope({})
        self.depth = 0
        self.proto_nodes_created = 0
        self._warned: set[str] = set()

    def warn_once(self, message: str) -> None:
        if message not in self._warned:
            self._warned.add(message)
            self.warnings.append(message)

    # -- statements ---------------------------------------------------------------------

    def statements(self, until_close: Token | None) -> list[Node]:
        """Nodes up to the end of file, or up to the ``}`` closing ``until_close``."""
        nodes = []
        while True:
            if until_close is None:
                if self.lx.peek().kind == END:
                    return nodes
            elif self.lx.at_close(b"}", until_close.start, "'{' of a PROTO body"):
                return nodes
            node = self.statement()
            if node is not None:
                nodes.append(node)

    def statement(self) -> Node | None:
        """One node, PROTO, EXTERNPROTO or ROUTE; returns the node or None."""
        token = self.lx.peek()
        if token.kind == NAME:
            if token.text == b"PROTO":
                self.proto()
                return None
            if token.text == b"EXTERNPROTO":
                self.externproto()
                return None
            if token.text == b"ROUTE":
                self.route()
                return None
            return self.node_statement()
        raise self.lx.error(f"expected a node, found {describe(token)}")

    def route(self) -> None:
        """``ROUTE a.field TO b.field``: events do not change geometry; read and drop."""
        start = self.lx.next()
        for expected in (NAME, b".", NAME, b"TO", NAME, b".", NAME):
            token = self.lx.next()
            if (token.kind if expected == NAME else token.text) != expected:
                raise self.lx.error(f"malformed ROUTE: unexpected {describe(token)}", start.start)

    # -- nodes ----------------------------------------------------------------------------

    def node_statement(self) -> Node | None:
        """``DEF name node``, ``USE name``, ``NULL`` or a plain node."""
        token = self.lx.next()
        if token.text == b"USE":
            name = self._name_after("USE")
            node = self.scope.defs.get(name)
            if node is None:
                self.warnings.append(f"line {self.lx.line_of(token.start)}: USE of undefined name {name!r} ignored")
            return node
        if token.text == b"DEF":
            name = self._name_after("DEF")
            type_token = self.lx.next()
            if type_token.kind != NAME:
                raise self.lx.error(
                    f"expected a node type after DEF {name}, found {describe(type_token)}", type_token.start
                )
            node = self.node(type_token)
            if node is not None:
                self.scope.defs[name] = node
            return node
        if token.text == b"NULL":
            return None
        return self.node(token)

    def _name_after(self, what: str) -> str:
        """The name that must follow the keyword ``what`` (DEF, USE, IS, PROTO...)."""
        token = self.lx.next()
        if token.kind != NAME:
            raise self.lx.error(f"expected a name after {what}, found {describe(token)}", token.start)
        return token.text.decode("utf-8", errors="replace")

    def node(self, type_token: Token) -> Node:
        """A node whose type name was just read: its ``{ body }``, PROTOs expanded."""
        type_name = type_token.text.decode("utf-8", errors="replace")
        brace = self.lx.next()
        if brace.kind != PUNCT or brace.text != b"{":
            raise self.lx.error(f"expected '{{' after node type {type_name!r}, found {describe(brace)}", brace.start)
        node = Node(type_name, type_token.start, self.lx)
        self._enter(brace)
        self.body(node, brace)
        self.depth -= 1
        if type_name in self.scope.protos:
            return self.instantiate(node, self.scope.protos[type_name])
        return node

    def _enter(self, token: Token) -> None:
        self.depth += 1
        if self.depth > MAX_NESTING:
            raise self.lx.error(f"nodes or lists nested deeper than {MAX_NESTING} levels", token.start)

    def body(self, node: Node, brace: Token) -> None:
        """Fields and (VRML 1.0) child nodes up to the closing ``}``."""
        lx = self.lx
        while not lx.at_close(b"}", brace.start, f"'{{' of {node.type}"):
            token = lx.peek()
            if token.kind != NAME:
                raise lx.error(f"expected a field name or '}}' in {node.type}, found {describe(token)}")
            word = token.text
            if word in (b"DEF", b"USE", b"PROTO", b"EXTERNPROTO", b"ROUTE"):
                self._add_child(node, self.statement())
                continue
            if self._starts_node(token):  # VRML 1.0 child node
                self._add_child(node, self.node(lx.next()))
                continue
            lx.next()
            name = word.decode("utf-8", errors="replace")
            if name in _INTERFACE_WITH_VALUE or name in _INTERFACE_EVENT:
                self.declaration(node, name)  # Script and PROTO-like field declarations
                continue
            value = self.field_value(name, node)
            node.fields[name] = value
            node.has_is |= _holds_is(value)

    @staticmethod
    def _add_child(node: Node, child: Node | None) -> None:
        if child is not None:
            node.children.append(child)
            node.has_is |= child.has_is

    def declaration(self, node: Node, keyword: str) -> None:
        """``field TYPE name value`` / ``eventIn TYPE name`` inside a Script node."""
        type_token, name_token = self.lx.next(), self.lx.next()
        if type_token.kind != NAME or name_token.kind != NAME:
            raise self.lx.error(f"malformed '{keyword}' declaration in {node.type}", type_token.start)
        name = name_token.text.decode("utf-8", errors="replace")
        after = self.lx.peek()
        if after.kind == NAME and after.text == b"IS":
            self.lx.next()
            node.fields[name] = IsRef(self._name_after("IS"))
            node.has_is = True
        elif keyword in _INTERFACE_WITH_VALUE:
            node.fields[name] = self.typed_value(type_token, name)

    # -- values ---------------------------------------------------------------------------

    def field_value(self, name: str, node: Node):
        """The value of field ``name``: decided by its first token."""
        lx = self.lx
        token = lx.peek()
        if token.kind == NAME and token.text == b"IS":
            lx.next()
            return IsRef(self._name_after("IS"))
        if token.kind == NUMBER:
            return self.numbers()
        if token.kind == STRING:
            return [decode_string(lx.next())]
        if token.kind == PUNCT:
            if token.text == b"[":
                return self.bracketed_list()
            if token.text == b"(":
                return self.bit_mask()
        if token.kind == NAME:
            if token.text == b"TRUE" or token.text == b"FALSE":
                return lx.next().text == b"TRUE"
            if token.text in (b"DEF", b"USE", b"NULL"):
                return self.node_statement()
            if self._starts_node(token):
                return self.node(lx.next())
        if self.version == 1 and token.kind in (NAME, PUNCT) and token.text not in _BRACES:
            # an enum (``vertexOrdering CLOCKWISE``) or a string without quotes
            return tuple(lx.raw_word().decode("utf-8", errors="replace").split("|"))
        if token.kind == NAME:
            lx.next()
            return (token.text.decode("utf-8", errors="replace"),)
        raise lx.error(f"expected a value for field '{name}' of {node.type}, found {describe(token)}")

    def _starts_node(self, token: Token) -> bool:
        """Is the name ``token`` (the next token) a node type, followed by ``{``?"""
        after = self.lx.peek(1)
        return after.kind == PUNCT and after.text == b"{"

    def numbers(self) -> np.ndarray:
        """Numbers written without brackets (``translation 1 2 3``), token by token: few."""
        values = []
        while self.lx.peek().kind == NUMBER:
            text = self.lx.next().text
            values.append(float(int(text, 16)) if b"x" in text or b"X" in text else float(text))
        return np.array(values, dtype=np.float64)

    def bracketed_list(self):
        """``[ ... ]``: numbers in bulk, else strings, nodes or words one by one."""
        lx = self.lx
        opening = lx.next()
        first = lx.peek()
        if first.kind == NUMBER:
            return lx.numbers_in_brackets(opening.start)
        self._enter(opening)
        items: list = []
        while not lx.at_close(b"]", opening.start, "'['"):
            token = lx.peek()
            if token.kind == STRING:
                items.append(decode_string(lx.next()))
            elif token.kind == NUMBER:
                items.extend(self.numbers().tolist())
            elif token.kind == NAME and token.text in (b"ROUTE", b"PROTO", b"EXTERNPROTO"):
                self.statement()
            elif token.kind == NAME:
                items.append(self._list_item(token))
            else:
                raise lx.error(f"unexpected {describe(token)} in a '[ ]' list")
        self.depth -= 1
        return [item for item in items if item is not None]

    def _list_item(self, token: Token):
        """A node in an MFNode list, or a word (VRML 1.0 ``fields [ SFFloat size ]``)."""
        if token.text in (b"DEF", b"USE", b"NULL"):
            return self.node_statement()
        if self._starts_node(token):
            return self.node(self.lx.next())
        return self.lx.next().text.decode("utf-8", errors="replace")

    def bit_mask(self) -> tuple[str, ...]:
        """VRML 1.0 ``(SIDES | TOP)``: the words between the parentheses."""
        opening = self.lx.next()
        words = []
        while True:
            token = self.lx.next()
            if token.kind == PUNCT and token.text == b")":
                return tuple(words)
            if token.kind == NAME:
                words.extend(w for w in token.text.decode("utf-8", errors="replace").replace(")", "|").split("|") if w)
                if token.text.endswith(b")"):
                    return tuple(words)
            elif not (token.kind == PUNCT and token.text == b"|"):
                raise self.lx.error(f"unexpected {describe(token)} in a '( | )' bit mask", opening.start)

    def typed_value(self, type_token: Token, name: str):
        """A value whose type is declared (PROTO interface, Script field)."""
        type_name = type_token.text
        token = self.lx.peek()
        if type_name == b"SFNode":
            if token.kind == NAME:
                return self.node_statement() if token.text in (b"DEF", b"USE", b"NULL") else self.node(self.lx.next())
            raise self.lx.error(f"expected a node or NULL for SFNode field '{name}', found {describe(token)}")
        if type_name == b"MFNode" and token.kind == NAME:
            node = self.node_statement() if token.text in (b"DEF", b"USE", b"NULL") else self.node(self.lx.next())
            return [node] if node is not None else []
        return self.field_value(name, Node("declaration", type_token.start, self.lx))

    # -- PROTO ----------------------------------------------------------------------------

    def proto(self) -> None:
        """``PROTO Name [ interface ] { body }``: remembered as a template."""
        self.lx.next()  # PROTO
        name = self._name_after("PROTO")
        opening = self.lx.expect(b"[", f"after PROTO {name}")
        defaults = self.interface(opening, with_values=True)
        brace = self.lx.expect(b"{", f"to open the body of PROTO {name}")
        outer = self.scope
        self.scope = _Scope(dict(outer.protos))  # the body has its own DEF names
        self._enter(brace)
        try:
            body = self.statements(until_close=brace)
        finally:
            self.scope = outer
            self.depth -= 1
        outer.protos[name] = ProtoDef(name, defaults, body)

    def externproto(self) -> None:
        """``EXTERNPROTO Name [ interface ] "url"``: not loaded; its instances are skipped."""
        keyword = self.lx.next()
        name = self._name_after("EXTERNPROTO")
        opening = self.lx.expect(b"[", f"after EXTERNPROTO {name}")
        self.interface(opening, with_values=False)
        url = self.field_value("url", Node("EXTERNPROTO", keyword.start, self.lx))
        if not isinstance(url, list) or not all(isinstance(u, str) for u in url):
            raise self.lx.error(f"expected the url string(s) of EXTERNPROTO {name}", keyword.start)
        self.scope.protos[name] = None
        self.warn_once(f"EXTERNPROTO {name} is defined in another file and is not loaded: its instances are skipped")

    def interface(self, opening: Token, with_values: bool) -> dict[str, Any]:
        """A PROTO/EXTERNPROTO interface; returns the default value of each field."""
        defaults: dict[str, Any] = {}
        while not self.lx.at_close(b"]", opening.start, "'[' of a PROTO interface"):
            token = self.lx.next()
            keyword = token.text.decode("utf-8", errors="replace")
            if token.kind != NAME or keyword not in _INTERFACE_WITH_VALUE | _INTERFACE_EVENT:
                raise self.lx.error(
                    f"expected field, exposedField, eventIn or eventOut, found {describe(token)}", token.start
                )
            type_token, name_token = self.lx.next(), self.lx.next()
            if type_token.kind != NAME or name_token.kind != NAME:
                raise self.lx.error(f"malformed '{keyword}' declaration", token.start)
            if with_values and keyword in _INTERFACE_WITH_VALUE:
                name = name_token.text.decode("utf-8", errors="replace")
                defaults[name] = self.typed_value(type_token, name)
        return defaults

    def instantiate(self, instance: Node, proto: ProtoDef | None) -> Node:
        """The node a PROTO instance stands for: its body's first node, IS replaced."""
        if proto is None:  # EXTERNPROTO
            instance.external = True
            return instance
        first = next((n for n in proto.body if n is not None), None)
        if first is None:
            return Node(f"{proto.name} (empty PROTO)", instance.offset, instance.source)
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
            raise self.lx.error(
                f"PROTO expansion creates more than {MAX_PROTO_NODES:,} nodes (refused as a possible bomb)"
            )
        copy = Node(template.type, template.offset, template.source, external=template.external)
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
