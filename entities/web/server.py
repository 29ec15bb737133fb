"""The web ground station's HTTP side (`ROUTES`; the API in docs/web-gcs.md): standard library only, no Zenoh.
Every error is a JSON ``{"error": "..."}`` with a 4xx/5xx status, never a crash. A `Backend` does the work (in
live mode it hands each command to the Zenoh main thread and waits for its answer: the HTTP threads never touch
the game state); the `Hub` keeps the latest state and feeds every SSE client, a reconnecting page at once.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import socket
import sys
import threading
from collections import Counter
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any, Protocol
from urllib.parse import urlsplit

from schema import RejectCounter, RemoteInputError, UsageError
from schema.errors import excerpt
from schema.tuning import KEEPALIVE, STREAMS_CLOSE_S

from .model import Rejected, parse_cell

MAX_BODY = 16 * 1024
STATIC = {  # the only files served: name -> content type
    "index.html": "text/html; charset=utf-8",
    "app.js": "text/javascript; charset=utf-8",
    "style.css": "text/css; charset=utf-8",
}
#: Seconds a connection may make no progress -- send nothing of its request, or read nothing of what it is sent
#: -- before it is closed: a browser sends a request at once and reads as it comes, so only an idle, half-sent
#: (slowloris) or dead peer waits that long; an event stream that the page reads lives on (it only writes).
IDLE_TIMEOUT = 20.0
#: Bytes written at a time, each within `IDLE_TIMEOUT` (a socket's timeout bounds a whole `sendall`): a page that
#: reads a few kB/s still gets a state of megabytes; one that reads nothing is dropped.
WRITE_PIECE = 64 * 1024
#: Connections served at once (a thread each); more are refused at once with a 503. A page holds at most 7 (its
#: event stream and a browser's 6 per host): this is 9 pages at once, more than a ground station has; and the
#: threads fit under a small memory limit (each reserves a stack, and maybe a malloc arena: some 20 MiB of
#: address space; half-sent requests by the hundred used to start a thread each, for ever, until none could start).
MAX_CONNECTIONS = 64
#: Connections served at once from one client address: four pages' worth (a page holds at most 7), half the places,
#: so that one host holding connections half-sent or unread (slowloris) leaves the other half to everyone else.
PER_CLIENT = 32
#: Our refusals that no page of ours causes (a client's bug, a probe, an attack): each counted and logged (bounded,
#: `RejectCounter`), as the base class's (`send_error`). A human's refused target (422) or a replay's 409 are
#: answers, not noise.
MALFORMED = frozenset({400, 403, 411, 413, 415})


class Backend(Protocol):
    mode: str

    def world(self) -> dict: ...

    def replay(self) -> dict: ...

    def command(self, action: str, args: dict) -> dict:
        """Carry out a command ("target" with drone and cell, or a control action); raise `Rejected`."""
        ...


def parse_address(text: str) -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` or ``[V6]:PORT`` -> (host, port); the host defaults to 127.0.0.1."""
    host, _, port = text.rpartition(":")  # (no colon: no host)
    host = host.strip("[]") or "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        raise UsageError(f"bad --web address {text!r}: expected [HOST:]PORT") from None
    if not 0 <= number <= 65535:
        raise UsageError(f"bad --web port {number}: expected 0..65535 (0: any free port)")
    return host, number


class _Stream:
    """What an event stream has still to send: the newest state it has not sent (a slot, not a queue: a page that
    falls behind skips to the newest, and one that reads nothing holds one state, not every state since) and
    whether the stream ends after it."""

    __slots__ = ("state", "end")

    def __init__(self, state: str | None, end: bool) -> None:
        self.state, self.end = state, end


