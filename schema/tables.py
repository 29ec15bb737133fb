"""Columns for the swarm-sized parts of messages: a STATUS's drone states, a TURN's orders and moves, a
MOVES's steps, a WELCOME's starts and a ground station's DONE's targets.

A swarm of 1000 drones puts 1000 records in each of the first four every turn (and in the last, every turn
its targets change). As Python records they cost every
process that reads or writes them about a microsecond and a few hundred bytes per drone; as columns they
cost a few bytes per drone and are checked, read and written by numpy at once. On the wire a table is one
MessagePack ``bin``: its rows back to back, each row the fields of the record in declaration order, in the
fixed little-endian layout its class declares (``LAYOUT``, documented in schema/README.md):

- a drone is its number, ``u16`` (D01 is 1, D1000 is 1000: ids are canonical, see ``is_drone_id``);
- a cell is three ``i32`` (x, y, z); an optional cell that is absent is (-1, -1, -1);
- an enum is the ``u8`` index of its member in declaration order.

A table is immutable and validates on construction, like a message: an instance that exists is well
formed. Iterating it yields the records (``DroneStatus``, ``Order``, ...), so code that reads records keeps
working; code on a hot path reads the columns (``numbers``, ``column(name)``).
"""

from __future__ import annotations

import enum
import typing
from typing import ClassVar

import numpy as np

from .errors import MalformedMessage

if typing.TYPE_CHECKING:
    from collections.abc import Iterable, Iterator

#: Largest coordinate a cell may have, in a table or any message (worlds are far smaller; this bounds garbage).
MAX_COORD = 1 << 16
#: Largest drone number (D9999).
MAX_DRONE = 9999


class Col(enum.Enum):
    """What kind of column a record field is stored in."""

    DRONE = "u16 drone number"
    CELL = "3 x i32, each in 0..65536"
    SIGNED = "3 x i32, each in -65536..65536"
    OPTIONAL = "3 x i32, each in 0..65536, or (-1, -1, -1) for none"


_DTYPES = {Col.DRONE: ("<u2", ()), Col.CELL: ("<i4", (3,)), Col.SIGNED: ("<i4", (3,)), Col.OPTIONAL: ("<i4", (3,))}
_NONE = (-1, -1, -1)
_ABSENT = (1 << 32) - 1  # -1 as a u32


def drone_number(drone: str) -> int:
    """The number of a canonical drone id: 'D01' -> 1."""
    return int(drone[1:])


def drone_name(n: int) -> str:
    """The canonical id of drone number n: 1 -> 'D01' (unchecked: `messages.drone_id` checks n)."""
    return f"D{n:02d}"


def optional_cell(c: list[int]) -> tuple[int, int, int] | None:
    """An optional cell as a table holds it ((-1, -1, -1): none), read as a Python list."""
    return None if c[0] == -1 else (c[0], c[1], c[2])


