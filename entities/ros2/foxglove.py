"""The game for Foxglove (foxglove-sdk), live (a WebSocket server, subprotocol ``foxglove.sdk.v1``) or in an MCAP file:
the ROS 2 topics of `entities.ros2.model.Scene` and a Foxglove scene on ``/<namespace>/scene``, every channel a
``ros2msg`` schema with CDR payloads. The scene is ``foxglove_msgs/msg/SceneUpdate`` (Foxglove's scene as ROS 2
messages, `entities.ros2.foxglove_msgs`): the buildings as cubes, each drone a sphere in its own frame (moved by
``/tf``; in a file sent again only when its state changes, live every turn), each target a cube, each trail a line
strip (its last `SCENE_TRAIL` cells). An MCAP file of it is a ROS 2 bag as well (rosbags reads no protobuf schema).

A swarm's scene is made as its topics are: a layout per kind of entity and length of drone name (`cdr.Layout`,
the name a string field), filled for every drone that changed at once; a message per drone.
"""

from __future__ import annotations

import functools
import logging
import threading
from collections.abc import Callable, Mapping
from typing import Any

import foxglove
import numpy as np
from foxglove.websocket import ChannelView, Client, ServerListener

from .cdr import Layout, Repeated, make, msgdef, serialize
from .model import (
    BUILDING_COLOUR,
    COLOURS,
    FRAME,
    MARKERS,
    PATH,
    TARGET_COLOUR,
    Outs,
    Scene,
    Snapshot,
    drone_topic,
    rows_of,
)

SCENE = "foxglove_msgs/msg/SceneUpdate"
_ENTITY, _TIME = "foxglove_msgs/msg/SceneEntity", "builtin_interfaces/msg/Time"

#: Cells of a trail the scene draws (its last ones; a shorter trail starts with its first cell repeated).
SCENE_TRAIL = 50


def _colour(rgba: Any) -> Any:
    r, g, b, a = (float(v) for v in rgba)
    return make("foxglove_msgs/msg/Color", r=r, g=g, b=b, a=a)


def _size(s: float) -> Any:
    return make("geometry_msgs/msg/Vector3", x=s, y=s, z=s)


def _at(xyz: Any, i: int) -> Any:
    x, y, z = (float(v) for v in xyz[3 * i:3 * i + 3])
    return make("geometry_msgs/msg/Pose", position=make("geometry_msgs/msg/Point", x=x, y=y, z=z))


def _update(v: Mapping[str, np.ndarray], **entity: Any) -> Any:
    """A SceneUpdate of one entity stamped `v`'s sec and nsec (0 without them)."""
    stamp = make(_TIME, sec=int(v["sec"][0]), nanosec=int(v["nsec"][0])) if "sec" in v else make(_TIME)
    return make(SCENE, entities=[make(_ENTITY, timestamp=stamp, **entity)])


@functools.cache
def _layout(kind: str, width: int, cell_size: float) -> Layout:
    """A SceneUpdate of one entity of a drone whose name is `width` bytes: ``drone`` (a sphere in the drone's
    frame, coloured `rgba`), ``target`` (a cube at `xyz`), ``trail`` (a line strip through `xyz`)."""
    s, stamp = cell_size, {"sec": ("<i4", 1), "nsec": ("<u4", 1), "name": (f"S{width}", 1)}
    if kind == "drone":
        def build(v: Mapping[str, np.ndarray]) -> Any:
            name = v["name"][0].decode()
            return _update(v, frame_id=name, id=f"drone/{name}", frame_locked=True, spheres=[make(
                "foxglove_msgs/msg/SpherePrimitive", size=_size(0.8 * s), color=_colour(v["rgba"]))])

        return Layout.of(SCENE, {**stamp, "rgba": ("<f8", 4)}, build)
    if kind == "target":
        def build(v: Mapping[str, np.ndarray]) -> Any:
            return _update(v, frame_id=FRAME, id=f"target/{v['name'][0].decode()}", cubes=[make(
                "foxglove_msgs/msg/CubePrimitive", pose=_at(v["xyz"], 0), size=_size(0.5 * s),
                color=_colour(TARGET_COLOUR))])

        return Layout.of(SCENE, {**stamp, "xyz": ("<f8", 3)}, build)

    def line(v: Mapping[str, np.ndarray]) -> Any:
        return _update(v, frame_id=FRAME, id=f"trail/{v['name'][0].decode()}", lines=[make(
            "foxglove_msgs/msg/LinePrimitive", type=0, thickness=0.1 * s, color=_colour(COLOURS[0]),  # LINE_STRIP
            points=[make("geometry_msgs/msg/Point", x=float(x), y=float(y), z=float(z))
                    for x, y, z in np.reshape(v["xyz"], (-1, 3)).tolist()])])

    return Layout.of(SCENE, {**stamp, "xyz": ("<f8", 3 * SCENE_TRAIL)}, line)