class Hub:
    """The latest state (JSON text) and the SSE subscribers; thread-safe."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._subs: set[_Stream] = set()
        self._latest: str | None = None
        self._closed = False

    def publish(self, state: dict) -> None:
        data = json.dumps(state, separators=(",", ":"))
        with self._cond:
            self._latest = data
            for stream in self._subs:
                stream.state = data
            self._cond.notify_all()

    def latest(self) -> str | None:
        with self._cond:
            return self._latest

    def subscribe(self) -> _Stream:
        """A new stream, due the latest state at once (a page that connects or reconnects gets it all)."""
        with self._cond:
            stream = _Stream(self._latest, self._closed)
            self._subs.add(stream)
        return stream

    def next(self, stream: _Stream, timeout: float) -> tuple[str | None, bool]:
        """Wait up to `timeout` s for what `stream` is due: (the newest state or None, whether it ends after)."""
        with self._cond:
            self._cond.wait_for(lambda: stream.state is not None or stream.end, timeout)
            state, stream.state = stream.state, None
            return state, stream.end

    def unsubscribe(self, stream: _Stream) -> None:
        with self._cond:
            self._subs.discard(stream)
            self._cond.notify_all()

    @property
    def subscribers(self) -> int:
        with self._cond:
            return len(self._subs)

    def close(self, timeout: float = STREAMS_CLOSE_S) -> bool:
        """End every stream after the state it is due (the final state); wait until they are written."""
        with self._cond:
            self._closed = True
            for stream in self._subs:
                stream.end = True
            self._cond.notify_all()
            return self._cond.wait_for(lambda: not self._subs, timeout)


class _Handler(BaseHTTPRequestHandler):
    server_version = "dronesim-web"
    protocol_version = "HTTP/1.0"  # one request per connection: simple, and an SSE stream ends with it
    timeout = IDLE_TIMEOUT  # the socket's: for every read and every write (a piece) of the connection
    server: WebServer

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 (the base class's name)
        self.server.log.debug("%s %s", self.address_string(), format % args)

    def log_error(self, format: str, *args: object) -> None:  # noqa: A002
        """The base class's only use of it here (`send_error` is ours): a read or a write that timed out, after
        which it closes the connection."""
        self.server.refused(self.client_address[0], "timeout", format % args)

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """Every error as JSON, including those the base class raises (bad request line, 501...); a peer that
        has hung up meanwhile (a TLS hello, a port scan) is no error of ours."""
        self.request_version = "HTTP/1.0"  # a garbled request line leaves it at HTTP/0.9: no status line
        self.close_connection = True
        text = message or self.responses.get(code, ("error",))[0]
        self.server.refused(self.client_address[0], f"http-{code}", f"{getattr(self, 'requestline', '')!r}: {text}")
        try:
            self._json(code, {"error": text})
        except OSError:
            pass

    def _json(self, code: int, body: dict | str) -> None:
        self._send(code, (body if isinstance(body, str) else json.dumps(body)).encode(), "application/json")

    def _send(self, code: int, data: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        self._write(data)

    def _write(self, data: bytes) -> None:
        """`data` in pieces of `WRITE_PIECE`, each within the socket's timeout (`IDLE_TIMEOUT`)."""
        view = memoryview(data)
        for start in range(0, len(view), WRITE_PIECE):
            self.wfile.write(view[start:start + WRITE_PIECE])

    def _route(self) -> str:
        try:
            return urlsplit(self.path).path
        except ValueError:  # (an absolute URL with a broken host: http://[::1/...)
            raise Rejected(f"bad request target {self.path[:100]!r}", 400) from None

    def _check_host(self) -> None:
        """Refuse a Host that is not one of this server's (`WebServer.serves`): a web site whose name has come to
        resolve to this machine (DNS rebinding) would otherwise be the page's own origin, and pass `_body`'s check."""
        host = self.headers.get("Host")
        if host is not None and not self.server.serves(host):
            raise Rejected(f"Host {host[:100]!r} is not a name of this ground station: open the page by an IP "
                           f"address, localhost or this machine's name", 403)

    ROUTES = {  # path -> (method, handler)
        "/": ("GET", "_file"), **{f"/{name}": ("GET", "_file") for name in STATIC}, "/api/world": ("GET", "_world"),
        "/api/state": ("GET", "_state"), "/api/events": ("GET", "_events"), "/api/replay": ("GET", "_replay"),
        "/api/target": ("POST", "_target"), "/api/control": ("POST", "_control"),
    }

    def _dispatch(self) -> None:
        """Every method's handler (the base class calls ``do_<METHOD>``)."""
        method = self.command
        try:
            self._check_host()
            path = self._route()
            route = self.ROUTES.get(path)
            if route is None:
                raise Rejected(f"no such resource: {path}", 404)
            if route[0] != method:
                self.close_connection = True
                raise Rejected(f"{method} is not allowed on {path}: use {route[0]}", 405)
            getattr(self, route[1])()
        except Rejected as err:
            if err.status in MALFORMED:
                self.server.refused(self.client_address[0], f"http-{err.status}",
                                    f"{method} {self.path!r}: {err.text}")
            self._json(err.status, {"error": err.text})
        except (TimeoutError, ConnectionError):  # the peer is idle or gone: the connection is closed
            raise  # (the base class's `handle_one_request` counts a timeout, the server's `handle_error` the rest)
        except Exception:  # a bug: answer 500, keep serving
            self.server.log.exception("error serving %s %s", method, self.path)
            try:
                self._json(500, {"error": "internal error (see the ground station's log)"})
            except OSError:
                pass

    do_GET = do_POST = do_PUT = do_DELETE = do_PATCH = _dispatch

    def _file(self) -> None:
        name = self._route().lstrip("/") or "index.html"
        data = resources.files(__package__).joinpath("static", name).read_bytes()
        self._send(200, data, STATIC[name])

    def _world(self) -> None:
        self._json(200, self.server.backend.world())

    def _replay(self) -> None:
        self._json(200, self.server.backend.replay())

    def _live_only(self) -> None:
        if self.server.backend.mode != "live":
            raise Rejected("a replay has no live state: GET /api/replay", 404)

    def _state(self) -> None:
        self._live_only()
        latest = self.server.hub.latest()
        if latest is None:
            raise Rejected("no state yet: the ground station is still connecting", 503)
        self._json(200, latest)

    def _events(self) -> None:
        """The stream: the newest state at once and on every change, a keep-alive comment when nothing changes
        (so a vanished page is noticed), the end after the final state. A page that reads nothing for
        `IDLE_TIMEOUT` is dropped (EventSource reconnects by itself)."""
        self._live_only()
        hub = self.server.hub
        stream = hub.subscribe()  # (before the answer's head: a page that has read it is subscribed)
        try:
            self.send_response(200)
            self.send_header("Content-Type", "text/event-stream; charset=utf-8")
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Accel-Buffering", "no")
            self.end_headers()
            self._write(b"retry: 1000\n\n")
            while True:
                state, end = hub.next(stream, KEEPALIVE)
                if state is not None:
                    self._write(b"event: state\ndata: " + state.encode() + b"\n\n")
                if end:
                    self._write(b"event: end\ndata: {}\n\n")
                    return
                if state is None:
                    self._write(b": keepalive\n\n")
        finally:
            hub.unsubscribe(stream)

    def _body(self, fields: set[str], hint: str) -> dict:
        """The request's JSON object, of some of `fields` (`hint` says which to send)."""
        ctype = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if ctype != "application/json":
            raise Rejected("send JSON (Content-Type: application/json)", 415)
        if origin := self.headers.get("Origin"):
            try:
                netloc = urlsplit(origin).netloc
            except ValueError:  # (http://[::1)
                raise Rejected(f"bad Origin {origin[:100]!r}", 400) from None
            if netloc != self.headers.get("Host"):
                raise Rejected(f"cross-origin request from {origin[:100]} refused", 403)
        length = self.headers.get("Content-Length")
        if length is None:
            raise Rejected("a Content-Length is required", 411)
        try:
            if (n := int(length)) < 0:
                raise ValueError
        except ValueError:
            raise Rejected(f"bad Content-Length {length[:100]!r}", 400) from None
        if n > MAX_BODY:
            self.close_connection = True
            raise Rejected(f"body of {n} bytes is larger than {MAX_BODY}", 413)
        raw = self.rfile.read(n)
        try:
            body = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise Rejected(f"the body is not JSON: {exc}", 400) from None
        except (ValueError, RecursionError):  # (an integer of over 4300 digits; arrays or objects nested too deep)
            raise Rejected("the body is not JSON we read: a number of too many digits, or nested too deep", 400) \
                from None
        if not isinstance(body, dict):
            raise Rejected("the body must be a JSON object", 400)
        if unknown := set(body) - fields:
            raise Rejected(f"unknown fields {sorted(unknown)}: {hint}", 400)
        return body

    def _target(self) -> None:
        body = self._body({"drone", "cell"}, "send drone and cell")
        if "drone" not in body or "cell" not in body:
            raise Rejected('send {"drone": "D01", "cell": [x, y, z]}', 400)
        if not isinstance(body["drone"], str):
            raise Rejected(f"drone must be a string like D01, got {excerpt(repr(body['drone']))}", 400)
        cell = parse_cell(body["cell"])
        self._json(200, self.server.backend.command("target", {"drone": body["drone"], "cell": cell}))

    def _control(self) -> None:
        body = self._body({"action", "value"}, "send action (and value for pace)")
        action = body.get("action")
        if action not in ("pause", "resume", "step", "quit", "pace"):
            raise Rejected(f"unknown action {excerpt(repr(action))}: use pause, resume, step, pace or quit", 400)
        self._json(200, self.server.backend.command(action, {"value": body.get("value")}))


