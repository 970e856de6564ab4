"""What a local web server exposed to a browser needs besides its routes.

* :class:`HostOriginGuard` (ASGI middleware): headers of at most :data:`MAX_HEADER_BYTES`
  (431 beyond); the ``Host`` header must name the server
  (:func:`allowed_hosts`: localhost, 127.0.0.1, [::1] and the address it was bound to), so a
  page served by another site whose name is made to resolve to 127.0.0.1 (DNS rebinding)
  gets 400, never the store's paths; a request that carries an ``Origin`` must come from the
  page itself (same scheme, host and port: 403 otherwise), so a page on any site the user
  visits cannot POST uploads to the server; ``Sec-Fetch-Site`` other than ``same-origin``
  or ``none`` is refused on the API (an ``<img>`` on another site cannot load thumbnails).
* :class:`BodyTimeout` (ASGI middleware): a request body must keep coming (at most
  :data:`BODY_IDLE_TIMEOUT` seconds between two pieces) and be complete within
  :data:`BODY_TIMEOUT` seconds, or the request is answered 408 and the connection closed.
* :func:`header_timeout_protocol`: uvicorn's HTTP/1.1 protocol with a time limit on a
  request's head (request line and headers): a client that opens a connection and sends its
  headers a byte at a time (slowloris) is answered 408 and cut off after
  :data:`HEADER_TIMEOUT` seconds, as is a kept-alive connection whose next request does not
  come whole in that time. Its connections close lingering (:class:`LingeringClose`), so a
  client refused before it finished sending still reads why.
"""

from __future__ import annotations

import asyncio
import ipaddress
import socket

#: Seconds a client has to send a request's line and headers, from the connection's opening
#: (or the end of the previous response).
HEADER_TIMEOUT = 10.0
#: Longest pause in a request body, seconds.
BODY_IDLE_TIMEOUT = 10.0
#: Longest time to receive a whole request body, seconds (64 MB at 1 MB/s fits).
BODY_TIMEOUT = 120.0

#: Largest request head (the headers' names and values), bytes: 431 beyond (h11 limits only a
#: head that arrives in pieces).
MAX_HEADER_BYTES = 16 * 1024
#: Seconds a closing connection keeps reading (and dropping) what the client still sends.
LINGER_SECONDS = 2.0

LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
WILDCARDS = ("0.0.0.0", "::", "")


def _bare(host: str) -> str:
    """A host name as compared: lower case, without an IPv6 literal's brackets or a final dot."""
    host = host.strip().lower()
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    return host.rstrip(".")


def split_host_header(value: str) -> tuple[str, str | None] | None:
    """``Host`` (or an Origin's authority) as (host, port); None when it is not well formed."""
    value = value.strip()
    if not value or any(c in value for c in "/\\@ \t?#"):
        return None
    if value.startswith("["):
        end = value.find("]")
        if end < 0:
            return None
        host, rest = value[: end + 1], value[end + 1 :]
        if rest and not rest.startswith(":"):
            return None
        port = rest[1:] if rest else None
    elif value.count(":") == 1:
        host, port = value.split(":")
    elif ":" in value:
        return None  # a bare IPv6 literal is not a valid Host
    else:
        host, port = value, None
    if port is not None and not (port.isdigit() and len(port) <= 5):
        return None
    return _bare(host), port


