#!/usr/bin/env python3
"""Hostile requests against a real ``shapeidx serve``: tried / held / fell short.

Usage::

    python scripts/web_probes.py TREE --work DIR [--json out.json]

Copies TREE (a few dozen part files are enough) to DIR, builds a store of it, starts
``shapeidx serve`` on a free port of 127.0.0.1 and sends each probe: ids that are paths
(traversal, absolute, NUL, 100 kB), foreign Host headers (DNS rebinding), other sites'
Origins and cross-site fetches, slow headers and bodies, malformed, unterminated,
oversized and lying uploads, broken part files of every format and a gzip bomb, names
with markup and line breaks, bad parameters and methods, static path traversal, WebSocket
upgrades, pipelining, more uploads at once than allowed, and a FIFO put in an entry's place
(45 thumbnail requests at once). A probe **held** when the answer is the expected one
(status and, where it matters, body and timing), no answer is a 500 or leaks a path of the
store, and the server still answers ``/api/store`` right after. Prints a line per probe and
the totals.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.parse
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path


def shapeidx(*args) -> list[str]:
    return [sys.executable, "-m", "shapeidx.cli", *map(str, args)]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    def __init__(self, store: Path, work: Path):
        self.port = free_port()
        self.log = open(work / "serve.log", "w")
        self.proc = subprocess.Popen(shapeidx("serve", "--store", store, "--port", self.port, "--max-upload", "2"),
                                     stdout=self.log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 120
        while True:
            try:
                if http(self.port, "GET", "/api/store")[0] == 200:
                    break
            except OSError:
                pass
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"shapeidx serve did not start: {(work / 'serve.log').read_text()}")
            time.sleep(0.3)

    def stop(self):
        self.proc.terminate()
        self.proc.wait(timeout=30)
        self.log.close()


def raw(port: int, data: bytes, wait: float = 15.0, pause_after: float = 0.0) -> tuple[bytes, float]:
    """Send bytes, read until the server closes (or ``wait``); (answer, seconds)."""
    started = time.monotonic()
    with socket.create_connection(("127.0.0.1", port), timeout=wait) as s:
        s.sendall(data)
        chunks = []
        try:
            while chunk := s.recv(65536):
                chunks.append(chunk)
        except (socket.timeout, ConnectionResetError):
            pass
    return b"".join(chunks), time.monotonic() - started


def status_of(answer: bytes) -> int | None:
    try:
        return int(answer.split(b" ", 2)[1])
    except (IndexError, ValueError):
        return None


def http(port: int, method: str, path: str, headers: dict | None = None, body: bytes = b"", wait: float = 30.0):
    head = {"Host": f"127.0.0.1:{port}", "Connection": "close", **(headers or {})}
    if body or method == "POST":
        head.setdefault("Content-Length", str(len(body)))
    request = f"{method} {path} HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in head.items() if v is not None) + "\r\n"
    answer, seconds = raw(port, request.encode("latin-1") + body, wait)
    return status_of(answer), answer, seconds


def multipart(name: str, content: bytes, boundary: str = "probe", fields: dict | None = None, close: bool = True):
    parts = [f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; filename=\"{name}\"\r\n"
             "Content-Type: application/octet-stream\r\n\r\n".encode("utf-8") + content + b"\r\n"]
    for key, value in (fields or {}).items():
        parts.append(f"--{boundary}\r\nContent-Disposition: form-data; name=\"{key}\"\r\n\r\n{value}\r\n".encode())
    body = b"".join(parts) + (f"--{boundary}--\r\n".encode() if close else b"")
    return body, {"Content-Type": f"multipart/form-data; boundary={boundary}"}


# ----------------------------------------------------------------------------- the probes


def probes(port: int, tree: Path, store: Path, entry: str, part: bytes) -> list:
    """(name, callable returning (held, detail))."""
    out = []
    q = lambda text: urllib.parse.quote(text, safe="")  # noqa: E731

    def expect(method, path, statuses, headers=None, body=b"", leak=True, within=30.0):
        def probe():
            status, answer, seconds = http(port, method, path, headers, body)
            held = status in statuses and seconds < within and (not leak or str(store) not in answer.decode("latin-1"))
            return held, f"{status} in {seconds:.1f} s"
        return probe

    bad_ids = ["../../../../etc/passwd", "/etc/passwd", f"{entry}/../../../etc/passwd", "..%2f..%2fetc%2fpasswd",
               "nul\x00l", "A" * 100_000, "..\\..\\windows\\win.ini", f"./{entry}", f"{entry}\x00.png",
               "\u202e" + entry, str(tree / entry), "s.shapeidx/main.h5", "~/.ssh/id_rsa", "%00", ""]
    for api in ("thumbnail", "entry", "query"):
        for bad in bad_ids:
            out.append((f"{api}: id {bad[:30]!r}", expect("GET", f"/api/{api}?id={q(bad)}", {400, 404, 414})))
    out.append(("compare: traversal in b", expect("GET", f"/api/compare?a={q(entry)}&b={q('../../etc/passwd')}", {404})))

    for host in ("evil.example", "evil.example:80", "127.0.0.1.evil.example", "localhost.evil.example", "127.0.0.1@evil.example",
                 "[::1", "", "127.0.0.1 evil", "0x7f000001", "127.1"):
        out.append((f"Host {host!r}", expect("GET", "/api/store", {400}, {"Host": host})))
    out.append(("two Host headers", lambda: _two_hosts(port)))
    out.append(("HTTP/1.0 without Host", lambda: _http10(port)))
    out.append(("/static with a foreign Host", lambda: (lambda r: (r[0] == 400 and b"evil" not in r[1], f"{r[0]}"))(
        http(port, "GET", "/static", {"Host": "evil.example"}))))
    body, head = multipart("part.wrl", part)
    for origin in ("http://evil.example", "null", f"http://127.0.0.1:{port + 1}", f"https://127.0.0.1:{port}",
                   f"http://localhost:{port}"):
        out.append((f"upload from Origin {origin}", expect("POST", "/api/query", {403}, {**head, "Origin": origin}, body)))
    out.append(("upload from the page itself", expect("POST", "/api/query", {200}, {**head, "Origin": f"http://127.0.0.1:{port}"}, body)))
    for site in ("cross-site", "same-site"):
        out.append((f"thumbnail with Sec-Fetch-Site {site}", expect("GET", f"/api/thumbnail?id={q(entry)}", {403},
                                                                    {"Sec-Fetch-Site": site})))

    out.append(("slowloris: headers never end", lambda: _slow_head(port)))
    out.append(("50 slowloris connections while others query", lambda: _many_slow(port)))
    out.append(("body stops half-way", lambda: _stalled_body(port, body, head)))
    out.append(("multipart without its closing boundary", expect("POST", "/api/query", {400}, head, multipart("p.wrl", part, close=False)[0])))
    out.append(("no Content-Length (chunked)", expect("POST", "/api/query", {411, 400},
                                                      {**head, "Transfer-Encoding": "chunked", "Content-Length": None},
                                                      b"5\r\nhello\r\n0\r\n\r\n")))
    out.append(("Content-Length over the limit", expect("POST", "/api/query", {413}, {**head, "Content-Length": str(3 << 20)})))
    out.append(("Content-Length larger than the body, then close", lambda: _short_body(port, head)))
    out.append(("two files", expect("POST", "/api/query", {400}, head, _two_files(part))))
    out.append(("1,000 fields", expect("POST", "/api/query", {400}, head,
                                       multipart("p.wrl", part, fields={f"f{i}": "x" for i in range(1000)})[0])))
    out.append(("text/plain body", expect("POST", "/api/query", {415}, {"Content-Type": "text/plain"}, b"x" * 100)))
    out.append(("multipart without a boundary", expect("POST", "/api/query", {400}, {"Content-Type": "multipart/form-data"}, body)))
    out.append(("a 100 kB header", expect("GET", "/api/store", {400, 431}, {"X-Big": "a" * 100_000})))
    out.append(("empty upload", expect("POST", "/api/query", {422}, head, multipart("p.stl", b"")[0])))
    for name, content in (("bad.stl", b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0\nendsolid\n"),
                          ("bad.obj", b"v 1 2\nf 1 2 3\n"), ("bad.off", b"OFF\n3 1 0\n0 0 0\n"),
                          ("bad.ply", b"ply\nformat ascii 1.0\nelement vertex 99999999999999999999\nend_header\n"),
                          ("bad.wrl", b"#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0"),
                          ("bad.step", b"ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\n#1=CARTESIAN_POINT('',(0.,0.,0.));\n"),
                          ("bad.iges", b"x" * 80 + b"\n"), ("bomb.wrl.gz", gzip.compress(b" " * (300 << 20))[: 2 << 20]),
                          ("noise.bin", os.urandom(4096)), ("part.wrl.gz", gzip.compress(b"\x00" * 1000))):
        out.append((f"broken upload {name}", expect("POST", "/api/query", {422}, head, multipart(name, content)[0], within=60)))
    for name in ("<img src=x onerror=alert(1)>.wrl", "a\r\nSet-Cookie: x=1.wrl", "../../../../tmp/evil.wrl", "\u202egpj.wrl"):
        out.append((f"upload named {name[:24]!r}", lambda name=name: _named_upload(port, name, part)))
    out.append(("three uploads at once (2 allowed)", lambda: _three_uploads(port, part)))
    for params in ("top=0", "top=-1", "top=1000000000", "top=abc", "metric=nope", "metric=%3Cscript%3E",
                   "&".join(f"where=material%3Dx{i}" for i in range(21)), "where=nokey%3D1", "where=%3D%3D%3D"):
        out.append((f"query with {params[:30]}", expect("GET", f"/api/query?id={q(entry)}&{params}", {400})))
    out.append(("entries limit 10^6", expect("GET", "/api/entries?limit=1000000", {400})))
    for method in ("PUT", "DELETE", "PATCH", "TRACE"):
        out.append((f"{method} /api/query", expect(method, "/api/query", {404, 405})))
    for path in ("/static/../app.py", "/static/%2e%2e/%2e%2e/%2e%2e/etc/passwd", "/static/..%2fapp.py", "/%2e%2e/etc/passwd",
                 "/static//etc/passwd"):
        out.append((f"GET {path}", lambda path=path: (lambda r: (r[0] in (400, 404) and b"root:" not in r[1], f"{r[0]}"))(
            http(port, "GET", path))))
    # no WebSocket is served: the upgrade is never granted (101); the page may come back as to a plain GET
    out.append(("WebSocket upgrade", expect("GET", "/", {200, 400, 403, 404, 426}, {"Upgrade": "websocket", "Connection": "Upgrade",
                                                                                     "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
                                                                                     "Sec-WebSocket-Version": "13"})))
    out.append(("WebSocket upgrade from another site", expect("GET", "/", {403}, {"Upgrade": "websocket", "Connection": "Upgrade",
                                                                                   "Origin": "http://evil.example",
                                                                                   "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
                                                                                   "Sec-WebSocket-Version": "13"})))
    out.append(("100 pipelined requests", lambda: _pipelined(port)))
    return out


def _two_hosts(port):
    answer, _ = raw(port, f"GET /api/store HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nHost: evil.example\r\nConnection: close\r\n\r\n".encode())
    return status_of(answer) == 400, f"{status_of(answer)}"


def _http10(port):
    answer, _ = raw(port, b"GET /api/store HTTP/1.0\r\n\r\n")
    return status_of(answer) == 400, f"{status_of(answer)}"


def _slow_head(port):
    started = time.monotonic()
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        s.sendall(b"GET /api/store HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        answer = b""
        try:
            while time.monotonic() - started < 25:
                s.sendall(b"X-a: b\r\n")
                s.settimeout(1.0)
                try:
                    chunk = s.recv(4096)
                    if not chunk:
                        break
                    answer += chunk
                except socket.timeout:
                    continue
        except OSError:
            pass
    seconds = time.monotonic() - started
    return seconds < 15 and (answer == b"" or status_of(answer) == 408), f"cut off after {seconds:.1f} s ({status_of(answer)})"


def _many_slow(port):
    sockets = []
    try:
        for _ in range(50):
            s = socket.create_connection(("127.0.0.1", port), timeout=30)
            s.sendall(b"GET /api/store HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            sockets.append(s)
        answered = sum(http(port, "GET", "/api/store", wait=10)[0] == 200 for _ in range(5))
    finally:
        for s in sockets:
            s.close()
    return answered == 5, f"{answered} of 5 answered meanwhile"


def _stalled_body(port, body, head):
    request = (f"POST /api/query HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: {head['Content-Type']}\r\n"
               f"Content-Length: {len(body)}\r\n\r\n").encode() + body[: len(body) // 2]
    answer, seconds = raw(port, request, wait=40)
    return status_of(answer) == 408 and seconds < 20, f"{status_of(answer)} after {seconds:.1f} s"


def _short_body(port, head):
    with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
        s.sendall((f"POST /api/query HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: {head['Content-Type']}\r\n"
                   "Content-Length: 100000\r\n\r\n").encode() + b"--probe\r\n")
        s.shutdown(socket.SHUT_WR)
        try:
            answer = s.recv(4096)
        except (socket.timeout, ConnectionResetError):
            answer = b""
    alive = http(port, "GET", "/api/store")[0] == 200
    return alive and status_of(answer) in (None, 400, 408), f"{status_of(answer)}"


def _two_files(part):
    one, _ = multipart("a.wrl", part, close=False)
    two, _ = multipart("b.wrl", part)
    return one + two


def _named_upload(port, name, part):
    body, head = multipart(name, part)
    status, answer, _ = http(port, "POST", "/api/query", head, body)
    headers = answer.split(b"\r\n\r\n", 1)[0].lower()
    return (status == 200 and b"set-cookie" not in headers and b"content-type: application/json" in headers
            and b"nosniff" in headers), f"{status}"


def _three_uploads(port, part):
    body, head = multipart("part.wrl", part)
    head_bytes = (f"POST /api/query HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: {head['Content-Type']}\r\n"
                  f"Content-Length: {len(body)}\r\n\r\n").encode()
    holders = [socket.create_connection(("127.0.0.1", port), timeout=30) for _ in range(2)]
    try:
        for s in holders:
            s.sendall(head_bytes + body[:50])
        time.sleep(0.5)
        status = http(port, "POST", "/api/query", head, body)[0]
        for s in holders:
            s.sendall(body[50:])
        finished = [status_of(s.recv(64)) for s in holders]
    finally:
        for s in holders:
            s.close()
    return status == 503 and finished == [200, 200], f"third {status}, the two {finished}"


def _pipelined(port):
    one = b"GET /favicon.ico HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    answer, _ = raw(port, one * 99 + b"GET /favicon.ico HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n", wait=30)
    count = answer.count(b"HTTP/1.1 204")
    return count == 100, f"{count} answers"


def _fifo_probe(port, tree: Path, entry: str):
    victim = tree / entry
    saved = victim.with_name(victim.name + ".saved")
    os.replace(victim, saved)
    os.mkfifo(victim)
    try:
        started = time.monotonic()
        path = f"/api/thumbnail?id={urllib.parse.quote(entry, safe='')}"
        with ThreadPoolExecutor(45) as pool:
            statuses = list(pool.map(lambda _: http(port, "GET", path, wait=60)[0], range(45)))
        seconds = time.monotonic() - started
        alive = http(port, "GET", "/api/store", wait=10)[0] == 200
    finally:
        os.unlink(victim)
        os.replace(saved, victim)
    return all(s == 404 for s in statuses) and alive, f"{statuses.count(404)} x 404 in {seconds:.1f} s, alive {alive}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("tree", type=Path)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    work = args.work.resolve()
    shutil.rmtree(work, ignore_errors=True)
    tree = work / "tree"
    shutil.copytree(args.tree, tree)
    store = work / "s.shapeidx"
    done = subprocess.run(shapeidx("build", tree, "--store", store, "--points", "128", "--workers", "1", "-q"),
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    files = sorted(p for p in tree.rglob("*.wrl"))
    entry = str(files[0].relative_to(tree))
    fifo_entry = str(files[-1].relative_to(tree))
    part = files[1].read_bytes()
    server = Server(store, work)
    report = []
    try:
        all_probes = probes(server.port, tree, store, entry, part)
        all_probes.append(("45 thumbnail requests for a FIFO", lambda: _fifo_probe(server.port, tree, fifo_entry)))
        for name, probe in all_probes:
            try:
                held, detail = probe()
            except Exception as exc:  # the probe itself broke: count it as not held, say why
                held, detail = False, f"probe error {type(exc).__name__}: {exc}"
            try:
                alive = http(server.port, "GET", "/api/store", wait=15)[0] == 200
            except OSError:
                alive = False
            held = held and alive and server.proc.poll() is None
            report.append({"probe": name, "held": held, "detail": detail + ("" if alive else "; SERVER DOWN")})
            print(f"{'held' if held else 'FELL SHORT':10s} {name[:60]:60s} {detail}", flush=True)
            if server.proc.poll() is not None:
                break
    finally:
        server.stop()
    held = sum(r["held"] for r in report)
    print(f"tried {len(report)}, held {held}, fell short {len(report) - held}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    return 0 if held == len(report) else 1


if __name__ == "__main__":
    sys.exit(main())
