"""ROS 2 messages without ROS: rosbags' type store (ROS 2 Jazzy, and Foxglove's scene from
`entities.ros2.foxglove_msgs`), its CDR and RIHS01 type hashes, and `Layout`s that make thousands of messages at once.

A `Layout` is one message rosbags serialised with marked values in its fields, whose places it finds, and fills with
many messages' columns (numpy, every message at once); it checks itself against rosbags at construction, byte for
byte. `Repeated` gives the layout of a message whose one sequence holds any number of alike elements (a trail's
poses, a world's buildings) from rosbags' messages of three and four elements: no hand-written CDR.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np


@functools.cache
def typestore() -> Any:
    """rosbags' ROS 2 Jazzy type store (messages, CDR, RIHS01 hashes), with Foxglove's scene (foxglove_msgs)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from .foxglove_msgs import DEFINITIONS

    store = get_typestore(Stores.ROS2_JAZZY)
    for name, text in DEFINITIONS.items():
        store.register(get_types_from_msg(text, name))
    return store


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
    """`count` values of `dtype` whose bytes are found nowhere else in a message: a big finite float64 whose
    high word is the group and low word the index, or four bytes 0xA5, group (4 bits), index (20 bits); a string
    (``S<width>``, one value) is its width of bytes 0x10 + group. Only the words at a field's alignment are read
    (CDR aligns each to its size, after the 4-byte encapsulation)."""
    if dtype.startswith("S"):
        return np.array([bytes([0x10 + group]) * np.dtype(dtype).itemsize] * count, dtype)
    index = np.arange(count, dtype=np.uint64)
    if dtype == "<f8":
        return ((np.uint64(_F64_TAG | group) << np.uint64(32)) | index).view("<f8")
    bits = (np.uint32(_U32_TAG << 24) | np.uint32(group << 20) | index.astype(np.uint32))
    return bits.view(dtype)


def _sample(dtype: str, count: int) -> np.ndarray:
    """Values other than the marks, to check a layout with."""
    if dtype.startswith("S"):
        width = np.dtype(dtype).itemsize
        return np.array([(b"Zq" * width)[:width]] * count, dtype)
    return (np.arange(count) * 3 + 1).astype(dtype)


def _words(data: np.ndarray, width: int) -> np.ndarray:
    """The little-endian unsigned word of `width` bytes that starts at each byte of `data`."""
    n = len(data) - width + 1
    word = np.zeros(max(n, 0), np.uint64)
    for k in range(width):
        word |= data[k:k + n].astype(np.uint64) << np.uint64(8 * k)
    return word


def _found(template: np.ndarray, dtype: str, group: int, count: int, typename: str, name: str) -> np.ndarray:
    """Where each of a field's marked values starts in `template` (value order); a string's every place."""
    width = np.dtype(dtype).itemsize
    if dtype.startswith("S"):
        data, mark = template.tobytes(), bytes([0x10 + group]) * width
        places, i = [], data.find(mark)
        while i >= 0:
            places.append(i)
            i = data.find(mark, i + width)
        if not places:
            raise ValueError(f"{typename}: string field {name!r} not found")
        return np.array(places, np.int64)
    words = _words(template, width)
    if width == 8:
        at = np.flatnonzero((words >> np.uint64(32)) == np.uint64(_F64_TAG | group))
        index = (words[at] & np.uint64(0xFFFFFFFF)).astype(np.int64)
    else:
        at = np.flatnonzero((words >> np.uint64(20)) == np.uint64((_U32_TAG << 4) | group))
        index = (words[at] & np.uint64(0xFFFFF)).astype(np.int64)
    keep = (at - 4) % width == 0  # CDR aligns a field to its size
    at, index = at[keep], index[keep]
    if len(at) != count or not np.array_equal(np.sort(index), np.arange(count)):
        raise ValueError(f"{typename}: field {name!r} found {len(at)} times for {count} values")
    starts = np.empty(count, np.int64)
    starts[index] = at
    return starts


#: At most this many lattices to a field (more: its values are written byte by byte).
_PIECES = 16


class Piece(NamedTuple):
    """Values `row * group` to `(row + rows) * group` of a field, as a lattice: groups of `group` values `inner`
    bytes apart, groups `outer` bytes apart, from byte `first`."""

    row: int
    rows: int
    group: int
    first: int
    outer: int
    inner: int