@functools.cache
def _buildings(cell_size: float) -> Repeated:
    """A SceneUpdate of one entity, ``buildings``: a cube at each of `xyz`."""
    def build(k: int, v: Mapping[str, np.ndarray]) -> Any:
        return _update(v, frame_id=FRAME, id="buildings", cubes=[make(
            "foxglove_msgs/msg/CubePrimitive", pose=_at(v["xyz"], i), size=_size(cell_size),
            color=_colour(BUILDING_COLOUR)) for i in range(k)])

    return Repeated(SCENE, lambda k: {"xyz": ("<f8", 3 * k)}, build)


class FoxScene:
    """The Foxglove scene's updates, from what `Scene` was fed (pure of any network or file)."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.topic = drone_topic(scene.namespace, "scene")
        self._last: Snapshot | None = None  # the last turn's snapshot: what the scene shows

    def _outs(self, time: int, payloads: list[bytes]) -> Outs:
        return Outs(time, [self.topic] * len(payloads), [SCENE] * len(payloads), payloads)

    def _each(self, kind: str, names: list[str], drones: np.ndarray, values: Mapping[str, np.ndarray],
              time: int) -> list[bytes]:
        """A message for each of `drones` (indices in `names`), grouped by the length of their names; `values`:
        the layout's fields but the stamp and the name, a row per drone."""
        if not len(drones):
            return []
        sec, nsec = time // 1_000_000_000, time % 1_000_000_000
        widths = np.fromiter((len(names[i]) for i in drones.tolist()), np.int64, len(drones))
        out: list[bytes] = []
        for width in np.unique(widths).tolist():
            rows = np.flatnonzero(widths == width)
            block = _layout(kind, width, self.scene.cell_size).fill(
                {"sec": [[sec]], "nsec": [[nsec]], "name": np.array([names[i] for i in drones[rows].tolist()],
                                                                    f"S{width}"),
                 **{k: v[rows] for k, v in values.items()}})
            out += rows_of(block)
        return out

    def buildings(self, grid: np.ndarray) -> Outs:
        cells = np.argwhere(grid).astype(np.float64) * self.scene.cell_size
        block = _buildings(self.scene.cell_size).layout(len(cells)).fill({"xyz": cells.reshape(1, -1)})
        return self._outs(0, rows_of(block))

    def turn(self, snap: Snapshot, names: list[str], *, whole: bool = False) -> Outs:
        """The drones whose state and the targets that changed (every drone and target if `whole`: a live viewer
        may have subscribed since the last turn, and a hovering drone changes nothing)."""
        s, time = self.scene.cell_size, self.scene.time_of(snap.turn)
        last, self._last = self._last, snap
        if last is None or len(last.view) != len(names):
            drones = targets = np.arange(len(names))
            gone = np.zeros(0, np.int64)
        else:
            drones = np.arange(len(names)) if whole else np.flatnonzero(snap.view != last.view)
            changed = np.flatnonzero((snap.target != last.target).any(axis=1))
            gone = changed[snap.target[changed, 0] < 0]
            targets = np.arange(len(names)) if whole else changed
        targets = targets[snap.target[targets, 0] >= 0]
        payloads = self._each("drone", names, drones, {"rgba": COLOURS[snap.view[drones]].astype(np.float64)}, time)
        payloads += self._each("target", names, targets, {"xyz": snap.target[targets].astype(np.float64) * s}, time)
        if len(gone):  # (rare: rosbags' own objects)
            stamp = make(_TIME, sec=time // 1_000_000_000, nanosec=time % 1_000_000_000)
            payloads += [serialize(make(SCENE, deletions=[make("foxglove_msgs/msg/SceneEntityDeletion",
                                                               timestamp=stamp, type=0,  # MATCHING_ID
                                                               id=f"target/{names[i]}")]), SCENE)
                         for i in gone.tolist()]
        return self._outs(time, payloads)

    def trails(self, turn: int, trails: list[tuple[np.ndarray, np.ndarray]], names: list[str]) -> Outs:
        """The trails `Scene` sent last (groups of drones and their cells), each as its last `SCENE_TRAIL` cells."""
        time, payloads = self.scene.time_of(turn), []
        for drones, cells in trails:
            last = cells[:, -SCENE_TRAIL:]
            if last.shape[1] < SCENE_TRAIL:
                last = np.concatenate([np.repeat(last[:, :1], SCENE_TRAIL - last.shape[1], axis=1), last], axis=1)
            payloads += self._each("trail", names, drones,
                                   {"xyz": last.reshape(len(drones), -1).astype(np.float64) * self.scene.cell_size},
                                   time)
        return self._outs(time, payloads)


class FoxgloveSink:
    """Logs a game to a foxglove-sdk context (its sinks: an MCAP file, a WebSocket server): each topic on a channel
    of its own (its ``ros2msg`` schema, CDR), the scene on ``/<namespace>/scene`` unless not `with_scene`; every
    message at its simulated time. `logged` counts the ROS 2 topics' messages (not the scene's)."""

    def __init__(self, context: foxglove.Context, scene: Scene, *, with_scene: bool = True) -> None:
        self.context, self.scene = context, scene
        self.fox = FoxScene(scene) if with_scene else None
        self._channels: dict[str, foxglove.Channel] = {}
        self._logs: dict[str, Any] = {}  # topic -> its channel's log
        self.logged = 0
        self.whole = False  # each turn's scene: what changed (a file), or every drone and target (a live server)

    def _log_of(self, topic: str, typename: str) -> Any:
        schema = foxglove.Schema(name=typename, encoding="ros2msg", data=msgdef(typename).encode())
        channel = foxglove.Channel(topic, schema=schema, message_encoding="cdr", context=self.context)
        self._channels[topic] = channel
        log = self._logs[topic] = channel.base.log  # (bytes, without the wrapper's checks: a swarm logs millions)
        return log

    def _write(self, outs: Outs) -> None:
        logs, time = self._logs, outs.time
        for topic, typename, payload in zip(outs.topics, outs.typenames, outs.payloads):
            log = logs.get(topic)
            if log is None:
                log = self._log_of(topic, typename)
            log(payload, time, None)

    def log(self, outs: Outs) -> None:
        self._write(outs)
        self.logged += len(outs)

    def world(self, grid: np.ndarray, outs: Outs) -> None:
        self.log(outs)
        if self.fox is not None:
            self._write(self.fox.buildings(grid))

    def turn(self, snap: Snapshot, outs: Outs) -> None:
        self.log(outs)
        self.trails(snap.turn)
        if self.fox is not None:
            self._write(self.fox.turn(snap, self.scene.drones(), whole=self.whole))

    def trails(self, turn: int) -> None:
        """The scene's trails of the paths `Scene` made last."""
        if self.fox is not None and self.scene.sent_trails:
            self._write(self.fox.trails(turn, self.scene.sent_trails, self.scene.drones()))


def parse_address(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535:
        from schema import UsageError

        raise UsageError(f"--foxglove wants [HOST:]PORT, got {text!r}")
    return host or "127.0.0.1", number


class FoxgloveLive(FoxgloveSink, ServerListener):
    """A live Foxglove WebSocket server of the game (`address`: ``[HOST:]PORT``), opened at the game's first turn with
    a channel for every topic of the game made before it opens: foxglove-sdk (0.30.3) advertises a channel made
    while a client is connected before it can take that client's subscription to it, which it then refuses
    ("Unknown channel ID", the topic lost for that client). The buildings, logged once, are logged again at the
    turn after a client subscribes to the scene or the markers; every turn's scene holds every drone and target.
    `opened` is called with the server's URL."""

    def __init__(self, address: str, scene: Scene, logger: logging.Logger, *,
                 opened: Callable[[str], None] = lambda url: None) -> None:
        self.host, self.port = parse_address(address)
        super().__init__(foxglove.Context(), scene)
        self.whole = True  # a client that subscribes late sees every drone at the next turn
        self.server: foxglove.WebSocketServer | None = None
        self.url: str | None = None
        self._logger, self._opened = logger, opened
        self._world: tuple[np.ndarray, Outs] | None = None
        self._joined = threading.Event()  # a client subscribed to the buildings' topics since they were logged

    def world(self, grid: np.ndarray, outs: Outs) -> None:
        self._world = (grid, outs)
        super().world(grid, outs)

    def turn(self, snap: Snapshot, outs: Outs) -> None:
        if self.server is None:
            self._open(outs)
        if self._world is not None and self._joined.is_set():
            self._joined.clear()
            super().world(*self._world)
        super().turn(snap, outs)

    def _open(self, outs: Outs) -> None:
        """Every channel of the game (this turn's topics, each drone's path, the scene), then the server."""
        names = self.scene.drones()
        for topic, typename in [*zip(outs.topics, outs.typenames), (self.scene.markers_topic, MARKERS),
                                *((self.scene.path_topic(n), PATH) for n in names),
                                *(((self.fox.topic, SCENE),) if self.fox is not None else ())]:
            if topic not in self._logs:
                self._log_of(topic, typename)
        self.server = foxglove.start_server(name="dronesim", host=self.host, port=self.port, context=self.context,
                                            server_listener=self)
        self.url = f"ws://{self.host}:{self.server.port}"
        self._logger.info("Foxglove WebSocket server on %s", self.url)
        self._opened(self.url)

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        """(foxglove-sdk's thread) A client subscribed: the buildings again if to their topics."""
        if channel.topic in (self.scene.markers_topic, self.fox.topic if self.fox is not None else None):
            self._joined.set()

    def close(self) -> None:
        if self.server is not None:
            self.server.stop()
