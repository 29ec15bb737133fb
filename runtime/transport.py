"""The thin Zenoh adapter shared by every process: flags, session config, and an event inbox.

Zenoh callbacks run on Zenoh's threads and swallow exceptions, so they only decode, validate the
key against the message and hand the result to an `Inbox` that the process's single main thread
drains. Everything that mutates state runs on that thread: no locks in the cores, no races.
"""

from __future__ import annotations

import argparse
import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from dronesim.schema import Keys, Message, RejectCounter, RemoteInputError, Target, Turn, UsageError, decode, encode
from dronesim.schema.errors import WrongSender

# --------------------------------------------------------------------------- flags and config


def add_zenoh_args(parser: argparse.ArgumentParser) -> None:
    """Zenoh's conventional flags (as in zenoh-python's examples), plus the key root and logging."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("-m", "--mode", choices=["peer", "client", "router"], help="the zenoh session mode")
    g.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable)")
    g.add_argument("-c", "--config", metavar="FILE", help="a zenoh JSON5 configuration file")
    g.add_argument("--lease", type=float, metavar="SECONDS",
                   help="link lease (transport/link/tx/lease): a hung or cut-off process is declared gone after "
                        "about 0.75 x this (zenoh's default: 10)")
    g.add_argument("--root", default="sim", help="key expression root of this simulation (default: sim)")
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
                   "(python -m dronesim.schema.acl)")


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
        conf = _local_defaults()
    conf.insert_json5("scouting/delay", "0")
    if args.mode:
        conf.insert_json5("mode", json.dumps(args.mode))
    if args.connect:
        conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    if args.listen:
        conf.insert_json5("listen/endpoints", json.dumps(args.listen))
    apply_lease(conf, args)
    apply_security(conf, args)
    return conf


def apply_lease(conf: zenoh.Config, args: argparse.Namespace) -> None:
    """--lease into `conf` (transport/link/tx/lease, in milliseconds)."""
    if getattr(args, "lease", None) is not None:
        if args.lease <= 0:
            raise UsageError("--lease must be positive")
        conf.insert_json5("transport/link/tx/lease", str(int(args.lease * 1000)))
        conf.insert_json5("transport/link/tx/keep_alive", "4")  # keep-alives per lease, zenoh's default


#: The environment variable holding the password of --user when no --password-file is given.
PASSWORD_ENV = "DRONESIM_PASSWORD"


def _existing(path: str, flag: str) -> str:
    import os

    if not os.path.isfile(path):
        if flag == "--password-file":  # never echo it: it may be a password typed as `--password SECRET`
            raise UsageError("--password-file: no such file (it takes the path of a file holding the password)")
        raise UsageError(f"{flag} {path}: no such file")
    return os.path.abspath(path)


def apply_security(conf: zenoh.Config, args: argparse.Namespace, *, router: bool | None = None) -> None:
    """The security flags (TLS, mutual TLS, user/password, a router's dictionary and ACL) into `conf`.

    A client's --tls-cert/--tls-key are presented to the router (mutual TLS); a router's are its server
    certificate, and --tls-mtls makes it require clients' ones. `router` defaults to the config's mode."""
    get = lambda name: getattr(args, name, None)  # noqa: E731 -- parsers without these flags
    tls = "transport/link/tls/"
    if router is None:
        mode = get("mode") or json.loads(conf.get_json("mode") or "null")
        router = mode == "router"
    if get("tls_ca"):
        conf.insert_json5(tls + "root_ca_certificate", json.dumps(_existing(args.tls_ca, "--tls-ca")))
    if bool(get("tls_cert")) != bool(get("tls_key")):
        raise UsageError("--tls-cert and --tls-key go together")
    if get("tls_cert"):
        cert, key = _existing(args.tls_cert, "--tls-cert"), _existing(args.tls_key, "--tls-key")
        for side in ("listen", "connect"):
            conf.insert_json5(f"{tls}{side}_certificate", json.dumps(cert))
            conf.insert_json5(f"{tls}{side}_private_key", json.dumps(key))
        if not router:
            conf.insert_json5(tls + "enable_mtls", "true")  # a client presents its certificate only then
    if get("tls_mtls"):
        conf.insert_json5(tls + "enable_mtls", "true")
    password = None
    if get("password_file"):
        with open(_existing(args.password_file, "--password-file"), encoding="utf-8") as f:
            password = f.readline().rstrip("\r\n")
        if not password:
            raise UsageError(f"--password-file {args.password_file}: its first line is empty")
    elif get("user"):
        import os

        password = os.environ.get(PASSWORD_ENV) or None
    if get("user"):
        if password is None:
            raise UsageError(f"--user {args.user} needs --password-file FILE or the {PASSWORD_ENV} environment variable")
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(args.user))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    elif get("password_file"):
        raise UsageError("--password-file needs --user NAME")
    if get("users_file"):
        conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(_existing(args.users_file, "--users-file")))
    if get("acl"):
        try:
            block = zenoh.Config.from_file(_existing(args.acl, "--acl")).get_json("access_control")
        except Exception as exc:
            raise UsageError(f"cannot load --acl {args.acl}: {exc}") from None
        if not json.loads(block).get("enabled"):
            raise UsageError(f"--acl {args.acl}: its access_control block is missing or not enabled")
        conf.insert_json5("access_control", block)


def setup_logging(level: str, name: str) -> logging.Logger:
    """Entry points only: configure logging to stderr, prefixed with the process's role."""
    logging.basicConfig(level=level.upper(), format=f"%(asctime)s {name} %(levelname)s %(message)s",
                        datefmt="%H:%M:%S")
    return logging.getLogger(f"dronesim.{name}")


def _local_defaults() -> zenoh.Config:
    """A config with this project's defaults (see `zenoh_config`): no multicast scouting, no shared memory."""
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/shared_memory/enabled", "false")
    return conf


def router_config(listen: str = "tcp/127.0.0.1:0") -> zenoh.Config:
    """An embedded router's config: fast start, no multicast, admin space readable (for its port)."""
    conf = _local_defaults()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([listen]))
    conf.insert_json5("scouting/delay", "0")
    conf.insert_json5("adminspace", '{"enabled": true, "permissions": {"read": true, "write": false}}')
    return conf