@dataclass(frozen=True, slots=True)
class Place:
    """Where a field's values start in a message (`starts`, value order) and, when they are a few lattices (a
    transform's translation after a name of one length, then of another), those `pieces`: a swarm's columns are
    then written through a strided view each, not byte by byte."""

    starts: np.ndarray
    pieces: tuple[Piece, ...] | None

    @classmethod
    def of(cls, starts: np.ndarray, width: int) -> Place:
        best: tuple[Piece, ...] | None = None
        for g in range(1, 9):
            if len(starts) % g:
                continue
            grid = starts.reshape(-1, g)
            inner = int(grid[0, 1] - grid[0, 0]) if g > 1 else width
            if inner < width or not np.array_equal(grid - grid[:, :1], np.broadcast_to(np.arange(g) * inner,
                                                                                        grid.shape)):
                continue
            pieces = _runs(grid[:, 0], g, inner)
            if pieces is None or not all(p.outer >= p.inner * (g - 1) + width for p in pieces):
                continue
            if best is None or len(pieces) < len(best):
                best = pieces
            if len(pieces) <= 1:
                break
        return cls(starts, best)


def _runs(heads: np.ndarray, group: int, inner: int) -> tuple[Piece, ...] | None:
    """`heads` (where each group starts) cut into its longest runs of equal steps, as pieces (None: more than
    `_PIECES`)."""
    steps = np.diff(heads)
    changes = np.flatnonzero(steps[1:] != steps[:-1]) + 1  # (steps[c] differs from steps[c - 1])
    if len(changes) > 2 * _PIECES:
        return None
    pieces: list[Piece] = []
    row = 0
    while row < len(heads):
        if len(pieces) == _PIECES:
            return None
        later = changes[np.searchsorted(changes, row + 1):]
        end = len(heads) if row + 1 >= len(heads) or not len(later) else int(later[0]) + 1
        outer = int(steps[row]) if end - row > 1 else inner * group
        pieces.append(Piece(row, end - row, group, int(heads[row]), outer, inner))
        row = end
    return tuple(pieces)


@dataclass(frozen=True, slots=True, kw_only=True)
class Layout:
    """One message of `typename` as rosbags serialises it, and where each of its `fields` lies in it.
    `fields`: name -> (numpy dtype ``<f8``, ``<f4``, ``<i4``, ``<u4``, or ``S<width>`` for a string of that many
    bytes, found wherever it is, count); `build(values)` makes the message (rosbags' objects) from one array of
    each field's values (a string's: bytes). `fill` gives many messages at once."""

    typename: str
    template: np.ndarray  # uint8
    places: Mapping[str, Place]
    dtypes: Mapping[str, str]

    @classmethod
    def of(cls, typename: str, fields: Mapping[str, tuple[str, int]],
           build: Callable[[Mapping[str, np.ndarray]], Any]) -> Layout:
        if len(fields) > 16:
            raise ValueError("a layout marks at most 16 fields")
        marks = {name: _marks(dt, g, n) for g, (name, (dt, n)) in enumerate(fields.items())}
        template = np.frombuffer(serialize(build(marks), typename), np.uint8).copy()
        starts = {name: _found(template, dt, g, n, typename, name) for g, (name, (dt, n)) in enumerate(fields.items())}
        layout = cls.at(typename, template, starts, {name: dt for name, (dt, _) in fields.items()})
        layout.check(fields, build)
        return layout

    @classmethod
    def at(cls, typename: str, template: np.ndarray, starts: Mapping[str, np.ndarray],
           dtypes: Mapping[str, str]) -> Layout:
        return cls(typename=typename, template=template, dtypes=dict(dtypes),
                   places={name: Place.of(at, np.dtype(dtypes[name]).itemsize) for name, at in starts.items()})

    def check(self, fields: Mapping[str, tuple[str, int]], build: Callable[[Mapping[str, np.ndarray]], Any]) -> None:
        """The layout fills exactly what rosbags serialises, for values other than the marks."""
        values = {name: _sample(dt, n) for name, (dt, n) in fields.items()}
        if self.fill({k: v[None] for k, v in values.items()})[0].tobytes() != serialize(build(values), self.typename):
            raise AssertionError(f"{self.typename}: the layout does not match rosbags' serialisation")

    def fill(self, values: Mapping[str, Any]) -> np.ndarray:
        """Messages, one a row (uint8, rows x bytes): `values[field]` is (rows, count) (or broadcasts to it; a
        string field's count is 1, whatever its places)."""
        rows = max(np.shape(v)[0] for v in values.values())
        out = np.tile(self.template, (rows, 1))
        size = len(self.template)
        for name, place in self.places.items():
            dt = self.dtypes[name]
            n = len(place.starts)
            v = np.asarray(values[name], dt)
            if dt.startswith("S"):  # (the same string at each of its places)
                v = np.broadcast_to(v.reshape(-1, 1), (rows, n))
            else:
                v = np.broadcast_to(v, (rows, n))
            if place.pieces is not None:
                for p in place.pieces:
                    view = np.ndarray((rows, p.rows, p.group), dt, out, p.first, (size, p.outer, p.inner))
                    view[...] = v[:, p.row * p.group:(p.row + p.rows) * p.group].reshape(rows, p.rows, p.group)
            else:
                width = np.dtype(dt).itemsize
                at = (place.starts[:, None] + np.arange(width)).ravel()
                out[:, at] = np.ascontiguousarray(v).view(np.uint8).reshape(rows, -1)
        return out


