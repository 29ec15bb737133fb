"""The thin Zenoh adapter shared by every process: flags, session config, and an event inbox.

One threading model, in every process and at every fleet size. Zenoh's callbacks, on Zenoh's threads, only refuse
(unread) what is too big, stale or over its origin's budget and queue the rest in the process's `Inbox`; what fails
there is counted as a rejection, never raised (Zenoh would swallow it). A query's reply, which its asker waits for, is
decoded there too. The main thread takes the payloads one at a time, in order of arrival but for a bursting origin
(`FairQueue`), decodes and checks each (`check_addressed`), and does everything else: a big payload costs its origin's
turn, not Zenoh's thread, which every other message waits for, and the only locks guard the queue and the rejections
(`RejectCounter`). A key whose newest message alone matters, read only when needed (`Inbox.newest`), has no callback:
Zenoh keeps that message, and the main thread reads and checks it when it wants it.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import ctypes
import json
import logging
import os
import queue
import re
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import msgpack
import zenoh

from schema import Keys, Message, Target, Turn, decode, encode
from schema.acl import flood_filters
from schema.errors import (
    MalformedMessage,
    RejectCounter,
    RemoteInputError,
    StaleTurn,
    UsageError,
    WrongSender,
    excerpt,
    seconds,
)
from schema.keys import ROOT, size_limit
from schema.messages import is_entity_id
from schema.tuning import AUDIT_S, ORIGIN_BYTES, ORIGIN_QUEUE, ORIGIN_SHARE, QUIET_MOST, ROUTER_ANSWER_S


def add_zenoh_args(parser: argparse.ArgumentParser) -> None:
    """Zenoh's conventional flags (as in zenoh-python's examples), plus the key root and logging."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("-m", "--mode", choices=["peer", "client", "router"], help="the zenoh session mode")
    g.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable)")
    g.add_argument("-c", "--config", metavar="FILE", help="a zenoh JSON5 configuration file")
    g.add_argument("--lease", type=seconds, metavar="SECONDS",
                   help="link lease (transport/link/tx/lease): a hung or cut-off process is declared gone after "
                        "about 0.75 x this (zenoh's default: 10)")
    g.add_argument("--root", default=ROOT, help=f"key expression root of this simulation (default: {ROOT})")
    g.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ERROR (default: INFO)")
    s = parser.add_argument_group("zenoh security (docs/security.md)")
    s.add_argument("--tls-ca", metavar="FILE", help="CA certificate that signed the router's (and peers') TLS "
                   "certificates, for tls/HOST:PORT endpoints")
    s.add_argument("--tls-cert", metavar="FILE", help="this process's TLS certificate (mutual TLS; with --tls-key)")
    s.add_argument("--tls-key", metavar="FILE", help="the private key of --tls-cert")
    s.add_argument("--tls-mtls", action="store_true",
                   help="a router: require every client to present a certificate signed by --tls-ca")
    s.add_argument("--user", metavar="NAME", help="user name for the router's user/password authentication")
    s.add_argument("--password-file", metavar="FILE",
                   help=f"file whose first line is the password of --user (or set {PASSWORD_ENV}); never a flag")
    s.add_argument("--users-file", metavar="FILE",
                   help="a router: the user:password dictionary it authenticates clients against")
    s.add_argument("--acl", metavar="FILE", help="a router: a JSON5 file with an access_control block "
                   "(python -m schema.acl)")


def zenoh_config(args: argparse.Namespace) -> zenoh.Config:
    """A zenoh.Config from the conventional flags. Multicast scouting and shared memory are off unless
    a config file turns them on: endpoints are explicit, so parallel runs never cross-talk; and Zenoh's
    shared-memory transport maps a pool of tens of MiB into every process that receives a message of
    a few KiB from a peer on the same host (a swarm's STATUS), for no measurable gain at these sizes."""
    if args.config:
        try:
            conf = zenoh.Config.from_file(args.config)
        except Exception as exc:
            raise UsageError(f"cannot load zenoh config {args.config}: {exc}") from None
    else:
        conf = _config({})
    _insert(conf, {"scouting/delay": 0, "mode": args.mode, "listen/endpoints": args.listen})
    connect_to(conf, args.connect)
    apply_flags(conf, args)
    return conf


def connect_to(conf: zenoh.Config, endpoints: list[str]) -> None:
    """Connect to `endpoints` (given on the command line): one that cannot be reached fails the session's
    opening at once, in every mode (a peer or a router would otherwise wait for it in the background)."""
    if endpoints:
        _insert(conf, {"connect/endpoints": endpoints, "connect/timeout_ms": 0, "connect/exit_on_failure": True})


def open_session(conf: zenoh.Config) -> zenoh.Session:
    """`zenoh.open`, failing with a UsageError (one line: what failed) when an endpoint cannot be reached or
    listened on, instead of Zenoh's error and its source locations."""
    try:
        return zenoh.open(conf)
    except zenoh.ZError as err:
        raise UsageError(f"cannot open a Zenoh session: {zenoh_error(err)}") from None


def zenoh_error(err: BaseException) -> str:
    """Zenoh's error message without the Rust source locations it appends (`... at /path/file.rs:12.`)."""
    return re.sub(r"\s+at \S+\.rs:\d+\.?", "", str(err)).strip()


