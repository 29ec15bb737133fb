"""The game as ROS 2 messages, pure: no network, no clock (docs/ros2.md).

`Scene` is fed what an observer hears, as `Snapshot`s (a STATUS live, a turn record of a journal), and returns
the messages of each turn as `Out` (topic, type, CDR payload, time): every drone's pose, the frame transforms,
the markers (drones coloured by state, targets), the clock, and the trails. The buildings' markers are made once.

Every payload is rosbags' CDR (its ROS 2 Jazzy type store; type hashes by its RIHS01). A turn's thousands of poses
are not built as thousands of objects: a `Layout` is one message rosbags serialised with marked numbers in its
numeric fields, whose places it finds, and fills with a turn's columns (numpy, every message at once); it checks
itself against rosbags at construction, byte for byte.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from schema import Status
from schema.tables import drone_name

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

#: Cells of a drone's trail kept and published (its last ones).
TRAIL_LIMIT = 200


@functools.cache
def typestore() -> Any:
    """rosbags' ROS 2 Jazzy type store (messages, CDR, RIHS01 hashes)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


@functools.cache
def type_hash(typename: str) -> str:
    return typestore().hash_rihs01(typename)


@functools.cache
def msgdef(typename: str) -> str:
    """The type's definition with its dependencies, as ROS 2 tools write it (MCAP's ``ros2msg`` schema)."""
    return typestore().generate_msgdef(typename, ros_version=2)[0]


def own_msgdef(typename: str) -> str:
    """The type's own ``.msg`` text (its fields and constants, not its dependencies')."""
    return msgdef(typename).split("=" * 80)[0].rstrip() + "\n"


def dependencies(typename: str) -> list[str]:
    """The message types `typename` is made of, itself first, each once."""
    found: list[str] = []

    def visit(name: str) -> None:
        if name in found:
            return
        found.append(name)
        for _, (kind, rest) in typestore().fielddefs[name][1]:
            sub = rest if kind.name == "NAME" else rest[0][1] if kind.name in ("ARRAY", "SEQUENCE") else None
            if isinstance(sub, str) and sub in typestore().fielddefs:
                visit(sub)

    visit(typename)
    return found


def make(typename: str, **fields: Any) -> Any:
    """A rosbags message of `typename`: `fields` as given, every other one its type's zero (a quaternion w=1)."""
    store = typestore()
    cls = store.types[typename]
    values: dict[str, Any] = {}
    for name, (kind, rest) in store.fielddefs[typename][1]:
        if name in fields:
            values[name] = fields[name]
        elif kind.name == "NAME":
            values[name] = make(rest, w=1.0) if rest == "geometry_msgs/msg/Quaternion" else make(rest)
        elif kind.name == "BASE":
            values[name] = "" if rest[0] == "string" else False if rest[0] == "bool" else 0
        elif rest[0][0].name == "BASE":  # an array or sequence of numbers
            values[name] = np.zeros(rest[1] if kind.name == "ARRAY" else 0, _NUMPY.get(rest[0][1][0], "f8"))
        else:
            values[name] = [make(rest[0][1]) for _ in range(rest[1] if kind.name == "ARRAY" else 0)]
    return cls(**values)


_NUMPY = {"float64": "f8", "float32": "f4", "int32": "i4", "uint32": "u4", "uint8": "u1", "int8": "i1",
          "int16": "i2", "uint16": "u2", "int64": "i8", "uint64": "u8", "octet": "u1", "byte": "u1", "char": "u1"}


def serialize(msg: Any, typename: str) -> bytes:
    return bytes(typestore().serialize_cdr(msg, typename))


def deserialize(data: bytes, typename: str) -> Any:
    return typestore().deserialize_cdr(data, typename)


# ----------------------------------------------------------------------------------------------- layouts

_F64_TAG, _U32_TAG = 0x7E5A0000, 0xA5


def _marks(dtype: str, group: int, count: int) -> np.ndarray:
    """`count` numbers of `dtype` whose bytes are found nowhere else in a message: a big finite float64 whose
    high word is the group and low word the index, or four bytes 0xA5, group (4 bits), index (20 bits). Only
    the words at a field's alignment are read (CDR aligns each to its size, after the 4-byte encapsulation)."""
    index = np.arange(count, dtype=np.uint64)
    if dtype == "<f8":
        return ((np.uint64(_F64_TAG | group) << np.uint64(32)) | index).view("<f8")
    bits = (np.uint32(_U32_TAG << 24) | np.uint32(group << 20) | index.astype(np.uint32))
    return bits.view(dtype)