class Repeated:
    """The layouts of a message whose one growing sequence holds any number `k` of alike elements (a path's
    poses, a cube list's cubes). `fields(k)`: the fields of `k` elements, each field's values its fixed ones
    (before or after the sequence) and then the same number for each element, in element order; `build(k,
    values)`: rosbags' message. From rosbags' messages of 3 and 4 elements: the window of bytes the fourth
    added, inserted k - 3 times, and the count set; the model is checked against rosbags' messages of 4 and 5
    elements when made, byte for byte (CDR aligns each field to its size from the start: an element a multiple of
    8 bytes long repeats as it is)."""

    def __init__(self, typename: str, fields: Callable[[int], Mapping[str, tuple[str, int]]],
                 build: Callable[[int, Mapping[str, np.ndarray]], Any]) -> None:
        self.typename, self.fields, self.build = typename, fields, build
        three, four = (Layout.of(typename, fields(k), functools.partial(build, k)) for k in (3, 4))
        self.size = len(four.template) - len(three.template)
        self.dtypes = three.dtypes
        if self.size <= 0 or self.size % 8:
            raise AssertionError(f"{typename}: an element is {self.size} bytes, not a multiple of 8")
        t3, full4 = self._bare(three), self._bare(four)
        differ = np.flatnonzero(t3 != full4[:len(t3)])
        self.count = int(differ[0]) if len(differ) else -1
        if (self.count < 4 or (self.count - 4) % 4 or t3[self.count:self.count + 4].view("<u4")[0] != 3
                or full4[self.count:self.count + 4].view("<u4")[0] != 4):
            raise AssertionError(f"{typename}: no element count found")
        t4 = full4.copy()
        t3[self.count:self.count + 4] = t4[self.count:self.count + 4] = 0
        same = np.flatnonzero(t3 != t4[:len(t3)])
        prefix = int(same[0]) if len(same) else len(t3)
        rev = np.flatnonzero(t3[::-1] != t4[::-1][:len(t3)])
        suffix = int(rev[0]) if len(rev) else len(t3)
        self.cut, self.bare = max(self.count + 4, len(t3) - suffix), t3
        self.window = t4[self.cut:self.cut + self.size]
        if self.cut > prefix or not np.array_equal(self._template(4), full4):
            raise AssertionError(f"{typename}: the fourth element is not a window inserted in the third's message")
        self.per: dict[str, tuple[int, int]] = {}  # field -> (values per element, fixed values)
        self.after: dict[str, np.ndarray] = {}  # field -> which fixed values lie after the sequence
        self.three = {name: place.starts for name, place in three.places.items()}
        for name, (_, n3) in fields(3).items():
            c = fields(4)[name][1] - n3
            f = n3 - 3 * c
            fixed3, fixed4 = three.places[name].starts[:f], four.places[name].starts[:f]
            self.per[name], self.after[name] = (c, f), fixed4 != fixed3
            if not np.array_equal(fixed4, fixed3 + self.size * self.after[name]):
                raise AssertionError(f"{typename}: field {name!r}'s fixed values move with the elements")
        for k, real in ((4, four), (5, Layout.of(typename, fields(5), functools.partial(build, 5)))):
            model = self.layout(k)
            if not (np.array_equal(model.template, self._bare(real))
                    and all(np.array_equal(model.places[n].starts, p.starts) for n, p in real.places.items())):
                raise AssertionError(f"{typename}: {k} elements are not laid out as the model says")
            model.check(fields(k), functools.partial(build, k))

    @staticmethod
    def _bare(layout: Layout) -> np.ndarray:
        """The layout's template without its marks."""
        bare = layout.template.copy()
        for name, place in layout.places.items():
            width = np.dtype(layout.dtypes[name]).itemsize
            bare[(place.starts[:, None] + np.arange(width)).ravel()] = 0
        return bare

    def _template(self, k: int) -> np.ndarray:
        template = np.concatenate([self.bare[:self.cut], np.tile(self.window, k - 3), self.bare[self.cut:]])
        template[self.count:self.count + 4] = np.frombuffer(np.uint32(k).tobytes(), np.uint8)
        return template

    def layout(self, k: int) -> Layout:
        """The layout of `k` elements (rosbags' own below 3)."""
        if k < 3:
            return Layout.of(self.typename, self.fields(k), functools.partial(self.build, k))
        starts = {}
        shift = self.size * (k - 3)
        for name, (c, f) in self.per.items():
            s3 = self.three[name]
            fixed = s3[:f] + shift * self.after[name]
            first, second = s3[f:f + c], s3[f + c:f + 2 * c]
            later = second[None, :] + self.size * np.arange(k - 1)[:, None]  # (the second element's from on)
            starts[name] = np.concatenate([fixed, first, later.ravel()]) if c else fixed
        return Layout.at(self.typename, self._template(k), starts, self.dtypes)
