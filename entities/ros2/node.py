"""``dronesim ros2``: the game as ROS 2 topics over the game's own Zenoh router (rmw_zenoh's wire format), and as a
live Foxglove WebSocket server with ``--foxglove [HOST:]PORT``. See docs/ros2.md.

It is an observer: it hears STATUS and OVER as a ground station does, asks the environment for the map (ENV/MAP,
a read), and never writes to the game. It publishes each turn while the game goes no faster than ``--rate``,
else the newest turn at that rate (Zenoh keeps only the newest STATUS for it: nothing queues; the turns it
skipped are counted), with congestion control DROP: a slow or absent ROS 2 subscriber never slows the game.

`RosGraph` is our node in ROS 2's graph: its liveliness tokens, its publishers (rmw_zenoh's attachment on every
sample) and its goal subscriptions, also used by the ground station's ROS 2 face (`dronesim gcs --ros2`).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import logging
import signal
import struct
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import numpy as np
import zenoh
import zenoh.ext

from network.signals import until_stopped, waking
from network.transport import Inbox, Newest, Received, add_zenoh_args, open_session, setup_logging, zenoh_config
from schema import Cell, Keys, MapRequest, Over, RemoteInputError, Status, UsageError, WorldMap
from schema.keys import RosKeys
from schema.tuning import (
    FINAL_STATUS_WAIT,
    ROS_CPU_SHARE,
    ROS_GOAL_BYTES,
    ROS_LISTEN_GAP,
    ROS_MAP_RETRY,
    ROS_PATH_PERIOD,
    ROS_RATE,
    ROS_SLOWEST,
)
from world.grid import CELL_SIZE_M

from ..gcs import OBSERVED_ENDS, Ground
from .cdr import type_hash
from .goals import Goal, Goals, reason
from .model import NAMESPACE, POSE, TURN_PERIOD_S, Out, Outs, Scene, Snapshot, drone_topic

#: The ROS 2 node the viewer is in the graph (`ros2 node list`), whose token tells it is there.
NODE = "dronesim"

#: rmw_zenoh's QoS strings (reliability:durability:history,depth:deadline:lifespan:liveliness), for the tokens.
QOS_TELEMETRY = "2:2:1,1:,:,:,,"  # best effort, volatile, keep last 1
QOS_LATCHED = "1:1:1,1:,:,:,,"  # reliable, transient local, keep last 1
QOS_GOALS = "1:2:1,10:,:,:,,"  # reliable, volatile, keep last 10

#: The signals that detach the viewer from the game and attach it again (POSIX only): detached, it is subscribed
#: to no STATUS (Zenoh sends it none) and publishes nothing, its node and publishers staying in ROS 2's graph; once
#: attached it publishes the newest turn again. A user's pause; `dronesim bench perf` measures the viewer's cost
#: with it, attached and detached in alternate windows of one game.
DETACH, ATTACH = getattr(signal, "SIGUSR1", None), getattr(signal, "SIGUSR2", None)


def add_ros2_args(parser: argparse.ArgumentParser, *, viewer: bool = True) -> None:
    g = parser.add_argument_group("ROS 2 (docs/ros2.md)")
    g.add_argument("--domain", type=int, default=0, help="the ROS 2 domain id (ROS_DOMAIN_ID; default 0)")
    g.add_argument("--namespace", default=NAMESPACE, help=f"prefix of the drones' topics (default {NAMESPACE})")
    g.add_argument("--cell-size", type=float, default=CELL_SIZE_M, help=f"metres a cell (default {CELL_SIZE_M})")
    if viewer:
        g.add_argument("--turn-period", type=float, default=TURN_PERIOD_S,
                       help=f"simulated seconds a turn, the stamps' and /clock's (default {TURN_PERIOD_S})")
        g.add_argument("--rate", type=float, default=ROS_RATE,
                       help=f"turns a second at most published; faster games are sampled (default {ROS_RATE:g})")
        g.add_argument("--foxglove", metavar="[HOST:]PORT",
                       help="also serve the game live to Foxglove on this WebSocket address (host 127.0.0.1 unless "
                            "given; port 0: any free port)")


def scene_of(args: argparse.Namespace) -> Scene:
    try:
        return Scene(namespace=args.namespace, cell_size=args.cell_size, turn_period=args.turn_period)
    except ValueError as err:
        raise UsageError(str(err)) from None


def ros_keys(args: argparse.Namespace) -> RosKeys:
    try:
        return RosKeys(args.domain)
    except ValueError as err:
        raise UsageError(str(err)) from None


#: rmw_zenoh's attachment: sequence number, source timestamp (ns), then the publisher's gid (its length, 16 bytes).
_ATTACHMENT = struct.Struct("<QQB16s")


def _gid(zid: str, entity: int) -> bytes:
    """An endpoint's 16-byte id, as rmw_zenoh sends in its attachment: derived from the session and entity ids."""
    return hashlib.blake2b(f"{zid}/{entity}".encode(), digest_size=16).digest()