def _words(data: np.ndarray, width: int) -> np.ndarray:
    """The little-endian unsigned word of `width` bytes that starts at each byte of `data`."""
    n = len(data) - width + 1
    word = np.zeros(max(n, 0), np.uint64)
    for k in range(width):
        word |= data[k:k + n].astype(np.uint64) << np.uint64(8 * k)
    return word


@dataclass(frozen=True, slots=True, kw_only=True)
class Layout:
    """One message of `typename` as rosbags serialises it, and where each of its `fields` lies in it.
    `fields`: name -> (numpy dtype ``<f8``, ``<f4``, ``<i4`` or ``<u4``, count); `build(values)` makes the
    message (rosbags' objects) from one array of each field's values. `fill` gives many messages at once."""

    typename: str
    template: np.ndarray  # uint8
    offsets: Mapping[str, np.ndarray]  # field -> (count * size,) byte indices, in value order
    dtypes: Mapping[str, str]

    @classmethod
    def of(cls, typename: str, fields: Mapping[str, tuple[str, int]],
           build: Callable[[Mapping[str, np.ndarray]], Any]) -> Layout:
        if len(fields) > 16:
            raise ValueError("a layout marks at most 16 fields")
        marks = {name: _marks(dt, g, n) for g, (name, (dt, n)) in enumerate(fields.items())}
        template = np.frombuffer(serialize(build(marks), typename), np.uint8).copy()
        words = {8: _words(template, 8), 4: _words(template, 4)}
        offsets: dict[str, np.ndarray] = {}
        for g, (name, (dt, n)) in enumerate(fields.items()):
            width = np.dtype(dt).itemsize
            if width == 8:
                at = np.flatnonzero((words[8] >> np.uint64(32)) == np.uint64(_F64_TAG | g))
                index = (words[8][at] & np.uint64(0xFFFFFFFF)).astype(np.int64)
            else:
                at = np.flatnonzero((words[4] >> np.uint64(20)) == np.uint64((_U32_TAG << 4) | g))
                index = (words[4][at] & np.uint64(0xFFFFF)).astype(np.int64)
            at, index = at[(at - 4) % width == 0], index[(at - 4) % width == 0]  # CDR aligns a field to its size
            if len(at) != n or not np.array_equal(np.sort(index), np.arange(n)):
                raise ValueError(f"{typename}: field {name!r} found {len(at)} times for {n} values")
            starts = np.empty(n, np.int64)
            starts[index] = at
            offsets[name] = (starts[:, None] + np.arange(width)).ravel()
        layout = cls(typename=typename, template=template, offsets=offsets,
                     dtypes={name: dt for name, (dt, _) in fields.items()})
        layout._check(fields, build)
        return layout

    def _check(self, fields: Mapping[str, tuple[str, int]], build: Callable[[Mapping[str, np.ndarray]], Any]) -> None:
        """The layout fills exactly what rosbags serialises, for values other than the marks."""
        values = {name: (np.arange(n) * 3 + 1).astype(dt) for name, (dt, n) in fields.items()}
        if self.fill({k: v[None] for k, v in values.items()})[0].tobytes() != serialize(build(values), self.typename):
            raise AssertionError(f"{self.typename}: the layout does not match rosbags' serialisation")

    def fill(self, values: Mapping[str, Any]) -> np.ndarray:
        """Messages, one a row (uint8, rows x bytes): `values[field]` is (rows, count) (or broadcasts to it)."""
        rows = max(np.shape(v)[0] for v in values.values())
        out = np.tile(self.template, (rows, 1))
        for name, at in self.offsets.items():
            v = np.broadcast_to(np.asarray(values[name], self.dtypes[name]), (rows, len(at) // np.dtype(
                self.dtypes[name]).itemsize))
            out[:, at] = np.ascontiguousarray(v).view(np.uint8).reshape(rows, -1)
        return out


def _stamp(values: Mapping[str, np.ndarray], i: int) -> Any:
    return make("builtin_interfaces/msg/Time", sec=int(values["sec"][i]), nanosec=int(values["nsec"][i]))


def _header(values: Mapping[str, np.ndarray], i: int, frame: str = FRAME) -> Any:
    return make("std_msgs/msg/Header", stamp=_stamp(values, i), frame_id=frame)


def _point(xyz: np.ndarray, i: int, typename: str = "geometry_msgs/msg/Point") -> Any:
    return make(typename, x=float(xyz[3 * i]), y=float(xyz[3 * i + 1]), z=float(xyz[3 * i + 2]))


