"""Columns for the swarm-sized parts of messages: a STATUS's drone states, a TURN's orders and moves, a
MOVES's steps, a WELCOME's starts and a ground station's DONE's targets.

A swarm of 1000 drones puts 1000 records in most of them every turn: as Python records, about a microsecond and
a few hundred bytes per drone for every process that reads or writes them; as columns, a few bytes per drone,
checked, read and written by numpy at once. On the wire a table is one MessagePack ``bin`` of fixed-size
little-endian rows (`Col`, README.md). A table is immutable and validates on construction, like a message.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import itertools
import struct
import typing
from collections.abc import Iterable, Iterator
from typing import ClassVar, Self

import numpy as np

from .errors import MalformedMessage
from .tuning import CHECK_FEW_ROWS

#: Largest coordinate a cell may have, in a table or any message (worlds are far smaller; this bounds garbage).
MAX_COORD = 1 << 16
#: Largest drone number (D65535): the most a table's `u16` drone column holds.
MAX_DRONE = 65535


class Col(enum.Enum):
    """What kind of column a record field is stored in."""

    DRONE = "u16 drone number"
    CELL = "3 x i32, each in 0..65536"
    SIGNED = "3 x i32, each in -65536..65536"
    OPTIONAL = "3 x i32, each in 0..65536, or (-1, -1, -1) for none"
    RANKED = "u32 ranked steps: 3 bits each, lowest first, codes 1..7 (see `ranked_steps`), 0 for none"


#: Each `Col`'s numpy type and shape, and its ints in a row's bytes for `struct`.
_CELL = ("<i4", (3,), "3i")
_DTYPES: dict[object, tuple[str, tuple, str]] = {Col.DRONE: ("<u2", (), "H"), Col.RANKED: ("<u4", (), "I"),
                                                  Col.CELL: _CELL, Col.SIGNED: _CELL, Col.OPTIONAL: _CELL}
_NONE = (-1, -1, -1)
#: The smallest coordinate of each cell column (the largest is MAX_COORD).
_LOWEST = {Col.CELL: 0, Col.SIGNED: -MAX_COORD, Col.OPTIONAL: 0}


def _numbered(value: object, letter: str) -> bool:
    """`letter` then 2 to 5 ASCII digits (D01, H12, D1000, D10000)."""
    return (type(value) is str and 3 <= len(value) <= 6 and value[0] == letter and value.isascii()
            and value[1:].isdigit())


def is_drone_id(value: object) -> bool:
    """A drone's id: D01, D02, ... D65535 (`MAX_DRONE`), canonical (`drone_name(n)`: no D00, D001 or D0100), so
    that it is one number in a table's drone column."""
    return _numbered(value, "D") and (value in _TWO_DIGITS  # (a string: _numbered checks the type first)
                                      or value[1] != "0" and int(value[1:]) <= MAX_DRONE)  # type: ignore[index]


_TWO_DIGITS = frozenset(f"D0{n}" for n in range(1, 10))


def drone_number(drone: str) -> int:
    """The number of a canonical drone id: 'D01' -> 1."""
    return int(drone[1:])


def drone_name(n: int) -> str:
    """The canonical id of drone number n: 1 -> 'D01' (unchecked: `messages.drone_id` checks n)."""
    return f"D{n:02d}"


#: The steps a drone may rank (`Col.RANKED`, an NPS's `ranked`), code k + 1 for RANK_STEPS[k]: the
#: 6-neighbourhood (+x, -x, +y, -y, +z, -z) and staying.
RANK_STEPS: tuple[tuple[int, int, int], ...] = ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1),
                                                (0, 0, 0))
_RANK_CODE = {s: k + 1 for k, s in enumerate(RANK_STEPS)}
#: Largest valid ranking (all seven codes): anything at or above 8**7 is malformed.
RANKED_LIMIT = 8 ** len(RANK_STEPS)


def rank_steps(steps: Iterable[tuple[int, int, int]]) -> int:
    """A drone's ranked steps, best first (each in RANK_STEPS, distinct), packed: 3 bits each, best lowest."""
    value, shift = 0, 0
    for s in steps:
        value |= _RANK_CODE[s] << shift
        shift += 3
    return value


def ranked_steps(value: int) -> tuple[tuple[int, int, int], ...]:
    """The steps packed by `rank_steps`, best first (() for 0: no ranking)."""
    out = []
    while value:
        out.append(RANK_STEPS[(value & 7) - 1])
        value >>= 3
    return tuple(out)


def ranked_ok(value: object) -> bool:
    """Is `value` steps packed by `rank_steps`: an int below RANKED_LIMIT whose 3-bit codes are nonzero up to
    the last and distinct (0: none)? `_column_ok` is the same rule on a column."""
    if type(value) is not int or not 0 <= value < RANKED_LIMIT:
        return False
    seen = 0
    while value:
        code = value & 7
        if not code or seen >> code & 1:
            return False
        seen, value = seen | 1 << code, value >> 3
    return True