@dataclass(slots=True)
class _Publisher:
    pub: Any  # zenoh.Publisher or zenoh.ext.AdvancedPublisher
    token: zenoh.LivelinessToken
    gid: bytes
    seq: int = 0
    matching: bool = True  # telemetry: someone subscribes (kept by a matching listener: asking Zenoh at each put
    # costs several µs, a swarm's turn is thousands of puts)
    listener: Any = None

    def heard(self, status: Any) -> None:
        self.matching = status.matching  # (on Zenoh's thread)


class RosGraph:
    """A ROS 2 node over Zenoh, as rmw_zenoh makes one: a node token, and per topic a publisher with its token
    (declared on first use; telemetry best effort with congestion control DROP; a latched topic keeps its last
    sample for late joiners, as a transient-local publisher does) or a subscription with its token."""

    def __init__(self, session: zenoh.Session, keys: RosKeys, node: str, namespace: str = "/") -> None:
        self.session, self.keys, self.node, self.namespace = session, keys, node, namespace
        self.zid = str(session.info.zid())
        self._node_token = session.liveliness().declare_token(keys.node_token(self.zid, 0, namespace, node))
        self._entities = 0
        self._pubs: dict[tuple[str, bool], _Publisher] = {}
        self._handles: list[Any] = []
        self.sent = 0
        self.unheard = 0  # telemetry not sent: nobody subscribed to its topic

    def _entity(self) -> int:
        self._entities += 1
        return self._entities

    def _token(self, kind: str, entity: int, topic: str, typename: str, qos: str) -> zenoh.LivelinessToken:
        key = self.keys.endpoint_token(self.zid, 0, entity, kind, self.namespace, self.node, topic, typename,
                                       type_hash(typename), qos)
        return self.session.liveliness().declare_token(key)

    def _publisher(self, topic: str, typename: str, latched: bool) -> _Publisher:
        if (p := self._pubs.get((topic, latched))) is None:
            entity, key = self._entity(), self.keys.topic(topic, typename, type_hash(typename))
            if latched:
                pub: Any = zenoh.ext.declare_advanced_publisher(
                    self.session, key, encoding=zenoh.Encoding("application/cdr"), cache=zenoh.ext.CacheConfig(1),
                    publisher_detection=True, reliability=zenoh.Reliability.RELIABLE)
            else:
                pub = self.session.declare_publisher(key, encoding=zenoh.Encoding("application/cdr"),
                                                     congestion_control=zenoh.CongestionControl.DROP,
                                                     reliability=zenoh.Reliability.BEST_EFFORT)
            token = self._token(self.keys.PUBLISHER, entity, topic, typename, QOS_LATCHED if latched else QOS_TELEMETRY)
            p = self._pubs[(topic, latched)] = _Publisher(pub, token, _gid(self.zid, entity))
            if not latched:
                p.listener = pub.declare_matching_listener(p.heard)
                p.matching = pub.matching_status.matching  # (a change from here on reaches the listener)
        return p

    def publish(self, out: Out, *, latched: bool = False) -> None:
        """Publish `out` (telemetry: only if someone subscribes to its topic; a latched sample always, for later)."""
        self.publish_all([out.topic], [out.typename], [out.payload], latched=latched)

    def publish_all(self, topics: Sequence[str], typenames: Sequence[str], payloads: Sequence[bytes], *,
                    latched: bool = False) -> None:
        """`publish` each (topic, type, payload), stamped alike: a swarm's turn is thousands of them (a loop of
        lookups and puts, nothing else)."""
        pubs, pack, now, sent = self._pubs, _ATTACHMENT.pack, time.time_ns(), 0
        for topic, typename, payload in zip(topics, typenames, payloads):
            if (p := pubs.get((topic, latched))) is None:
                p = self._publisher(topic, typename, latched)
            if not (latched or p.matching):
                self.unheard += 1
                continue
            p.pub.put(payload, attachment=pack(p.seq, now, 16, p.gid))
            p.seq += 1
            sent += 1
        self.sent += sent

    def subscribe(self, topics: dict[str, str], typename: str, on: Callable[[str, bytes], None]) -> None:
        """Subscribe to each of `topics` (topic -> what `on` is told it came for) with a token each, through one
        Zenoh subscriber on their keys' common pattern: `on(what, payload)` on Zenoh's thread."""
        by_key = {self.keys.topic(t, typename, type_hash(typename)): what for t, what in topics.items()}
        for topic in topics:
            self._handles.append(self._token(self.keys.SUBSCRIPTION, self._entity(), topic, typename, QOS_GOALS))

        def on_sample(sample: zenoh.Sample) -> None:
            what = by_key.get(str(sample.key_expr))
            if what is not None:
                on(what, sample.payload.to_bytes())

        for key in by_key:
            self._handles.append(self.session.declare_subscriber(key, on_sample))

    def close(self) -> None:
        for p in self._pubs.values():
            if p.listener is not None:
                p.listener.undeclare()
            p.token.undeclare()
            p.pub.undeclare()
        for h in self._handles:
            h.undeclare()
        self._node_token.undeclare()
        self._pubs, self._handles = {}, []