class Table:
    """Rows of one record type, held as a structured numpy array (read-only). Subclasses declare the
    record type and each field's column (a `Col`, or an enum class)."""

    __slots__ = ("rows",)
    RECORD: ClassVar[type]
    LAYOUT: ClassVar[tuple[tuple[str, Col | type[enum.Enum]], ...]]
    DTYPE: ClassVar[np.dtype]
    rows: np.ndarray

    def __init_subclass__(cls) -> None:
        names = tuple(name for name, _ in cls.LAYOUT)
        assert names == tuple(cls.RECORD.__dataclass_fields__), \
            f"{cls.__name__}: LAYOUT must name {cls.RECORD.__name__}'s fields in order"
        cls.DTYPE = np.dtype([(name, *(_DTYPES[kind] if isinstance(kind, Col) else ("u1", ())))
                              for name, kind in cls.LAYOUT])

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
    def of(cls, records: Iterable[object]) -> "Table":
        """The table of records (each already a checked instance of `RECORD`)."""
        records = tuple(records)
        for r in records:
            if type(r) is not cls.RECORD:
                raise MalformedMessage(f"{cls.__name__} holds {cls.RECORD.__name__} records, got {type(r).__name__}")
        rows = cls.empty(len(records))
        for name, kind in cls.LAYOUT:
            values = [getattr(r, name) for r in records]
            if not values:
                continue
            if kind is Col.DRONE:
                rows[name] = [drone_number(v) for v in values]
            elif kind is Col.OPTIONAL:
                rows[name] = [_NONE if v is None else v for v in values]
            elif isinstance(kind, Col):
                rows[name] = values
            else:
                index = _index_of(kind)
                rows[name] = [index[v] for v in values]
        return cls(rows)

    @classmethod
    def build(cls, **columns: object) -> "Table":
        """The table of the given columns, each a sequence of raw values (drone numbers, cells, enum codes),
        one per row; every column of `LAYOUT` must be given (an absent optional cell is (-1, -1, -1))."""
        if set(columns) != {name for name, _ in cls.LAYOUT}:
            raise MalformedMessage(f"{cls.__name__} needs the columns {[name for name, _ in cls.LAYOUT]}")
        n = len(columns[cls.LAYOUT[0][0]])  # type: ignore[arg-type]
        rows = cls.empty(n)
        if n:
            for name, values in columns.items():
                rows[name] = values
        return cls(rows)

    @classmethod
    def from_wire(cls, data: object) -> "Table":
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
    def trusted(cls, rows: np.ndarray) -> "Table":
        """The table of rows this process built from values it has already checked (its own state), without
        checking them again, as `messages.unchecked` builds records: receivers check every table they get."""
        rows.flags.writeable = False
        table = object.__new__(cls)
        object.__setattr__(table, "rows", rows)
        return table

    @classmethod
    def _check(cls, rows: np.ndarray) -> None:
        """Every row valid: a few array operations per column, or for a few rows (where numpy's fixed cost
        per operation is the whole cost) the same test on Python lists."""
        if not len(rows):
            return
        small = len(rows) <= SMALL
        for name, kind in cls.LAYOUT:
            col = rows[name]
            if kind is Col.DRONE:
                numbers = col.tolist()
                if min(numbers) < 1 or max(numbers) > MAX_DRONE:
                    raise MalformedMessage(f"{cls.__name__}: drone numbers must be in 1..{MAX_DRONE}")
                if len(set(numbers)) != len(numbers):
                    raise MalformedMessage(f"{cls.__name__}: one row per drone")
            elif isinstance(kind, Col):
                if not (_cells_ok_few if small else _cells_ok)(col, kind):
                    raise MalformedMessage(f"{cls.__name__}: each {name} must be {kind.value}")
            elif (max(col.tolist()) if small else col.max()) >= len(kind):
                raise MalformedMessage(f"{cls.__name__}: {name} codes must be below {len(kind)} "
                                       f"(members of {kind.__name__})")

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
        """The rows as records (built unchecked: the table was checked whole)."""
        columns = []
        for name, kind in self.LAYOUT:
            values = self.rows[name].tolist()
            if kind is Col.DRONE:
                columns.append([drone_name(n) for n in values])
            elif kind is Col.OPTIONAL:
                columns.append([optional_cell(c) for c in values])
            elif isinstance(kind, Col):
                columns.append([tuple(c) for c in values])
            else:
                members = tuple(kind)
                columns.append([members[c] for c in values])
        make = _unchecked(self.RECORD)
        return tuple(make(*r) for r in zip(*columns))

    def __iter__(self) -> Iterator:
        return iter(self.records())

    def __getitem__(self, i: int | slice):
        """A row's record (a slice: a tuple of them), built from that row alone."""
        if isinstance(i, slice):
            return type(self).trusted(self.rows[i]).records()
        return type(self).trusted(self.rows[[i]]).records()[0]

    def __bool__(self) -> bool:
        return len(self.rows) > 0

    def __eq__(self, other: object) -> bool:
        if type(other) is type(self):
            return self.rows.tobytes() == other.rows.tobytes()  # type: ignore[union-attr]
        if isinstance(other, tuple):
            return self.records() == other
        return NotImplemented

    def __hash__(self) -> int:
        return hash((type(self).__name__, self.rows.tobytes()))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.records()!r})"

    def __reduce__(self):
        return (type(self).from_wire, (self.to_wire(),))


#: Up to this many rows, a table is checked on Python lists rather than with numpy.
SMALL = 8


def _cells_ok(col: np.ndarray, kind: Col) -> bool:
    """A cell column valid, with numpy: a u32 view of an i32 turns negative values into huge ones, so one
    maximum checks both bounds."""
    if kind is Col.CELL:
        return bool(col.view(np.uint32).max() <= MAX_COORD)
    if kind is Col.SIGNED:
        return bool((col + MAX_COORD).view(np.uint32).max() <= 2 * MAX_COORD)
    u = col.view(np.uint32)  # OPTIONAL: an absent cell is (-1, -1, -1), all three 2**32 - 1
    return bool(np.where(u.min(axis=1) == _ABSENT, 0, u.max(axis=1)).max() <= MAX_COORD)


def _cells_ok_few(col: np.ndarray, kind: Col) -> bool:
    """`_cells_ok` on Python lists."""
    cells = col.tolist()
    if kind is Col.OPTIONAL:
        cells = [c for c in cells if c != [-1, -1, -1]]
    lo = -MAX_COORD if kind is Col.SIGNED else 0
    return all(lo <= v <= MAX_COORD for c in cells for v in c)


_INDEXES: dict[type, dict] = {}


def _index_of(kind: type[enum.Enum]) -> dict:
    index = _INDEXES.get(kind)
    if index is None:
        index = _INDEXES[kind] = {m: i for i, m in enumerate(kind)}
    return index


def code_of(member: enum.Enum) -> int:
    """A member's code in a table: its index in its enum's declaration order."""
    return _index_of(type(member))[member]


def _unchecked(cls: type):
    from .messages import unchecked  # the records' module imports this one
    return unchecked(cls)