@functools.cache
def _rankings() -> frozenset[int]:
    """Every valid ranking (`ranked_ok`): each ordered choice of distinct steps, packed (13,700; about 0.9 MiB as a
    set, made on first use: only the processes that check steps pay it)."""
    return frozenset(rank_steps(p) for k in range(len(RANK_STEPS) + 1) for p in itertools.permutations(RANK_STEPS, k))


def optional_cell(c: list[int]) -> tuple[int, int, int] | None:
    """An optional cell as a table holds it ((-1, -1, -1): none), read as a Python list."""
    return None if c[0] == -1 else (c[0], c[1], c[2])


#: A row's value (read as a Python list) -> a record's, for the cell and drone columns.
_FROM_ROW: dict[Col, typing.Callable] = {Col.DRONE: drone_name, Col.OPTIONAL: optional_cell, Col.CELL: tuple,
                                         Col.SIGNED: tuple}


class Table:
    """Rows of one record type, held as a structured numpy array (read-only). A subclass names the record
    type and the column of each of its fields, in order (a `Col`, or an enum class):
    ``class T(Table, record=R, layout=(Col.DRONE, ...))``."""

    __slots__ = ("rows",)
    RECORD: ClassVar[type]
    LAYOUT: ClassVar[tuple[tuple[str, Col | type[enum.Enum]], ...]]
    DTYPE: ClassVar[np.dtype]
    ROW: ClassVar[struct.Struct]  # a row's bytes, unpacked to ints: a cell column gives three (`_why_few`)
    AT: ClassVar[tuple[int, ...]]  # each column's first int in an unpacked row
    rows: np.ndarray

    def __init_subclass__(cls, *, record: type, layout: tuple[Col | type[enum.Enum], ...]) -> None:
        cls.RECORD, cls.LAYOUT = record, tuple(zip((f.name for f in dataclasses.fields(record)), layout, strict=True))
        assert issubclass(record, Row) and "LAYOUT" not in vars(record), f"{cls.__name__}: one table per Row"
        record.LAYOUT = cls.LAYOUT
        dtypes = [_DTYPES.get(kind, ("u1", (), "B")) for _, kind in cls.LAYOUT]  # an enum column: a u8 code
        cls.DTYPE = np.dtype([(name, dt, shape) for (name, _), (dt, shape, _) in zip(cls.LAYOUT, dtypes)])
        codes = [code for _, _, code in dtypes]
        cls.ROW = struct.Struct("<" + "".join(codes))
        cls.AT = tuple(itertools.accumulate((3 if c == "3i" else 1 for c in codes[:-1]), initial=0))
        assert cls.ROW.size == cls.DTYPE.itemsize, f"{cls.__name__}: rows are packed, little-endian"

    def __init__(self, rows: np.ndarray) -> None:
        """`rows`: a 1-d array of `DTYPE` (it is made read-only). MalformedMessage if any row is not valid."""
        if not (isinstance(rows, np.ndarray) and rows.dtype == self.DTYPE and rows.ndim == 1):
            raise MalformedMessage(f"{type(self).__name__} needs a 1-d array of its rows")
        rows.flags.writeable = False
        self._check(rows)
        object.__setattr__(self, "rows", rows)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")

    # ------------------------------------------------------------------ building

    @classmethod
    def empty(cls, n: int) -> np.ndarray:
        """Rows to fill (then pass to the constructor, which checks them)."""
        return np.zeros(n, cls.DTYPE)

    @classmethod
    def of(cls, records: Iterable[object]) -> Self:
        """The table of records (each already a checked instance of `RECORD`)."""
        records = tuple(records)
        for r in records:
            if type(r) is not cls.RECORD:
                raise MalformedMessage(f"{cls.__name__} holds {cls.RECORD.__name__} records, got {type(r).__name__}")
        rows = cls.empty(len(records))
        for name, kind in cls.LAYOUT if records else ():
            values = [getattr(r, name) for r in records]
            if kind is Col.DRONE:
                values = [drone_number(v) for v in values]
            elif kind is Col.OPTIONAL:
                values = [_NONE if v is None else v for v in values]
            elif not isinstance(kind, Col):
                values = list(map(_index_of(kind).__getitem__, values))
            rows[name] = values
        return cls(rows)

    @classmethod
    def pack(cls, rows: Iterable[tuple[int, ...]]) -> Self:
        """The table of raw rows, each the values of `ROW` (a cell's three ints in place of the cell), checked."""
        try:
            return cls(np.frombuffer(b"".join(cls.ROW.pack(*row) for row in rows), cls.DTYPE))
        except struct.error as exc:
            raise MalformedMessage(f"{cls.__name__}: {exc}") from None

    @classmethod
    def build(cls, **columns: object) -> Self:
        """The table of the given columns, each a sequence of raw values (drone numbers, cells, enum codes),
        one per row; every column of `LAYOUT` must be given (an absent optional cell is (-1, -1, -1)), but a
        ranking (`Col.RANKED`), which is 0 (none) where it is not."""
        needed = {name for name, kind in cls.LAYOUT if kind is not Col.RANKED}
        if not needed <= set(columns) <= {name for name, _ in cls.LAYOUT}:
            raise MalformedMessage(f"{cls.__name__} needs the columns {[name for name, _ in cls.LAYOUT]}")
        n = len(columns[cls.LAYOUT[0][0]])  # type: ignore[arg-type]
        rows = cls.empty(n)
        for name, values in columns.items() if n else ():
            rows[name] = values
        return cls(rows)

    @classmethod
    def from_wire(cls, data: object) -> Self:
        if not isinstance(data, bytes):
            raise MalformedMessage(f"{cls.__name__} travels as bytes, got {type(data).__name__}")
        size = cls.DTYPE.itemsize
        if len(data) % size:
            raise MalformedMessage(f"{cls.__name__}: {len(data)} bytes is not a whole number of {size}-byte rows")
        return cls(np.frombuffer(data, cls.DTYPE))

    def to_wire(self) -> bytes:
        return self.rows.tobytes()

    # ------------------------------------------------------------------ checks

    @classmethod
    def _check(cls, rows: np.ndarray) -> None:
        """Every row valid: a few checked one by one in Python (`_why_few`), more by numpy columns (`_why_columns`,
        about a microsecond each at any size): the same rules, which a property test holds to one verdict."""
        if len(rows):
            why = cls._why_few(rows) if len(rows) <= CHECK_FEW_ROWS else cls._why_columns(rows)
            if why is not None:
                raise MalformedMessage(f"{cls.__name__}: {why}")

    @classmethod
    def _why_columns(cls, rows: np.ndarray) -> str | None:
        """Why some row of `rows` (at least one) is not valid, the first column's reason; None if all are."""
        for name, kind in cls.LAYOUT:
            col = rows[name]
            if kind is Col.DRONE:  # sorted (tables come in ids' order, D10 before D9): the least, then the steps
                numbers = np.sort(col)  # (a u16 is at most MAX_DRONE)
                if numbers[0] < 1:
                    return _WHY_NUMBER
                if not np.subtract(numbers[1:], numbers[:-1]).all():  # a repeat is a step of 0
                    return _WHY_ONCE
            elif isinstance(kind, Col):
                if not _column_ok(col, kind):
                    return f"each {name} must be {_must_be(kind)}"
            elif col.max() >= len(kind):
                return _why_code(name, kind)
        return None

    @classmethod
    def _why_few(cls, rows: np.ndarray) -> str | None:
        """`_why_columns`, row by row: each row unpacked to Python ints (`ROW`), checked by the records' rules."""
        unpacked = list(cls.ROW.iter_unpack(rows.tobytes()))
        for (name, kind), at in zip(cls.LAYOUT, cls.AT):
            if kind is Col.DRONE:
                numbers = [r[at] for r in unpacked]
                if min(numbers) < 1:  # (a u16 is at most MAX_DRONE)
                    return _WHY_NUMBER
                if len(set(numbers)) != len(numbers):
                    return _WHY_ONCE
            elif kind is Col.RANKED:
                if not all(ranked_ok(r[at]) for r in unpacked):
                    return f"each {name} must be {_must_be(kind)}"
            elif isinstance(kind, Col):
                lo, end = _LOWEST[kind], at + 3
                if not all(_cell_ok(r[at:end], lo) or kind is Col.OPTIONAL and r[at:end] == _NONE for r in unpacked):
                    return f"each {name} must be {_must_be(kind)}"
            elif max(r[at] for r in unpacked) >= len(kind):
                return _why_code(name, kind)
        return None

    # ------------------------------------------------------------------ reading

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def numbers(self) -> np.ndarray:
        """The drone numbers, in row order."""
        return self.rows["drone"]

    def ids(self) -> list[str]:
        return [drone_name(n) for n in self.rows["drone"].tolist()]

    def column(self, name: str) -> np.ndarray:
        """A column: a cell column is (n, 3) int32 (an absent optional cell is (-1, -1, -1)), an enum
        column each member's index in its enum's declaration order."""
        return self.rows[name]

    def records(self) -> tuple:
        """The rows as records, for people (each checked as it is built: a few microseconds a row)."""
        return self._records(self.rows)

    @classmethod
    def _records(cls, rows: np.ndarray) -> tuple:
        columns = []
        for name, kind in cls.LAYOUT:
            values = rows[name].tolist()
            if not isinstance(kind, Col):
                values = list(map(tuple(kind).__getitem__, values))
            elif kind in _FROM_ROW:
                values = list(map(_FROM_ROW[kind], values))
            columns.append(values)
        names = [name for name, _ in cls.LAYOUT]
        return tuple(cls.RECORD(**dict(zip(names, r))) for r in zip(*columns))

    def __iter__(self) -> Iterator:
        return iter(self.records())

    def __getitem__(self, i: int | slice):
        """A row's record (a slice: a tuple of them), built from that row alone."""
        return self._records(self.rows[i]) if isinstance(i, slice) else self._records(self.rows[[i]])[0]

    def __eq__(self, other: object) -> bool:
        if type(other) is type(self):
            return self.rows.tobytes() == other.rows.tobytes()
        if isinstance(other, tuple):
            return self.records() == other
        return NotImplemented

    def __hash__(self) -> int:
        return hash((type(self).__name__, self.rows.tobytes()))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.records()!r})"

    def __reduce__(self):
        return (type(self).from_wire, (self.to_wire(),))


