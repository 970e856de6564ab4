"""Stanford PLY, ASCII and binary (either byte order); polygons kept as written."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import LoadError
from .base import Format, LoadLimits, PolygonMesh, head_of
from .formats import SUFFIXES

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


@dataclass
class _Property:
    name: str
    dtype: str  # numpy type code of the value (of the items, for a list)
    count_dtype: str | None = None  # set for list properties


@dataclass
class _Element:
    name: str
    count: int
    properties: list[_Property]


def read_ply(path, data: bytes, limits: LoadLimits | None = None) -> PolygonMesh:
    """Read PLY bytes: the ``vertex`` element's x, y, z and the ``face`` element's index list."""
    end = data.find(b"end_header")
    if not data[:3].lower() == b"ply" or end < 0:
        raise LoadError(path, "not a PLY file (missing 'ply' magic or 'end_header')")
    body_start = data.find(b"\n", end) + 1 or len(data)  # no line end after end_header: no body
    fmt, elements = _parse_header(path, data[:end].decode("ascii", errors="replace"))
    _check_header_elements(path, elements)
    if fmt == "ascii":
        values = _read_ascii(path, data[body_start:].decode("ascii", errors="replace"), elements)
    else:
        values = _read_binary(path, data, body_start, elements, "<" if fmt == "binary_little_endian" else ">")

    if "vertex" not in values:
        raise LoadError(path, "PLY file has no vertex element")
    vertex = values["vertex"]
    if any(c not in vertex for c in "xyz"):
        raise LoadError(path, "PLY vertex element lacks x, y or z")
    if any(isinstance(vertex[c], tuple) for c in "xyz"):
        raise LoadError(path, "PLY vertex x, y or z is declared a list, not a number")
    points = np.stack([np.asarray(vertex[c], dtype=np.float64) for c in "xyz"], axis=1)
    face = values.get("face", {})
    lists = face.get("vertex_indices", face.get("vertex_index"))
    if lists is None:
        raise LoadError(path, "PLY file has no faces (a point cloud is not a surface)")
    if not isinstance(lists, tuple):
        raise LoadError(path, "PLY face vertex_indices is declared a number, not a list")
    sizes, corners = lists
    warnings = []
    owner = np.repeat(np.arange(len(sizes)), sizes)
    bad_face = (sizes < 3) | (np.bincount(owner, weights=(corners < 0) | (corners >= len(points)), minlength=len(sizes)) > 0)
    if bad_face.any():
        warnings.append(f"{int(bad_face.sum())} face(s) with fewer than three corners or out-of-range indices skipped")
        keep = ~bad_face
        corners = corners[np.repeat(keep, sizes)]
        sizes = sizes[keep]
    return PolygonMesh(points, sizes.astype(np.int64), corners.astype(np.int64), "ply", warnings)


def _check_header_elements(path, elements: list[_Element]) -> None:
    """Refuse, before reading any data, a header without what a surface needs."""
    by_name = {e.name: e for e in elements}
    vertex = by_name.get("vertex")
    if vertex is None:
        raise LoadError(path, "PLY file has no vertex element")
    props = {p.name: p for p in vertex.properties}
    if any(c not in props for c in "xyz"):
        raise LoadError(path, "PLY vertex element lacks x, y or z")
    if any(props[c].count_dtype is not None for c in "xyz"):
        raise LoadError(path, "PLY vertex x, y or z is declared a list, not a number")
    face = by_name.get("face")
    lists = [p for p in face.properties if p.name in ("vertex_indices", "vertex_index")] if face else []
    if not lists:
        raise LoadError(path, "PLY file has no faces (a point cloud is not a surface)")
    if lists[0].count_dtype is None:
        raise LoadError(path, f"PLY face {lists[0].name} is declared a number, not a list")
    if lists[0].dtype[0] == "f":
        raise LoadError(path, f"PLY face list {lists[0].name!r} holds floating-point numbers, not vertex indices")


def _parse_header(path, header: str):
    fmt = None
    elements: list[_Element] = []
    for number, line in enumerate(header.splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0] in ("ply", "comment", "obj_info"):
            continue
        try:
            if fields[0] == "format":
                fmt = fields[1]
                if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
                    raise LoadError(path, f"unknown PLY format {fmt!r}", number)
            elif fields[0] == "element":
                elements.append(_Element(fields[1], int(fields[2]), []))
            elif fields[0] == "property":
                if fields[1] == "list":
                    elements[-1].properties.append(_Property(fields[4], _TYPES[fields[3]], _TYPES[fields[2]]))
                else:
                    elements[-1].properties.append(_Property(fields[2], _TYPES[fields[1]]))
        except (IndexError, KeyError, ValueError):
            raise LoadError(path, f"bad PLY header line {line.strip()!r}", number) from None
    if fmt is None:
        raise LoadError(path, "PLY header has no format line")
    for element in elements:
        if element.count < 0:
            raise LoadError(path, f"negative element count for {element.name!r}")
    return fmt, elements


def _read_ascii(path, text: str, elements: list[_Element]):
    lines = [line.split() for line in text.splitlines() if line.strip()]
    values: dict = {}
    row = 0
    for element in elements:
        rows = lines[row : row + element.count]
        if len(rows) < element.count:
            raise LoadError(path, f"PLY announces {element.count:,} {element.name} rows but has {len(rows):,}")
        row += element.count
        if all(p.count_dtype is None for p in element.properties):
            width = len(element.properties)
            short = next((r for r in rows if len(r) < width), None)
            if short is not None:
                raise LoadError(path, f"PLY {element.name} row with {len(short)} value(s), fewer than its {width} properties")
            try:
                table = np.array([r[:width] for r in rows], dtype=np.float64)
            except ValueError:
                raise LoadError(path, f"PLY {element.name} row that is not numbers") from None
            table = table.reshape(element.count, width)
            values[element.name] = {p.name: table[:, i] for i, p in enumerate(element.properties)}
            continue
        columns: dict = {p.name: ([], []) for p in element.properties}
        for r in rows:
            pos = 0
            try:
                for p in element.properties:
                    if p.count_dtype is None:
                        columns[p.name][1].append(float(r[pos]))
                        pos += 1
                    else:
                        n = int(r[pos])
                        items = r[pos + 1 : pos + 1 + n]
                        if n < 0 or len(items) < n:
                            raise LoadError(
                                path,
                                f"PLY {element.name} row whose list announces {n} values but has {len(items)}: "
                                f"{' '.join(r)[:60]!r}",
                            )
                        columns[p.name][0].append(n)
                        columns[p.name][1].extend(int(x) for x in items)
                        pos += 1 + n
            except (ValueError, IndexError):
                raise LoadError(path, f"bad PLY {element.name} row {' '.join(r)[:60]!r}") from None
        try:
            values[element.name] = {
                p.name: (np.array(columns[p.name][0], dtype=np.int64), np.array(columns[p.name][1], dtype=np.int64))
                if p.count_dtype
                else np.array(columns[p.name][1])
                for p in element.properties
            }
        except OverflowError:
            raise LoadError(path, f"PLY {element.name} list holds a number too large to be an index (past 2^63)") from None
    return values


def declared_ply(data: bytes) -> tuple[int, int]:
    """Faces and vertices the PLY header announces, bounded by what the bytes after it can
    hold (a face takes 4 bytes at least, a vertex 3); (0, 0) when the header cannot be read."""
    end = data.find(b"end_header")
    if data[:3].lower() != b"ply" or end < 0:
        return 0, 0
    counts = {}
    for line in data[:end].split(b"\n"):
        fields = line.split()
        if len(fields) == 3 and fields[0] == b"element" and fields[2].isdigit():
            counts[fields[1]] = int(fields[2])
    body = len(data) - end
    return min(counts.get(b"face", 0), body // 4), min(counts.get(b"vertex", 0), body // 3)


def _read_binary(path, data: bytes, offset: int, elements: list[_Element], order: str):
    values: dict = {}
    for element in elements:
        props = element.properties
        if not props:  # nothing to read, whatever the count says
            values[element.name] = {}
            continue
        if len({p.name for p in props}) < len(props):
            raise LoadError(path, f"PLY {element.name!r} element names a property twice")
        if all(p.count_dtype is None for p in props):
            dtype = np.dtype([(p.name, order + p.dtype) for p in props])
            offset = _need(path, data, offset, dtype.itemsize * element.count, element)
            table = np.frombuffer(data, dtype=dtype, count=element.count, offset=offset - dtype.itemsize * element.count)
            values[element.name] = {p.name: table[p.name] for p in props}
            continue
        fast = _fixed_length_lists(data, offset, element, order)
        if fast is not None:
            table, dtype = fast
            offset += dtype.itemsize * element.count
            values[element.name] = {
                p.name: (table[p.name + "#n"].astype(np.int64), table[p.name].reshape(-1).astype(np.int64))
                if p.count_dtype
                else table[p.name]
                for p in props
            }
            continue
        columns: dict = {p.name: ([], []) for p in props}
        for _ in range(element.count):
            for p in props:
                if p.count_dtype is None:
                    size = np.dtype(p.dtype).itemsize
                    _need(path, data, offset, size, element)
                    columns[p.name][1].append(np.frombuffer(data, order + p.dtype, 1, offset)[0])
                    offset += size
                else:
                    csize = np.dtype(p.count_dtype).itemsize
                    _need(path, data, offset, csize, element)
                    n = int(np.frombuffer(data, order + p.count_dtype, 1, offset)[0])
                    offset += csize
                    if n < 0:
                        raise LoadError(path, f"PLY {element.name!r} list with a negative length ({n})")
                    isize = np.dtype(p.dtype).itemsize
                    _need(path, data, offset, isize * n, element)
                    columns[p.name][0].append(n)
                    columns[p.name][1].extend(np.frombuffer(data, order + p.dtype, n, offset).tolist())
                    offset += isize * n
        values[element.name] = {
            p.name: (np.array(columns[p.name][0], dtype=np.int64), np.array(columns[p.name][1], dtype=np.int64))
            if p.count_dtype
            else np.array(columns[p.name][1])
            for p in props
        }
    return values


def _fixed_length_lists(data: bytes, offset: int, element: _Element, order: str):
    """Read an element whose lists all have the lengths of its first row, or return None."""
    fields = []
    pos = offset
    for p in element.properties:
        if p.count_dtype is None:
            fields.append((p.name, order + p.dtype))
            pos += np.dtype(p.dtype).itemsize
        else:
            if pos + np.dtype(p.count_dtype).itemsize > len(data):
                return None
            n = int(np.frombuffer(data, order + p.count_dtype, 1, pos)[0])
            if n < 0 or pos + n * np.dtype(p.dtype).itemsize > len(data):
                return None  # left to the row-by-row reading, which says what is wrong
            fields.append((p.name + "#n", order + p.count_dtype))
            fields.append((p.name, order + p.dtype, (n,)))
            pos += np.dtype(p.count_dtype).itemsize + n * np.dtype(p.dtype).itemsize
    dtype = np.dtype(fields)
    if offset + dtype.itemsize * element.count > len(data):
        return None
    table = np.frombuffer(data, dtype=dtype, count=element.count, offset=offset)
    for p in element.properties:
        if p.count_dtype is not None and not (table[p.name + "#n"] == table.dtype[p.name].shape[0]).all():
            return None
    return table, dtype


def _need(path, data: bytes, offset: int, size: int, element: _Element) -> int:
    if offset + size > len(data):
        raise LoadError(path, f"PLY file ends inside its {element.name!r} data (truncated)")
    return offset + size


FORMATS = [Format("ply", "PLY", SUFFIXES["ply"], read_ply, declared=declared_ply, sniff=lambda data: head_of(data)[:3].lower() == b"ply")]
