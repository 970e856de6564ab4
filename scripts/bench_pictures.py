#!/usr/bin/env python3
"""Benchmark of the pictures and the web page: thumbnails, result sheets, a ``serve`` query.

Usage::

    python scripts/bench_pictures.py --source kicad6.shapeidx [--size 100000] [--work DIR]

``--source`` is a store of the kicad6 folder built by ``shapeidx build`` (the sheet's hits
and the synthetic store's signatures come from it). Measured, in one run:

* **thumbnail**: a 256 px PNG (2 x 2 rays per pixel) of parts of 50k, 100k and 250k
  triangles: the largest kicad6 part (BGA-1295), the Altech AK300 terminal block split
  once into four times its triangles (midpoint subdivision: same shape, 108k triangles),
  and the 248k-triangle FreeCAD leg assembly of vrml-wild; reading the file is timed apart;
* **sheet of 10 hits**: ``query --id ... --sheet`` through :func:`query_sheet` with an empty
  thumbnail cache (cold: every picture rendered) and again (warm: every picture read);
* **serve query**: a real ``shapeidx serve`` process over a synthetic store of ``--size``
  entries made from the source's real signatures (``scripts/make_store.py``):
  its start (reading the store, calibrating the words), ``GET /api/query?id=...`` (k = 10)
  over HTTP, and ``POST /api/query`` uploading a real kicad6 part (its signature included).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shlex
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
import uuid
from pathlib import Path

import numpy as np

from shapeidx.pictures.render import render_rgba, png_bytes
from shapeidx.pictures.sheet import query_sheet
from shapeidx.signing.pipeline import solid_of_file
from shapeidx.store import open_store

REPO = Path(__file__).resolve().parents[1]


def load_script(name: str):
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def best_of(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - started)
    return min(times), out


def subdivided(solid):
    """Midpoint subdivision: every triangle into four, the shape unchanged."""
    v, f = solid.vertices, solid.faces
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    mids = len(v) + inverse.reshape(3, -1).T  # midpoints of edges 01, 12, 20
    vertices = np.concatenate([v, v[unique].mean(axis=1)])
    a, b, c = f.T
    m01, m12, m20 = mids.T
    faces = np.concatenate([np.stack(t, axis=1) for t in ((a, m01, m20), (m01, b, m12), (m20, m12, c), (m01, m12, m20))])
    return vertices, faces


def embree_scene(vertices, faces):
    """Only the scene construction a thumbnail starts with (embreex copies the arrays element by element)."""
    from embreex import mesh_construction, rtcore_scene

    from shapeidx.signing.occlusion import embree_device

    scene = rtcore_scene.EmbreeScene(embree_device())
    mesh_construction.TriangleMesh(scene, np.ascontiguousarray(vertices, dtype=np.float32), np.ascontiguousarray(faces, dtype=np.int32))
    return scene


def thumbnails(data: Path, repeats: int) -> None:
    kicad = data / "kicad6"
    parts = [
        ("BGA-1295 (kicad6)", kicad / "Package_BGA" / "BGA-1295_37.5x37.5mm_Layout36x36_P1.0mm.wrl", False),
        ("Altech AK300 x4 (kicad6, subdivided)", kicad / "TerminalBlock_Altech" / "Altech_AK300_1x19_P5.00mm_45-Degree.wrl", True),
        ("assieme_leg (vrml-wild)", data / "vrml-wild" / "freecad-kicad-tests" / "test-vrml" / "assieme_leg-fc.wrl", False),
    ]
    for label, path, split in parts:
        started = time.perf_counter()
        solid = solid_of_file(path)
        read = time.perf_counter() - started
        vertices, faces = subdivided(solid) if split else (solid.vertices, solid.faces)
        seconds, png = best_of(lambda: png_bytes(render_rgba(vertices, faces)), repeats)
        scene, _ = best_of(lambda: embree_scene(vertices, faces), repeats)
        print(f"thumbnail  {label:40s} {len(faces):>8,} triangles: {seconds:.3f} s (best of {repeats}), of which"
              f" {scene:.3f} s handing the triangles to Embree; reading the file {read:.2f} s; PNG {len(png) / 1000:.1f} kB")


def sheets(source: Path, work: Path) -> None:
    store = work / "sheet" / source.name
    store.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy2(source, store)  # a copy: its thumbnail folder starts empty
    shutil.rmtree(Path(str(store) + ".thumbs"), ignore_errors=True)
    entry = "Battery/BatteryHolder_Keystone_500.wrl"
    out = work / "sheet" / "sheet.html"
    for label in ("cold (no thumbnail, no calibration kept)", "warm", "warm"):
        started = time.perf_counter()
        hits = query_sheet(store, out, entry=entry, top=10)
        seconds = time.perf_counter() - started
        print(f"sheet      10 hits, {label}: {seconds:.3f} s ({len(hits)} hits, {out.stat().st_size / 1000:.0f} kB)")
    # the pictures alone: the 10 hits' thumbnails from an empty cache, then from the cache
    from shapeidx.pictures.thumbcache import StoreThumbnails

    shutil.rmtree(work / "sheet" / "pictures-only", ignore_errors=True)
    with open_store(store) as reader:
        for label in ("cold", "warm"):
            thumbs = StoreThumbnails(reader, folder=work / "sheet" / "pictures-only")
            started = time.perf_counter()
            for hit in hits:
                thumbs.png(hit["path"])
            print(f"sheet      the 10 hits' thumbnails alone, {label}: {time.perf_counter() - started:.3f} s"
                  f" ({thumbs.cache.rendered} rendered)")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def multipart(path: Path, fields: dict) -> tuple[bytes, str]:
    boundary = uuid.uuid4().hex
    parts = [f'--{boundary}\r\nContent-Disposition: form-data; name="{k}"\r\n\r\n{v}\r\n'.encode() for k, v in fields.items()]
    parts.append(f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="{path.name}"\r\n'
                 "Content-Type: application/octet-stream\r\n\r\n".encode() + path.read_bytes() + b"\r\n")
    return b"".join(parts) + f"--{boundary}--\r\n".encode(), f"multipart/form-data; boundary={boundary}"


def start_server(store: Path):
    """A real ``shapeidx serve`` process; (process, base URL, seconds until it answered)."""
    port = free_port()
    started = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "shapeidx.cli", "serve", "--store", str(store), "--port", str(port)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    base = f"http://127.0.0.1:{port}"
    while True:
        try:
            urllib.request.urlopen(base + "/api/store", timeout=5).read()
            return process, base, time.perf_counter() - started
        except OSError:
            if process.poll() is not None:
                raise SystemExit(f"serve failed: {process.stderr.read().decode()}")
            time.sleep(0.1)


def serve(source: Path, size: int, work: Path, data: Path, repeats: int) -> None:
    make_store = load_script("make_store")
    store = work / f"synthetic-{size}.shapeidx"
    if not store.exists():
        make_store.write_store(store, size, make_store.real_signatures(source))
    from shapeidx.search import Searcher

    with Searcher(store) as searcher:
        position = len(searcher) // 3
        entry = searcher.path_at(position)
        query = searcher.query_of_entry(entry)
        bare, _ = best_of(lambda: searcher.search(query, 10, "weighted"), repeats)
    print(f"serve      the search road in process (Searcher.search, k 10) on {size:,} entries: {bare:.3f} s")
    for old in (store / "thumbs").glob("calibration-*.npz"):
        old.unlink()  # the first start calibrates the words; the second finds them kept
    for start in ("first", "second"):
        process, base, ready = start_server(store)
        if start == "first":
            process.terminate()
            process.wait(timeout=30)
            print(f"serve      {size:,} entries: ready in {ready:.2f} s (reading the store, calibrating the words)")
    print(f"serve      {size:,} entries: ready in {ready:.2f} s (reading the store; the words' calibration kept)")
    try:
        url = f"{base}/api/query?" + urllib.parse.urlencode({"id": entry, "top": 10})
        seconds, body = best_of(lambda: urllib.request.urlopen(url, timeout=60).read(), repeats)
        hits = json.loads(body)["hits"]
        assert hits[0]["id"] == entry and hits[0]["distance"] == 0
        print(f"serve      GET /api/query?id=... (k 10) on {size:,} entries: {seconds:.3f} s (best of {repeats});"
              f" {seconds / bare:.2f} times the bare ranking")
        part = data / "kicad6" / "Battery" / "BatteryHolder_Keystone_500.wrl"
        body, content_type = multipart(part, {"top": 10, "metric": "weighted"})

        def upload():
            request = urllib.request.Request(base + "/api/query", data=body, headers={"Content-Type": content_type})
            return urllib.request.urlopen(request, timeout=120).read()

        first, _ = best_of(upload, 1)
        again, _ = best_of(upload, repeats)
        print(f"serve      POST /api/query (upload {part.name}, k 10) on {size:,} entries: first {first:.3f} s"
              f" (signature and picture), again {again:.3f} s (the upload is kept)")
    finally:
        process.terminate()
        process.wait(timeout=30)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--source", type=Path, required=True, help="a store of kicad6 (shapeidx build)")
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    parser.add_argument("--size", type=int, default=100_000, help="entries of the synthetic store for serve")
    parser.add_argument("--work", type=Path, help="where the stores go (default: a temporary folder)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    bench_query = load_script("bench_query")
    print(f"machine: {bench_query.machine()}")
    print(f"command: {shlex.join([sys.executable, *sys.argv])}")
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        thumbnails(args.data, args.repeats)
        sheets(args.source, work)
        serve(args.source, args.size, work, args.data, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
