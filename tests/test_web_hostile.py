"""shapeidx serve under hostile requests, over real HTTP (uvicorn on a socket) and raw sockets.

What a local server exposed to a browser must refuse: requests addressed to another host name
(DNS rebinding), uploads posted by another site's page (Origin), cross-site API loads,
headers sent a byte at a time (slowloris), bodies that stop coming or end before their
closing boundary, more uploads at once than the server reads; and a FIFO put in the indexed
tree must not block the threads that read files (it once stopped the whole server).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import threading
import time
import urllib.error
import urllib.request
from concurrent.futures import ThreadPoolExecutor

import pytest
from clitools import cli, shapeidx_command
from storetools import FAST_POINTS, small_kicad

uvicorn = pytest.importorskip("uvicorn", reason="the web extra is not installed (pip install -e '.[web]')")

from shapeidx.web.app import StoreService, create_app  # noqa: E402
from shapeidx.web.guard import AllowedHosts, header_timeout_protocol, split_host_header  # noqa: E402

HEADER_TIMEOUT = 1.5
BODY_IDLE = 1.5


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ThreadServer:
    """uvicorn serving an app on a free port of 127.0.0.1, in a thread of the test process."""

    def __init__(self, app, header_timeout=HEADER_TIMEOUT):
        self.port = free_port()
        config = uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="error", access_log=False,
                                http=header_timeout_protocol(header_timeout), lifespan="off")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            assert time.monotonic() < deadline, "uvicorn did not start"
            time.sleep(0.05)

    def stop(self):
        self.server.should_exit = True
        self.thread.join(timeout=10)


@pytest.fixture(scope="module")
def tree_and_store(data_dir, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("hostile-web")
    tree = small_kicad(data_dir, tmp, ("LED_SMD",))
    store = tmp / "s.shapeidx"
    result = cli("build", tree, "--store", store, "--points", FAST_POINTS)
    assert result.exit_code == 0, result.output
    return tree, store


@pytest.fixture(scope="module")
def served(tree_and_store):
    tree, store = tree_and_store
    service = StoreService(store)
    server = ThreadServer(create_app(service, 3 * 1024 * 1024, uploads_at_once=2, file_threads=2, file_wait=20,
                                     body_idle=BODY_IDLE, body_total=30))
    yield tree, store, server.port
    server.stop()
    service.close()


def request(port, path, method="GET", headers=None, body=None, timeout=20):
    """(status, headers, JSON or bytes) of one real HTTP request to 127.0.0.1:port."""
    req = urllib.request.Request(f"http://127.0.0.1:{port}{path}", data=body, method=method, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as response:
            status, got, data = response.status, response.headers, response.read()
    except urllib.error.HTTPError as exc:
        status, got, data = exc.code, exc.headers, exc.read()
    try:
        return status, got, json.loads(data)
    except ValueError:
        return status, got, data


def raw(port, data: bytes, wait=10.0) -> bytes:
    """Send ``data`` on a raw socket and read what comes back until the server closes (or ``wait``)."""
    with socket.create_connection(("127.0.0.1", port), timeout=wait) as s:
        s.sendall(data)
        chunks = []
        try:
            while chunk := s.recv(65536):
                chunks.append(chunk)
        except socket.timeout:
            pass
        return b"".join(chunks)


def multipart(filename: str, content: bytes, boundary="----shapeidxtest", close=True) -> tuple[bytes, str]:
    body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; filename=\"{filename}\"\r\n"
            "Content-Type: application/octet-stream\r\n\r\n").encode() + content + b"\r\n"
    if close:
        body += f"--{boundary}--\r\n".encode()
    return body, f"multipart/form-data; boundary={boundary}"


def a_part(tree):
    return sorted((tree / "LED_SMD").iterdir())[0]


class TestHostAndOrigin:
    @pytest.mark.parametrize("host", ["evil.example", "evil.example:8765", "127.0.0.1.evil.example", "localhost.evil.example",
                                      "127.0.0.1@evil.example", "", "[::1", "a b"])
    def test_a_foreign_host_is_refused_before_anything_is_read(self, served, host):
        _, _, port = served
        answer = raw(port, f"GET /api/store HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode())
        assert answer.split(b"\r\n", 1)[0].split(b" ")[1] in (b"400",), answer[:200]
        assert b"/parts" not in answer and b"s.shapeidx" not in answer  # no path of the store leaks

    @pytest.mark.parametrize("host", ["127.0.0.1", "localhost", "LOCALHOST.", "[::1]", "127.0.0.1:{port}", "localhost:{port}"])
    def test_the_servers_own_names_answer(self, served, host):
        _, store, port = served
        status, _, info = request(port, "/api/store", headers={"Host": host.format(port=port)})
        assert status == 200 and info["store"] == str(store.absolute())

    @pytest.mark.parametrize("size", [20_000, 100_000, 2_000_000])
    def test_oversized_headers_are_refused_and_the_client_reads_why(self, served, size):
        # The server stops reading at the limit; it must not reset the connection under a
        # client still sending (a reset throws the answer away), so the client reads the refusal.
        _, _, port = served
        for _ in range(5):
            answer = raw(port, b"GET /api/store HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * size + b"\r\nConnection: close\r\n\r\n")
            assert answer.split(b"\r\n", 1)[0].split(b" ")[1] in (b"431", b"400"), answer[:100]

    def test_static_redirect_does_not_echo_a_foreign_host(self, served):
        _, _, port = served
        answer = raw(port, b"GET /static HTTP/1.1\r\nHost: evil.example\r\nConnection: close\r\n\r\n")
        assert answer.startswith(b"HTTP/1.1 400") and b"evil.example" not in answer

    def test_another_sites_page_cannot_upload(self, served, monkeypatch):
        tree, _, port = served
        calls = []
        body, content_type = multipart("part.wrl", a_part(tree).read_bytes())
        for origin in ("http://evil.example", "null", f"http://127.0.0.1:{port + 1}", f"https://127.0.0.1:{port}"):
            status, _, answer = request(port, "/api/query", "POST", {"Content-Type": content_type, "Origin": origin}, body)
            assert status == 403 and "cross-origin" in answer["error"], (origin, answer)
            calls.append(status)
        # the page itself (same origin) uploads as before
        status, _, answer = request(port, "/api/query", "POST",
                                    {"Content-Type": content_type, "Origin": f"http://127.0.0.1:{port}"}, body)
        assert status == 200 and answer["hits"][0]["id"] == f"LED_SMD/{a_part(tree).name}"

    def test_cross_site_loads_of_the_api_are_refused(self, served):
        tree, _, port = served
        entry = f"LED_SMD/{a_part(tree).name}"
        path = "/api/thumbnail?id=" + urllib.request.quote(entry, safe="")
        assert request(port, path, headers={"Sec-Fetch-Site": "cross-site"})[0] == 403
        assert request(port, path, headers={"Sec-Fetch-Site": "same-site"})[0] == 403  # another port of localhost
        assert request(port, path, headers={"Sec-Fetch-Site": "same-origin"})[0] == 200
        assert request(port, "/", headers={"Sec-Fetch-Site": "cross-site"})[0] == 200  # a link to the page is fine

    def test_allowed_hosts_of_a_wildcard_bind(self):
        hosts = AllowedHosts("0.0.0.0")
        assert "192.168.1.20" in hosts and "[fe80::1]" in hosts and socket.gethostname().lower() in hosts
        assert "evil.example" not in hosts
        only = AllowedHosts("cad.example.org")
        assert "cad.example.org" in only and "localhost" in only and "192.168.1.20" not in only
        assert split_host_header("[::1]:80") == ("::1", "80") and split_host_header("::1") is None
        assert split_host_header("a:b") is None and split_host_header("x:123456") is None


class TestTimeouts:
    def test_slowloris_headers_are_cut_off_and_others_are_answered(self, served):
        _, _, port = served
        with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
            s.sendall(b"GET /api/store HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            start = time.monotonic()
            answer = b""
            closed = False
            while time.monotonic() - start < 3 * HEADER_TIMEOUT + 5:
                try:
                    s.sendall(b"X-Slow: a\r\n")  # a header line now and then, never the blank line
                except OSError:
                    closed = True
                    break
                # meanwhile the server answers others
                assert request(port, "/api/store", timeout=5)[0] == 200
                s.settimeout(0.4)
                try:
                    chunk = s.recv(4096)
                    answer += chunk
                    if not chunk:
                        closed = True
                        break
                except socket.timeout:
                    pass
                except ConnectionResetError:  # closed while a header line was on its way
                    closed = True
                    break
            elapsed = time.monotonic() - start
        assert closed or answer.startswith(b"HTTP/1.1 408"), answer
        assert answer == b"" or answer.startswith(b"HTTP/1.1 408")
        assert elapsed < 3 * HEADER_TIMEOUT + 5

    def test_a_kept_alive_connection_must_send_its_next_head_in_time(self, served):
        _, _, port = served
        with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
            s.sendall(b"GET /favicon.ico HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            first = s.recv(4096)
            assert first.startswith(b"HTTP/1.1 204")
            s.sendall(b"GET /api/store HTTP/1.1\r\n")  # and nothing more
            start = time.monotonic()
            rest = b""
            while chunk := s.recv(4096):
                rest += chunk
            assert time.monotonic() - start < HEADER_TIMEOUT + 5
        assert rest == b"" or rest.startswith(b"HTTP/1.1 408")

    def test_a_body_that_stops_coming_is_a_408(self, served):
        tree, _, port = served
        body, content_type = multipart("part.wrl", a_part(tree).read_bytes())
        head = (f"POST /api/query HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: {content_type}\r\n"
                f"Content-Length: {len(body)}\r\n\r\n").encode()
        start = time.monotonic()
        answer = raw(port, head + body[: len(body) // 2], wait=BODY_IDLE + 10)
        assert answer.startswith(b"HTTP/1.1 408"), answer[:300]
        assert b"did not arrive in time" in answer and time.monotonic() - start < BODY_IDLE + 8

    def test_an_unterminated_multipart_body_is_refused(self, served):
        tree, _, port = served
        content = a_part(tree).read_bytes()
        body, content_type = multipart("part.wrl", content[: len(content) // 2], close=False)
        status, _, answer = request(port, "/api/query", "POST", {"Content-Type": content_type}, body)
        assert status == 400 and "cut short" in answer["error"]
        # the same part whole is answered
        body, content_type = multipart("part.wrl", content)
        assert request(port, "/api/query", "POST", {"Content-Type": content_type}, body)[0] == 200


class TestBoundedWork:
    def test_uploads_at_once_are_capped(self, served):
        tree, _, port = served
        body, content_type = multipart("part.wrl", a_part(tree).read_bytes())
        head = (f"POST /api/query HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: {content_type}\r\n"
                f"Content-Length: {len(body)}\r\n\r\n").encode()
        holders = [socket.create_connection(("127.0.0.1", port), timeout=20) for _ in range(2)]
        try:
            for s in holders:  # two uploads in progress: their bodies keep coming, slowly
                s.sendall(head + body[:100])
            time.sleep(0.3)
            status, got, answer = request(port, "/api/query", "POST", {"Content-Type": content_type}, body)
            assert status == 503 and "uploads" in answer["error"] and got["Retry-After"]
            for s in holders:
                s.sendall(body[100:])
            for s in holders:
                assert s.recv(64).startswith(b"HTTP/1.1 200")
        finally:
            for s in holders:
                s.close()
        assert request(port, "/api/query", "POST", {"Content-Type": content_type}, body)[0] == 200

    def test_a_fifo_in_the_tree_never_blocks_the_server(self, served, tmp_path):
        tree, _, port = served
        victim = sorted((tree / "LED_SMD").iterdir())[-1]
        entry = f"LED_SMD/{victim.name}"
        saved = tmp_path / victim.name
        os.replace(victim, saved)
        os.mkfifo(victim)  # no writer: opening it for reading blocks forever
        try:
            path = "/api/thumbnail?id=" + urllib.request.quote(entry, safe="")
            start = time.monotonic()
            with ThreadPoolExecutor(45) as pool:
                answers = list(pool.map(lambda _: request(port, path, timeout=30), range(45)))
            assert all(status == 404 and "FIFO" in answer["error"] for status, _, answer in answers), answers[:2]
            assert time.monotonic() - start < 30
            assert request(port, "/api/store", timeout=5)[0] == 200
            other = "/api/thumbnail?id=" + urllib.request.quote(f"LED_SMD/{a_part(tree).name}", safe="")
            assert request(port, other, timeout=30)[0] == 200
        finally:
            os.unlink(victim)
            os.replace(saved, victim)


def test_the_serve_command_checks_hosts_and_cuts_off_slow_headers(tree_and_store, tmp_path):
    """The real ``shapeidx serve`` process: its Host check and its 10 s header limit."""
    _, store = tree_and_store
    port = free_port()
    with open(tmp_path / "serve.log", "w") as log:
        process = subprocess.Popen(shapeidx_command("serve", "--store", store, "--port", port), stdout=log,
                                   stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 60
            while True:
                try:
                    urllib.request.urlopen(f"http://127.0.0.1:{port}/api/store", timeout=2).read()
                    break
                except OSError:
                    assert process.poll() is None and time.monotonic() < deadline, (tmp_path / "serve.log").read_text()
                    time.sleep(0.2)
            assert request(port, "/api/store", headers={"Host": "rebound.example"})[0] == 400
            start = time.monotonic()
            answer = raw(port, b"GET /api/store HTTP/1.1\r\nHost: 127.0.0.1\r\n", wait=30)
            assert answer.startswith(b"HTTP/1.1 408") and 8 < time.monotonic() - start < 25
        finally:
            process.terminate()
            process.wait(timeout=20)