def _insert(conf: zenoh.Config, settings: dict[str, object]) -> None:
    """Each setting given (not None, not an empty list) into `conf`, as JSON (UsageError if Zenoh refuses one, e.g.
    an endpoint that is not <protocol>/<address>)."""
    for key, value in settings.items():
        if value not in (None, []):
            try:
                conf.insert_json5(key, json.dumps(value))
            except zenoh.ZError as exc:
                raise UsageError(f"bad zenoh setting {key} = {json.dumps(value)}: {exc}") from None


#: The environment variable holding the password of --user when no --password-file is given.
PASSWORD_ENV = "DRONESIM_PASSWORD"


def _existing(path: str, flag: str) -> str:
    if not os.path.isfile(path):
        if flag == "--password-file":  # never echo it: it may be a password typed as `--password SECRET`
            raise UsageError("--password-file: no such file (it takes the path of a file holding the password)")
        raise UsageError(f"{flag} {path}: no such file")
    return os.path.abspath(path)


def apply_flags(conf: zenoh.Config, args: argparse.Namespace, *, router: bool | None = None) -> None:
    """--lease and the security flags into `conf`. A client's --tls-cert/--tls-key are presented to the
    router (mutual TLS); a router's are its server certificate, and --tls-mtls makes it require clients'
    ones. `router` defaults to the config's mode."""
    tls, auth = "transport/link/tls/", "transport/auth/usrpwd/"
    if args.lease is not None:
        if args.lease <= 0:
            raise UsageError("--lease must be positive")
        # (in milliseconds; keep_alive: keep-alives per lease, zenoh's default)
        _insert(conf, {"transport/link/tx/lease": int(args.lease * 1000), "transport/link/tx/keep_alive": 4})
    if router is None:
        router = (args.mode or json.loads(conf.get_json("mode") or "null")) == "router"
    if args.tls_ca:
        _insert(conf, {tls + "root_ca_certificate": _existing(args.tls_ca, "--tls-ca")})
    if bool(args.tls_cert) != bool(args.tls_key):
        raise UsageError("--tls-cert and --tls-key go together")
    if args.tls_cert:
        cert, key = _existing(args.tls_cert, "--tls-cert"), _existing(args.tls_key, "--tls-key")
        for side in ("listen", "connect"):
            _insert(conf, {f"{tls}{side}_certificate": cert, f"{tls}{side}_private_key": key})
    if args.tls_mtls or (args.tls_cert and not router):  # a client presents its certificate only then
        _insert(conf, {tls + "enable_mtls": True})
    password = os.environ.get(PASSWORD_ENV) or None
    if args.password_file:
        with open(_existing(args.password_file, "--password-file"), encoding="utf-8") as f:
            password = f.readline().rstrip("\r\n")
        if not password:
            raise UsageError(f"--password-file {args.password_file}: its first line is empty")
        if not args.user:
            raise UsageError("--password-file needs --user NAME")
    if args.user:
        if password is None:
            raise UsageError(f"--user {args.user} needs --password-file FILE or the {PASSWORD_ENV} "
                             "environment variable")
        _insert(conf, {auth + "user": args.user, auth + "password": password})
    if args.users_file:
        _insert(conf, {auth + "dictionary_file": _existing(args.users_file, "--users-file")})
    if args.acl:
        try:
            block = zenoh.Config.from_file(_existing(args.acl, "--acl")).get_json("access_control")
        except Exception as exc:
            raise UsageError(f"cannot load --acl {args.acl}: {exc}") from None
        if not json.loads(block).get("enabled"):
            raise UsageError(f"--acl {args.acl}: its access_control block is missing or not enabled")
        conf.insert_json5("access_control", block)
        if router:  # the budgets of puts a second key by key, for the keys it grants (`flood_filters`)
            _insert(conf, {"downsampling": flood_filters(["**"], json.loads(block))["downsampling"]})


def setup_logging(level: str, name: str) -> logging.Logger:
    """Entry points only: configure logging to stderr, prefixed with the process's role."""
    logging.basicConfig(level=level.upper(), format=f"%(asctime)s {name} %(levelname)s %(message)s", datefmt="%H:%M:%S")
    return logging.getLogger(f"dronesim.{name}")


def _config(settings: dict[str, object]) -> zenoh.Config:
    """`settings` over this project's defaults (`zenoh_config` says why)."""
    conf = zenoh.Config()
    _insert(conf, {"scouting/multicast/enabled": False, "transport/shared_memory/enabled": False, **settings})
    return conf


def router_config(listen: str | list[str] = "tcp/127.0.0.1:0") -> zenoh.Config:
    """A router's config, listening on `listen` (one endpoint or several): fast start, no multicast, admin
    space readable (for its port), and the key table's flood filters for any root (`schema.acl.flood_filters`)."""
    endpoints = [listen] if isinstance(listen, str) else listen
    return _config({**flood_filters(["**"]), "mode": "router", "listen/endpoints": endpoints, "scouting/delay": 0,
                    "adminspace": {"enabled": True, "permissions": {"read": True, "write": False}}})


def client_config(locator: str) -> zenoh.Config:
    """A client session's config for one router endpoint: no multicast, fast start."""
    return _config({"mode": "client", "connect/endpoints": [locator], "scouting/delay": 0})


