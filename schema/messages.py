"""Every message of the wire contract, defined once, with its MessagePack codec (the wire form: README.md).

Messages are frozen, slotted, keyword-only dataclasses that validate on construction, so an instance that
exists is well formed. Fields go on the wire in declaration order, so encoding is deterministic (golden bytes:
vectors.json). World bounds are context, not syntax: a message only checks that a cell is three integers in
range; receivers check it against the world (``OutOfRange``).
"""

from __future__ import annotations

import dataclasses
import enum
import operator
import re
import typing
from dataclasses import dataclass
from typing import ClassVar

import msgpack
import numpy as np

from .errors import MalformedMessage, UsageError
from .tables import (
    MAX_COORD,
    MAX_DRONE,
    RANK_STEPS,
    Col,
    Row,
    Table,
    _cell_ok,
    _numbered,
    code_of,
    drone_name,
    is_drone_id,
    optional_cell,
    ranked_ok,
)
from .tuning import PACK_BUFFER

#: 2: swarm-sized record tuples travel as tables (tables.py); 3: also WELCOME's starts, DONE's targets;
#: 4: NPS and a MOVES's steps carry the drone's ranked candidate steps (`ranked`, for cooperative arbitration);
#: 5: WELCOME, TURN, STATUS and OVER carry the game's identity.
SCHEMA_VERSION = 5

#: Largest turn a message may carry.
MAX_TURN = 1 << 40
#: Largest payload any receiver decodes; bigger ones are rejected before parsing.
MAX_PAYLOAD = 1 << 22
#: Most cells a world may have (nx * ny * nz), checked with its size before anything is allocated for it: the
#: largest world the project makes is the 512 x 512 x 64 of `dronesim bench perf`'s generation (2^24 cells), eight
#: times the largest played (the 256 x 256 x 32 city, 2^21). Its packed map, 2 MiB, is the largest that travels in
#: one MAP or WELCOME (a map of 2^25 cells exceeds `MAX_PAYLOAD`), and every process holds a few bytes a cell (a
#: grid, labels, padded copies): a size of 65536^3 passed every other check and cost 16 GiB before it failed.
MAX_CELLS = 1 << 24
#: Largest text (in UTF-8 bytes) an OVER carries: the whole OVER stays under its key's size limit
#: (`schema.keys.ENVELOPE`, which every receiver enforces unread). A longer one never reached anyone: the end of a
#: game that named its hundred lost drones one by one.
MAX_OVER_TEXT = 768

Cell = tuple[int, int, int]


def is_host_id(value: object) -> bool:
    """A swarm host's id: H01, H02, ..."""
    return _numbered(value, "H")


def drone_id(n: int) -> str:
    """The conventional id of the n-th drone: 1 -> 'D01', 100 -> 'D100'."""
    if not 1 <= n <= MAX_DRONE:
        raise ValueError(f"drone number {n} out of 1..{MAX_DRONE}")
    return drone_name(n)


def drone_list(text: str) -> tuple[str, ...]:
    """``D01`` / ``D01,D02`` / ``D01-D08`` / ``1-8`` -> the drone ids, in that order (a UsageError saying why, for
    anything else: a drone twice, a range backwards, a number out of 1..MAX_DRONE)."""
    ids: list[str] = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        m = re.fullmatch(r"D?(\d{1,6})(?:\s*-\s*D?(\d{1,6}))?", part)
        first, last = (int(m[1]), int(m[2] or m[1])) if m else (0, 0)
        if not 1 <= first <= last <= MAX_DRONE:
            raise UsageError(f"bad drone list {text!r}: {part!r} is not D01, D01-D08 or 1-8 (drones 1 to {MAX_DRONE})")
        ids += map(drone_name, range(first, last + 1))
    if not ids or len(set(ids)) != len(ids):
        raise UsageError(f"bad drone list {text!r}: {'no drone' if not ids else 'a drone listed twice'}")
    return tuple(ids)


class Role(enum.Enum):
    """What an entity is; the coordinator admits at most one ENV and one GCS per game."""

    ENV = "ENV"
    GCS = "GCS"
    DRONE = "DRONE"


class Phase(enum.Enum):
    """Phases of one turn, in order (the seed's GCS -> D01 -> ENV -> OBS cycle)."""

    GCS = "GCS"
    DRONES = "DRONES"
    ENV = "ENV"


