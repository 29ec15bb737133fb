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
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from dronesim.schema import Keys, Message, RejectCounter, RemoteInputError, Target, UsageError, decode, encode
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


def zenoh_config(args: argparse.Namespace) -> zenoh.Config:
    """A zenoh.Config from the conventional flags. Multicast scouting is off unless a config file
    turns it on: endpoints are explicit, so parallel runs never cross-talk."""
    if args.config:
        try:
            conf = zenoh.Config.from_file(args.config)
        except Exception as exc:
            raise UsageError(f"cannot load zenoh config {args.config}: {exc}") from None
    else:
        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/delay", "0")
    if args.mode:
        conf.insert_json5("mode", json.dumps(args.mode))
    if args.connect:
        conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    if args.listen:
        conf.insert_json5("listen/endpoints", json.dumps(args.listen))
    if getattr(args, "lease", None):
        if args.lease <= 0:
            raise UsageError("--lease must be positive")
        conf.insert_json5("transport/link/tx/lease", str(int(args.lease * 1000)))
        conf.insert_json5("transport/link/tx/keep_alive", "4")  # keep-alives per lease, zenoh's default
    return conf


def setup_logging(level: str, name: str) -> logging.Logger:
    """Entry points only: configure logging to stderr, prefixed with the process's role."""
    logging.basicConfig(level=level.upper(), format=f"%(asctime)s {name} %(levelname)s %(message)s",
                        datefmt="%H:%M:%S")
    return logging.getLogger(f"dronesim.{name}")


def router_config(listen: str = "tcp/127.0.0.1:0") -> zenoh.Config:
    """An embedded router's config: fast start, no multicast, admin space readable (for its port)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([listen]))
    conf.insert_json5("scouting/delay", "0")
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("adminspace", '{"enabled": true, "permissions": {"read": true, "write": false}}')
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


Event = Received | Asked | Presence


def session_id(session: zenoh.Session) -> str:
    return str(session.info.zid())


def check_addressed(keys: Keys, key: str, msg: Message) -> None:
    """The entity part of a key must be the message's subject: its drone for TGT, else its sender."""
    subject = msg.drone if isinstance(msg, Target) else msg.sender
    entity = keys.entity_of(key)
    if entity != subject:
        raise WrongSender(f"a {msg.TAG} about {subject} on {entity}'s key {key}")


class Inbox:
    """Decoded events from Zenoh callbacks, for one consuming thread; rejections are counted."""

    def __init__(self, session: zenoh.Session, keys: Keys, logger: logging.Logger) -> None:
        self.session = session
        self.keys = keys
        self.log = logger
        self.rejects = RejectCounter(logger)
        self._q: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self._handles: list[object] = []

    # callbacks (Zenoh threads): decode, validate, enqueue; never raise
    def _guard(self, where: str, fn: Callable[[], None]) -> None:
        try:
            fn()
        except RemoteInputError as err:
            self.rejects.reject(where, err)
        except Exception:  # a bug: log it, never let Zenoh swallow it silently
            self.log.exception("error handling %s", where)

    def subscribe(self, key: str, expect: type[Message] | tuple[type[Message], ...]) -> None:
        def on_sample(sample: zenoh.Sample) -> None:
            k = str(sample.key_expr)

            def handle() -> None:
                msg = decode(sample.payload.to_bytes(), expect)
                check_addressed(self.keys, k, msg)
                self._q.put(Received(k, msg))

            self._guard(k, handle)

        self._handles.append(self.session.declare_subscriber(key, on_sample))

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
                    self._q.put(Asked(query, msg))

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

        self._handles.append(self.session.declare_queryable(key, on_query, complete=True))

    def watch_presence(self, entity: str | None = None) -> None:
        """Presence events for every process (or only `entity`'s), starting with those already there."""

        def on_token(sample: zenoh.Sample) -> None:
            def handle() -> None:
                who, session = self.keys.presence_of(str(sample.key_expr))
                self._q.put(Presence(who, session, sample.kind == zenoh.SampleKind.PUT))

            self._guard(str(sample.key_expr), handle)

        key = self.keys.any_alive if entity is None else self.keys.alive_of(entity)
        self._handles.append(self.session.liveliness().declare_subscriber(key, on_token, history=True))

    def get(self, timeout: float | None = None) -> Event | None:
        """The next event, or None when `timeout` seconds pass first."""
        try:
            return self._q.get(timeout=timeout)
        except queue.Empty:
            return None


class Outbox:
    """Publishes messages with BLOCK congestion control (control messages must not be dropped)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self._pubs: dict[str, zenoh.Publisher] = {}

    def put(self, key: str, msg: Message) -> None:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                                 reliability=zenoh.Reliability.RELIABLE)
            self._pubs[key] = pub
        pub.put(encode(msg))


def request(session: zenoh.Session, key: str, msg: Message, expect: type[Message] | tuple[type[Message], ...],
            timeout: float) -> Message:
    """One query, one valid reply (raises RemoteInputError on an error reply, TimeoutError on none)."""
    replies = session.get(key, payload=encode(msg), timeout=timeout,
                          consolidation=zenoh.QueryConsolidation(zenoh.ConsolidationMode.NONE))
    for reply in replies:
        if reply.ok is not None:
            return decode(reply.ok.payload.to_bytes(), expect)
        raise RemoteInputError(f"{key} answered an error: {reply.err.payload.to_bytes().decode(errors='replace')}",
                               reason="error-reply")
    raise TimeoutError(f"no answer on {key} within {timeout:.1f} s")


def wait_for(what: str, predicate: Callable[[], bool], inbox_get: Callable[[float], object], timeout: float) -> None:
    """Block on events until `predicate()` holds (no sleeping); UsageError after `timeout`."""
    end = time.monotonic() + timeout
    while not predicate():
        left = end - time.monotonic()
        if left <= 0:
            raise UsageError(f"timed out waiting for {what}")
        inbox_get(left)