def router_locators(session: zenoh.Session) -> list[str]:
    """The endpoints a router session really listens on (with the port chosen for `:0`)."""
    for reply in session.get(f"@/{session_id(session)}/router", timeout=ROUTER_ANSWER_S):
        if reply.ok is not None:
            return list(json.loads(reply.ok.payload.to_bytes())["locators"])
    raise UsageError("the router did not report its locators")


@dataclass(frozen=True, slots=True)
class Sessions:
    """The sessions the routers say are connected (`audit_sessions`); None: the listing may be incomplete.
    `answered`: whether any router answered at all (no: none could be reached in time, e.g. one frozen)."""

    connected: frozenset[str] | None
    answered: bool = True


def sessions_listed(answers: list[dict[str, Any]]) -> frozenset[str] | None:
    """The session ids in the routers' admin-space answers (`@/<zid>/router`), if they cover every session:
    None when one lists a peer (which may carry sessions of its own) or a router that did not answer."""
    routers = {str(a.get("zid")) for a in answers}
    connected = set(routers)
    for answer in answers:
        for s in answer.get("sessions", []):
            zid, what = str(s.get("peer")), s.get("whatami")
            if what == "peer" or (what == "router" and zid not in routers):
                return None
            connected.add(zid)
    return frozenset(connected) if answers else None


def audit_sessions(session: zenoh.Session, post: Callable[[object], None], timeout: float = AUDIT_S) -> None:
    """Ask every router which sessions it connects, without waiting: `post(Sessions(...))` once answered. A
    presence token says nothing of who declared it: this tells a copy's (on a plain router) from its own."""
    answers: list[dict[str, Any]] = []

    def on_reply(reply: zenoh.Reply) -> None:
        # (not a router's answer: skipped; the listing stays incomplete only if a router is missing)
        with contextlib.suppress(ValueError):
            if reply.ok is not None:
                answers.append(json.loads(reply.ok.payload.to_bytes()))

    session.get("@/*/router", _direct(on_reply, lambda: post(Sessions(sessions_listed(answers), bool(answers)))),
                timeout=timeout)


@dataclass(frozen=True, slots=True)
class Received:
    """A valid message that arrived on `key`."""

    key: str
    msg: Message


@dataclass(frozen=True, slots=True)
class Asked:
    """A valid query payload; `query` must be replied to (or dropped) by the main thread."""

    query: zenoh.Query
    msg: Message


@dataclass(frozen=True, slots=True)
class Presence:
    """A process's liveliness token appeared (`alive`) or disappeared."""

    entity: str
    session: str
    alive: bool


@dataclass(frozen=True, slots=True)
class Matching:
    """Whether anyone subscribes to `key`, this process's publication, has changed (see `Outbox.watch`)."""

    key: str
    matching: bool


Event = Received | Asked | Presence | Matching


@dataclass(frozen=True, slots=True)
class _Unread:
    """A message (`query` None) or query that passed the cheap checks, not decoded yet (`Inbox._read` does)."""

    key: str
    origin: str
    query: zenoh.Query | None
    data: bytes
    expect: type[Message] | tuple[type[Message], ...]


def session_id(session: zenoh.Session) -> str:
    return str(session.info.zid())


def check_addressed(keys: Keys, key: str, msg: Message) -> None:
    """The entity part of a key must be the message's subject: its drone for TGT, else its sender."""
    subject = msg.drone if isinstance(msg, Target) else msg.sender
    parts = keys.parts_of(key)
    if parts[0] != subject:
        raise WrongSender(f"a {msg.TAG} about {subject} on {parts[0]}'s key {key}")
    phase = msg.phase.value if isinstance(msg, Turn) else None
    if parts[2:] != ([phase] if phase else []):
        raise WrongSender(f"a {msg.TAG}{'(' + phase + ')' if phase else ''} on key {key}")


#: Zenoh's threads that this process gave a lasting Python thread state (`_keep_thread_state`).
_KEPT = threading.local()


def _keep_thread_state() -> None:
    """Keep the Python thread state of the Zenoh thread that runs this (its callbacks' cost /10).

    Zenoh's threads are not Python's: for each callback zenoh-python (pyo3) takes the GIL with `PyGILState_Ensure`,
    which makes a thread state for a thread that has none, and gives it back with `PyGILState_Release`, which
    destroys it: each message paid a new thread state and its frame stack (an mmap, its pages faulted in, an
    munmap): 20-27 µs a callback against 2.3-2.8 kept (docs/performance.md). One more `PyGILState_Ensure`, never
    released, on the first callback of each thread keeps the state for the thread's life (the GIL is still
    released after each callback: the release that follows restores the state the callback found). Called with
    the GIL held; Python's `threading.local` lives in the thread state, so it is kept with it."""
    if not getattr(_KEPT, "kept", False):
        ctypes.pythonapi.PyGILState_Ensure()
        _KEPT.kept = True


def _direct(callback: Callable[[Any], None], drop: Callable[[], None] | None = None) -> zenoh.handlers.Callback:
    """Run `callback` (and `drop`, once it is done) on Zenoh's receiving thread itself, in order: by default
    zenoh-python hands each one to a thread of its own, and messages on different keys overtake each other
    on their way into the inbox. The thread keeps its Python thread state (`_keep_thread_state`)."""
    return zenoh.handlers.Callback(_kept(callback), None if drop is None else _kept(drop), indirect=False)


