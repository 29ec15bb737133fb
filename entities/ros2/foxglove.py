"""The game for Foxglove (foxglove-sdk), live (a WebSocket server, subprotocol ``foxglove.sdk.v1``) or in an MCAP file:
the ROS 2 topics of `entities.ros2.model.Scene` (``ros2msg`` schemas, CDR), and a Foxglove scene on
``/<namespace>/scene`` (``foxglove.SceneUpdate``): the buildings as cubes, each drone as a sphere in its own frame
(moved by ``/tf``; sent again only when its state changes), each target as a cube, each trail as a line strip.
"""

from __future__ import annotations

import logging
from typing import Any

import foxglove
import numpy as np
from foxglove.channels import SceneUpdateChannel
from foxglove.messages import (
    Color,
    CubePrimitive,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from .model import BUILDING_COLOUR, COLOURS, FRAME, TARGET_COLOUR, Out, Scene, Snapshot, drone_topic, msgdef

#: Cells of a trail the scene draws (its last ones): a line's points are objects, a ROS 2 path's are bytes.
SCENE_TRAIL = 50


def _colour(rgba: Any) -> Color:
    r, g, b, a = (float(v) for v in rgba)
    return Color(r=r, g=g, b=b, a=a)


def _at(x: float, y: float, z: float) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))


def _stamp(ns: int) -> Timestamp:
    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


class FoxScene:
    """The Foxglove scene's updates, from what `Scene` was fed (pure of any network or file)."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self._last: Snapshot | None = None  # the last turn's snapshot: what the scene shows
        self._colours = [_colour(c) for c in COLOURS]
        self._trail_colour = _colour(COLOURS[0])

    def buildings(self, grid: np.ndarray) -> SceneUpdate:
        s = self.scene.cell_size
        size, colour = Vector3(x=s, y=s, z=s), _colour(BUILDING_COLOUR)
        cubes = [CubePrimitive(pose=_at(x * s, y * s, z * s), size=size, color=colour)
                 for x, y, z in np.argwhere(grid).tolist()]
        return SceneUpdate(entities=[SceneEntity(timestamp=_stamp(0), frame_id=FRAME, id="buildings", cubes=cubes)])

    def turn(self, snap: Snapshot, names: list[str]) -> SceneUpdate | None:
        """The drones whose state and the targets that changed (None: nothing did)."""
        s, stamp = self.scene.cell_size, _stamp(self.scene.time_of(snap.turn))
        entities, deletions = [], []
        ball, box = Vector3(x=0.8 * s, y=0.8 * s, z=0.8 * s), Vector3(x=0.5 * s, y=0.5 * s, z=0.5 * s)
        last = self._last
        changed = (np.arange(len(names)) if last is None or len(last.view) != len(names) else
                   np.flatnonzero((snap.view != last.view) | (snap.target != last.target).any(axis=1)))
        first = last is None or len(last.view) != len(names)
        self._last = snap
        for i in changed.tolist():
            name, view, target = names[i], int(snap.view[i]), snap.target[i].tolist()
            if first or view != last.view[i]:  # type: ignore[union-attr]
                entities.append(SceneEntity(timestamp=stamp, frame_id=name, id=f"drone/{name}", frame_locked=True,
                                            spheres=[SpherePrimitive(pose=_at(0.0, 0.0, 0.0), size=ball,
                                                                     color=self._colours[view])]))
            if first or target != last.target[i].tolist():  # type: ignore[union-attr]
                if target[0] < 0:
                    if not first:
                        deletions.append(SceneEntityDeletion(timestamp=stamp, id=f"target/{name}",
                                                             type=SceneEntityDeletionType.MatchingId))
                else:
                    entities.append(SceneEntity(timestamp=stamp, frame_id=FRAME, id=f"target/{name}", cubes=[
                        CubePrimitive(pose=_at(target[0] * s, target[1] * s, target[2] * s), size=box,
                                      color=_colour(TARGET_COLOUR))]))
        return SceneUpdate(entities=entities, deletions=deletions) if entities or deletions else None

    def trails(self, turn: int, trails: dict[str, np.ndarray]) -> SceneUpdate | None:
        if not trails:
            return None
        s, stamp = self.scene.cell_size, _stamp(self.scene.time_of(turn))
        def line(cells: np.ndarray) -> LinePrimitive:
            return LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=0.1 * s, color=self._trail_colour,
                                 points=[Point3(x=x, y=y, z=z) for x, y, z in (cells[-SCENE_TRAIL:] * s).tolist()])

        return SceneUpdate(entities=[SceneEntity(timestamp=stamp, frame_id=FRAME, id=f"trail/{name}",
                                                 lines=[line(cells)]) for name, cells in trails.items()])


class FoxgloveSink:
    """Logs a game to a foxglove-sdk context (its sinks: an MCAP file, a WebSocket server): each ROS 2 topic on a
    channel of its own, the scene on ``/<namespace>/scene``; every message at its simulated time."""

    def __init__(self, context: foxglove.Context, scene: Scene, *, with_scene: bool = True) -> None:
        self.context, self.scene, self.fox = context, scene, FoxScene(scene)
        self._channels: dict[str, foxglove.Channel] = {}
        self._logs: dict[str, Any] = {}  # topic -> its channel's log
        self._scene = (SceneUpdateChannel(drone_topic(scene.namespace, "scene"), context=context) if with_scene
                       else None)
        self.logged = 0

    def _channel(self, out: Out) -> Any:
        schema = foxglove.Schema(name=out.typename, encoding="ros2msg", data=msgdef(out.typename).encode())
        channel = foxglove.Channel(out.topic, schema=schema, message_encoding="cdr", context=self.context)
        self._channels[out.topic] = channel
        return channel.base  # (its log of bytes, without the wrapper's checks for JSON: a swarm logs a million)

    def log(self, outs: list[Out]) -> None:
        channels = self._logs
        for out in outs:
            log = channels.get(out.topic)
            if log is None:
                log = channels[out.topic] = self._channel(out).log
            log(out.payload, out.time, None)
        self.logged += len(outs)

    def scene_log(self, update: SceneUpdate | None, time: int) -> None:
        if update is not None and self._scene is not None:
            self._scene.log(update, log_time=time)

    def world(self, grid: np.ndarray, outs: list[Out]) -> None:
        self.log(outs)
        if self._scene is not None:
            self.scene_log(self.fox.buildings(grid), 0)

    def turn(self, snap: Snapshot, outs: list[Out]) -> None:
        self.log(outs)
        if self._scene is None:
            return
        t = self.scene.time_of(snap.turn)
        self.scene_log(self.fox.turn(snap, self.scene.drones()), t)
        self.scene_log(self.fox.trails(snap.turn, self.scene.sent_trails), t)


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


class FoxgloveLive(FoxgloveSink):
    """A live Foxglove WebSocket server of the game (`address`: ``[HOST:]PORT``)."""

    def __init__(self, address: str, scene: Scene, logger: logging.Logger) -> None:
        host, port = parse_address(address)
        super().__init__(foxglove.Context(), scene)
        self.server = foxglove.start_server(name="dronesim", host=host, port=port, context=self.context)
        self.url = f"ws://{host}:{self.server.port}"
        logger.info("Foxglove WebSocket server on %s", self.url)

    def close(self) -> None:
        self.server.stop()