def _is_ip_literal(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


class AllowedHosts:
    """The host names the server answers to.

    Always localhost, 127.0.0.1 and ::1, and the address it was bound to (``--host``). A
    server bound to every interface (0.0.0.0 or ::) also answers to any IP address (a name
    is what DNS rebinding needs; an address cannot be rebound) and to the machine's own
    names (``socket.gethostname()``, ``socket.getfqdn()``).
    """

    def __init__(self, bound: str = "127.0.0.1"):
        bound = _bare(bound or "")
        self.any_address = bound in WILDCARDS
        names = set(LOOPBACK_NAMES)
        if not self.any_address:
            names.add(bound)
        else:
            for name in (socket.gethostname(), socket.getfqdn()):
                if name:
                    names.add(_bare(name))
        self.names = frozenset(names)

    def __contains__(self, host: str) -> bool:
        host = _bare(host)
        return host in self.names or (self.any_address and _is_ip_literal(host))

    def __repr__(self) -> str:
        return f"AllowedHosts({sorted(self.names)}{', any IP address' if self.any_address else ''})"


def allowed_hosts(bound: str = "127.0.0.1") -> AllowedHosts:
    return AllowedHosts(bound)


async def _refuse(send, status: int, message: str) -> None:
    import json

    body = json.dumps({"error": message}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


def _header(scope, name: bytes) -> str | None:
    found = [value for key, value in scope.get("headers") or () if key.lower() == name]
    if len(found) != 1:
        return None if not found else "\x00several"
    return found[0].decode("latin-1")


class HostOriginGuard:
    """ASGI middleware: refuse requests not addressed to this server, or sent by another site."""

    def __init__(self, app, hosts: AllowedHosts):
        self.app = app
        self.hosts = hosts

    def problem(self, scope) -> tuple[int, str] | None:
        """(status, reason) for a request to refuse, or None."""
        size = sum(len(key) + len(value) + 4 for key, value in scope.get("headers") or ())
        if size > MAX_HEADER_BYTES:
            return 431, f"the request's headers are too large ({size:,} bytes; at most {MAX_HEADER_BYTES:,})"
        host = _header(scope, b"host")
        if host is None or host == "\x00several":
            return 400, "the request needs one Host header"
        parsed = split_host_header(host)
        if parsed is None or parsed[0] not in self.hosts:
            return 400, "unknown host: this server answers only to its own address (DNS rebinding refused)"
        origin = _header(scope, b"origin")
        if origin is not None:
            scheme = scope.get("scheme", "http")
            if origin == "\x00several" or origin.lower() != f"{scheme}://{host}".lower():
                return 403, "cross-origin request refused: only the server's own page may call it"
        site = _header(scope, b"sec-fetch-site")
        if site is not None and scope.get("path", "").startswith("/api/") and site.lower() not in ("same-origin", "none"):
            return 403, "cross-site request refused: only the server's own page may call the API"
        return None

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            problem = self.problem(scope)
            if problem is not None:
                return await _refuse(send, *problem)
        elif scope["type"] == "websocket":  # none are served; refuse before anything reads it
            return await send({"type": "websocket.close", "code": 1008})
        return await self.app(scope, receive, send)


class BodyTimedOut(Exception):
    """A request body stopped coming (or came too slowly)."""


class BodyTimeout:
    """ASGI middleware: a request body must keep coming and be whole within a time limit.

    ``receive`` raises :class:`BodyTimedOut` past the limit; the routes that read a body turn
    it into a 408 (and a route that does not catch it gets one from here).
    """

    def __init__(self, app, idle: float = BODY_IDLE_TIMEOUT, total: float = BODY_TIMEOUT):
        self.app = app
        self.idle = idle
        self.total = total

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.total
        state = {"body_done": scope.get("method") in ("GET", "HEAD", "OPTIONS", "DELETE"), "started": False}

        async def timed_receive():
            if state["body_done"]:
                return await receive()
            left = min(self.idle, deadline - loop.time())
            try:
                if left <= 0:
                    raise asyncio.TimeoutError
                message = await asyncio.wait_for(receive(), left)
            except asyncio.TimeoutError:
                raise BodyTimedOut(f"the request body did not arrive in time (at most {self.idle:g} s between two"
                                   f" pieces, {self.total:g} s in all)") from None
            if message.get("type") != "http.request" or not message.get("more_body", False):
                state["body_done"] = True
            return message

        async def watched_send(message):
            if message.get("type") == "http.response.start":
                state["started"] = True
            await send(message)

        try:
            await self.app(scope, timed_receive, watched_send)
        except BodyTimedOut as exc:
            if not state["started"]:
                await _refuse(send, 408, str(exc))


class LingeringClose:
    """A transport whose ``close`` lingers: the answer goes out, then the connection half-closes
    and drops what the client still sends for up to :data:`LINGER_SECONDS` before it closes.

    A socket closed with unread bytes in its receive buffer sends a reset, and a reset makes
    the client's kernel throw away the answer it has not read yet: a client refused in the
    middle of sending (headers too large, a malformed request) would see "connection reset"
    instead of the 400 or 431 that says why. Apache and nginx close lingering for this reason.
    """

    def __init__(self, transport, loop, linger: float = LINGER_SECONDS):
        self._transport = transport
        self._loop = loop
        self._linger = linger
        self.lingering = False

    def __getattr__(self, name):
        return getattr(self._transport, name)

    def is_closing(self) -> bool:
        return self.lingering or self._transport.is_closing()

    def close(self) -> None:
        transport = self._transport
        if self.lingering or transport.is_closing():
            return
        self.lingering = True
        if not transport.can_write_eof():
            return transport.close()
        transport.write_eof()  # after what is buffered: the client reads the whole answer, then the end
        transport.resume_reading()
        self._loop.call_later(self._linger, transport.close)

    def client_done(self) -> None:
        """The client has stopped sending too: close now."""
        self._transport.close()


def header_timeout_protocol(timeout: float = HEADER_TIMEOUT):
    """uvicorn's h11 HTTP/1.1 protocol class with a time limit on each request's head.

    The timer starts when the connection opens and again when a response ends; it stops when
    a request's headers have been read whole. When it fires, the client gets ``408 Request
    Timeout`` and the connection is closed. (The h11 protocol, not httptools: its events say
    when a request's head is complete.)
    """
    import h11
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class HeaderTimeoutH11Protocol(H11Protocol):
        header_timeout = timeout

        def connection_made(self, transport):
            super().connection_made(transport)
            self.transport = LingeringClose(transport, self.loop)
            self._head_timer = None
            self._timed_cycle = None
            self._arm_head_timer()

        def _arm_head_timer(self):
            self._stop_head_timer()
            self._head_timer = self.loop.call_later(self.header_timeout, self._head_timed_out)

        def _stop_head_timer(self):
            timer = getattr(self, "_head_timer", None)
            if timer is not None:
                timer.cancel()
                self._head_timer = None

        def _head_timed_out(self):
            self._head_timer = None
            if self.transport.is_closing():
                return
            if self.cycle is not None and self.cycle is self._timed_cycle and not self.cycle.response_complete:
                return  # a request is being answered (its own body has its own limit)
            body = b'{"error": "the request headers did not come in time"}'
            try:
                self.transport.write(b"HTTP/1.1 408 Request Timeout\r\ncontent-type: application/json\r\n"
                                     b"connection: close\r\ncontent-length: %d\r\n\r\n%s" % (len(body), body))
            finally:
                self.transport.close()

        def data_received(self, data):
            if self.transport.lingering:
                return  # the rest of a refused request: dropped unread
            super().data_received(data)

        def eof_received(self):
            if self.transport.lingering:
                self.transport.client_done()

        def handle_events(self):
            super().handle_events()
            if self.cycle is not None and self.cycle is not self._timed_cycle:
                self._timed_cycle = self.cycle  # a new request's head was read whole
                self._stop_head_timer()

        def on_response_complete(self):
            super().on_response_complete()
            if not self.transport.is_closing() and (self.cycle is None or self.cycle.response_complete):
                self._arm_head_timer()  # the next request's head, on a kept-alive connection

        def connection_lost(self, exc):
            self._stop_head_timer()
            super().connection_lost(exc)

    _ = h11  # the class relies on uvicorn's h11 protocol; importing h11 fails early when it is missing
    return HeaderTimeoutH11Protocol
