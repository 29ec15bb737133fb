"""The game as ROS 2 messages, pure: no network, no clock (docs/ros2.md).

`Scene` is fed what an observer hears, as `Snapshot`s (a STATUS live, a turn record of a journal), and returns
the messages of each turn as `Outs` (topics, types, CDR payloads, time): every drone's pose, the frame transforms,
the markers (drones coloured by state, targets), the clock, and the trails. The buildings' markers are made once.

Every payload is rosbags' CDR (`entities.ros2.cdr`: its ROS 2 Jazzy type store, RIHS01 type hashes). A turn's
thousands of poses are not built as thousands of objects: a `cdr.Layout` fills every message of a kind at once.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from itertools import repeat
from typing import Any, NamedTuple

import numpy as np

from schema import Status
from schema.tables import drone_name
from world.grid import CELL_SIZE_M

from .cdr import Layout, Repeated, make

POSE, PATH, TF, MARKERS, CLOCK = ("geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Path", "tf2_msgs/msg/TFMessage",
                                  "visualization_msgs/msg/MarkerArray", "rosgraph_msgs/msg/Clock")
#: Every type this module publishes or takes (a goal is a PoseStamped).
TYPES = (POSE, PATH, TF, MARKERS, CLOCK)
FRAME = "map"

#: How a drone is shown, by its state: `VIEWS[code]` (the web page's names), and its colour (r, g, b, a).
VIEWS = ("alive", "reached", "unreachable", "dead", "lost")
COLOURS = np.array([(0.10, 0.45, 0.95, 1.0), (0.10, 0.75, 0.25, 1.0), (0.95, 0.60, 0.05, 1.0),
                    (0.85, 0.10, 0.10, 1.0), (0.50, 0.50, 0.50, 1.0)], np.float32)
TARGET_COLOUR = (1.0, 0.85, 0.0, 0.8)
BUILDING_COLOUR = (0.55, 0.55, 0.6, 1.0)

#: By default, the prefix of the drones' topics (``/<namespace>/<Dnn>/pose``) and the simulated seconds a turn (the
#: stamps' and /clock's), unless told (--namespace, --turn-period).
NAMESPACE = "dronesim"
TURN_PERIOD_S = 0.1

#: Cells of a drone's trail kept and published (its last ones).
TRAIL_LIMIT = 200



def _stamp(values: Mapping[str, np.ndarray], i: int) -> Any:
    return make("builtin_interfaces/msg/Time", sec=int(values["sec"][i]), nanosec=int(values["nsec"][i]))


def _header(values: Mapping[str, np.ndarray], i: int, frame: str = FRAME) -> Any:
    return make("std_msgs/msg/Header", stamp=_stamp(values, i), frame_id=frame)


def _point(xyz: np.ndarray, i: int, typename: str = "geometry_msgs/msg/Point") -> Any:
    return make(typename, x=float(xyz[3 * i]), y=float(xyz[3 * i + 1]), z=float(xyz[3 * i + 2]))


def _pose(values: Mapping[str, np.ndarray], i: int, xyz: str = "xyz", stamp: int | None = None) -> Any:
    return make(POSE, header=_header(values, i if stamp is None else stamp),
                pose=make("geometry_msgs/msg/Pose", position=_point(values[xyz], i)))


def clock_layout() -> Layout:
    return Layout.of(CLOCK, {"sec": ("<i4", 1), "nsec": ("<u4", 1)},
                     lambda v: make(CLOCK, clock=_stamp(v, 0)))


def pose_layout() -> Layout:
    return Layout.of(POSE, {"sec": ("<i4", 1), "nsec": ("<u4", 1), "xyz": ("<f8", 3)}, lambda v: _pose(v, 0))


@functools.cache
def _paths() -> Repeated:
    def build(k: int, v: Mapping[str, np.ndarray]) -> Any:
        return make(PATH, header=_header(v, 0), poses=[_pose(v, i, stamp=i + 1) for i in range(k)])

    return Repeated(PATH, lambda k: {"sec": ("<i4", k + 1), "nsec": ("<u4", k + 1), "xyz": ("<f8", 3 * k)}, build)


@functools.cache
def path_layout(k: int) -> Layout:
    """A path of `k` poses (its header's stamp first in `sec` and `nsec`, then each pose's)."""
    if k < 1:
        raise ValueError("a trail has at least one cell")
    return _paths().layout(k)


def tf_layout(frames: Sequence[str]) -> Layout:
    n = len(frames)

    def build(v: Mapping[str, np.ndarray]) -> Any:
        return make(TF, transforms=[make(
            "geometry_msgs/msg/TransformStamped", header=_header(v, i), child_frame_id=frames[i],
            transform=make("geometry_msgs/msg/Transform", translation=_point(v["xyz"], i, "geometry_msgs/msg/Vector3")))
            for i in range(n)])

    return Layout.of(TF, {"sec": ("<i4", n), "nsec": ("<u4", n), "xyz": ("<f8", 3 * n)}, build)


def markers_layout(n: int, cell_size: float) -> Layout:
    """Two markers of `n` points each: the drones (spheres, coloured by state) and their targets (cubes; a drone
    without one has its target's colour transparent)."""
    def marker(v: Mapping[str, np.ndarray], i: int, ns: str, kind: int, scale: float) -> Any:
        colour = make("std_msgs/msg/ColorRGBA", r=1.0, g=1.0, b=1.0, a=1.0)
        return make("visualization_msgs/msg/Marker", header=_header(v, i), ns=ns, id=0, type=kind, action=0,
                    scale=make("geometry_msgs/msg/Vector3", x=scale, y=scale, z=scale), color=colour,
                    points=[_point(v[ns], j) for j in range(n)],
                    colors=[make("std_msgs/msg/ColorRGBA", r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3]))
                            for c in np.reshape(v[ns + "_rgba"], (n, 4))])

    def build(v: Mapping[str, np.ndarray]) -> Any:
        return make(MARKERS, markers=[marker(v, 0, "drones", 7, 0.8 * cell_size),  # SPHERE_LIST
                                      marker(v, 1, "targets", 6, 0.5 * cell_size)])  # CUBE_LIST

    fields = {"sec": ("<i4", 2), "nsec": ("<u4", 2), "drones": ("<f8", 3 * n), "drones_rgba": ("<f4", 4 * n),
              "targets": ("<f8", 3 * n), "targets_rgba": ("<f4", 4 * n)}
    return Layout.of(MARKERS, fields, build)