def take_goals(args: argparse.Namespace, session: zenoh.Session, inbox: Inbox, ground: Ground,
               set_target: Callable[[str, Cell], object], say: Callable[[str], None],
               logger: logging.Logger) -> Callable[[object], bool]:
    """ROS 2 goals as a ground station's targets, whatever its face (terminal, web page): each drone's goal topic
    is subscribed (`args`: the ROS 2 flags), each goal posted to `inbox`. Returns the handler of the inbox's
    events: a goal is read (`Goals`) and, if it is one, `set_target(drone, cell)` (which may refuse it too, with
    a UsageError); what became of it is logged and `say`-ed (a refusal counted by reason). True for a goal."""
    goals = Goals(ground.world, frozenset(ground.starts), args.cell_size)
    graph = RosGraph(session, ros_keys(args), "dronesim_gcs")
    topic = {d: drone_topic(args.namespace, d, "goal_pose") for d in ground.starts}

    def heard(drone: str, payload: bytes) -> None:  # (on Zenoh's thread: each drone's goals a budget of their own)
        inbox.post_from(topic[drone], f"ros2/{drone}", Goal(drone, payload), len(payload), ROS_GOAL_BYTES)

    graph.subscribe({t: d for d, t in topic.items()}, POSE, heard)
    logger.info("taking ROS 2 goals on %s, domain %d", drone_topic(args.namespace, "<Dnn>", "goal_pose"), args.domain)

    def refused(drone: str, err: UsageError) -> bool:
        why = RemoteInputError(str(err), reason=reason(err).replace(" ", "-"))
        if inbox.rejects.reject(topic[drone], why, f"ros2/{drone}"):  # (a flood's: a few, then a summary)
            say(f"refused a ROS 2 goal for {drone}: {err} (refused so far: {dict(goals.refused)})")
        return True

    def take(event: object) -> bool:
        if not isinstance(event, Goal):
            return False
        try:
            drone, cell = goals.read(event)
        except UsageError as err:
            return refused(event.drone, err)
        try:
            set_target(drone, cell)
        except UsageError as err:
            goals.refuse(err)
            return refused(drone, err)
        logger.info("ROS 2 goal: %s -> %s", drone, cell)
        say(f"ROS 2 goal: {drone} -> {cell}")
        return True
    return take


@dataclass(frozen=True, slots=True)
class MapAnswer:
    """The environment's replies to our MAP query (none: nobody answered)."""

    replies: tuple


def world_grid(reply: WorldMap) -> np.ndarray:
    size = reply.size
    bits = np.unpackbits(np.frombuffer(reply.buildings, np.uint8))[:size[0] * size[1] * size[2]]
    return bits.reshape(size).astype(bool)


class Sink(Protocol):
    """Where a game's messages go: the world's (once) and each turn's."""

    def world(self, grid: np.ndarray, outs: Outs) -> None: ...
    def turn(self, snap: Snapshot, outs: Outs) -> None: ...