def _kept(f: Callable[..., None]) -> Callable[..., None]:
    """`f`, run on a thread that keeps its Python thread state (`_keep_thread_state`)."""

    def run(*args: Any) -> None:
        _keep_thread_state()
        f(*args)

    return run


def _stamp(data: bytes) -> tuple[object, object]:
    """(turn, sender) as the first bytes of a payload say them, without decoding the rest (a
    payload's map starts with them: schema/README.md); None for what they do not say."""
    head = msgpack.Unpacker(raw=False)
    head.feed(data[:64])
    found: dict[object, object] = {}
    try:
        for _ in range(min(head.read_map_header(), 4)):
            name = head.unpack()
            found[name] = head.unpack()
    except Exception:  # noqa: BLE001 - not MessagePack, or cut short: decode says why
        pass
    return found.get("turn"), found.get("from")


_TURN = b"\xa4turn"  # the key "turn" as MessagePack writes it
#: An unsigned int's MessagePack type byte -> its length (bytes after it); a positive fixint is the byte itself.
_UINTS = {0xCC: 1, 0xCD: 2, 0xCE: 4, 0xCF: 8}


def _turn(data: bytes) -> object:
    """The turn the first bytes of a payload say (`_stamp`'s), read without an Unpacker from a payload as `encode`
    writes them: a map of 3 items at least, "v" a positive fixint, "t" a short ASCII string, "turn" an unsigned int (and
    not "turn" again): a few byte comparisons, about a tenth of `_stamp`'s time, for each message of a flood the
    router lets through. Anything else is read by `_stamp`."""
    if (len(data) >= 12 and 0x83 <= data[0] <= 0x8F and data[1] == 0xA1 and data[2] == 0x76 and data[3] < 0x80
            and data[4] == 0xA1 and data[5] == 0x74 and 0xA0 <= data[6] <= 0xBF
            and data.startswith(_TURN, at := 7 + data[6] - 0xA0) and data[7:at].isascii()
            and (at := at + 5) < len(data)):
        first = data[at]
        if first < 0x80:
            turn, end = first, at + 1
        elif (n := _UINTS.get(first)) is not None and at + 1 + n <= len(data):
            turn, end = int.from_bytes(data[at + 1:at + 1 + n], "big"), at + 1 + n
        else:
            return _stamp(data)[0]
        if not data.startswith(_TURN, end):
            return turn
    return _stamp(data)[0]


#: Keys a subscription remembers the origin of (`Keys.origin_of`, read once a key instead of once a message); a
#: flood on ever new keys (a wildcard subscription's) has the rest read each time.
KEYS_REMEMBERED = 1024


def _budgeted(origin: str) -> bool:
    """Whether the events of an origin proven by the key they came on count against its budget: all but the
    coordinator's (a process that lags behind must not lose the game's end)."""
    return origin != "SRV"


def _answer(key: str, reply: zenoh.Reply, expect: type[Message] | tuple[type[Message], ...]) -> Message:
    """A query's reply, decoded (RemoteInputError on an error reply or a malformed one)."""
    if reply.ok is None:
        said = reply.err.payload.to_bytes().decode(errors="replace") if reply.err is not None else "nothing"
        raise RemoteInputError(f"{key} answered an error: {said}", reason="error-reply")
    return decode(reply.ok.payload.to_bytes(), expect)


class _Overdue:
    """Wakes its `FairQueue`'s consumer when it waits past its time limit. `SimpleQueue.get(timeout=...)` can wait
    forever in CPython 3.11: when an acquire of its lock finds the queue empty, it recomputes the time left, and once
    the deadline is past a negative time means no limit; it then waits for the next event (`dronesim bench perf`'s
    ground station once waited so, its game idle, every process waiting for it; tests/test_transport.py has a mix
    of steps that does it). Waiting otherwise (threading's Event or Condition) costs every message a waiting
    consumer gets 30-50 µs more. So a thread looks every `PERIOD` s whether the queue's consumer, waiting with a
    time limit, is more than a period late, and wakes it (`FairQueue.wake`): a flawed wait lasts a period or two, a
    sound one is never touched but by a consumer running late (then one spurious wake-up).

    One per queue (an `Inbox`'s: one per session), from its first wait with a time limit, in the process that
    waits (a forked child starts its own), until `stop` or the queue is gone: the thread holds it weakly."""

    PERIOD = 0.1

    def __init__(self, q: FairQueue) -> None:
        self.pid = os.getpid()
        self._stopped = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(weakref.ref(q), self._stopped),
                                       name="fairqueue-overdue", daemon=True)
        self.thread.start()

    @staticmethod
    def _run(ref: weakref.ref[FairQueue], stopped: threading.Event) -> None:
        while True:
            time.sleep(_Overdue.PERIOD)  # (not a timed wait on a lock: the flaw it watches for is one)
            q = ref()
            if q is None or stopped.is_set():
                return
            if q.overdue(time.monotonic(), _Overdue.PERIOD):
                q.wake()
            del q  # (the queue is not kept alive by its watcher while it sleeps)

    def stop(self) -> None:
        self._stopped.set()


