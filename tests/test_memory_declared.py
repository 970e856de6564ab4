"""Memory is estimated from what a file declares, and a refusal comes before it is spent.

The class of input the attack used: big files of every text format made from real ones
(their polygons repeated: OFF, OBJ, ASCII PLY, ASCII STL), and a gzipped VRML whose one
coordIndex is huge. Each is refused by the memory limit (``LoadLimits.max_bytes``, set low
here so that the files stay small) with the one line of :meth:`LoadLimits.check_memory`,
and the allocations made on the way (tracemalloc, which numpy reports to) stay a fraction
of the file: before, each reader parsed the whole text first (ten bytes and more per byte
of text) and the VRML scanner stored every index.
"""

from __future__ import annotations

import gzip
import re
import tracemalloc
from pathlib import Path

import pytest

from shapeidx.errors import LoadError
from shapeidx.io import LoadLimits, load

MODELS = Path("mesh-wild/assimp-testmodels/usr/share/assimp/models")
#: The memory limit of these tests: 40 MiB, some 50,000 triangles.
LIMIT = 40 << 20
#: Triangles the files are made to hold: twice what LIMIT admits.
WANTED = 2 * LIMIT // 800


def _repeat_lines(text: bytes, pattern: bytes, times: int) -> bytes:
    """``text`` with every line matching ``pattern`` (a polygon) repeated ``times`` times."""
    return re.sub(rb"(?m)^(" + pattern + rb".*\n)", lambda m: m.group(1) * times, text)


def big_off(data_dir: Path) -> tuple[bytes, str]:
    text = (data_dir / MODELS / "OFF/Cube.off").read_bytes()
    header = re.search(rb"(?m)^\s*(\d+)\s+(\d+)\s+(\d+)", text)
    n_vertices, faces = int(header.group(1)), int(header.group(2))
    times = WANTED // (2 * faces) + 1  # quads: two triangles each
    lines = [line for line in text[header.end():].split(b"\n") if line.strip() and not line.strip().startswith(b"#")]
    vertex_lines, face_lines = lines[:n_vertices], lines[n_vertices:n_vertices + faces]
    out = b"OFF\n%d %d 0\n" % (n_vertices, faces * times) + b"\n".join(vertex_lines) + b"\n"
    return out + (b"\n".join(face_lines) + b"\n") * times, "x.off"


def big_obj(data_dir: Path) -> tuple[bytes, str]:
    text = (data_dir / MODELS / "OBJ/box.obj").read_bytes()
    faces = len(re.findall(rb"(?m)^f ", text))
    return _repeat_lines(text, rb"f ", WANTED // faces + 1), "x.obj"


def big_ply(data_dir: Path) -> tuple[bytes, str]:
    text = (data_dir / MODELS / "PLY/cube.ply").read_bytes()
    faces = int(re.search(rb"element face (\d+)", text).group(1))
    times = WANTED // (2 * faces) + 1  # quads: two triangles each
    text = text.replace(b"element face %d" % faces, b"element face %d" % (faces * times))
    return _repeat_lines(text, rb"4 ", times), "x.ply"


def big_stl(data_dir: Path) -> tuple[bytes, str]:
    text = (data_dir / MODELS / "STL/triangle.stl").read_bytes()
    facet = re.search(rb"(?is)\s*facet.*?endfacet\s*?\n", text)
    return text[: facet.start()] + facet.group(0) * WANTED + text[facet.end():], "x.stl"


def big_vrml(data_dir: Path) -> tuple[bytes, str]:
    """A real KiCad VRML whose first coordIndex is made huge, gzipped (the attack's bomb)."""
    text = min((data_dir / "vrml-wild" / "kicad-wrz").rglob("*.wrl"), key=lambda p: p.stat().st_size).read_bytes()
    start = re.search(rb"coordIndex\s*\[", text).end()
    return gzip.compress(text[:start] + b"0,1,2,-1," * WANTED + text[start:]), "x.wrl.gz"


@pytest.mark.parametrize("make", [big_off, big_obj, big_ply, big_stl, big_vrml], ids=lambda f: f.__name__)
def test_refused_before_the_memory_is_spent(data_dir, tmp_path, make):
    data, name = make(data_dir)
    path = tmp_path / name
    path.write_bytes(data)
    text_size = len(gzip.decompress(data)) if name.endswith(".gz") else len(data)
    tracemalloc.start()
    try:
        with pytest.raises(LoadError) as caught:
            load(path, LoadLimits(max_bytes=LIMIT))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    message = str(caught.value)
    assert re.fullmatch(rf"{re.escape(str(path))}: would need about [\d.]+ MiB of memory \([\d,]+ triangles.*\), more than "
                        r"the limit of 40.0 MiB \(refused as a possible bomb\)", message), message
    triangles = int(re.search(r"\(([\d,]+) triangles", message).group(1).replace(",", ""))
    assert triangles * 800 > LIMIT
    # the file's text (and for gzip its decompressed copy) and little more
    assert peak < 2.5 * text_size + (1 << 20), (peak, text_size)


def test_files_within_the_limit_are_still_read(data_dir, tmp_path):
    """The declared counts are lower bounds: a file of what the limit admits is read."""
    for name in ("OFF/Cube.off", "OBJ/box.obj", "PLY/cube.ply", "STL/triangle.stl"):
        mesh = load(data_dir / MODELS / name, LoadLimits(max_bytes=LIMIT))
        assert len(mesh.face_sizes) > 0


def test_gzip_declaring_more_than_the_limit_is_refused_unread(data_dir, tmp_path):
    data, _ = big_vrml(data_dir)
    path = tmp_path / "x.wrl.gz"
    path.write_bytes(data)
    size = len(gzip.decompress(data))
    with pytest.raises(LoadError, match=rf"gzip data expands beyond the limit of {size - 1:,} bytes \(it declares {size:,}: a bomb"):
        load(path, LoadLimits(max_uncompressed_bytes=size - 1))


def test_a_coordindex_without_separators_is_refused_before_it_is_split(data_dir, tmp_path):
    """The same KiCad part inside a Transform (read by the Python reader, not the compiled
    scanner), its coordIndex a run of indices with no ``-1``: no polygon end declares
    triangles, so the reader refuses it from the count of values, before splitting them."""
    text = min((data_dir / "vrml-wild" / "kicad-wrz").rglob("*.wrl"), key=lambda p: p.stat().st_size).read_bytes()
    start = re.search(rb"coordIndex\s*\[", text).end()
    header_end = text.index(b"\n") + 1
    body = text[header_end:start] + b"0 1 2 " * (LIMIT // 100) + text[start:]  # 3 values per 100 bytes of limit
    path = tmp_path / "x.wrl"
    path.write_bytes(text[:header_end] + b"Transform { children [\n" + body + b"\n] }\n")
    tracemalloc.start()
    try:
        with pytest.raises(LoadError, match=r"would need about [\d.]+ MiB of memory to split its [\d,]+ coordIndex values "
                                            r"into polygons, more than the limit of 40.0 MiB"):
            load(path, LoadLimits(max_bytes=LIMIT))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 8 * path.stat().st_size, peak