@functools.cache
def _building_marker(cell_size: float) -> Repeated:
    """A MarkerArray of one cube list, ``buildings``, of any number of cubes (`xyz`: their centres)."""
    def build(k: int, v: Mapping[str, np.ndarray]) -> Any:
        colour = make("std_msgs/msg/ColorRGBA", r=BUILDING_COLOUR[0], g=BUILDING_COLOUR[1], b=BUILDING_COLOUR[2],
                      a=BUILDING_COLOUR[3])
        return make(MARKERS, markers=[make(
            "visualization_msgs/msg/Marker", header=make("std_msgs/msg/Header", frame_id=FRAME), ns="buildings", id=0,
            type=6, action=0, color=colour, scale=make("geometry_msgs/msg/Vector3", x=cell_size, y=cell_size,
                                                       z=cell_size),
            points=[_point(v["xyz"], i) for i in range(k)])])

    return Repeated(MARKERS, lambda k: {"xyz": ("<f8", 3 * k)}, build)


def building_markers(grid: np.ndarray, cell_size: float) -> bytes:
    """The buildings as one marker (a cube per building cell): a MarkerArray's CDR."""
    cells = np.argwhere(grid).astype(np.float64) * cell_size
    return _building_marker(cell_size).layout(len(cells)).fill({"xyz": cells.reshape(1, -1)})[0].tobytes()


# ----------------------------------------------------------------------------------------------- the scene


def drone_topic(namespace: str, *parts: str) -> str:
    """``/<namespace>/<part>/...`` (``/<part>/...`` without a namespace): ``/dronesim/D01/pose``."""
    return "/" + "/".join(p for p in (namespace.strip("/"), *parts) if p)


@dataclass(frozen=True, slots=True, kw_only=True)
class Snapshot:
    """Every drone at the end of a turn, as columns in drone order: number, cell, view (index in `VIEWS`),
    target cell ((-1, -1, -1): none)."""

    turn: int
    numbers: np.ndarray
    pos: np.ndarray
    view: np.ndarray
    target: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.numbers)
        if not (np.shape(self.pos) == (n, 3) and np.shape(self.target) == (n, 3) and np.shape(self.view) == (n,)):
            raise ValueError("a snapshot's columns must have one row per drone")
        if not isinstance(self.turn, int) or self.turn < 0:
            raise ValueError(f"bad turn {self.turn!r}")

    @classmethod
    def of_status(cls, status: Status) -> Snapshot:
        rows = status.drones
        state, note = rows.column("state").astype(np.int8), rows.column("note").astype(np.int8)
        view = np.where(state == 0, note, state + 2)  # ALIVE: its note (none, reached, unreachable); DEAD 3, LOST 4
        return cls(turn=status.turn, numbers=rows.numbers, pos=rows.column("pos"), view=view,
                   target=rows.column("target"))