def client_config(locator: str) -> zenoh.Config:
    """A client session's config for one router endpoint: no multicast, fast start."""
    conf = _local_defaults()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([locator]))
    conf.insert_json5("scouting/delay", "0")
    return conf


def router_locators(session: zenoh.Session) -> list[str]:
    """The endpoints a router session really listens on (with the port chosen for `:0`)."""
    zid = str(session.info.zid())
    for reply in session.get(f"@/{zid}/router", timeout=5.0):
        if reply.ok is not None:
            return list(json.loads(reply.ok.payload.to_bytes())["locators"])
    raise UsageError("the router did not report its locators")


# --------------------------------------------------------------------------- inbox


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


def _direct(callback: Callable[[object], None]) -> zenoh.handlers.Callback:
    """Run `callback` on Zenoh's receiving thread itself. By default zenoh-python hands each Python
    callback to a thread of its own, and then messages on different keys overtake each other on their
    way into the inbox; our callbacks decode and enqueue (or, under `Inbox.run`, handle the event), so they
    run in place, in order."""
    return zenoh.handlers.Callback(callback, indirect=False)


_EVERY_REPLY = zenoh.QueryConsolidation(zenoh.ConsolidationMode.NONE)


def _answer(key: str, reply: zenoh.Reply, expect: type[Message] | tuple[type[Message], ...]) -> Message:
    """A query's reply, decoded (RemoteInputError on an error reply or a malformed one)."""
    if reply.ok is None:
        raise RemoteInputError(f"{key} answered an error: {reply.err.payload.to_bytes().decode(errors='replace')}",
                               reason="error-reply")
    return decode(reply.ok.payload.to_bytes(), expect)


#: Games of at most this many drones have their turn's messages handled on Zenoh's thread (`Inbox.run`'s
#: `inline`): a small game's turn is mostly handoffs between threads. A big game's messages, and the work
#: they cause, are big: done on Zenoh's threads (which come and go, each with its own allocator arena) they
#: grow a process's resident memory by about 1 KiB per drone, for a handoff that is a small share of its turn.
INLINE_FLEET = 32


def inline_for(drones: int) -> Callable[[object], bool]:
    """`Inbox.run`'s `inline` for a game of `drones` drones: its received messages, if the game is small."""
    small = drones <= INLINE_FLEET
    return lambda event: small and isinstance(event, Received)


def _due(left: float | None) -> bool:
    return left is not None and left <= 0.0


_WAKE = object()  # not an event: makes `Inbox.run`'s thread look at its deadline and its end again