class WebServer(ThreadingHTTPServer):
    """Binds at construction (so a taken port fails before anything else starts); `start` serves."""

    daemon_threads = True
    block_on_close = False
    #: The listen backlog: a burst of connections (a page's requests, pages reloading at once, a script) waits in
    #: the kernel's queue until accepted, where socketserver's 5 dropped them (a burst of 200: 78 timed out); the
    #: kernel caps it at net.core.somaxconn.
    request_queue_size = 1024

    def __init__(self, address: tuple[str, int], backend: Backend, hub: Hub, logger: logging.Logger) -> None:
        self.backend, self.hub, self.log = backend, hub, logger
        self.rejects = RejectCounter(logger)  # refused requests and connections, by reason and client
        self._lock = threading.Lock()
        self._connections = 0  # being served, a thread each (`MAX_CONNECTIONS`)
        self._by_client: Counter[str] = Counter()  # of them, from each client address (`PER_CLIENT`)
        machine = socket.gethostname().lower()
        self._names = {"localhost", address[0].lower().rstrip("."), machine, machine.split(".")[0]} - {""}
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        try:
            super().__init__(address, _Handler)
        except OSError as exc:
            raise UsageError(f"cannot serve the web ground station on {address[0]}:{address[1]}: {exc}") from None
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host, port = self.server_address[:2]
        assert isinstance(host, str)  # bound to a host name or address, never bytes
        shown = {"0.0.0.0": "127.0.0.1", "::": "[::1]"}.get(host, f"[{host}]" if ":" in host else host)
        return f"http://{shown}:{port}/"

    def serves(self, host: str) -> bool:
        """Whether a request's Host header names this server: an IP address, localhost (or a name under it,
        which browsers keep to this machine), this machine's name or the name it is bound to -- never a name that
        a web site's DNS could point here (docs/web-gcs.md)."""
        try:
            name = (urlsplit(f"//{host}").hostname or "").rstrip(".")
            ipaddress.ip_address(name)
            return True
        except ValueError:  # (a bad Host, or a name)
            pass
        return name in self._names or name.endswith(".localhost")

    def refused(self, client: str, reason: str, text: str) -> None:
        """Count a refused request or connection; logged bounded (`RejectCounter`: a few a second per client)."""
        self.rejects.flush()  # (the summary of any window that is over)
        self.rejects.reject("HTTP", RemoteInputError(text, reason=reason), client)

    def process_request(self, request: Any, client_address: Any) -> None:
        """A thread for the connection; beyond `MAX_CONNECTIONS`, or `PER_CLIENT` from its address, a 503 at once
        and the connection closed."""
        client = client_address[0]
        with self._lock:
            if self._connections >= MAX_CONNECTIONS:
                busy = f"{MAX_CONNECTIONS} connections open"
            elif self._by_client[client] >= PER_CLIENT:
                busy = f"{PER_CLIENT} connections open from {client}"
            else:
                busy = ""
                self._connections += 1
                self._by_client[client] += 1
        if busy:
            self._refuse(request, client, busy)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:  # no thread started: its place is free again
            self._served(client)
            raise

    def finish_request(self, request: Any, client_address: Any) -> None:
        try:
            super().finish_request(request, client_address)
        finally:
            self._served(client_address[0])  # (before the socket is closed: a client that sees the end finds it free)

    def _served(self, client: str) -> None:
        with self._lock:
            self._connections -= 1
            self._by_client[client] -= 1
            if not self._by_client[client]:
                del self._by_client[client]

    def _refuse(self, request: socket.socket, client: str, busy: str) -> None:
        """Answer 503 without ever waiting (this thread accepts every connection): the socket's buffer is empty."""
        body = json.dumps({"error": f"busy: {busy} already; try again"}).encode()
        head = (f"HTTP/1.0 503 Service Unavailable\r\nContent-Type: application/json\r\nContent-Length: {len(body)}"
                f"\r\nRetry-After: 1\r\nConnection: close\r\n\r\n").encode()
        try:
            request.setblocking(False)
            request.send(head + body)
            request.recv(MAX_BODY)  # what came of the request: closing on unread bytes would reset, maybe unread
        except OSError:
            pass
        self.refused(client, "busy", f"{busy}: one more refused")
        self.shutdown_request(request)

    def handle_error(self, request: Any, client_address: Any) -> None:
        """An error out of a connection's thread: one that broke (the peer hung up) is routine, logged at debug;
        anything else is a bug, logged with its traceback (the base class printed it to stderr)."""
        exc = sys.exc_info()[1]
        if isinstance(exc, OSError):
            self.log.debug("connection from %s ended: %r", client_address, exc)
        else:
            self.log.exception("error serving %s", client_address)

    def start(self) -> None:
        self._thread = threading.Thread(target=self.serve_forever, name="web-gcs-http", daemon=True)
        self._thread.start()

    def stop(self, drain: float = STREAMS_CLOSE_S) -> None:
        """Let every SSE stream write what it has (the final state), then stop serving."""
        self.hub.close(drain)
        if self._thread is not None:
            self.shutdown()
            self._thread.join()
        self.server_close()
        self.rejects.flush(everything=True)