class CellKind(enum.IntEnum):
    EMPTY = 0
    BUILDING = 1
    OUTSIDE = 2


class Note(enum.Enum):
    """What a drone says about its own progress alongside its new position: REACHED, on its target; UNREACHABLE, the
    static world has no way to it (a building, outside the world, walled in); STUCK, a way exists but other drones
    have been in it for long (the arbitration's to resolve; never a reason to give up)."""

    NONE = "NONE"
    REACHED = "REACHED"
    UNREACHABLE = "UNREACHABLE"
    STUCK = "STUCK"


class DroneState(enum.Enum):
    ALIVE = "ALIVE"
    DEAD = "DEAD"
    LOST = "LOST"


class Cause(enum.Enum):
    """Why a drone died (observer rules) or was lost."""

    NONE = "NONE"
    BUILDING = "BUILDING"
    OUTSIDE = "OUTSIDE"
    VERTEX = "VERTEX"  # two drones in one cell
    SWAP = "SWAP"  # two drones swapped cells
    LOST = "LOST"  # missed its deadlines or its process vanished


class EndReason(enum.Enum):
    NO_DRONE_ALIVE = "NO_DRONE_ALIVE"
    ALL_REACHED = "ALL_REACHED"
    SETTLED = "SETTLED"  # every drone reached its target or reported it unreachable
    TURN_LIMIT = "TURN_LIMIT"
    GCS_QUIT = "GCS_QUIT"
    ABORTED = "ABORTED"
    INTERRUPTED = "INTERRUPTED"  # the coordinator was told to stop (SIGINT, SIGTERM)
    JOURNAL_FAILED = "JOURNAL_FAILED"  # the journal could not be written (a full disk): resumable once there is room


class Intent(enum.Enum):
    """What the GCS says with its DONE: more orders may come, its plan is complete, or end the game."""

    CONTINUE = "CONTINUE"
    FINAL = "FINAL"
    QUIT = "QUIT"


def _check(cond: bool, what: str) -> None:
    if not cond:
        raise MalformedMessage(what)


def _check_int(value: object, name: str, lo: int, hi: int) -> None:
    if not (type(value) is int and lo <= value <= hi):
        raise MalformedMessage(f"{name} must be an int in {lo}..{hi}, got {value!r}")


def _check_cell(value: object, name: str, *, signed: bool = False) -> None:
    lo = -MAX_COORD if signed else 0
    if _cell_ok(value, lo):
        return
    if not (isinstance(value, tuple) and len(value) == 3):
        raise MalformedMessage(f"{name} must be 3 integers, got {value!r}")
    for c in value:
        _check_int(c, name, lo, MAX_COORD)


def _check_drone(value: object, name: str = "drone") -> None:
    if not is_drone_id(value):
        raise MalformedMessage(f"{name} must be a drone id like D01, got {value!r}")


def _check_game(value: object) -> None:
    _check(isinstance(value, str) and len(value) <= 32 and (value.isalnum() or value == ""),
           "game must be a game id (up to 32 alphanumerics)")


def is_entity_id(value: object) -> bool:
    """ENV, GCS, SRV, OBS, a drone's id or a host's."""
    return isinstance(value, str) and (value in ("ENV", "GCS", "SRV", "OBS") or is_drone_id(value) or is_host_id(value))


def _check_sender(value: object) -> None:
    if not is_entity_id(value):
        raise MalformedMessage(f"sender must be ENV, GCS, SRV, OBS, Dnn or Hnn, got {value!r}")


def oversized(size: Cell) -> str:
    """Why a world of `size` cannot be (more than `MAX_CELLS` cells)."""
    return f"a world of {size[0]} x {size[1]} x {size[2]} cells exceeds the {MAX_CELLS} cells a world may have"