class Row:
    """A table's row as a record (a frozen dataclass deriving from this, named as a `Table`'s RECORD): how
    people write and read swarm-sized data (samples, tests, a console). It is checked on construction by
    the rules of its table's columns (`LAYOUT`), which the table checks with numpy."""

    __slots__ = ()
    LAYOUT: ClassVar[tuple[tuple[str, Col | type[enum.Enum]], ...]]

    def __post_init__(self) -> None:
        for name, kind in self.LAYOUT:
            value = getattr(self, name)
            if kind is Col.DRONE:
                if not is_drone_id(value):
                    raise MalformedMessage(f"{name} must be a drone id like D01, got {value!r}")
            elif isinstance(kind, Col):
                if not (ranked_ok(value) if kind is Col.RANKED
                        else value is None and kind is Col.OPTIONAL or _cell_ok(value, _LOWEST[kind])):
                    raise MalformedMessage(f"{type(self).__name__}: {name} must be {_must_be(kind)}, got {value!r:.60}")
            elif type(value) is not kind:
                raise MalformedMessage(f"{type(self).__name__}: {name} must be a {kind.__name__}, got {value!r:.60}")


def _cell_ok(value: object, lo: int) -> bool:
    """Is `value` a cell, a tuple of 3 ints in lo..MAX_COORD?"""
    if type(value) is tuple and len(value) == 3:
        x, y, z = value
        return (type(x) is int and type(y) is int and type(z) is int
                and lo <= x <= MAX_COORD and lo <= y <= MAX_COORD and lo <= z <= MAX_COORD)
    return False