class Inbox:
    """Decoded events from Zenoh callbacks, for one consuming thread; rejections are counted.

    The events are taken one at a time, in order of arrival, by `get` or by `run`'s handler. With `run`,
    an event that finds nothing queued and nobody handling one is handled at once on the Zenoh thread
    that brought it: a turn's hot message then costs no handoff to the main thread (two thread wake-ups).
    """

    def __init__(self, session: zenoh.Session, keys: Keys, logger: logging.Logger) -> None:
        self.session = session
        self.keys = keys
        self.log = logger
        self.rejects = RejectCounter(logger)
        self._q: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self._handles: list[object] = []
        self._handling = threading.Lock()  # held by whichever thread handles an event in `run`
        self._queueing = threading.Lock()  # an event is queued and counted together
        self._pending = 0  # events queued and not yet handled
        self._handler: Callable[[Event], None] | None = None  # `run`'s handler, for events handled in place
        self._resume_by = float("inf")  # when `run`'s thread wakes up at the latest (monotonic)
        self._next: Callable[[], float | None] = lambda: None
        self._until: Callable[[], bool] = lambda: False
        self._inline: Callable[[Event], bool] = lambda event: True
        self._failure: BaseException | None = None
        self._back: list[Event] = []  # the one event `run` took after its end, for `get`

    def _deliver(self, event: Event) -> None:
        """A new event: handled here and now (see the class), or queued."""
        handler = self._handler
        if handler is not None and not self._pending and self._handling.acquire(blocking=False):
            try:
                if not self._pending and self._handler is not None and self._inline(event) and not self._until():
                    self._handle_here(handler, event)
                    return
            finally:
                self._handling.release()
        with self._queueing:
            self._pending += 1
            self._q.put(event)

    def _handle_here(self, handler: Callable[[Event], None], event: Event) -> None:
        try:
            handler(event)
        except BaseException as exc:  # `run` raises it on its own thread, as if it had handled the event
            self._failure, self._handler = exc, None
            self._q.put(_WAKE)  # type: ignore[arg-type]
            return
        due = self._next()
        if self._until() or (due is not None and time.monotonic() + due < self._resume_by):
            self._q.put(_WAKE)  # type: ignore[arg-type]

    def run(self, handler: Callable[[Event | None], None], *, timeout: Callable[[], float | None],
            until: Callable[[], bool], inline: Callable[[Event], bool] = lambda event: True) -> None:
        """Hand every event to `handler` (None when `timeout()` seconds pass without one) until `until()`;
        events are handled one at a time, in order of arrival, on this thread or, for those `inline`
        allows, on Zenoh's (see the class). There `handler` must not wait for another message (no
        blocking query: Zenoh's thread would not bring its answer); an exception it raises there is
        raised here."""
        self._next, self._until, self._inline = timeout, until, inline
        self._handler = handler
        try:
            while True:
                with self._handling:  # (an event handled meanwhile on Zenoh's thread sees when this one wakes)
                    if self._failure is not None:
                        raise self._failure
                    if until():
                        break
                    wait = timeout()
                    self._resume_by = float("inf") if wait is None else time.monotonic() + wait
                try:
                    event = self._q.get(timeout=wait)
                except queue.Empty:
                    event = None
                if event is _WAKE:
                    continue
                with self._handling:
                    if self._failure is not None:
                        raise self._failure
                    if until():  # it came after the end: for the next `get`
                        if event is not None:
                            self._back.append(event)
                        break
                    if event is None and not _due(timeout()):  # events handled on Zenoh's thread while
                        continue  # this one waited have moved its deadline on (or away)
                    handler(event)
                    if event is not None:
                        with self._queueing:
                            self._pending -= 1
                event = None  # not kept while waiting: a swarm's MOVES is thousands of records
        finally:
            self._handler = None
            self._resume_by = float("inf")

    # callbacks (Zenoh threads): decode, validate, enqueue; never raise
    def _guard(self, where: str, fn: Callable[[], None]) -> None:
        try:
            fn()
        except RemoteInputError as err:
            self.rejects.reject(where, err)
        except Exception:  # a bug: log it, never let Zenoh swallow it silently
            self.log.exception("error handling %s", where)

    def subscribe(self, key: str, expect: type[Message] | tuple[type[Message], ...]) -> zenoh.Subscriber:
        """Decoded messages on `key` become `Received` events (until `unsubscribe`)."""
        def on_sample(sample: zenoh.Sample) -> None:
            k = str(sample.key_expr)

            def handle() -> None:
                msg = decode(sample.payload.to_bytes(), expect)
                check_addressed(self.keys, k, msg)
                self._deliver(Received(k, msg))

            self._guard(k, handle)

        sub = self.session.declare_subscriber(key, _direct(on_sample))
        self._handles.append(sub)
        return sub

    def unsubscribe(self, sub: zenoh.Subscriber) -> None:
        sub.undeclare()
        self._handles.remove(sub)

    def serve(self, key: str, expect: type[Message], *, inline: Callable[[zenoh.Query, Message], bool] | None = None) -> None:
        """Declare a queryable; valid queries become `Asked` events (or are answered by `inline`
        on Zenoh's thread when it returns True), malformed ones get an error reply at once."""

        def on_query(query: zenoh.Query) -> None:
            def handle() -> None:
                payload = query.payload
                if payload is None:
                    raise RemoteInputError(f"query on {key} without payload", reason="malformed")
                msg = decode(payload.to_bytes(), expect)
                if inline is None or not inline(query, msg):
                    self._deliver(Asked(query, msg))

            try:
                handle()
            except RemoteInputError as err:
                self.rejects.reject(key, err)
                query.reply_err(str(err).encode())
                query.drop()
            except Exception:
                self.log.exception("error handling a query on %s", key)
                query.reply_err(b"internal error")
                query.drop()

        self._handles.append(self.session.declare_queryable(key, _direct(on_query), complete=True))

    def fetch(self, key: str, msg: Message, expect: type[Message], *, timeout: float) -> None:
        """One query, not waited for: its valid reply becomes a `Received` event (on `key`); an error
        reply or a malformed one is counted as a rejection, and no reply is no event."""

        def on_reply(reply: zenoh.Reply) -> None:
            def handle() -> None:
                got = _answer(key, reply, expect)
                check_addressed(self.keys, key, got)
                self._deliver(Received(key, got))

            self._guard(key, handle)

        self.session.get(key, _direct(on_reply), payload=encode(msg), timeout=timeout, consolidation=_EVERY_REPLY)

    def watch_presence(self, entity: str | None = None) -> None:
        """Presence events for every process (or only `entity`'s), starting with those already there."""

        def on_token(sample: zenoh.Sample) -> None:
            def handle() -> None:
                who, session = self.keys.presence_of(str(sample.key_expr))
                self._deliver(Presence(who, session, sample.kind == zenoh.SampleKind.PUT))

            self._guard(str(sample.key_expr), handle)

        key = self.keys.any_alive if entity is None else self.keys.alive_of(entity)
        self._handles.append(self.session.liveliness().declare_subscriber(key, _direct(on_token), history=True))

    def post(self, event: object) -> None:
        """Queue an event from another thread of this process (e.g. a web request for the main loop)."""
        self._deliver(event)  # type: ignore[arg-type]

    def drain(self) -> list[Event]:
        """Every event already queued, without waiting."""
        out: list[Event] = [self._taken(self._back.pop())] if self._back else []
        while True:
            try:
                out.append(self._taken(self._q.get_nowait()))
            except queue.Empty:
                return [e for e in out if e is not _WAKE]

    def get(self, timeout: float | None = None) -> Event | None:
        """The next event, or None when `timeout` seconds pass first."""
        if self._back:
            return self._taken(self._back.pop())
        end = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                event = self._q.get(timeout=None if end is None else max(0.0, end - time.monotonic()))
            except queue.Empty:
                return None
            if event is not _WAKE:
                return self._taken(event)

    def _taken(self, event: Event) -> Event:
        if event is not _WAKE:
            with self._queueing:
                self._pending -= 1
        return event