class RosSink:
    """A game's messages to ROS 2: the buildings latched, the rest telemetry."""

    def __init__(self, graph: RosGraph) -> None:
        self.graph = graph

    def world(self, grid: np.ndarray, outs: Outs) -> None:
        self.graph.publish_all(outs.topics, outs.typenames, outs.payloads, latched=True)

    def turn(self, snap: Snapshot, outs: Outs) -> None:
        self.graph.publish_all(outs.topics, outs.typenames, outs.payloads)


class Viewer:
    """What `dronesim ros2` does with what it hears, given where its messages go (`sinks`): pure of the network
    but for the sinks. Times are seconds of any monotonic clock."""

    def __init__(self, scene: Scene, sinks: list[Sink], *, rate: float, logger: logging.Logger,
                 cpu: Callable[[], float] = time.process_time) -> None:
        if not (np.isfinite(rate) and rate > 0):
            raise UsageError(f"--rate must be > 0, got {rate!r}")
        self.scene, self.sinks, self.period, self.log, self.cpu = scene, sinks, 1.0 / rate, logger, cpu
        self.turn = -1  # the last turn published
        self.published = 0  # turns published
        self.skipped = 0  # turns not published since the first (a newer STATUS had come, or it was not listening)
        self.due = 0.0  # when to look for the newest STATUS again
        self.paths_due = 0.0
        self.over: Over | None = None
        self.over_since = 0.0
        self.missed_last = False  # OVER came while the viewer was not listening: the last turn's STATUS went by
        self.have_map = False

    def world(self, grid: np.ndarray) -> None:
        self.have_map = True
        outs = self.scene.buildings(grid)
        for sink in self.sinks:
            sink.world(grid, outs)

    def tick(self, now: float, newest: Callable[[], Received | None]) -> None:
        """When due: the newest STATUS, if one came since the last look. Due again a period later, or later still
        after a turn that cost much CPU (`ROS_CPU_SHARE`, at most `ROS_SLOWEST` s): the viewer of a swarm takes a
        bounded share of the machine, whatever the game's speed."""
        if now < self.due:
            return
        spent = self.cpu()
        if (got := newest()) is not None and isinstance(got.msg, Status):
            self.status(got.msg, now)
        self.due = now + min(max(self.period, (self.cpu() - spent) / ROS_CPU_SHARE), max(self.period, ROS_SLOWEST))

    def status(self, status: Status, now: float) -> None:
        if status.turn <= self.turn:
            return
        paths = now >= self.paths_due or self._final(status.turn)
        snap = Snapshot.of_status(status)
        outs = self.scene.turn(snap, paths=paths)
        for sink in self.sinks:
            sink.turn(snap, outs)
        self.skipped += status.turn - self.turn - 1 if self.published else 0
        self.published += 1
        self.turn = status.turn
        if paths:
            self.paths_due = now + ROS_PATH_PERIOD

    def _final(self, turn: int) -> bool:
        return self.over is not None and turn >= self.over.turn

    def ended(self, now: float) -> bool:
        """After OVER, once the last turn's STATUS went out (or `FINAL_STATUS_WAIT` s after OVER)."""
        over = self.over
        return over is not None and (self.turn >= over.turn or over.reason not in OBSERVED_ENDS or self.missed_last
                                     or now >= self.over_since + FINAL_STATUS_WAIT)


@contextlib.contextmanager
def attaching(wanted: list[bool]) -> Iterator[None]:
    """While inside (on the main thread): `DETACH` sets ``wanted[0]`` False, `ATTACH` True; the previous handlers
    come back on leaving. (Inside `waking`, a signal also wakes the loop.)"""
    def on(signum: int, _frame: object) -> None:
        wanted[0] = signum == ATTACH

    previous = {s: signal.signal(s, on) for s in (DETACH, ATTACH) if s is not None}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def listen(viewer: Viewer, newest: Newest | None, now: float, attached: bool,
           subscribe: Callable[[], Newest]) -> Newest | None:
    """The viewer's turn, if one is due, and its STATUS subscription (`newest`, None: none) as it is after it.
    Zenoh sends the viewer the game's STATUS only while it listens: from when a turn is due until it has published
    one, and on while it is due again within `ROS_LISTEN_GAP` s (a small game's viewer, publishing at `ROS_RATE`,
    always listens). A swarm's viewer, publishing about once a second, thus hears a few STATUS a second, not every
    one (at 1000 drones, some 150 of 20 KB a second that the router would copy to it and it would take in: 3-5 % of
    a core). The price: the last turn's STATUS, sent just before OVER, is published only if it came while the viewer
    listened (a swarm's viewer then ends on OVER with a turn up to a second older, `Viewer.missed_last`)."""
    if not attached:
        if newest is not None:
            newest.close()
        return None
    if now < viewer.due:
        return newest
    if newest is None:  # the next STATUS to come is the newest: look a period later
        viewer.due = now + viewer.period
        return subscribe()
    viewer.tick(now, newest)
    if viewer.due - now >= ROS_LISTEN_GAP:
        newest.close()
        return None
    return newest