def _check_world(size: Cell, bits: bytes, name: str, *, optional: bool = False) -> None:
    """A world's size and its building cells, one bit each (packed; `optional`: or none)."""
    _check_cell(size, "size")
    _check(all(s >= 1 for s in size), "world sizes must be >= 1")
    n = size[0] * size[1] * size[2]
    _check(n <= MAX_CELLS, oversized(size))
    _check(isinstance(bits, bytes), f"{name} must be bytes")
    _check(optional and not bits or len(bits) == (n + 7) // 8, f"{name} must hold one bit per cell")


@dataclass(frozen=True, slots=True, kw_only=True)
class CellInfo:
    """What is in one cell: the seed's ``whatInside``. Outside the world, kind is OUTSIDE."""

    pos: Cell
    kind: CellKind
    drones: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if _cell_ok(self.pos, -MAX_COORD) and type(self.kind) is CellKind and self.drones == ():
            return  # the common case: an empty or building cell
        _check_cell(self.pos, "cell", signed=True)
        _check(isinstance(self.kind, CellKind), f"kind must be a CellKind, got {self.kind!r}")
        _check(isinstance(self.drones, tuple), "drones must be a tuple")
        for d in self.drones:
            _check_drone(d)


#: The 6-neighbourhood, in the order an ASK's `around` cells are expanded: +x, -x, +y, -y, +z, -z.
AROUND: tuple[Cell, ...] = RANK_STEPS[:6]
#: Most cells one ASK may ask (its cells plus 6 per `around` cell).
MAX_ASKED = 1 << 15


@dataclass(frozen=True, slots=True, kw_only=True)
class Order(Row):
    """Coordinator -> drone, in the DRONES phase: where the drone is and where it must go."""

    drone: str
    pos: Cell
    target: Cell | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class Move(Row):
    """Coordinator -> environment, in the ENV phase: a drone's accepted move (may leave the world)."""

    drone: str
    src: Cell
    dst: Cell


@dataclass(frozen=True, slots=True, kw_only=True)
class Aim(Row):
    """GCS -> SRV, inside its DONE: one drone's target (the seed's ``GCS:D01:TGT:x:y:z``, batched)."""

    drone: str
    pos: Cell


@dataclass(frozen=True, slots=True, kw_only=True)
class Step(Row):
    """Swarm host -> SRV, inside its MOVES: one hosted drone's move (the seed's NPS, batched)."""

    drone: str
    pos: Cell
    note: Note = Note.NONE
    ranked: int = 0  # as an NPS's


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneStatus(Row):
    """One drone's state at the end of a turn, as the observer sees it."""

    drone: str
    pos: Cell
    state: DroneState
    target: Cell | None = None
    note: Note = Note.NONE
    cause: Cause = Cause.NONE

    @property
    def alive(self) -> bool:
        return self.state is DroneState.ALIVE


@dataclass(frozen=True, slots=True, kw_only=True)
class Start(Row):
    """A drone admitted to the game and the cell it starts in."""

    drone: str
    pos: Cell


@dataclass(frozen=True, slots=True, kw_only=True)
class WorldSpec:
    """The world of a game, as the coordinator's scenario fixes it and the environment builds it:
    generated from `seed` (keeping the start cells free) or, when `cells` is not empty, exactly the
    given building cells (packed bits, as in `WorldMap`)."""

    size: Cell
    seed: int = 0
    cells: bytes = b""

    def __post_init__(self) -> None:
        _check_world(self.size, self.cells, "cells", optional=True)
        _check_int(self.seed, "seed", 0, (1 << 63) - 1)


# --------------------------------------------------------------------------- tables (see tables.py)


_ALIVE_CODE = code_of(DroneState.ALIVE)


class StartTable(Table, record=Start, layout=(Col.DRONE, Col.CELL)):
    """A WELCOME's starts, one row per drone admitted."""

    __slots__ = ()

    def cells(self) -> dict[str, Cell]:
        """Each drone's start cell, read from the columns."""
        return dict(zip(self.ids(), map(tuple, self.rows["pos"].tolist())))


class AimTable(Table, record=Aim, layout=(Col.DRONE, Col.CELL)):
    """A ground station's DONE's targets, one row per drone."""

    __slots__ = ()


class OrderTable(Table, record=Order, layout=(Col.DRONE, Col.CELL, Col.OPTIONAL)):
    """A TURN(DRONES)'s orders, one row per alive drone."""

    __slots__ = ()

    def orders(self, mine: typing.Container[str] | None = None) -> tuple[tuple[str, Cell, Cell | None], ...]:
        """(drone, where it is, its target) of each row (of the drones in `mine`), read from the columns."""
        return tuple((d, (x, y, z), optional_cell(t))
                     for d, (x, y, z), t in zip(self.ids(), self.rows["pos"].tolist(), self.rows["target"].tolist())
                     if mine is None or d in mine)


class MoveTable(Table, record=Move, layout=(Col.DRONE, Col.CELL, Col.SIGNED)):
    """A TURN(ENV)'s accepted moves, one row per moving drone."""

    __slots__ = ()


class StepTable(Table, record=Step, layout=(Col.DRONE, Col.SIGNED, Note, Col.RANKED)):
    """A MOVES's steps, one row per hosted drone."""

    __slots__ = ()


class StatusTable(Table, record=DroneStatus, layout=(Col.DRONE, Col.SIGNED, DroneState, Col.OPTIONAL, Note, Cause)):
    """A STATUS's drone states, one row per drone."""

    __slots__ = ()

    def alive_mask(self) -> np.ndarray:
        return self.rows["state"] == _ALIVE_CODE

    def alive(self) -> list[str]:
        """The ids of the alive drones, in row order."""
        return [drone_name(n) for n in self.rows["drone"][self.alive_mask()].tolist()]


TABLES: tuple[type[Table], ...] = (StartTable, AimTable, OrderTable, MoveTable, StepTable, StatusTable)
_EMPTY: dict[type[Table], Table] = {cls: cls(cls.empty(0)) for cls in TABLES}  # (immutable: one of each)


def _as_table(msg: Message, name: str, cls: type[Table]) -> None:
    """A message's table field given as a tuple of records becomes the table (messages hold tables)."""
    value = getattr(msg, name)
    if type(value) is not cls:
        _check(isinstance(value, tuple), f"{name} must be a {cls.__name__} or a tuple of {cls.RECORD.__name__}")
        object.__setattr__(msg, name, _EMPTY[cls] if not value else cls.of(value))


@dataclass(frozen=True, slots=True, kw_only=True)
class Message:
    """Common header: the turn it belongs to and who says it."""

    TAG: ClassVar[str] = ""
    turn: int
    sender: str

    def __post_init__(self) -> None:
        _check_int(self.turn, "turn", 0, MAX_TURN)
        _check_sender(self.sender)
        self._validate()

    def _validate(self) -> None:
        """A message type's checks of its own fields, after the header's."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Connect(Message):
    """Entity -> SRV (query on SRV/CONNECT): ``X:SRV:CONNECT``. A drone process lists the drones it hosts
    and the autopilot flying them."""

    TAG: ClassVar[str] = "CONNECT"
    role: Role
    drones: tuple[str, ...] = ()
    autopilot: str = ""
    cooperative: bool = False  # its drones give way to others when moves conflict (arbitration)
    session: str = ""  # the sender's Zenoh session id: tells a reconnection from an impostor

    def _validate(self) -> None:
        _check(isinstance(self.role, Role), "role must be a Role")
        _check(isinstance(self.drones, tuple), "drones must be a tuple")
        for d in self.drones:
            _check_drone(d)
        _check(len(set(self.drones)) == len(self.drones), "drones must be distinct")
        _check(self.role is Role.DRONE or not self.drones, "only a DRONE entity hosts drones")
        _check(self.role is not Role.DRONE or bool(self.drones), "a DRONE entity must host at least one drone")
        _check(isinstance(self.autopilot, str) and len(self.autopilot) <= 32, "autopilot must be a short string")
        _check(type(self.cooperative) is bool, "cooperative must be a bool")
        _check(isinstance(self.session, str) and (self.session == "" or len(self.session) <= 64
                                                  and self.session.isalnum()),
               "session must be a Zenoh id (up to 64 alphanumerics)")


@dataclass(frozen=True, slots=True, kw_only=True)
class Welcome(Message):
    """SRV -> entity (reply to CONNECT): "You are connected as ROLE", with what the entity needs."""

    TAG: ClassVar[str] = "WELCOME"
    entity: str
    text: str
    world: WorldSpec
    starts: StartTable = ()  # type: ignore[assignment]  # a tuple of records becomes the table (`_as_table`)
    game: str = ""  # the game's identity: its TURN, STATUS and OVER carry it, the entity takes no other

    def _validate(self) -> None:
        _check_game(self.game)
        _check_sender(self.entity)
        _check(isinstance(self.text, str), "text must be a string")
        _check(isinstance(self.world, WorldSpec), "world must be a WorldSpec")
        _as_table(self, "starts", StartTable)


@dataclass(frozen=True, slots=True, kw_only=True)
class Refused(Message):
    """SRV -> entity (reply to CONNECT): admission refused, with the reason."""

    TAG: ClassVar[str] = "REFUSED"
    text: str

    def _validate(self) -> None:
        _check(isinstance(self.text, str), "text must be a string")


@dataclass(frozen=True, slots=True, kw_only=True)
class Turn(Message):
    """SRV -> all: a phase of a turn begins. DRONES carries the orders, ENV the accepted moves."""

    TAG: ClassVar[str] = "TURN"
    phase: Phase
    orders: OrderTable = ()  # type: ignore[assignment]
    moves: MoveTable = ()  # type: ignore[assignment]
    game: str = ""  # the game's identity (its WELCOME's)

    def _validate(self) -> None:
        _check_game(self.game)
        _as_table(self, "orders", OrderTable)
        _as_table(self, "moves", MoveTable)
        _check(isinstance(self.phase, Phase), "phase must be a Phase")
        _check(self.turn >= 1, "turns start at 1")
        _check(self.phase is Phase.DRONES or not self.orders, "only the DRONES phase carries orders")
        _check(self.phase is Phase.ENV or not self.moves, "only the ENV phase carries moves")


@dataclass(frozen=True, slots=True, kw_only=True)
class Target(Message):
    """GCS -> drone (key ``<drone>/TGT``): ``GCS:D01:TGT:x:y:z``."""

    TAG: ClassVar[str] = "TGT"
    drone: str
    pos: Cell

    def _validate(self) -> None:
        _check_drone(self.drone)
        _check_cell(self.pos, "target")


@dataclass(frozen=True, slots=True, kw_only=True)
class Done(Message):
    """Entity -> SRV: ``X:SRV:DONE``, the end of the sender's phase (the GCS's; NPS/MOVES close the
    drones' phase themselves). The GCS's DONE may carry its targets (one message for a whole swarm);
    `count` says how many separate TGT messages it also sent."""

    TAG: ClassVar[str] = "DONE"
    phase: Phase
    intent: Intent = Intent.CONTINUE
    count: int = 0  # (TGTs and the DONE travel on different keys: a DONE may overtake them)
    targets: AimTable = ()  # type: ignore[assignment]

    def _validate(self) -> None:
        _check(isinstance(self.phase, Phase), "phase must be a Phase")
        _check(isinstance(self.intent, Intent), "intent must be an Intent")
        _check_int(self.count, "count", 0, 1 << 20)
        _as_table(self, "targets", AimTable)


@dataclass(frozen=True, slots=True, kw_only=True)
class Ask(Message):
    """Drone -> ENV (query on ENV/ASK): ``D01:ENV:ASK:x:y:z``, for one or several cells, and for the
    6 neighbours (in `AROUND` order) of each `around` cell: a swarm's whole neighbourhood in one ASK."""

    TAG: ClassVar[str] = "ASK"
    cells: tuple[Cell, ...] = ()
    around: tuple[Cell, ...] = ()

    MAX_CELLS: ClassVar[int] = MAX_ASKED

    def _validate(self) -> None:
        _check(isinstance(self.cells, tuple) and isinstance(self.around, tuple), "cells and around are arrays")
        _check(1 <= len(self.cells) + 6 * len(self.around) <= self.MAX_CELLS,
               f"an ASK asks for 1..{self.MAX_CELLS} cells")
        for c in self.cells:
            if not _cell_ok(c, -MAX_COORD):
                _check_cell(c, "cell", signed=True)
        for c in self.around:
            if not _cell_ok(c, -MAX_COORD + 1) or max(c) >= MAX_COORD:
                _check(False, f"around cells must be 3 integers with neighbours in range, got {c!r}")

    def asked(self) -> tuple[Cell, ...]:
        """Every asked cell, in answer order (`asked_cells`)."""
        return asked_cells(self.cells, self.around)


def asked_cells(cells: typing.Iterable[Cell], around: typing.Iterable[Cell]) -> tuple[Cell, ...]:
    """`cells`, then the 6 neighbours of each `around` cell in `AROUND` order: what an ASK asks."""
    return (*cells, *((x + dx, y + dy, z + dz) for x, y, z in around for dx, dy, dz in AROUND))


@dataclass(frozen=True, slots=True, kw_only=True)
class Ans(Message):
    """ENV -> drone (reply to ASK): ``ENV:D01:ANS:content`` for every asked cell (`Ask.asked` order):
    its CellKind, one byte each, and (index, drone) for each drone in an asked cell, in that order."""

    TAG: ClassVar[str] = "ANS"
    kinds: bytes
    drones: tuple[tuple[int, str], ...] = ()

    def _validate(self) -> None:
        _check(isinstance(self.kinds, bytes) and len(self.kinds) <= MAX_ASKED, "kinds must be bytes")
        _check(max(self.kinds, default=0) <= max(CellKind), "kinds must be CellKind values")
        _check(type(self.drones) is tuple, "drones must be an array")
        n, last = len(self.kinds), (-1, "")
        for p in self.drones:
            if not (type(p) is tuple and len(p) == 2 and type(p[0]) is int and 0 <= p[0] < n
                    and is_drone_id(p[1]) and p > last):
                raise MalformedMessage(f"drones must be (index of an asked cell, drone id) pairs in increasing "
                                       f"order, got {p!r:.60} after {last!r}")
            last = p

    def check_fits(self, cells: tuple[Cell, ...]) -> None:
        """MalformedMessage if this is not an answer to a question about `cells` (one kind each)."""
        _check(len(cells) == len(self.kinds), f"{len(self.kinds)} answers for {len(cells)} asked cells")

    def infos(self, cells: tuple[Cell, ...]) -> tuple[CellInfo, ...]:
        """One CellInfo per asked cell; MalformedMessage if the answer does not fit the question."""
        self.check_fits(cells)
        drones: dict[int, tuple[str, ...]] = {}  # asked cell index -> the drones in it
        for i, d in self.drones:
            drones[i] = drones.get(i, ()) + (d,)
        return tuple(CellInfo(pos=c, kind=_KINDS[k], drones=drones.get(i, ())) for i, (c, k) in
                     enumerate(zip(cells, self.kinds)))


@dataclass(frozen=True, slots=True, kw_only=True)
class Nps(Message):
    """Drone -> SRV/ENV (key ``<drone>/NPS``): ``D01:ENV:NPS:x:y:z``, the drone's move for this turn."""

    TAG: ClassVar[str] = "NPS"
    pos: Cell
    note: Note = Note.NONE
    #: The cells the drone offers the arbiter, best first, as steps from where it is (packed by
    #: `tables.rank_steps`; 0: none, it takes `pos` or hovers): a cooperative drone may be given any of them.
    ranked: int = 0

    def _validate(self) -> None:
        _check_drone(self.sender, "sender")
        _check_cell(self.pos, "pos", signed=True)
        _check(isinstance(self.note, Note), "note must be a Note")
        _check(ranked_ok(self.ranked), f"ranked must be steps packed by rank_steps (each once), got {self.ranked!r}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Moves(Message):
    """Swarm host -> SRV (key ``<host>/MOVES``): the NPS of every drone it flies, in one message. Sent in the
    turn's GCS phase (with the GCS's DONE, by a host that decides from the STATUS alone), it is held until the
    drones' phase opens. An empty MOVES, in the drones' phase, says the host is still deciding that turn: the
    phase's deadline counts again from it, up to a cap (`--phase-cap`); never held."""

    TAG: ClassVar[str] = "MOVES"
    moves: StepTable

    def _validate(self) -> None:
        _as_table(self, "moves", StepTable)


@dataclass(frozen=True, slots=True, kw_only=True)
class Upd(Message):
    """ENV -> OBS (key ``ENV/UPD``): ``ENV:OBS:UPD:x:y:z:content`` for every changed cell, in one batch."""

    TAG: ClassVar[str] = "UPD"
    cells: tuple[CellInfo, ...]

    def _validate(self) -> None:
        _check(isinstance(self.cells, tuple) and all(type(c) is CellInfo for c in self.cells),
               "cells must be a tuple of CellInfo records")


@dataclass(frozen=True, slots=True, kw_only=True)
class Status(Message):
    """OBS -> all (key ``OBS/STATUS``): every drone's state at the end of the turn (turn 0: the starts)."""

    TAG: ClassVar[str] = "STATUS"
    drones: StatusTable
    game: str = ""  # the game's identity (its WELCOME's)

    def _validate(self) -> None:
        _check_game(self.game)
        _as_table(self, "drones", StatusTable)


@dataclass(frozen=True, slots=True, kw_only=True)
class Over(Message):
    """SRV -> all (key ``SRV/OVER``): ``SRV:X:OVER``, the game has ended; every process exits 0 (75, EX_TEMPFAIL,
    when its journal could not be written: JOURNAL_FAILED)."""

    TAG: ClassVar[str] = "OVER"
    reason: EndReason
    text: str = ""
    game: str = ""  # the game's identity (its WELCOME's)

    def _validate(self) -> None:
        _check_game(self.game)
        _check(isinstance(self.reason, EndReason), "reason must be an EndReason")
        _check(isinstance(self.text, str) and len(self.text.encode()) <= MAX_OVER_TEXT,
               f"text must be a string of at most {MAX_OVER_TEXT} bytes")


@dataclass(frozen=True, slots=True, kw_only=True)
class MapRequest(Message):
    """GCS or drone process -> ENV (query on ENV/MAP): the static world."""

    TAG: ClassVar[str] = "MAPREQ"


@dataclass(frozen=True, slots=True, kw_only=True)
class WorldMap(Message):
    """ENV -> GCS or drone process (reply to MAPREQ): world size and the building cells as a packed bit array
    (numpy ``packbits`` of the C-ordered boolean grid indexed [x, y, z])."""

    TAG: ClassVar[str] = "MAP"
    size: Cell
    buildings: bytes

    def _validate(self) -> None:
        _check_world(self.size, self.buildings, "buildings")


_KINDS = tuple(CellKind)
MESSAGE_TYPES: tuple[type[Message], ...] = (
    Connect, Welcome, Refused, Turn, Target, Done, Ask, Ans, Nps, Moves, Upd, Status, Over, MapRequest, WorldMap,
)
_BY_TAG: dict[str, type[Message]] = {cls.TAG: cls for cls in MESSAGE_TYPES}


# --------------------------------------------------------------------------- codec
#
# Driven by each dataclass's type hints, resolved once (`_codec`): int, str, bytes, Cell, enums, the records
# that travel as records (`CellInfo`, `WorldSpec`), tables, and tuple[X, ...] of those.

Encoder = typing.Callable[[object], typing.Any]


def _identity(v: object) -> object:
    return v


def _as_seq(v: object) -> tuple:
    """A MessagePack array (decoded as a tuple)."""
    if type(v) is not tuple:
        raise MalformedMessage(f"expected an array, got {type(v).__name__}")
    return v


def _codec(hint: object) -> tuple[Encoder, Encoder]:
    """How a field of type `hint` goes on the wire (msgpack packs ints, strings, bytes and tuples itself) and
    is read from it (the types only: the values are checked by the message or record that receives them)."""
    args = typing.get_args(hint)
    if typing.get_origin(hint) is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            item, dec = _codec(args[0])
            return (_identity if item is _identity else lambda v: [item(x) for x in typing.cast(tuple, v)],
                    _as_seq if dec is _as_seq or dec is _identity else lambda v: tuple(map(dec, _as_seq(v))))
        return _identity, _as_seq  # Cell: validated by the record itself
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return operator.attrgetter("value"), _enum_converter(hint)
    if hint in (CellInfo, WorldSpec):
        return _record_codec(hint)
    if hint in TABLES:
        return Table.to_wire, hint.from_wire  # type: ignore[return-value]
    return _identity, _identity  # int, str, bytes: checked by __post_init__


def _enum_converter(cls: type[enum.Enum]) -> Encoder:
    """The member of `cls` whose value is v, of the members' type (an IntEnum takes an int, not True or 1.0)."""
    members = {m.value: m for m in cls}
    value_type, = {type(v) for v in members}

    def convert(v: object) -> enum.Enum:
        m = members.get(v) if type(v) is value_type else None
        if m is None:
            raise MalformedMessage(f"{v!r:.40} is not a valid {cls.__name__}")
        return m
    return convert


def _fields(cls: type) -> tuple[tuple[str, str, Encoder, Encoder], ...]:
    """(attribute, wire name, encoder, decoder) of each field of `cls`, in order."""
    hints = typing.get_type_hints(cls)
    return tuple((f.name, "from" if f.name == "sender" else f.name, *_codec(hints[f.name]))
                 for f in dataclasses.fields(cls))


def _record_codec(cls: type) -> tuple[Encoder, Encoder]:
    """A record's encoder (the array of its fields, in declaration order) and decoder (from that array, built
    by its constructor, which checks the fields)."""
    fields = _fields(cls)
    n, values = len(fields), operator.attrgetter(*(name for name, *_ in fields))
    encoders = [enc for _, _, enc, _ in fields]

    def convert(v: object) -> object:
        if type(v) is not tuple or len(v) != n:
            raise MalformedMessage(f"{cls.__name__} needs {n} items, got {v!r:.80}")
        return cls(**{name: dec(x) for (name, _, _, dec), x in zip(fields, v)})
    return lambda record: [enc(v) for enc, v in zip(encoders, values(record))], convert


_FIELDS = {cls: _fields(cls) for cls in MESSAGE_TYPES}
_WIRE_NAMES = {cls: frozenset(wire for _, wire, _, _ in fields) for cls, fields in _FIELDS.items()}


def encode(msg: Message) -> bytes:
    """The MessagePack bytes of a message: a map of the header ("v", "t") and the fields, in order."""
    fields = _FIELDS[type(msg)]
    packer = msgpack.Packer(use_bin_type=True, autoreset=False, buf_size=PACK_BUFFER)
    pack = packer.pack
    packer.pack_map_header(2 + len(fields))
    pack("v"), pack(SCHEMA_VERSION), pack("t"), pack(msg.TAG)
    for name, wire, enc, _ in fields:
        pack(wire)
        pack(enc(getattr(msg, name)))
    return packer.bytes()


M = typing.TypeVar("M", bound=Message)


@typing.overload
def decode(data: bytes, expect: type[M]) -> M: ...
@typing.overload
def decode(data: bytes, expect: tuple[type[Message], ...] | None = None) -> Message: ...


def decode(data: bytes, expect: type[Message] | tuple[type[Message], ...] | None = None) -> Message:
    """Decode and validate bytes; raise `MalformedMessage` with a clear reason on anything wrong. `expect`: the
    type (or types) the key it arrived on carries, any other is rejected as wrongly addressed."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MalformedMessage(f"payload must be bytes, got {type(data).__name__}")
    if len(data) > MAX_PAYLOAD:
        raise MalformedMessage(f"payload of {len(data)} bytes exceeds {MAX_PAYLOAD}", reason="too-large")
    try:
        body = msgpack.unpackb(bytes(data), raw=False, strict_map_key=True, use_list=False)
    except Exception as exc:  # msgpack raises several unrelated types
        raise MalformedMessage(f"not MessagePack: {exc.__class__.__name__}: {exc}") from None
    _check(isinstance(body, dict), f"payload must be a map, got {type(body).__name__}")
    version = body.pop("v", None)
    _check(type(version) is int and version == SCHEMA_VERSION,
           f"schema version {version!r}, this build speaks {SCHEMA_VERSION}")
    tag = body.pop("t", None)
    cls = _BY_TAG.get(tag) if isinstance(tag, str) else None
    if cls is None:
        raise MalformedMessage(f"unknown message type {tag!r}")
    if expect is not None:
        allowed = expect if isinstance(expect, tuple) else (expect,)
        if cls not in allowed:
            names = "/".join(a.TAG for a in allowed)
            raise MalformedMessage(f"a {tag} message on a key that carries {names}", reason="wrong-type")
    _check("sender" not in body, f"unknown fields ['sender'] in {tag} (the wire name is 'from')")
    extra = body.keys() - _WIRE_NAMES[cls]
    _check(not extra, f"unknown fields {sorted(map(str, extra))} in {tag}")
    try:
        return cls(**{name: dec(body[wire]) for name, wire, _, dec in _FIELDS[cls] if wire in body})
    except TypeError as exc:  # missing required field, wrong arity
        raise MalformedMessage(f"bad {tag}: {exc}") from None