class Outbox:
    """Publishes messages with BLOCK congestion control (control messages must not be dropped)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._listeners: list[zenoh.MatchingListener] = []

    def _pub(self, key: str) -> zenoh.Publisher:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                                 reliability=zenoh.Reliability.RELIABLE)
            self._pubs[key] = pub
        return pub

    def put(self, key: str, msg: Message, data: bytes | None = None) -> None:
        """Publish `msg` (`data`: its encoding, if the caller already has it)."""
        self._pub(key).put(encode(msg) if data is None else data)

    def matching(self, key: str) -> bool:
        """Does anyone subscribe to `key` now?"""
        return self._pub(key).matching_status.matching

    def watch(self, key: str, inbox: Inbox) -> None:
        """A `Matching` event in `inbox` each time someone starts or stops subscribing to `key` (the
        first, at once, if someone already does)."""
        def on_status(status: zenoh.MatchingStatus) -> None:
            inbox.post(Matching(key, status.matching))

        self._listeners.append(self._pub(key).declare_matching_listener(_direct(on_status)))


def request(session: zenoh.Session, key: str, msg: Message, expect: type[Message] | tuple[type[Message], ...],
            timeout: float) -> Message:
    """One query, one valid reply (raises RemoteInputError on an error reply, TimeoutError on none)."""
    for reply in session.get(key, payload=encode(msg), timeout=timeout, consolidation=_EVERY_REPLY):
        return _answer(key, reply, expect)
    raise TimeoutError(f"no answer on {key} within {timeout:.1f} s")


def wait_for(what: str, predicate: Callable[[], bool], inbox_get: Callable[[float], object], timeout: float) -> None:
    """Block on events until `predicate()` holds (no sleeping); UsageError after `timeout`."""
    end = time.monotonic() + timeout
    while not predicate():
        left = end - time.monotonic()
        if left <= 0:
            raise UsageError(f"timed out waiting for {what}")
        inbox_get(left)