class Out(NamedTuple):
    """One message: its topic, type, CDR payload and time (ns of simulated time, the stamp's)."""

    topic: str
    typename: str
    payload: bytes
    time: int


@dataclass(frozen=True, slots=True)
class Outs:
    """Messages of one time (ns of simulated time), as columns: message i is `payloads[i]`, of type
    `typenames[i]`, on `topics[i]`. A swarm's turn is a thousand poses: columns, not a thousand objects (the
    lists may be shared between turns: never changed). Iterating gives each as an `Out`."""

    time: int
    topics: Sequence[str] = ()
    typenames: Sequence[str] = ()
    payloads: Sequence[bytes] = ()

    def __iter__(self) -> Iterator[Out]:
        return map(Out, self.topics, self.typenames, self.payloads, repeat(self.time))

    def __len__(self) -> int:
        return len(self.payloads)

    def __add__(self, other: Outs) -> Outs:
        if other.time != self.time:
            raise ValueError("messages of two times")
        return Outs(self.time, [*self.topics, *other.topics], [*self.typenames, *other.typenames],
                    [*self.payloads, *other.payloads])


def rows_of(block: np.ndarray) -> list[bytes]:
    """Each row of a (messages x bytes) block as bytes (one copy of the block, then a slice each)."""
    data, width = block.tobytes(), block.shape[1]
    return [data[i:i + width] for i in range(0, len(data), width)]


