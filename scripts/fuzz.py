#!/usr/bin/env python
"""Mutation fuzzer for every reader: real files, mutated, loaded and cleaned in guarded workers.

Seeds are real files of every format in the shared data (``../shared/data`` or
``SHAPEIDX_DATA``): ASCII and binary STL, OBJ, OFF, ASCII and binary PLY, VRML 1.0 and 2.0,
and gzipped VRML (``.wrz``, ``.wrl.gz``). The data holds no big-endian PLY, so one is derived
from a real PLY file (its arrays written back big-endian). Each case takes one seed and
applies one to three mutations:

``flip``      flip 1-8 random bits
``bytes``     set 1-8 random bytes to ones that mean something to a parser (``{ } [ ] - . 0``,
              NUL, 0xff, newline, ...)
``truncate``  cut the file at a random point
``delete``    delete a chunk (up to a tenth of the file)
``duplicate`` copy a chunk elsewhere, or repeat it in place up to 64 times
``number``    replace numbers written in the text (biased to the header: the counts) by
              hostile ones (0, -1, 2^31, 2^40, 1e200, 1e-320, nan, inf, 20 digits, ...), or
              in a binary file a 4-byte word by a hostile int32/float32 (NaN, signalling
              NaN, inf, 0x80000000, ...), the binary STL triangle count among them
``splice``    insert a run of tokens (or bytes) taken from another seed of the same format
``rename``    give the file a name without a known ending, so the reader is sniffed

A gzip seed is mutated inside (decompressed, mutated, compressed again) two times in three,
else as compressed bytes.

Each case runs in a worker process (``spawn``) with a memory limit (``RLIMIT_DATA``,
``--memory``) and a time limit (``--timeout``): :func:`shapeidx.io.load`, then
:func:`shapeidx.signing.solid.make_solid` (and with ``--signature`` the whole signature). A case ends
as one of

``mesh``        a usable part: finite vertices, indices in range, positive finite area
``load_error``  a clean :class:`~shapeidx.errors.LoadError`: one line, naming the file, not
                a wrapped internal exception
``wrapped``     a LoadError that only stands for an internal exception (its reason says the
                input was something "shapeidx's checks did not foresee") or quotes one
                (a class name, zlib's "Error -3 while decompressing")
``exception``   any other exception (its type is recorded)
``crash``       the worker died (a signal: a native crash, or killed)
``hang``        the worker ran past the time limit and was killed

and, on the side, ``noisy``: something besides the result reached stderr (a numpy warning,
a native library's message). Peak memory per case is the worker's VmHWM, reset before each
case (``/proc/self/clear_refs``).

Every case is reproducible alone: its random choices come from ``(--seed, case number)``;
``--keep DIR`` saves every case that did not end as ``mesh`` or ``load_error`` (and the
noisy ones) with a line of JSON describing it, and ``--replay FILE...`` runs saved files.

Usage::

    python scripts/fuzz.py --cases 10000 --workers 2 --seed 1 --keep /tmp/fuzz-keep
    python scripts/fuzz.py --cases 300 --max-seed-bytes 20000      # a quick look
"""

from __future__ import annotations

import argparse
import gzip
import json
import multiprocessing
import os
import platform
import random
import re
import shutil
import signal
import statistics
import struct
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from multiprocessing.connection import wait
from pathlib import Path