def _pose(values: Mapping[str, np.ndarray], i: int, xyz: str = "xyz", stamp: int | None = None) -> Any:
    return make(POSE, header=_header(values, i if stamp is None else stamp),
                pose=make("geometry_msgs/msg/Pose", position=_point(values[xyz], i)))


def pose_layout() -> Layout:
    return Layout.of(POSE, {"sec": ("<i4", 1), "nsec": ("<u4", 1), "xyz": ("<f8", 3)}, lambda v: _pose(v, 0))


@functools.cache
def path_layout(k: int) -> Layout:
    """A path of `k` poses: rosbags' path of two poses, its second pose repeated (from the second on, a pose of a
    ``map`` frame starts at the same alignment and is a multiple of 8 bytes), its count set; checked against
    rosbags up to 4 poses."""
    if k < 1:
        raise ValueError("a trail has at least one cell")
    fields = {"sec": ("<i4", k + 1), "nsec": ("<u4", k + 1), "xyz": ("<f8", 3 * k)}

    def build(v: Mapping[str, np.ndarray]) -> Any:
        return make(PATH, header=_header(v, 0), poses=[_pose(v, i, stamp=i + 1) for i in range(k)])

    if k <= 2:
        return Layout.of(PATH, fields, build)
    two = path_layout(2)
    count, start = int(two.offsets["sec"][4]) - 4, int(two.offsets["sec"][8])  # (each value's 4 bytes)
    size = len(two.template) - start
    if size % 8 or (start - 4) % 8 or two.template[count:count + 4].view("<u4")[0] != 2:
        raise AssertionError("nav_msgs/Path: its poses are not aligned blocks after their count")
    template = np.concatenate([two.template[:start], np.tile(two.template[start:], k - 1)])
    template[count:count + 4] = np.frombuffer(np.uint32(k).tobytes(), np.uint8)
    shift = (np.arange(k - 1) * size)[:, None]

    def repeated(at: np.ndarray, fixed: int) -> np.ndarray:
        """`at`'s first `fixed` bytes as they are, its others once for each pose from the second on."""
        return np.concatenate([at[:fixed], (at[None, fixed:] + shift).ravel()])

    layout = Layout(typename=PATH, template=template, dtypes=two.dtypes,
                    offsets={"sec": repeated(two.offsets["sec"], 8), "nsec": repeated(two.offsets["nsec"], 8),
                             "xyz": repeated(two.offsets["xyz"], 24)})
    if k <= 4:
        layout._check(fields, build)
    return layout


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


def building_markers(grid: np.ndarray, cell_size: float) -> Any:
    """The buildings as one marker (a cube per building cell), a rosbags MarkerArray."""
    cells = np.argwhere(grid) * cell_size
    colour = make("std_msgs/msg/ColorRGBA", r=BUILDING_COLOUR[0], g=BUILDING_COLOUR[1], b=BUILDING_COLOUR[2],
                  a=BUILDING_COLOUR[3])
    marker = make("visualization_msgs/msg/Marker", header=make("std_msgs/msg/Header", frame_id=FRAME),
                  ns="buildings", id=0, type=6, action=0, color=colour,
                  scale=make("geometry_msgs/msg/Vector3", x=cell_size, y=cell_size, z=cell_size),
                  points=[make("geometry_msgs/msg/Point", x=float(x), y=float(y), z=float(z))
                          for x, y, z in cells.tolist()])
    return make(MARKERS, markers=[marker])


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
    """One message: its topic, type, CDR payload and time (ns of simulated time, the stamp's). A tuple, not a
    frozen dataclass: a swarm's turn makes a thousand of them, and a tuple is built several times faster."""

    topic: str
    typename: str
    payload: bytes
    time: int


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
    poses: list[str]  # each drone's pose topic
    tf: Layout
    markers: Layout
    trails: Trails
    last_pos: np.ndarray | None = None