class FairQueue:
    """Events by origin, for one consuming thread, with a bound per origin and turns under pressure.

    Events are taken in order of arrival, except that an origin has at most `share` of its events in line at a
    time: the rest wait and join the end of the line one by one, as its events are taken. So one origin's burst
    delays another origin's next event by at most `share` of its own, and below that nothing is reordered. At
    most `budget` events and `budget_bytes` bytes (the payloads they came as) are queued per origin: `put`
    raises a `flood` RemoteInputError beyond. An event put `quiet` does not wake the consumer: it is taken first
    when the consumer next takes one (at most `quiet_most` of them are so kept). Thread-safe."""

    def __init__(self, budget: int = ORIGIN_QUEUE, budget_bytes: int = ORIGIN_BYTES, share: int = ORIGIN_SHARE,
                 quiet_most: int = QUIET_MOST) -> None:
        self.budget, self.budget_bytes, self.share, self.quiet_most = budget, budget_bytes, share, quiet_most
        self._lock = threading.Lock()  # guards the three below and the order of entries into the line
        self._queues: dict[str, collections.deque[tuple[object, int]]] = {}  # origin -> (event, size), in order
        self._bytes: dict[str, int] = {}  # origin -> bytes of its events queued
        self._lined: dict[str, int] = {}  # origin -> its events in line
        # an origin per event in line, in order (None: a wake-up); the consumer waits on it, in C, lock-free
        self._line: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self._until: float | None = None  # while the consumer waits with a time limit: when it must be back
        self._watcher: _Overdue | None = None
        # the quiet events, in order of arrival (taken before the line; the consumer alone pops them)
        self._quiet: collections.deque[object] = collections.deque()
        self._woken_by: str | None = None  # an origin taken from the line while quiet events came: its turn is next

    def full(self, origin: str, size: int = 0) -> str | None:
        """Why an event of `size` bytes from `origin` would be over its budget (None: it would not). A
        hint for refusing it unread: `put` checks again."""
        queued = len(self._queues.get(origin, ()))
        if queued >= self.budget:
            return f"{queued} events from {origin} are already waiting"
        held = self._bytes.get(origin, 0)
        if queued and held + size > self.budget_bytes:  # (one event alone is bounded by its size limit)
            return f"{held} bytes from {origin} are already waiting"
        return None

    def put(self, origin: str, event: object, size: int = 0, *, budgeted: bool = True, quiet: bool = False) -> None:
        """Queue `event` from `origin`; `quiet`: the consumer need not wake for it (a ground station's answer ahead,
        for a turn to come): it takes it before any other when it next takes one, unless `quiet_most` already are."""
        with self._lock:
            if budgeted and (why := self.full(origin, size)) is not None:
                raise RemoteInputError(why, reason="flood")
            if quiet and len(self._quiet) < self.quiet_most:
                self._quiet.append(event)
                return
            self._queues.setdefault(origin, collections.deque()).append((event, size))
            self._bytes[origin] = self._bytes.get(origin, 0) + size
            if self._lined.get(origin, 0) < self.share:
                self._enter(origin)

    def _enter(self, origin: str) -> None:
        self._lined[origin] = self._lined.get(origin, 0) + 1
        self._line.put(origin)

    def wake(self) -> None:
        """Make a `take` waiting now return (with nothing)."""
        self._line.put(None)

    def take(self, timeout: float | None) -> tuple[bool, object]:
        """(True, the next event), or (False, None) after `timeout` seconds (None: no limit) or a `wake`. The quiet
        events come first, those that came while it waited included (before the event that woke it)."""
        if self._quiet:
            return True, self._quiet.popleft()
        if (origin := self._woken_by) is not None:
            self._woken_by = None
        else:
            if timeout is not None:
                self._until = time.monotonic() + timeout
                if self._watcher is None or self._watcher.pid != os.getpid():
                    self._watcher = _Overdue(self)
            try:
                origin = self._line.get(timeout=timeout)
            except queue.Empty:
                return False, None
            finally:
                self._until = None
            if origin is not None and self._quiet:  # they came first
                self._woken_by = origin
                return True, self._quiet.popleft()
        if origin is None:
            return False, None
        with self._lock:
            self._lined[origin] -= 1
            waiting = self._queues[origin]
            event, size = waiting.popleft()
            self._bytes[origin] -= size
            if len(waiting) > self._lined[origin]:
                self._enter(origin)  # its next event waiting joins the end of the line
            elif not waiting:
                del self._queues[origin], self._bytes[origin], self._lined[origin]
            return True, event

    def overdue(self, now: float, margin: float) -> bool:
        """The consumer waits with a time limit that passed more than `margin` s ago."""
        until = self._until
        return until is not None and now > until + margin

    def close(self) -> None:
        """Stop watching the consumer's waits (a later wait with a time limit starts a new watcher)."""
        watcher, self._watcher = self._watcher, None
        if watcher is not None:
            watcher.stop()

    def drain(self) -> list[object]:
        """Every event queued, in the order `take` would give them (for the one consumer: never blocks)."""
        out: list[object] = []
        while self._quiet or self._woken_by is not None or not self._line.empty():
            got, event = self.take(None)
            if got:
                out.append(event)
        return out