DEFAULT_DATA = Path(os.environ.get("SHAPEIDX_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
FOLDERS = ("mesh-wild", "vrml-wild", "kicad6", "ndr", "xexp-dev", "kicad6-step")
KINDS = (
    "stl-ascii", "stl-binary", "obj", "off", "ply-ascii", "ply-binary-le", "ply-binary-be",
    "vrml1", "vrml2", "vrml-gzip", "step", "iges",
)  # fmt: skip
OUTCOMES = ("mesh", "load_error", "wrapped", "exception", "crash", "hang")
CLEAN = ("mesh", "load_error")

# -- seeds ------------------------------------------------------------------------------------


@dataclass
class Seed:
    kind: str
    name: str  # where it came from (path relative to the data folder, or "derived from ...")
    suffix: str  # file name ending to write cases with
    data: bytes


def kind_of(path: Path, data: bytes) -> str | None:
    """The fuzzing kind of a real file, from its name and content; None for others."""
    name = path.name.lower()
    if data[:2] == b"\x1f\x8b":
        return "vrml-gzip" if name.endswith((".wrz", ".wrl.gz", ".vrml.gz")) else None
    if name.endswith((".wrl", ".vrml")):
        head = data[:64]
        if head.startswith(b"#VRML V1.0"):
            return "vrml1"
        if head.startswith(b"#VRML V2.0"):
            return "vrml2"
        return None
    if name.endswith(".stl"):
        if len(data) >= 84 and len(data) == 84 + 50 * struct.unpack_from("<I", data, 80)[0]:
            return "stl-binary"
        return "stl-ascii" if data.lstrip()[:5].lower() == b"solid" else None
    if name.endswith(".obj"):
        return "obj"
    if name.endswith(".off"):
        return "off" if data.lstrip()[:3] in (b"OFF", b"COF", b"NOF") else None
    if name.endswith((".step", ".stp")):
        return "step" if data.lstrip()[:12] == b"ISO-10303-21" else None
    if name.endswith((".igs", ".iges")):
        return "iges"
    if name.endswith(".ply"):
        head = data[:200]
        for fmt, kind in ((b"ascii", "ply-ascii"), (b"binary_little", "ply-binary-le"), (b"binary_big", "ply-binary-be")):
            if b"format " + fmt in head:
                return kind
    return None


def suffix_of(path: Path) -> str:
    name = path.name.lower()
    for ending in (".wrl.gz", ".vrml.gz"):
        if name.endswith(ending):
            return ending
    return path.suffix.lower()


def find_seeds(data_dir: Path, per_kind: int, max_bytes: int, rng: random.Random) -> list[Seed]:
    """Up to ``per_kind`` real files of each kind, at most ``max_bytes`` each, picked by ``rng``
    among the candidates (the smallest one of each kind always included)."""
    found: dict[str, list[tuple[int, Path]]] = {}
    for folder in FOLDERS:
        root = data_dir / folder
        if not root.is_dir():
            continue
        for path in sorted(root.rglob("*")):
            if not path.is_file() or path.name.startswith(".") or path.suffix.lower() == ".tsv":
                continue
            size = path.stat().st_size
            if size == 0 or size > max_bytes:
                continue
            kind = kind_of(path, path.read_bytes())
            if kind is not None:
                found.setdefault(kind, []).append((size, path))
    seeds = []
    for kind in KINDS:
        candidates = sorted(found.get(kind, []))
        if not candidates:
            continue
        chosen = [candidates[0]]
        rest = candidates[1:]
        chosen += rng.sample(rest, min(per_kind - 1, len(rest)))
        for _, path in chosen:
            seeds.append(Seed(kind, str(path.relative_to(data_dir)), suffix_of(path), path.read_bytes()))
    if not any(s.kind == "ply-binary-be" for s in seeds):
        seeds += derived_big_endian_ply(data_dir, seeds)
    if not any(s.kind == "iges" for s in seeds):
        seeds += derived_iges(data_dir, seeds, per_kind)
    return seeds


def derived_iges(data_dir: Path, seeds: list[Seed], count: int) -> list[Seed]:
    """The data holds no IGES: write the STEP seeds' solids as IGES with OpenCASCADE's own
    writer, half as B-rep solids (mode 1), half as trimmed faces (mode 0)."""
    import tempfile

    try:
        from OCP.IGESControl import IGESControl_Writer
        from OCP.STEPControl import STEPControl_Reader
    except ImportError:
        return []
    derived = []
    for k, seed in enumerate(s for s in seeds if s.kind == "step"):
        reader = STEPControl_Reader()
        if not str(reader.ReadFile(str(data_dir / seed.name))).endswith("RetDone"):
            continue
        reader.TransferRoots()
        writer = IGESControl_Writer("MM", k % 2)
        if not writer.AddShape(reader.OneShape()):
            continue
        writer.ComputeModel()
        with tempfile.TemporaryDirectory() as folder:
            out = Path(folder) / "part.igs"
            if writer.Write(str(out)):
                derived.append(Seed("iges", f"derived from {seed.name} (IGES mode {k % 2})", ".igs", out.read_bytes()))
        if len(derived) == count:
            break
    return derived


def derived_big_endian_ply(data_dir: Path, seeds: list[Seed]) -> list[Seed]:
    """The data holds no big-endian PLY: write the arrays of its PLY seeds back big-endian
    (float x y z, uchar count, int indices), so that the big-endian reader is fuzzed too."""

    from shapeidx.io import load

    derived = []
    for seed in seeds:
        if not seed.kind.startswith("ply-"):
            continue
        try:
            mesh = load(data_dir / seed.name)
        except Exception:
            continue
        if mesh.face_sizes.max() > 255:
            continue
        derived.append(
            Seed("ply-binary-be", f"derived from {seed.name}", ".ply", write_ply_be(mesh.vertices, mesh.face_sizes, mesh.face_indices))
        )
        if len(derived) == 2:
            break
    return derived


def write_ply_be(vertices, sizes, corners) -> bytes:
    import numpy as np

    header = (
        f"ply\nformat binary_big_endian 1.0\nelement vertex {len(vertices)}\nproperty float x\nproperty float y\n"
        f"property float z\nelement face {len(sizes)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()
    body = [np.asarray(vertices, ">f4").tobytes()]
    start = 0
    for size in sizes:
        body.append(struct.pack(">B", size) + np.asarray(corners[start : start + size], ">i4").tobytes())
        start += size
    return header + b"".join(body)


# -- mutations --------------------------------------------------------------------------------

INTERESTING_BYTES = b"{}[]-.0\x00\xff\n\r\t #,\"\\e9"
INTERESTING_NUMBERS = (
    "0", "-1", "1", "2", "3", "-0", "255", "256", "65536", "2147483647", "2147483648", "4294967295",
    "4294967296", "1099511627776", "-2147483648", "99999999999999999999", "1e200", "-1e200", "1e308",
    "1e309", "-1e309", "1e-320", "1e-200", "nan", "NaN", "inf", "-inf", "0x7fffffff", "1.5", "0.5", "-0.0",
    "1e38", "3.5e38", "1e5", "",
)  # fmt: skip
INTERESTING_WORDS = (
    0, 1, 0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 0x7FC00000, 0x7F800001, 0xFF800000, 0x7F800000,
    0x00000001, 0x7F7FFFFF, 0x80000001, 0x40000000,
)  # nan, signalling nan, -inf, inf, denormal, max float among them  # fmt: skip
NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
TOKEN_RUN = re.compile(rb"\S+(?:\s+\S+){0,40}")


def _binary(seed_kind: str) -> bool:
    return seed_kind in ("stl-binary", "ply-binary-le", "ply-binary-be")


def mutate_flip(rng, data, kind, pool):
    if not data:
        return data
    out = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        i = rng.randrange(len(out))
        out[i] ^= 1 << rng.randrange(8)
    return bytes(out)


def mutate_bytes(rng, data, kind, pool):
    if not data:
        return data
    out = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        out[rng.randrange(len(out))] = rng.choice(INTERESTING_BYTES)
    return bytes(out)


def mutate_truncate(rng, data, kind, pool):
    return data[: rng.randrange(max(1, len(data)))]


def _chunk(rng, data):
    length = max(1, int(len(data) * rng.random() ** 3 * 0.1) + rng.randint(0, 16))
    start = rng.randrange(max(1, len(data) - length + 1))
    return start, min(len(data), start + length)


def mutate_delete(rng, data, kind, pool):
    if len(data) < 2:
        return data
    a, b = _chunk(rng, data)
    return data[:a] + data[b:]


def mutate_duplicate(rng, data, kind, pool):
    if not data:
        return data
    a, b = _chunk(rng, data)
    piece = data[a:b]
    if rng.random() < 0.5:
        return data[:b] + piece * rng.randint(1, 64) + data[b:]
    at = rng.randrange(len(data) + 1)
    return data[:at] + piece + data[at:]


def mutate_number(rng, data, kind, pool):
    if _binary(kind):
        return _mutate_binary_word(rng, data, kind)
    matches = []
    for match in NUMBER.finditer(data):
        matches.append(match.span())
        if len(matches) >= 5000:
            break
    if not matches:
        return mutate_bytes(rng, data, kind, pool)
    out = data
    for _ in range(rng.randint(1, 3)):
        # a third of the time one of the first ten numbers: the counts of a header
        span = matches[rng.randrange(min(10, len(matches)))] if rng.random() < 0.33 else rng.choice(matches)
        value = rng.choice(INTERESTING_NUMBERS).encode()
        out = out[: span[0]] + value + out[span[1] :]
        shift = len(value) - (span[1] - span[0])
        matches = [(a + shift, b + shift) if a > span[0] else (a, b) for a, b in matches]
    return out


def _mutate_binary_word(rng, data, kind):
    header_end = data.find(b"end_header\n") + 11 if kind.startswith("ply") else 84
    if rng.random() < 0.3:  # the header: the STL count, or a PLY header number
        if kind == "stl-binary" and len(data) >= 84:
            word = rng.choice(INTERESTING_WORDS + (len(data) // 50, (len(data) - 84) // 50 + 1))
            return data[:80] + struct.pack("<I", word) + data[84:]
        header = data[: max(0, header_end)]
        return mutate_number(rng, header, "ply-ascii", None) + data[max(0, header_end) :]
    if len(data) <= header_end + 4:
        return mutate_flip(rng, data, kind, None)
    at = rng.randrange(header_end, len(data) - 3)
    order = ">" if kind.endswith("be") else "<"
    return data[:at] + struct.pack(order + "I", rng.choice(INTERESTING_WORDS)) + data[at + 4 :]


def mutate_splice(rng, data, kind, pool):
    donor = rng.choice(pool).data if pool else data
    if donor[:2] == b"\x1f\x8b":
        donor = gzip.decompress(donor)
    if not donor:
        return data
    if _binary(kind):
        a, b = _chunk(rng, donor)
        piece = donor[a:b]
    else:
        matches = list(TOKEN_RUN.finditer(donor, rng.randrange(len(donor)), min(len(donor), 1 << 20)))[:1]
        piece = matches[0].group() if matches else donor[:64]
    at = rng.randrange(len(data) + 1)
    if not _binary(kind):  # at a white-space boundary, when there is one nearby
        space = data.find(b" ", at, at + 200)
        at = space if space >= 0 else at
    if rng.random() < 0.5:
        return data[:at] + b" " + piece + b" " + data[at:]
    return data[:at] + piece + data[at + len(piece) :]


def mutate_bracket(rng, data, kind, pool):
    """Delete or insert one bracket: a STEP entity without its ``)``, a VRML node without ``}``."""
    if _binary(kind) or not data:
        return mutate_flip(rng, data, kind, pool)
    spots = [m.start() for m in re.finditer(rb"[()\[\]{}]", data[: 1 << 20])]
    if not spots:
        return mutate_bytes(rng, data, kind, pool)
    at = rng.choice(spots)
    if rng.random() < 0.7:
        return data[:at] + data[at + 1 :]
    return data[:at] + bytes([data[at]]) * rng.choice((1, 1, 64, 4096)) + data[at:]


MUTATIONS = {
    "bracket": mutate_bracket,
    "flip": mutate_flip,
    "bytes": mutate_bytes,
    "truncate": mutate_truncate,
    "delete": mutate_delete,
    "duplicate": mutate_duplicate,
    "number": mutate_number,
    "splice": mutate_splice,
}
WEIGHTS = {"bracket": 1, "flip": 2, "bytes": 2, "truncate": 1, "delete": 2, "duplicate": 2, "number": 4, "splice": 2}


def make_case(seeds: list[Seed], base_seed: int, number: int) -> tuple[bytes, str, dict]:
    """The bytes, the file name ending and a description of case ``number``."""
    rng = random.Random(f"{base_seed}:{number}")
    seed = rng.choice(seeds)
    pool = [s for s in seeds if s.kind == seed.kind or (seed.kind.startswith("vrml") and s.kind.startswith("vrml"))]
    names = rng.choices(list(WEIGHTS), weights=list(WEIGHTS.values()), k=rng.choice((1, 1, 2, 3)))
    data = seed.data
    inner_kind = seed.kind
    gzipped = data[:2] == b"\x1f\x8b" and rng.random() < 2 / 3
    if gzipped:
        data = gzip.decompress(data)
        inner_kind = "vrml2" if data.startswith(b"#VRML V2") else "vrml1"
    for name in names:
        data = MUTATIONS[name](rng, data, inner_kind, pool)
    if gzipped:
        data = gzip.compress(data, compresslevel=1, mtime=0)
    suffix = seed.suffix
    if rng.random() < 0.05:
        names.append("rename")
        suffix = ".dat"
    return data, suffix, {"case": number, "seed": seed.name, "kind": seed.kind, "mutations": names}


# -- the worker -------------------------------------------------------------------------------


def _peak_kb() -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return -1


def _cpu_seconds() -> float:
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _reset_peak() -> None:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


#: A reason quoting an exception or a library's own text: a class name (``OverflowError``,
#: ``Transfer_TransferFailure``) or zlib's "Error -3 while decompressing": counted as wrapped.
RAW_REASON = re.compile(r"\b[A-Z]\w*(Error|Exception|Failure)\b|\b[A-Z][a-z]+[A-Za-z]*_[A-Z][a-z]\w*|\bError -?\d|Traceback")
#: Text a reason quotes from the file (a token, a node type): not the reason's own words.
QUOTED = re.compile(r"'[^']*'")

#: The time limit of OpenCASCADE's contained child (LoadLimits.max_seconds) in the cases: below
#: the case's own --timeout, so that a STEP/IGES file OpenCASCADE hangs on is refused as the
#: commands refuse it, not counted as a hang of the worker.
STEP_SECONDS = 20.0


def run_case(path: str, root: str, signature: bool) -> dict:
    """Load and clean one file; classify the end. Runs inside the worker."""
    import warnings

    import numpy as np

    from shapeidx.errors import UNFORESEEN, LoadError, printable
    from shapeidx.io import LoadLimits, load
    from shapeidx.signing.solid import make_solid

    result: dict = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            mesh = load(path, LoadLimits(root=Path(root), max_seconds=STEP_SECONDS))
            solid = make_solid(mesh, path)
            problem = _mesh_problem(np, solid)
            if signature and problem is None:
                from shapeidx.signing.pipeline import signature_of_solid

                signature_of_solid(solid)
            result = {"outcome": "exception", "error": f"bad mesh: {problem}"} if problem else {
                "outcome": "mesh",
                "triangles": int(len(solid.faces)),
            }
        except LoadError as exc:
            message = str(exc)
            reason = QUOTED.sub("''", message[len(printable(path)):])
            clean = ("\n" not in message and message.startswith(printable(path)) and "cannot read (" not in message
                     and UNFORESEEN not in message and not RAW_REASON.search(reason))
            result = {"outcome": "load_error" if clean else "wrapped", "error": message}
        except BaseException as exc:  # noqa: BLE001 - everything is a finding
            result = {"outcome": "exception", "error": f"{type(exc).__name__}: {exc}"[:300], "type": type(exc).__name__}
    result["warnings"] = [f"{w.category.__name__}: {w.message}"[:200] for w in caught]
    return result


def _mesh_problem(np, solid) -> str | None:
    v, f = solid.vertices, solid.faces
    if len(f) == 0:
        return "no faces"
    if not np.isfinite(v).all():
        return "non-finite vertices"
    if f.min() < 0 or f.max() >= len(v):
        return "face index out of range"
    area = solid.area
    if not (np.isfinite(area) and area > 0):
        return f"area {area}"
    return None


def _worker(conn, memory: int, signature: bool, stderr_path: str) -> None:
    import resource

    if memory:
        resource.setrlimit(resource.RLIMIT_DATA, (memory, memory))
    # stderr goes to a file the parent reads after each case: anything written there by
    # Python or by a native library is noise beside the one-line error
    fd = os.open(stderr_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.dup2(fd, 2)
    os.close(fd)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    import shapeidx.io  # noqa: F401 - imports outside the timed cases
    import shapeidx.signing.solid  # noqa: F401

    while True:
        job = conn.recv()
        if job is None:
            return
        path, root = job
        os.ftruncate(2, 0)
        os.lseek(2, 0, os.SEEK_SET)
        _reset_peak()
        started, cpu = time.monotonic(), _cpu_seconds()
        result = run_case(path, root, signature)
        result["seconds"] = round(time.monotonic() - started, 4)
        result["cpu_seconds"] = round(_cpu_seconds() - cpu, 4)  # what a busy machine does not inflate
        result["peak_kb"] = _peak_kb()
        sys.stderr.flush()
        conn.send(result)


class Worker:
    def __init__(self, context, memory: int, signature: bool, scratch: Path, number: int):
        self.stderr_path = str(scratch / f"worker-{number}.stderr")
        self.conn, child = context.Pipe()
        # not a daemon: a daemonic process may not have children, and STEP/IGES cases must be
        # read as every command reads them, in OpenCASCADE's contained child process
        self.process = context.Process(target=_worker, args=(child, memory, signature, self.stderr_path), daemon=False)
        self.process.start()
        child.close()
        self.job = None
        self.deadline = float("inf")

    def stderr(self) -> str:
        try:
            with open(self.stderr_path, "rb") as f:
                return f.read(2000).decode("utf-8", "replace")
        except OSError:
            return ""

    def kill(self) -> None:
        if self.process.is_alive():
            self.process.kill()
        self.process.join()
        self.conn.close()


def run_cases(jobs, workers: int, memory: int, timeout: float, signature: bool, scratch: Path):
    """Yield (job, result) for every job ``(info, path, root)``, ``workers`` at a time."""
    context = multiprocessing.get_context("spawn")
    counter = iter(range(1 << 30))
    idle = [Worker(context, memory, signature, scratch, next(counter)) for _ in range(workers)]
    busy: list[Worker] = []
    pending = iter(jobs)
    exhausted = False
    try:
        while True:
            while idle and not exhausted:
                job = next(pending, None)
                if job is None:
                    exhausted = True
                    break
                worker = idle.pop()
                worker.job, worker.deadline = job, time.monotonic() + timeout
                worker.conn.send((job[1], job[2]))
                busy.append(worker)
            if not busy:
                return
            now = time.monotonic()
            ready = wait([w.conn for w in busy] + [w.process.sentinel for w in busy], max(0.0, min(w.deadline for w in busy) - now))
            for worker in list(busy):
                result = None
                if worker.conn in ready:
                    try:
                        result = worker.conn.recv()
                        noise = worker.stderr().strip()
                        if noise:
                            result["stderr"] = noise[:500]
                    except (EOFError, OSError):
                        pass
                lost = False
                if result is None and (worker.conn in ready or worker.process.sentinel in ready):
                    worker.process.join(timeout=5)
                    code = worker.process.exitcode
                    name = signal.Signals(-code).name if code is not None and code < 0 else f"status {code}"
                    result = {"outcome": "crash", "error": f"worker died ({name})", "stderr": worker.stderr()[-500:]}
                    lost = True
                elif result is None and time.monotonic() >= worker.deadline:
                    result = {"outcome": "hang", "error": f"still running after {timeout:g} s"}
                    lost = True
                if result is None:
                    continue
                busy.remove(worker)
                job = worker.job
                if lost:
                    worker.kill()
                    worker = Worker(context, memory, signature, scratch, next(counter))
                idle.append(worker)
                yield job, result
    finally:
        for worker in idle + busy:
            try:
                if worker.job is None or worker not in busy:
                    worker.conn.send(None)
            except OSError:
                pass
            worker.process.join(timeout=1)
            worker.kill()


# -- the run ----------------------------------------------------------------------------------


def fuzz(seeds, cases: int, base_seed: int, workers: int, memory: int, timeout: float, signature: bool, keep: Path | None, progress=None):
    """Run ``cases`` cases; returns the list of (info, result)."""
    scratch = Path(tempfile.mkdtemp(prefix="shapeidx-fuzz-"))
    results = []
    try:
        def jobs():
            for number in range(cases):
                data, suffix, info = make_case(seeds, base_seed, number)
                case_dir = scratch / f"c{number % 64}"
                case_dir.mkdir(exist_ok=True)
                for old in case_dir.iterdir():
                    old.unlink()
                path = case_dir / f"case-{number}{suffix}"
                path.write_bytes(data)
                info["bytes"] = len(data)
                yield info, str(path), str(case_dir)

        for (info, path, _), result in run_cases(jobs(), workers, memory, timeout, signature, scratch):
            results.append((info, result))
            if keep is not None and (result["outcome"] not in CLEAN or result.get("warnings") or result.get("stderr")):
                keep.mkdir(parents=True, exist_ok=True)
                if os.path.exists(path):
                    shutil.copy(path, keep / Path(path).name)
                with open(keep / "cases.jsonl", "a") as f:
                    f.write(json.dumps({**info, **result}) + "\n")
            if progress is not None:
                progress(len(results))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return results


def replay(files: list[str], workers: int, memory: int, timeout: float, signature: bool):
    scratch = Path(tempfile.mkdtemp(prefix="shapeidx-fuzz-"))
    try:
        jobs = (({"case": f}, str(Path(f).resolve()), str(Path(f).resolve().parent)) for f in files)
        return list(run_cases(jobs, workers, memory, timeout, signature, scratch))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def summarise(results) -> dict:
    """Counts per outcome, per kind and per mutation; time and peak memory figures."""
    outcomes = Counter(r["outcome"] for _, r in results)
    by_kind: dict[str, Counter] = {}
    for info, r in results:
        by_kind.setdefault(info.get("kind", "?"), Counter())[r["outcome"]] += 1
    peaks = [r["peak_kb"] for _, r in results if r.get("peak_kb", -1) > 0]
    seconds = [r["seconds"] for _, r in results if "seconds" in r]
    cpu = [r["cpu_seconds"] for _, r in results if "cpu_seconds" in r]
    exception_types = Counter(r.get("type", r["outcome"]) for _, r in results if r["outcome"] in ("exception", "wrapped"))
    return {
        "cases": len(results),
        "outcomes": {k: outcomes.get(k, 0) for k in OUTCOMES},
        "noisy": sum(1 for _, r in results if r.get("warnings") or r.get("stderr")),
        "out_of_memory_errors": sum(1 for _, r in results if "out of memory" in r.get("error", "")),
        "exception_types": dict(exception_types),
        "by_kind": {k: dict(v) for k, v in sorted(by_kind.items())},
        "peak_mb": {
            "median": round(statistics.median(peaks) / 1024, 1) if peaks else None,
            "max": round(max(peaks) / 1024, 1) if peaks else None,
        },
        "seconds": {
            "median": round(statistics.median(seconds), 4) if seconds else None,
            "max": round(max(seconds), 2) if seconds else None,
            "total": round(sum(seconds), 1),
        },
        "cpu_seconds": {
            "median": round(statistics.median(cpu), 4) if cpu else None,
            "max": round(max(cpu), 2) if cpu else None,
        },
    }


def markdown(summary: dict, seeds: list[Seed], command: str, wall: float) -> str:
    lines = [
        f"Command: `{command}`",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"{wall:.0f} s wall time.",
        "",
        f"{summary['cases']:,} cases from {len(seeds)} seed files "
        f"({', '.join(f'{k} {sum(s.kind == k for s in seeds)}' for k in KINDS if any(s.kind == k for s in seeds))}).",
        "",
        "| outcome | cases |",
        "|---|---:|",
    ]
    lines += [f"| {k} | {v:,} |" for k, v in summary["outcomes"].items()]
    lines += [
        f"| noisy (anything else on stderr) | {summary['noisy']:,} |",
        "",
        "| kind | " + " | ".join(OUTCOMES) + " |",
        "|---|" + "---:|" * len(OUTCOMES),
    ]
    for kind, counts in summary["by_kind"].items():
        lines.append(f"| {kind} | " + " | ".join(f"{counts.get(k, 0):,}" for k in OUTCOMES) + " |")
    lines += [
        "",
        f"Peak memory per case (worker VmHWM): median {summary['peak_mb']['median']} MB, "
        f"max {summary['peak_mb']['max']} MB. Time per case: median {summary['seconds']['median']} s, "
        f"max {summary['seconds']['max']} s (CPU: median {summary['cpu_seconds']['median']} s, max "
        f"{summary['cpu_seconds']['max']} s). Load errors that were out of memory: {summary['out_of_memory_errors']}.",
    ]
    if summary["exception_types"]:
        lines += ["", "Uncaught: " + ", ".join(f"{k} {v}" for k, v in summary["exception_types"].items())]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--cases", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 1)))
    parser.add_argument("--memory", type=float, default=2.0, help="worker memory limit, GiB (RLIMIT_DATA); 0: none")
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds per case before it counts as a hang")
    parser.add_argument("--per-kind", type=int, default=12, help="seed files per kind")
    parser.add_argument("--max-seed-bytes", type=int, default=300_000)
    parser.add_argument("--signature", action="store_true", help="also compute the signature of every part")
    parser.add_argument("--keep", type=Path, help="save every case that is not clean here, with cases.jsonl")
    parser.add_argument("--results", type=Path, help="write every case's outcome as a line of JSON here")
    parser.add_argument("--json", type=Path, help="write the summary as JSON here")
    parser.add_argument("--markdown", type=Path, help="write the summary as Markdown here")
    parser.add_argument("--replay", nargs="+", help="run these files instead of generated cases")
    args = parser.parse_args(argv)
    memory = int(args.memory * (1 << 30))

    if args.replay:
        for (info, _, _), result in replay(args.replay, args.workers, memory, args.timeout, args.signature):
            print(json.dumps({**info, **result}))
        return 0

    seeds = find_seeds(args.data, args.per_kind, args.max_seed_bytes, random.Random(args.seed))
    print(f"{len(seeds)} seeds: " + ", ".join(f"{k} {sum(s.kind == k for s in seeds)}" for k in KINDS), file=sys.stderr)
    started = time.monotonic()

    def progress(done):
        if done % 500 == 0:
            print(f"  {done:,} cases, {time.monotonic() - started:.0f} s", file=sys.stderr)

    results = fuzz(seeds, args.cases, args.seed, args.workers, memory, args.timeout, args.signature, args.keep, progress)
    wall = time.monotonic() - started
    summary = summarise(results)
    command = "python scripts/fuzz.py " + " ".join(argv if argv is not None else sys.argv[1:])
    text = markdown(summary, seeds, command, wall)
    print(text)
    if args.results:
        with open(args.results, "w") as f:
            for info, result in results:
                f.write(json.dumps({**info, **result}) + "\n")
    if args.json:
        args.json.write_text(json.dumps({"command": command, "wall_seconds": round(wall, 1), **summary}, indent=2) + "\n")
    if args.markdown:
        args.markdown.write_text(text + "\n")
    return 0 if all(summary["outcomes"][k] == 0 for k in OUTCOMES if k not in CLEAN) else 1


if __name__ == "__main__":
    sys.exit(main())