class Scene:
    """The messages of a game (see the module doc). `namespace` prefixes the per-drone topics and the markers'
    (``/<namespace>/<Dnn>/pose``); a cell is `cell_size` metres; turn t is at t x `turn_period` seconds."""

    def __init__(self, *, namespace: str = "dronesim", cell_size: float = 1.0, turn_period: float = 0.1) -> None:
        if not (np.isfinite(cell_size) and cell_size > 0):
            raise ValueError(f"the cell size must be > 0, got {cell_size!r}")
        if not (np.isfinite(turn_period) and turn_period > 0):
            raise ValueError(f"the turn period must be > 0, got {turn_period!r}")
        self.namespace = namespace
        self.cell_size, self.period_ns = float(cell_size), round(turn_period * 1e9)
        self.markers_topic = drone_topic(namespace, "markers")
        self._pose = pose_layout()
        self._fleet: _Fleet | None = None
        self.sent_trails: dict[str, np.ndarray] = {}  # the trails (cells x 3) of the last turn's paths, by drone

    def pose_topic(self, drone: str) -> str:
        return drone_topic(self.namespace, drone, "pose")

    def path_topic(self, drone: str) -> str:
        return drone_topic(self.namespace, drone, "path")

    def goal_topic(self, drone: str) -> str:
        return drone_topic(self.namespace, drone, "goal_pose")

    def time_of(self, turn: int) -> int:
        return turn * self.period_ns

    def buildings(self, grid: np.ndarray) -> Out:
        return Out(self.markers_topic, MARKERS, serialize(building_markers(grid, self.cell_size), MARKERS), 0)

    def _fleet_of(self, snap: Snapshot) -> _Fleet:
        f = self._fleet
        if f is None or not np.array_equal(f.numbers, snap.numbers):
            names = [drone_name(n) for n in snap.numbers.tolist()]
            f = self._fleet = _Fleet(numbers=np.array(snap.numbers), names=names,
                                     poses=[self.pose_topic(d) for d in names], tf=tf_layout(names),
                                     markers=markers_layout(len(names), self.cell_size),
                                     trails=Trails(len(names)))
        return f

    def turn(self, snap: Snapshot, *, paths: bool = True) -> list[Out]:
        """The messages of a turn: clock, frame transforms, markers, every drone's pose, and (if `paths`) the
        trail of each drone that moved since its last one."""
        f, t = self._fleet_of(snap), self.time_of(snap.turn)
        n, sec, nsec = len(f.names), t // 1_000_000_000, t % 1_000_000_000
        xyz = snap.pos.astype(np.float64) * self.cell_size
        moved = (np.arange(n) if f.last_pos is None else
                 np.flatnonzero((snap.pos != f.last_pos).any(axis=1)))
        f.last_pos = np.array(snap.pos)
        f.trails.add(moved, snap.pos[moved])
        out = [Out("/clock", CLOCK, serialize(make(CLOCK, clock=make("builtin_interfaces/msg/Time", sec=sec,
                                                                     nanosec=nsec)), CLOCK), t)]
        out.append(Out("/tf", TF, f.tf.fill({"sec": [sec], "nsec": [nsec], "xyz": xyz.reshape(1, -1)})[0].tobytes(), t))
        has = snap.target[:, 0] >= 0
        target_rgba = np.where(has[:, None], np.array(TARGET_COLOUR, np.float32), np.float32(0))
        markers = f.markers.fill({"sec": [sec], "nsec": [nsec], "drones": xyz.reshape(1, -1),
                                  "drones_rgba": COLOURS[snap.view].reshape(1, -1),
                                  "targets": (np.where(has[:, None], snap.target, snap.pos) * self.cell_size)
                                  .astype(np.float64).reshape(1, -1),
                                  "targets_rgba": target_rgba.reshape(1, -1)})
        out.append(Out(self.markers_topic, MARKERS, markers[0].tobytes(), t))
        poses = self._pose.fill({"sec": [[sec]], "nsec": [[nsec]], "xyz": xyz})
        out += [Out(topic, POSE, row.tobytes(), t) for topic, row in zip(f.poses, poses)]
        self.sent_trails = {}
        if paths:
            out += self.paths(snap.turn)
        return out

    def paths(self, turn: int) -> list[Out]:
        """The trail of every drone that moved since its last one (all of them at once, a layout per length)."""
        f = self._fleet
        if f is None:
            return []
        t = self.time_of(turn)
        sec, nsec = t // 1_000_000_000, t % 1_000_000_000
        out: list[Out] = []
        for k, drones, cells in f.trails.take():
            rows = path_layout(k).fill({"sec": [[sec] * (k + 1)], "nsec": [[nsec] * (k + 1)],
                                        "xyz": cells.reshape(len(drones), -1) * self.cell_size})
            names = [f.names[i] for i in drones.tolist()]
            out += [Out(self.path_topic(name), PATH, row.tobytes(), t) for name, row in zip(names, rows)]
            self.sent_trails.update(zip(names, cells))
        return out

    def drones(self) -> list[str]:
        return [] if self._fleet is None else list(self._fleet.names)