def run(args: argparse.Namespace, logger: logging.Logger) -> int:
    conf, keys, scene, ros = zenoh_config(args), Keys(args.root), scene_of(args), ros_keys(args)
    conf.insert_json5("timestamping/enabled", "true")  # a latched topic's cache orders its samples by timestamp
    fox = None
    if args.foxglove is not None:
        from .foxglove import FoxgloveLive

        fox = FoxgloveLive(args.foxglove, scene, logger,
                           opened=lambda url: print(f"ros2: foxglove on {url}", flush=True))
    with open_session(conf) as session:
        inbox = Inbox(session, keys, logger)
        inbox.subscribe(keys.over, Over)
        newest: Newest | None = None  # our STATUS subscription, declared only while a turn is due (see `listen`)
        graph = RosGraph(session, ros, NODE)
        sinks: list[Sink] = [RosSink(graph)]
        if fox is not None:
            sinks.append(fox)
        viewer = Viewer(scene, sinks, rate=args.rate, logger=logger)
        print(f"ros2: node /dronesim on domain {ros.domain}, topics under /{args.namespace.strip('/')}"
              + ("; foxglove from the first turn" if fox else ""), flush=True)
        map_due, wanted, attached, detached = 0.0, [True], True, 0
        try:
            with waking(partial(inbox.post, None)), attaching(wanted):
                while not viewer.ended(time.monotonic()):
                    now = time.monotonic()
                    if not viewer.have_map and now >= map_due:
                        map_due = now + ROS_MAP_RETRY
                        inbox.query(keys.map, MapRequest(turn=0, sender="OBS"), WorldMap, timeout=ROS_MAP_RETRY,
                                    then=MapAnswer)
                    due = viewer.due if attached else now + ROS_SLOWEST  # (detached: OVER's wait only)
                    event = inbox.get(max(0.0, min(due, map_due if not viewer.have_map else due) - now))
                    now = time.monotonic()
                    match event:
                        case Received(_, Over() as over) if viewer.over is None:
                            viewer.over, viewer.over_since = over, now
                            viewer.missed_last = newest is None and viewer.turn < over.turn  # (see `listen`)
                        case MapAnswer(replies) if not viewer.have_map:
                            for reply in replies:
                                if isinstance(reply, WorldMap):
                                    viewer.world(world_grid(reply))
                                    break
                    if wanted[0] != attached:
                        attached, detached = wanted[0], detached + (not wanted[0])
                        logger.info("attached: publishing the game again" if attached else
                                    "detached: no STATUS heard, nothing published until attached (SIGUSR2)")
                    newest = listen(viewer, newest, now, attached, lambda: inbox.newest(keys.status, Status))
        finally:
            graph.close()
            inbox.close()
            if fox is not None:
                fox.close()
    end = viewer.over
    print(f"ros2: published {graph.sent} messages of {viewer.published} turns up to turn {viewer.turn} "
          + ("(not the last: not listening when the game ended) " if viewer.missed_last else "")
          + f"({viewer.skipped} turns skipped: the game went faster, or detached; {graph.unheard} messages with no "
          "subscriber left unsent)" + (f"; detached {detached} times" if detached else "")
          + (f"; game over at turn {end.turn}: {end.reason.value}" if end else ""), flush=True)
    if inbox.rejects.total:
        logger.info("rejected inputs: %s", inbox.rejects.snapshot())
    return 0


def cli(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim ros2", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_zenoh_args(p)
    add_ros2_args(p)
    args = p.parse_args(argv)
    logger = setup_logging(args.log_level, "ROS2")
    try:
        return until_stopped(lambda: run(args, logger), logger)
    except UsageError as err:
        logger.error("%s", err)
        return 2


if __name__ == "__main__":
    sys.exit(cli())