def _column_ok(col: np.ndarray, kind: Col) -> bool:
    """A cell or ranking column valid, with as few numpy calls as it can: each costs tens of microseconds on a
    thread just woken, as a process is at each message (docs/performance.md, the Tables row). A ranking: its
    values, as Python ints, all among the valid rankings (a set). A cell: its least and greatest coordinates.
    No mask of one byte a row: numpy keeps freed buffers under 1 KiB, up to 7 of each size, and tables of every
    size come (docs/performance.md, Memory)."""
    if kind is Col.RANKED:
        return _rankings().issuperset(col.tolist())
    lo = _LOWEST[kind]
    least, most = col.min(), col.max()
    if kind is not Col.OPTIONAL or least != -1 or most > MAX_COORD:  # (optional: none absent, or out of bounds)
        return bool(least >= lo and most <= MAX_COORD)
    u = np.ascontiguousarray(col).view(np.uint32) + np.uint32(1)  # some -1: an absent cell's is 0 (u32 wraps)
    # all three absent or none: as many rows with no coordinate absent as rows with one present (column by
    # column: a reduction over each row's three values costs ten times as much)
    x, y, z = u[:, 0], u[:, 1], u[:, 2]
    return np.count_nonzero(np.minimum(np.minimum(x, y), z)) == np.count_nonzero(np.maximum(np.maximum(x, y), z))


_WHY_NUMBER = f"drone numbers must be in 1..{MAX_DRONE}"
_WHY_ONCE = "one row per drone"


def _must_be(kind: Col) -> str:
    return kind.value + (", each code once" if kind is Col.RANKED else "")


def _why_code(name: str, kind: type[enum.Enum]) -> str:
    return f"{name} codes must be below {len(kind)} (members of {kind.__name__})"


@functools.cache
def _index_of(kind: type[enum.Enum]) -> dict:
    return {m: i for i, m in enumerate(kind)}


def code_of(member: enum.Enum) -> int:
    """A member's code in a table: its index in its enum's declaration order."""
    return _index_of(type(member))[member]