class Trails:
    """Each drone's last `TRAIL_LIMIT` cells, in a ring of rows (numpy: a swarm's turn is a few array operations),
    and which drones moved since their trail was last taken."""

    def __init__(self, n: int, limit: int = TRAIL_LIMIT) -> None:
        self.limit = limit
        self.ring = np.zeros((n, limit, 3), np.float64)
        self.count = np.zeros(n, np.int64)  # cells ever added (the next goes to count % limit)
        self.dirty = np.zeros(n, bool)

    def add(self, drones: np.ndarray, cells: np.ndarray) -> None:
        self.ring[drones, self.count[drones] % self.limit] = cells
        self.count[drones] += 1
        self.dirty[drones] = True

    def take(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """(length k, drones, their cells (drones x k x 3), oldest first) for the drones moved since the last take,
        grouped by length."""
        moved = np.flatnonzero(self.dirty)
        self.dirty[:] = False
        lengths = np.minimum(self.count[moved], self.limit)
        groups = []
        for k in np.unique(lengths).tolist():
            drones = moved[lengths == k]
            start = np.where(self.count[drones] > self.limit, self.count[drones] % self.limit, 0)
            at = (start[:, None] + np.arange(k)) % self.limit
            groups.append((k, drones, self.ring[drones[:, None], at]))
        return groups


@dataclass(slots=True)
class _Fleet:
    numbers: np.ndarray
    names: list[str]
    topics: list[str]  # the clock's, /tf, the markers', each drone's pose topic
    path_topics: list[str]  # each drone's path topic
    typenames: list[str]
    tf: Layout
    markers: Layout
    trails: Trails
    last_pos: np.ndarray | None = None


class Scene:
    """The messages of a game (see the module doc). `namespace` prefixes the per-drone topics and the markers'
    (``/<namespace>/<Dnn>/pose``); a cell is `cell_size` metres; turn t is at t x `turn_period` seconds."""

    def __init__(self, *, namespace: str = NAMESPACE, cell_size: float = CELL_SIZE_M,
                 turn_period: float = TURN_PERIOD_S) -> None:
        if not (np.isfinite(cell_size) and cell_size > 0):
            raise ValueError(f"the cell size must be > 0, got {cell_size!r}")
        if not (np.isfinite(turn_period) and turn_period > 0):
            raise ValueError(f"the turn period must be > 0, got {turn_period!r}")
        self.namespace = namespace
        self.cell_size, self.period_ns = float(cell_size), round(turn_period * 1e9)
        self.markers_topic = drone_topic(namespace, "markers")
        self._pose, self._clock = pose_layout(), clock_layout()
        self._fleet: _Fleet | None = None
        #: the trails of the last turn's paths: (drones (indices in `drones()`), their cells (drones x k x 3)) for
        #: each length k
        self.sent_trails: list[tuple[np.ndarray, np.ndarray]] = []

    def pose_topic(self, drone: str) -> str:
        return drone_topic(self.namespace, drone, "pose")

    def path_topic(self, drone: str) -> str:
        return drone_topic(self.namespace, drone, "path")

    def goal_topic(self, drone: str) -> str:
        return drone_topic(self.namespace, drone, "goal_pose")

    def time_of(self, turn: int) -> int:
        return turn * self.period_ns

    def buildings(self, grid: np.ndarray) -> Outs:
        """The buildings' markers (at time 0: published once, kept for late joiners)."""
        return Outs(0, [self.markers_topic], [MARKERS], [building_markers(grid, self.cell_size)])

    def _fleet_of(self, snap: Snapshot) -> _Fleet:
        f = self._fleet
        if f is None or not np.array_equal(f.numbers, snap.numbers):
            names = [drone_name(n) for n in snap.numbers.tolist()]
            f = self._fleet = _Fleet(numbers=np.array(snap.numbers), names=names,
                                     topics=["/clock", "/tf", self.markers_topic, *map(self.pose_topic, names)],
                                     path_topics=[self.path_topic(name) for name in names],
                                     typenames=[CLOCK, TF, MARKERS, *[POSE] * len(names)], tf=tf_layout(names),
                                     markers=markers_layout(len(names), self.cell_size), trails=Trails(len(names)))
        return f

    def turn(self, snap: Snapshot, *, paths: bool = True) -> Outs:
        """The messages of a turn: clock, frame transforms, markers, every drone's pose, and (if `paths`) the
        trail of each drone that moved since its last one."""
        f, t = self._fleet_of(snap), self.time_of(snap.turn)
        n, sec, nsec = len(f.names), t // 1_000_000_000, t % 1_000_000_000
        xyz = snap.pos.astype(np.float64) * self.cell_size
        moved = (np.arange(n) if f.last_pos is None else
                 np.flatnonzero((snap.pos != f.last_pos).any(axis=1)))
        f.last_pos = np.array(snap.pos)
        f.trails.add(moved, snap.pos[moved])
        has = snap.target[:, 0] >= 0
        target_rgba = np.where(has[:, None], np.array(TARGET_COLOUR, np.float32), np.float32(0))
        markers = f.markers.fill({"sec": [sec], "nsec": [nsec], "drones": xyz.reshape(1, -1),
                                  "drones_rgba": COLOURS[snap.view].reshape(1, -1),
                                  "targets": (np.where(has[:, None], snap.target, snap.pos) * self.cell_size)
                                  .astype(np.float64).reshape(1, -1),
                                  "targets_rgba": target_rgba.reshape(1, -1)})
        payloads = [self._clock.fill({"sec": [sec], "nsec": [nsec]})[0].tobytes(),
                    f.tf.fill({"sec": [sec], "nsec": [nsec], "xyz": xyz.reshape(1, -1)})[0].tobytes(),
                    markers[0].tobytes()]
        payloads += rows_of(self._pose.fill({"sec": [[sec]], "nsec": [[nsec]], "xyz": xyz}))
        out = Outs(t, f.topics, f.typenames, payloads)
        self.sent_trails = []
        return out + self.paths(snap.turn) if paths else out

    def paths(self, turn: int) -> Outs:
        """The trail of every drone that moved since its last one (all of them at once, a layout per length)."""
        f, t = self._fleet, self.time_of(turn)
        if f is None:
            return Outs(t)
        sec, nsec = t // 1_000_000_000, t % 1_000_000_000
        topics: list[str] = []
        payloads: list[bytes] = []
        self.sent_trails = []
        for k, drones, cells in f.trails.take():
            rows = path_layout(k).fill({"sec": [[sec] * (k + 1)], "nsec": [[nsec] * (k + 1)],
                                        "xyz": cells.reshape(len(drones), -1) * self.cell_size})
            topics += [f.path_topics[i] for i in drones.tolist()]
            payloads += rows_of(rows)
            self.sent_trails.append((drones, cells))
        return Outs(t, topics, [PATH] * len(topics), payloads)

    def drones(self) -> list[str]:
        return [] if self._fleet is None else list(self._fleet.names)
