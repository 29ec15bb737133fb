"""The web ground station's HTTP side (`ROUTES`; the API in docs/web-gcs.md): standard library only, no Zenoh.
Every error is a JSON ``{"error": "..."}`` with a 4xx/5xx status, never a crash. A `Backend` does the work (in
live mode it hands each command to the Zenoh main thread and waits for its answer: the HTTP threads never touch
the game state); the `Hub` keeps the latest state and feeds every SSE client, a reconnecting page at once.
"""

from __future__ import annotations

import json
import logging
import queue
import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Protocol
from urllib.parse import urlsplit

from schema import UsageError
from schema.tuning import KEEPALIVE, STREAMS_CLOSE_S

from .model import Rejected, parse_cell

MAX_BODY = 16 * 1024
STATIC = {  # the only files served: name -> content type
    "index.html": "text/html; charset=utf-8",
    "app.js": "text/javascript; charset=utf-8",
    "style.css": "text/css; charset=utf-8",
}
_END = object()


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


class Hub:
    """The latest state (JSON text) and the SSE subscribers; thread-safe."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._subs: set[queue.SimpleQueue] = set()
        self._latest: str | None = None
        self._closed = False

    def publish(self, state: dict) -> None:
        data = json.dumps(state, separators=(",", ":"))
        with self._cond:
            self._latest = data
            for q in self._subs:
                q.put(data)

    def latest(self) -> str | None:
        with self._cond:
            return self._latest

    def subscribe(self) -> queue.SimpleQueue:
        q: queue.SimpleQueue = queue.SimpleQueue()
        with self._cond:
            if self._latest is not None:
                q.put(self._latest)
            if self._closed:
                q.put(_END)
            self._subs.add(q)
        return q

    def unsubscribe(self, q: queue.SimpleQueue) -> None:
        with self._cond:
            self._subs.discard(q)
            self._cond.notify_all()

    @property
    def subscribers(self) -> int:
        with self._cond:
            return len(self._subs)

    def close(self, timeout: float = STREAMS_CLOSE_S) -> bool:
        """End every stream after what it has queued (the final state); wait until they are written."""
        with self._cond:
            self._closed = True
            for q in self._subs:
                q.put(_END)
            return self._cond.wait_for(lambda: not self._subs, timeout)


class _Handler(BaseHTTPRequestHandler):
    server_version = "dronesim-web"
    protocol_version = "HTTP/1.0"  # one request per connection: simple, and an SSE stream ends with it
    server: WebServer

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 (the base class's name)
        self.server.log.debug("%s %s", self.address_string(), format % args)

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """Every error as JSON, including those the base class raises (bad request line, 501...)."""
        self.request_version = "HTTP/1.0"  # a garbled request line leaves it at HTTP/0.9: no status line
        self.close_connection = True
        self._json(code, {"error": message or self.responses.get(code, ("error",))[0]})

    def _json(self, code: int, body: dict | str) -> None:
        self._send(code, (body if isinstance(body, str) else json.dumps(body)).encode(), "application/json")

    def _send(self, code: int, data: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        self.wfile.write(data)

    def _route(self) -> str:
        return urlsplit(self.path).path

    ROUTES = {  # path -> (method, handler)
        "/": ("GET", "_file"), **{f"/{name}": ("GET", "_file") for name in STATIC}, "/api/world": ("GET", "_world"),
        "/api/state": ("GET", "_state"), "/api/events": ("GET", "_events"), "/api/replay": ("GET", "_replay"),
        "/api/target": ("POST", "_target"), "/api/control": ("POST", "_control"),
    }

    def _dispatch(self) -> None:
        """Every method's handler (the base class calls ``do_<METHOD>``)."""
        method, route = self.command, self.ROUTES.get(self._route())
        try:
            if route is None:
                raise Rejected(f"no such resource: {self._route()}", 404)
            if route[0] != method:
                self.close_connection = True
                raise Rejected(f"{method} is not allowed on {self._route()}: use {route[0]}", 405)
            getattr(self, route[1])()
        except Rejected as err:
            self._json(err.status, {"error": err.text})
        except (BrokenPipeError, ConnectionResetError):
            pass
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
        self._live_only()
        hub = self.server.hub
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream; charset=utf-8")
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Accel-Buffering", "no")
        self.end_headers()
        self.wfile.write(b"retry: 1000\n\n")
        self.wfile.flush()
        q = hub.subscribe()
        try:
            while True:
                try:
                    item = q.get(timeout=KEEPALIVE)
                except queue.Empty:
                    self.wfile.write(b": keepalive\n\n")
                    self.wfile.flush()
                    continue
                state = None
                while item is not _END:  # only the newest state matters: skip those a slow page had no time for
                    state = item
                    if q.empty():
                        break
                    item = q.get_nowait()
                if state is not None:
                    self.wfile.write(b"event: state\ndata: " + state.encode() + b"\n\n")
                if item is _END:
                    self.wfile.write(b"event: end\ndata: {}\n\n")
                    self.wfile.flush()
                    return
                self.wfile.flush()
        finally:
            hub.unsubscribe(q)

    def _body(self, fields: set[str], hint: str) -> dict:
        """The request's JSON object, of some of `fields` (`hint` says which to send)."""
        ctype = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if ctype != "application/json":
            raise Rejected("send JSON (Content-Type: application/json)", 415)
        origin = self.headers.get("Origin")
        if origin and urlsplit(origin).netloc != self.headers.get("Host"):
            raise Rejected(f"cross-origin request from {origin} refused", 403)
        length = self.headers.get("Content-Length")
        if length is None:
            raise Rejected("a Content-Length is required", 411)
        try:
            if (n := int(length)) < 0:
                raise ValueError
        except ValueError:
            raise Rejected(f"bad Content-Length {length!r}", 400) from None
        if n > MAX_BODY:
            self.close_connection = True
            raise Rejected(f"body of {n} bytes is larger than {MAX_BODY}", 413)
        raw = self.rfile.read(n)
        try:
            body = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise Rejected(f"the body is not JSON: {exc}", 400) from None
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
            raise Rejected(f"drone must be a string like D01, got {body['drone']!r}", 400)
        cell = parse_cell(body["cell"])
        self._json(200, self.server.backend.command("target", {"drone": body["drone"], "cell": cell}))

    def _control(self) -> None:
        body = self._body({"action", "value"}, "send action (and value for pace)")
        action = body.get("action")
        if action not in ("pause", "resume", "step", "quit", "pace"):
            raise Rejected(f"unknown action {action!r}: use pause, resume, step, pace or quit", 400)
        self._json(200, self.server.backend.command(action, {"value": body.get("value")}))


class WebServer(ThreadingHTTPServer):
    """Binds at construction (so a taken port fails before anything else starts); `start` serves."""

    daemon_threads = True
    block_on_close = False

    def __init__(self, address: tuple[str, int], backend: Backend, hub: Hub, logger: logging.Logger) -> None:
        self.backend, self.hub, self.log = backend, hub, logger
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
