"""Every reason is in words about the file: no Python exception's name or repr in any line.

The input class the attack found it with: numbers past what a C long or a float64 holds
(2^63 + 1, -2^63 - 1, 2^64, 10^50, 1e400) written in place of the numbers of real files of
every text format. A reason that names an exception class (``OverflowError: Python int too
large to convert to C long``) or says the input was not foreseen is a gap.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from shapeidx.errors import UNFORESEEN, LoadError, exception_in_words
from shapeidx.io import load_bytes

MODELS = Path("mesh-wild/assimp-testmodels/usr/share/assimp/models")
SEEDS = [
    MODELS / "PLY/cube.ply",
    MODELS / "OFF/Cube.off",
    MODELS / "OBJ/box.obj",
    MODELS / "STL/triangle.stl",
    Path("vrml-wild"),
]
HOSTILE = [b"9223372036854775809", b"-9223372036854775809", b"18446744073709551616", b"1" + b"0" * 50, b"1e400"]
#: An exception's class name (``OverflowError``, ``Transfer_TransferFailure``,
#: ``Standard_NumericError``) or a repr in a reason.
RAW = re.compile(r"\b[A-Z]\w*(Error|Exception|Failure|Overflow)\b|\b[A-Z][A-Za-z]+_[A-Z]\w+\b|Traceback|<class ")


def _seed(data_dir: Path, relative: Path) -> Path:
    path = data_dir / relative
    if path.is_dir():  # the smallest VRML of the folder
        path = min(path.rglob("*.wrl"), key=lambda p: p.stat().st_size)
    assert path.is_file(), path
    return path


@pytest.mark.parametrize("relative", SEEDS, ids=lambda p: p.suffix or p.name)
def test_huge_numbers_in_real_files_get_reasons_in_words(data_dir, relative):
    path = _seed(data_dir, relative)
    data = path.read_bytes()
    numbers = [m.span() for m in re.finditer(rb"-?\d+(\.\d+)?(e-?\d+)?", data)]
    numbers = numbers[:12] + numbers[12 :: max(1, len(numbers) // 24)]  # the header's, and some of each part
    assert numbers
    refused = 0
    for start, end in numbers:
        for number in HOSTILE:
            try:
                load_bytes(data[:start] + number + data[end:], path.name)
            except LoadError as exc:
                refused += 1
                assert not RAW.search(str(exc)) and UNFORESEEN not in str(exc), str(exc)
    assert refused > 0


def test_a_ply_index_past_2_63_is_refused_in_words(data_dir):
    data = (data_dir / MODELS / "PLY/cube.ply").read_bytes()
    face = re.search(rb"\n3 (\d+) (\d+) (\d+)", data) or re.search(rb"\n4 (\d+) (\d+) (\d+) (\d+)", data)
    hostile = data[: face.start(1)] + b"9223372036854775809" + data[face.end(1):]
    with pytest.raises(LoadError, match=r"cube.ply: PLY face list holds a number too large to be an index \(past 2\^63\)"):
        load_bytes(hostile, "cube.ply")


def test_unforeseen_exceptions_are_said_in_words():
    """What the readers' last resort says of a real exception of each kind."""
    caught = []
    for action in (lambda: np.array([2**70], dtype=np.int64), lambda: 1 / 0, lambda: b"\xff".decode("utf-8"),
                   lambda: [][1], lambda: int("x"), lambda: len(5)):
        try:
            action()
        except Exception as exc:  # noqa: BLE001
            caught.append(exception_in_words(exc))
    assert caught[0].startswith("a number too large to compute with")
    assert caught[1].startswith("values that lead to a division by zero")
    assert caught[2].startswith("text that is not in the expected encoding")
    assert caught[3].startswith("a reference to an element that does not exist")
    assert caught[4].startswith("a value of the wrong form")
    assert caught[5].startswith("a value of the wrong kind")
    for text in caught:
        assert not RAW.search(text) and text.endswith(f"{UNFORESEEN} (please report the file)")


def test_an_opencascade_exception_is_said_in_words(tmp_path):
    """A real exception of OpenCASCADE's (a zero vector made a direction raises
    ``Standard_ConstructionError``) in one of the reader's steps: its class and message
    stay out of the line, which says which step failed and why in words."""
    from OCP.gp import gp_Dir

    from shapeidx.io.step import _occt

    with pytest.raises(LoadError) as caught:
        _occt(tmp_path / "part.igs", "mesh its faces", gp_Dir, 0.0, 0.0, 0.0)
    message = str(caught.value)
    assert message.startswith(f"{tmp_path / 'part.igs'}: OpenCASCADE could not mesh its faces: ")
    assert not RAW.search(message) and "zero norm" not in message, message


def test_damaged_gzip_is_said_in_words(data_dir):
    """Bytes of a real gzipped KiCad VRML changed inside its compressed stream, or the file
    cut short: the reason says what is wrong, not zlib's "Error -3 while decompressing"."""
    import random

    path = min((data_dir / "vrml-wild").rglob("*.wrz"), key=lambda p: p.stat().st_size)
    data = path.read_bytes()
    rng = random.Random(4)
    reasons = set()
    for _ in range(40):
        damaged = bytearray(data)
        for _ in range(4):
            damaged[rng.randrange(20, len(data) - 8)] ^= 1 << rng.randrange(8)
        for case in (bytes(damaged), data[: rng.randrange(20, len(data) - 8)]):
            try:
                load_bytes(case, path.name)
            except LoadError as exc:
                reasons.add(str(exc))
    gzip_reasons = [r for r in reasons if "gzip" in r]
    assert gzip_reasons
    for reason in gzip_reasons:
        assert not re.search(r"\bError -?\d|zlib|\bb'", reason) and not RAW.search(reason), reason
    assert any("cut short" in r for r in gzip_reasons) and any("compressed stream is damaged" in r for r in gzip_reasons)