@dataclass(frozen=True, slots=True)
class Newest:
    """`Inbox.newest`'s reader: call it for the newest message since the last call; `close()` undeclares its
    subscriber (Zenoh then sends this process nothing more on that key)."""

    read: Callable[[], Received | None]
    close: Callable[[], None]

    def __call__(self) -> Received | None:
        return self.read()


class Inbox:
    """Events from Zenoh callbacks for the process's main thread (the module's docstring); a flood cannot move
    a game. Each event counts against the budget (`FairQueue`) of its origin: the writer of the key it came on
    (by the key table: SRV for TURN, STATUS and OVER, GCS for TGT and DONE, the drone or host whose key an NPS
    or MOVES is on), the sender a query names, the entity of a presence token."""

    def __init__(self, session: zenoh.Session, keys: Keys, logger: logging.Logger, *,
                 budget: int = ORIGIN_QUEUE, share: int = ORIGIN_SHARE) -> None:
        self.session, self.keys, self.log = session, keys, logger
        self._handles: list[Any] = []  # subscribers, queryables: undeclared by `close`
        self._events = FairQueue(budget, share=share)
        self.rejects = RejectCounter(logger, wake=self._events.wake)  # (its summaries are logged by `get`)
        self._held: collections.deque[Any] = collections.deque()  # events given back (`hold`)
        self._asked: collections.Counter[str] = collections.Counter()  # queries queued, by key (`serve`'s `most`)
        self._asking = threading.Lock()  # guards `_asked` (Zenoh's thread adds, the main thread takes)
        #: when this session's next CONNECT may go out (`network.membership.Membership`: every membership of the
        #: session, as the RL backend's station and swarm host, keeps `CONNECT_GAP` after the last)
        self.next_connect = float("-inf")

    def run(self, handler: Callable[[Event | None], None], *, timeout: Callable[[], float | None],
            until: Callable[[], bool]) -> None:
        """Hand every event to `handler`, one at a time, on this thread (None when `timeout()` seconds
        pass without one), until `until()`; events after the end stay queued."""
        while not until():
            handler(self.get(timeout()))  # (no reference kept while waiting: a swarm's MOVES is big)

    # callbacks (Zenoh threads): check, enqueue; never raise

    def _admit(self, origin: str, size: int, limit: int, budgeted: bool) -> None:
        """Refuse, unread, a payload above its key's size limit (`schema.keys.size_limit`) or, if `budgeted`, from
        an origin over its budget."""
        if size > limit:
            raise MalformedMessage(f"a payload of {size} bytes, above the key's limit of {limit}", reason="too-large")
        if budgeted and (why := self._events.full(origin, size)) is not None:
            raise RemoteInputError(why, reason="flood")

    def subscribe(self, key: str, expect: type[Message] | tuple[type[Message], ...], *,
                  since: Callable[[], int] | None = None, ahead_quiet: bool = False) -> zenoh.Subscriber:
        """Messages on `key` become `Received` events (until `unsubscribe`); with `since`, those stamped with
        a turn before `since()` are refused as stale, and with `ahead_quiet` those stamped with a later turn do not
        wake the main thread (`FairQueue.put`'s `quiet`: it takes them before the event it next wakes for)."""
        limit = max(size_limit(t) for t in (expect if isinstance(expect, tuple) else (expect,)))
        origins: dict[str, str] = {}  # key -> its origin, for the first `KEYS_REMEMBERED` keys it came on

        def on_sample(sample: zenoh.Sample) -> None:
            k = str(sample.key_expr)
            if (origin := origins.get(k)) is None:
                try:
                    origin = self.keys.origin_of(k)
                except ValueError:
                    origin = k
                if len(origins) < KEYS_REMEMBERED:
                    origins[k] = origin
            try:
                payload = sample.payload
                budgeted = _budgeted(origin)
                self._admit(origin, len(payload), limit, budgeted)
                data = payload.to_bytes()
                quiet = False
                if since is not None and type(turn := _turn(data)) is int:
                    if turn < (now := since()):
                        raise StaleTurn(f"a message for turn {turn}, before turn {now}")
                    quiet = ahead_quiet and turn > now
                self._events.put(origin, _Unread(k, origin, None, data, expect), len(data), budgeted=budgeted,
                                 quiet=quiet)
            except RemoteInputError as err:
                self.rejects.reject(k, err, origin)
            except Exception:  # a bug: log it, never let Zenoh swallow it silently
                self.log.exception("error handling %s", k)

        sub = self.session.declare_subscriber(key, _direct(on_sample))
        self._handles.append(sub)
        return sub

    def newest(self, key: str, expect: type[Message]) -> Newest:
        """The newest message on `key`, read only when wanted: Zenoh keeps the last one that came (a ring of one,
        no callback), so none wakes this process. Each call reads the one that came since the last call, checked
        as `subscribe` checks them (None: none came, or it was refused and counted). Its `close` undeclares it."""
        origin, limit = self.keys.origin_of(key), size_limit(expect)
        ring = self.session.declare_subscriber(key, zenoh.handlers.RingChannel(1))
        self._handles.append(ring)

        def read() -> Received | None:
            if (sample := ring.try_recv()) is None:
                return None
            try:
                self._admit(origin, len(sample.payload), limit, False)
            except RemoteInputError as err:
                self._refuse(key, origin, None, err)
                return None
            return self._read(_Unread(key, origin, None, sample.payload.to_bytes(), expect))  # type: ignore[return-value]

        return Newest(read, lambda: self.unsubscribe(ring))

    def unsubscribe(self, sub: zenoh.Subscriber) -> None:
        sub.undeclare()
        self._handles.remove(sub)

    def serve(self, key: str, expect: type[Message], *, most: int | None = None,
              waiting: Callable[[], int] = lambda: 0) -> None:
        """Declare a queryable; valid queries become `Asked` events, refused ones get an error reply (their
        origin is the sender they name). With `most`, one that finds `most` of them queued or held by the main
        thread (`waiting()`: read from Zenoh's thread) is refused at once there, unread (`flood`; its asker asks
        again): a flood of them, each naming another sender, costs the main thread nothing."""
        limit = size_limit(expect)

        def on_query(query: zenoh.Query) -> None:
            payload = query.payload
            origin = key
            try:
                if payload is None:
                    raise MalformedMessage(f"query on {key} without payload")
                data = payload.to_bytes() if len(payload) <= limit else b""
                sender = _stamp(data)[1]
                origin = sender if isinstance(sender, str) and is_entity_id(sender) else key
                # (the sender a query names is its payload's claim, not its key's: a query claiming SRV is budgeted)
                self._admit(origin, len(payload), limit, True)
                with self._asking:
                    if most is not None and (held := self._asked[key] + waiting()) >= most:
                        raise RemoteInputError(f"{held} queries on {key} already wait", reason="flood")
                    self._asked[key] += 1
                try:
                    self._events.put(origin, _Unread(key, origin, query, data, expect), len(data))
                except RemoteInputError:
                    self._taken(key)
                    raise
            except RemoteInputError as err:
                self._refuse(key, origin, query, err)
            except Exception:
                self.log.exception("error handling a query on %s", key)
                query.reply_err(b"internal error")
                query.drop()

        self._handles.append(self.session.declare_queryable(key, _direct(on_query), complete=True))

    def _refuse(self, key: str, origin: str, query: zenoh.Query | None, err: RemoteInputError) -> None:
        self.rejects.reject(key, err, origin)
        if query is not None:  # (a query gets an error reply)
            query.reply_err(excerpt(str(err)).encode())
            query.drop()

    def _taken(self, key: str) -> None:
        with self._asking:
            self._asked[key] -= 1

    def _read(self, event: object) -> Event | None:
        """A payload, decoded; None if it is malformed or not its key's (refused: `_refuse`)."""
        if not isinstance(event, _Unread):
            return event  # type: ignore[return-value]
        if event.query is not None:
            self._taken(event.key)
        try:
            msg = decode(event.data, event.expect)
            if event.query is not None:
                return Asked(event.query, msg)
            check_addressed(self.keys, event.key, msg)
            return Received(event.key, msg)
        except RemoteInputError as err:
            self._refuse(event.key, event.origin, event.query, err)
            return None

    def query(self, key: str, msg: Message, expect: type[Message], *, timeout: float,
              then: Callable[[tuple[Message | RemoteInputError, ...]], object]) -> None:
        """One query, not waited for: once it is finished, the event `then(replies)` is queued, with every
        reply decoded, or the RemoteInputError of an error reply or a malformed one (none: nobody answered
        within `timeout`). This process asked: its answer is never refused for the budget (`post`)."""
        replies: list[Message | RemoteInputError] = []

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.err is not None and reply.err.payload.to_bytes() == b"Timeout":
                return  # zenoh's own error reply: nobody answered in time
            try:
                got = _answer(key, reply, expect)
                check_addressed(self.keys, key, got)
                replies.append(got)
            except RemoteInputError as err:
                replies.append(err)
            except Exception:  # a bug: log it, never let Zenoh swallow it silently
                self.log.exception("error handling a reply on %s", key)

        done = _direct(on_reply, lambda: self.post(then(tuple(replies))))  # (after the last reply)
        self.session.get(key, done, payload=encode(msg), timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE)

    def watch_presence(self, entity: str | None = None) -> None:
        """Presence events for every process (or only `entity`'s), starting with those already there."""

        def on_token(sample: zenoh.Sample) -> None:
            k = str(sample.key_expr)
            try:
                who, session = self.keys.presence_of(k)
                self._events.put(who, Presence(who, session, sample.kind == zenoh.SampleKind.PUT),
                                 budgeted=_budgeted(who))
            except RemoteInputError as err:
                self.rejects.reject(k, err, k)
            except Exception:  # a bug, as above
                self.log.exception("error handling %s", k)

        key = self.keys.any_alive if entity is None else self.keys.alive_of(entity)
        self._handles.append(self.session.liveliness().declare_subscriber(key, _direct(on_token), history=True))

    def close(self) -> None:
        """Undeclare every subscription, queryable and presence watch of this inbox (the session stays open)."""
        handles, self._handles = self._handles, []
        for handle in handles:
            handle.undeclare()
        self._events.close()

    def post(self, event: object) -> None:
        """Queue an event from another thread of this process (e.g. a web request for the main loop)."""
        self._events.put("local", event, budgeted=False)  # (this process's own origin: never refused)

    def post_from(self, where: str, origin: str, event: object, size: int, limit: int) -> None:
        """Queue an event made of a remote input this process heard outside this inbox (a ROS 2 goal on a topic it
        subscribed to itself), from the thread that heard it: refused unread and counted in `rejects` (at `where`,
        from `origin`) above `limit` bytes or beyond `origin`'s budget, as `subscribe` refuses a game key's."""
        try:
            self._admit(origin, size, limit, True)
            self._events.put(origin, event, size)
        except RemoteInputError as err:
            self.rejects.reject(where, err, origin)

    # the main thread

    def drain(self) -> list[Event]:
        """Every event already queued, without waiting (in the order `get` takes them)."""
        held, self._held = list(self._held), collections.deque()
        return [*held, *(e for e in map(self._read, self._events.drain()) if e is not None)]

    def hold(self, events: list[object]) -> None:
        """Give `events`, taken from this inbox by the main thread and not handled yet, back: the next `get`s and
        `drain` return them first, in their order (admission takes the events it is waiting for, and holds the
        others for the loop that follows)."""
        self._held.extend(events)

    def get(self, timeout: float | None = None) -> Event | None:
        """The next event, or None when `timeout` seconds pass first, or at once for a `post(None)` (a wake: a
        signal noted by its handler, which the caller's loop must look at now, not when its wait is over)."""
        if self._held:
            return self._held.popleft()
        end = None if timeout is None else time.monotonic() + max(0.0, timeout)
        while True:
            self.rejects.flush()
            left = None if end is None else max(0.0, end - time.monotonic())
            summary = self.rejects.due_in()  # (a summary of rejections is logged when due)
            got, event = self._events.take(left if summary is None else summary if left is None else min(left, summary))
            if got and event is None:
                return None
            if got and (read := self._read(event)) is not None:
                return read
            if left is not None and time.monotonic() >= end:  # type: ignore[operator]
                return None


class Outbox:
    """Publishes messages with BLOCK congestion control (control messages must not be dropped)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._listeners: list[zenoh.MatchingListener] = []

    def _pub(self, key: str) -> zenoh.Publisher:
        if key not in self._pubs:
            self._pubs[key] = self.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                                             reliability=zenoh.Reliability.RELIABLE)
        return self._pubs[key]

    def put(self, key: str, msg: Message) -> None:
        """Publish `msg`."""
        self._pub(key).put(encode(msg))

    def close(self) -> None:
        """Undeclare this outbox's publishers and matching listeners (the session stays open)."""
        for listener in self._listeners:
            listener.undeclare()
        for pub in self._pubs.values():
            pub.undeclare()
        self._listeners, self._pubs = [], {}

    def watch(self, key: str, inbox: Inbox) -> None:
        """A `Matching` event in `inbox` each time someone starts or stops subscribing to `key` (the
        first, at once, if someone already does)."""
        on_status = _direct(lambda status: inbox.post(Matching(key, status.matching)))
        self._listeners.append(self._pub(key).declare_matching_listener(on_status))


def ask_later(session: zenoh.Session, key: str, msg: Message, expect: type[Message] | tuple[type[Message], ...],
              timeout: float, done: Callable[[Message | None, str, str], None],
              accept: Callable[[str], bool] | None = None) -> None:
    """`ask` without waiting: `done(reply, replier, error)` is called once, on Zenoh's thread, with the first valid
    reply and the session id of its replier, or with None and why none came (an error reply, none in time). With
    `accept` (called on Zenoh's thread), a reply from a session it does not accept is skipped (anyone may declare a
    queryable on a plain router)."""
    answered: list[bool] = []
    skipped: list[str] = []

    def on_reply(reply: zenoh.Reply) -> None:
        if answered:
            return
        replier = "" if reply.replier_id is None else str(reply.replier_id.zid)
        if accept is not None and not accept(replier):
            skipped.append(replier)
            return
        answered.append(True)
        try:
            done(_answer(key, reply, expect), replier, "")
        except RemoteInputError as err:
            done(None, "", str(err))

    def on_end() -> None:
        if not answered:
            done(None, "", f"no answer on {key} within {timeout:.1f} s" +
                 (f" but {len(skipped)} from sessions that may not answer it" if skipped else ""))

    session.get(key, _direct(on_reply, on_end), payload=encode(msg), timeout=timeout,
                consolidation=zenoh.ConsolidationMode.NONE)


def ask(session: zenoh.Session, key: str, msg: Message, expect: type[Message] | tuple[type[Message], ...],
        timeout: float, accept: Callable[[str], bool] | None = None) -> tuple[Message, str]:
    """One query, one valid reply (raises RemoteInputError on an error reply, TimeoutError on none), and the
    session id of the process that answered (as Zenoh says it, "" if it does not). With `accept`, only a reply from
    a session it accepts counts (the others are skipped: anyone may declare a queryable on a plain router)."""
    skipped = 0
    for reply in session.get(key, payload=encode(msg), timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE):
        replier = "" if reply.replier_id is None else str(reply.replier_id.zid)
        if accept is not None and not accept(replier):
            skipped += 1
            continue
        return _answer(key, reply, expect), replier
    raise TimeoutError(f"no answer on {key} within {timeout:.1f} s" +
                       (f" but {skipped} from sessions that may not answer it" if skipped else ""))
