"""The environment (the seed's ENV), pure: no network, no clock. `Environment` is its state, the static world
plus where each drone is: `answer` is the seed's whatInside for an ASK; `apply` is moveDrone, returning the
changed cells (the UPD); `sync` sets the drones from the observer's STATUS at the end of a turn (the dead and
lost are removed). `EnvironmentProcess` is its protocol.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from schema import Ans, Ask, Cell, CellInfo, CellKind, MapRequest, MoveTable, Over, Phase
from schema.errors import OutOfRange, Refusal, RemoteInputError, StaleTurn, UnknownEntity, WrongSender
from schema.messages import AROUND, Status, Turn, Upd, Welcome, WorldMap, asked_cells, is_host_id
from schema.tables import drone_name, drone_number, is_drone_id
from schema.tuning import SURVEY_FEW_CELLS
from world.grid import World, build_world, inside_rows, linear_rows


class Environment:
    """The world and where each drone is. The drones are rows, not records: their numbers (`schema.tables`)
    and cells, sorted by cell (`_linear`, the grid index) and by number within a cell; a cell's drones are
    found by bisection. A swarm of 1000 costs a few dozen bytes a drone."""

    def __init__(self, world: World, drones: Mapping[str, Cell]) -> None:
        self.world = world
        self._set(np.array([drone_number(d) for d in drones], np.int64),
                  np.array(list(drones.values()), np.int64).reshape(-1, 3))

    def _set(self, numbers: np.ndarray, cells: np.ndarray) -> None:
        """The drones: `numbers` and their `cells` ((n, 3)); only those inside the world are kept."""
        inside = inside_rows(cells, self.world.size)
        numbers, cells = numbers[inside], cells[inside]
        linear = linear_rows(cells, self.world.size)
        order = np.lexsort((numbers, linear))
        self._numbers, self._cells, self._linear = numbers[order], cells[order], linear[order]

    @property
    def drones(self) -> dict[str, Cell]:
        """drone -> cell (only drones inside the world), in id order: built on demand, for people."""
        pairs = zip(self._numbers.tolist(), map(tuple, self._cells.tolist()))
        return dict(sorted((drone_name(n), c) for n, c in pairs))

    def _occupants(self, linear: np.ndarray) -> list[tuple[str, ...]]:
        """The drones in each cell of `linear` (grid indexes of inside cells), each sorted by id."""
        lo = np.searchsorted(self._linear, linear, "left").tolist()
        hi = np.searchsorted(self._linear, linear, "right").tolist()
        return [tuple(sorted(map(drone_name, self._numbers[a:b].tolist()))) if b > a else () for a, b in zip(lo, hi)]

    def _at(self, cells: Sequence[Cell]) -> dict[Cell, tuple[str, ...]]:
        """The occupied cells among `cells` and their drones (as `World.what_inside` takes them)."""
        if not len(self._linear) or not cells:
            return {}
        a = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
        inside = inside_rows(a, self.world.size)
        kept: list[Cell] = [(c[0], c[1], c[2]) for c, ok in zip(cells, inside.tolist()) if ok]
        found = self._occupants(linear_rows(a[inside], self.world.size))
        return {c: ds for c, ds in zip(kept, found) if ds}

    def what_inside(self, cell: Cell) -> CellInfo:
        return self.world.what_inside(cell, self._at([cell]))

    def answer(self, cells: Iterable[Cell]) -> tuple[CellInfo, ...]:
        cells = list(cells)
        at = self._at(cells)
        return tuple(self.world.what_inside(c, at) for c in cells)

    def oracle(self, pending: Mapping[str, Sequence[Cell]]) -> dict[str, dict[Cell, CellInfo]]:
        """What it answers about each drone's cells: the oracle of pilots flown in-process (`drive`)."""
        return {d: dict(zip(cells, self.answer(cells))) for d, cells in pending.items()}

    def kinds(self, cells: np.ndarray, inside: np.ndarray | None = None) -> np.ndarray:
        """The CellKind code of each cell of an (n, 3) integer array (uint8): the static world, no drones
        (`inside`: `inside_rows` of the cells, when the caller has it)."""
        inside = inside_rows(cells, self.world.size) if inside is None else inside
        kinds = np.full(len(cells), CellKind.OUTSIDE, dtype=np.uint8)
        i = cells[inside]
        kinds[inside] = np.where(self.world.grid[i[:, 0], i[:, 1], i[:, 2]], CellKind.BUILDING, CellKind.EMPTY)
        return kinds

    def survey(self, cells: Sequence[Cell], around: Sequence[Cell] = (), *,
               drones: bool = True) -> tuple[bytes, tuple[tuple[int, str], ...]]:
        """`answer` for many cells at once, as an ANS carries it (see `Ask.asked`: `cells`, then the six
        neighbours of each `around` cell): one CellKind byte per cell and (index, drone) for every drone
        in an asked cell (none with `drones` False: the static world), in numpy over the grid (a few
        cells: in plain Python, cheaper then)."""
        if len(cells) + 6 * len(around) <= SURVEY_FEW_CELLS:
            infos = self.answer(asked_cells(cells, around))
            pairs = tuple((n, d) for n, info in enumerate(infos) for d in info.drones) if drones else ()
            return bytes(info.kind for info in infos), pairs
        ring = np.asarray(around, dtype=np.int64).reshape(-1, 1, 3) + np.asarray(AROUND, dtype=np.int64)
        a = np.concatenate([np.asarray(cells, dtype=np.int64).reshape(-1, 3), ring.reshape(-1, 3)])
        inside = inside_rows(a, self.world.size)
        kinds = self.kinds(a, inside)
        if not drones or not len(self._linear):
            return kinds.tobytes(), ()
        linear = np.where(inside, linear_rows(a, self.world.size), -1)
        hits = np.flatnonzero(np.isin(linear, self._linear))
        pairs = tuple((n, d) for n, ds in zip(hits.tolist(), self._occupants(linear[hits])) for d in ds)
        return kinds.tobytes(), pairs

    def apply(self, moves: MoveTable) -> tuple[CellInfo, ...]:
        """`move`, then what is now in every changed cell (the UPD)."""
        return self.answer(self.move(moves))

    def move(self, moves: MoveTable) -> list[Cell]:
        """Move the drones; return every changed cell (sources and in-world destinations), sorted. All moves
        are checked first: one whose source is not where the drone is refuses them all (`UnknownEntity` /
        `OutOfRange`)."""
        numbers, moved = self._numbers, moves.numbers.astype(np.int64)
        src, dst = moves.column("src").astype(np.int64), moves.column("dst").astype(np.int64)
        by_number = np.argsort(numbers)  # (numbers are distinct)
        at = by_number[np.searchsorted(numbers[by_number], moved).clip(0, max(len(numbers) - 1, 0))] \
            if len(numbers) else np.zeros(len(moved), np.int64)
        known = numbers[at] == moved if len(numbers) else np.zeros(len(moved), bool)
        there = known & (self._cells[at] == src).all(axis=1) if len(numbers) else known
        if not there.all():
            j = int(np.flatnonzero(~there)[0])  # the first move refused, in the table's order
            drone = drone_name(int(moved[j]))
            if not known[j]:
                raise UnknownEntity(f"move of {drone}, which is not in the world")
            raise OutOfRange(f"move of {drone} from {tuple(src[j].tolist())}, but it is at "
                             f"{tuple(self._cells[at[j]].tolist())}")
        cells = self._cells.copy()
        cells[at] = dst
        self._set(numbers, cells)  # (a destination outside the world: the drone left it, the observer will say it died)
        inside = inside_rows(dst, self.world.size)
        return sorted(set(map(tuple, src.tolist())) | set(map(tuple, dst[inside].tolist())))

    def sync(self, status: Status) -> None:
        """Take the drones' positions from the observer's STATUS: alive ones in the world, others removed."""
        alive = status.drones.alive_mask()
        self._set(status.drones.numbers[alive].astype(np.int64), status.drones.column("pos")[alive].astype(np.int64))


@dataclass(frozen=True, slots=True)
class ReplyToQuery:
    """Answer the query `query` (the adapter's handle: a zenoh.Query) with `msg` (an ANS or the MAP)."""

    query: Any
    msg: Ans | WorldMap


@dataclass(frozen=True, slots=True)
class Fail:
    """Answer the query `query` (the adapter's handle) with an error reply saying `why`."""

    query: Any
    why: str


@dataclass(frozen=True, slots=True)
class Report:
    """Publish the UPD (the cells the ENV phase's moves changed), for whoever listens."""

    msg: Upd


@dataclass(frozen=True, slots=True)
class Follow:
    """Take every STATUS (`status` True) and every ENV phase's TURN (`moves` True), or stop (False): subscribe to
    them. Not following STATUS, the adapter hands the newest one (if one came since) before each query."""

    moves: bool
    status: bool


Effect = ReplyToQuery | Fail | Report | Follow | Refusal


class EnvironmentProcess:
    """The environment's protocol. Its Zenoh adapter (entities/env_node.py) feeds it, one at a time, the
    queries it serves (`asked`: ASK and MAPREQ, each with an opaque handle to answer it by), the
    coordinator's messages it hears (`receive`: STATUS, TURN of the ENV phase, OVER) and whether anyone
    listens to its UPD (`listened`), and carries out the effects they return.

    It answers an ASK from the world as it stands at the start of the ASK's turn: an ASK for turn t once
    STATUS(t - 1) has been taken; one that arrives earlier (messages take different routes) waits for
    it, one for a past turn is refused. An ASK for turn 0 asks the static world (the kinds of the cells,
    buildings never move; no drones) and is answered at once. The drones' positions come from the last
    STATUS, put on the map only when needed (for an ASK of the turn, or to apply the ENV phase's moves).

    It takes a STATUS only when it needs one: the adapter hands it the newest before each query (drones that
    chart the map ask nothing once a game runs, and the environment then sleeps through the turns). From the
    first ASK that has to wait for its STATUS, or while someone listens to the UPD, it follows every STATUS
    (`Follow`; with `follow`, from the start). A STATUS that is not newer than the last one taken changes nothing.

    The ENV phase's moves make the UPD report. Nobody listening, the environment does not even follow
    that phase (the coordinator then publishes none): the drones' cells come from STATUS alone (the same
    cells), and a swarm's thousands of moves a turn go nowhere.
    """

    def __init__(self, welcome: Welcome, *, follow: bool = False) -> None:
        starts, self.spec = welcome.starts.cells(), welcome.world
        self.world = build_world(welcome.world, starts.values())
        self.env = Environment(self.world, starts)
        self.over: Over | None = None
        self._ready = 1  # the turn whose ASKs can be answered now (STATUS(ready - 1) is the last one taken)
        self._applied = False  # the ENV phase of turn `ready` is done
        self._early: Turn | None = None  # the ENV phase of turn `ready` + 1, come before STATUS(ready)
        self._waiting: list[tuple[object, Ask]] = []  # ASKs for a turn after `ready`
        self._unsynced: Status | None = None  # the last STATUS, until the drones' positions are needed
        self._listened = False  # someone subscribes to the UPD
        self._all = follow  # every STATUS followed: from the start (`follow`) or since an ASK waited for its STATUS

    def drawing(self) -> str:
        """The world and the drones in it, floor by floor, under a line saying what it is."""
        world = self.world
        return (f"World {world.size} seed {self.spec.seed}, {len(world.buildings)} buildings, "
                f"{int(world.grid.sum())} building cells:\n{world.draw(self.env.drones)}")

    def asked(self, query: object, msg: Ask | MapRequest) -> list[Effect]:
        """A query to answer (through `ReplyToQuery` or `Fail` with `query`)."""
        match msg:
            case MapRequest():
                return [ReplyToQuery(query, WorldMap(turn=self._ready - 1, sender="ENV", size=self.world.size,
                                              buildings=self.world.packed()))]
            case Ask(sender=who) if not (is_drone_id(who) or is_host_id(who)):
                return self._refuse(query, WrongSender(f"ASK from {who}: only drones ask"))
            case Ask(turn=turn) if turn == self._ready or turn == 0:
                return [self._answer(query, msg)]
            case Ask(turn=turn) if turn > self._ready and self.over is not None:
                return [Fail(query, "the game is over")]
            case Ask(turn=turn) if turn > self._ready:
                self._waiting.append((query, msg))
                following, self._all = self._following(), True
                return self._follow(following)
            case Ask(turn=turn, sender=who):
                return self._refuse(query, StaleTurn(f"ASK for past turn {turn} from {who}, "
                                                     f"the world is at turn {self._ready}"))

    def receive(self, msg: Status | Turn | Over) -> list[Effect]:
        """A message of the coordinator (already screened by the entity's `TurnClock`)."""
        match msg:
            case Status():
                return self._status(msg)
            case Turn(phase=Phase.ENV, turn=turn):
                if turn == self._ready and not self._applied:
                    return self._apply(msg)
                if turn == self._ready + 1 and self._applied:
                    self._early = msg  # STATUS(turn - 1) travels on another key and has not arrived yet
                elif turn != self._ready - 1:  # (after its own STATUS: the drones are already there)
                    return [Refusal("ENV", StaleTurn(f"ENV phase of turn {turn} while the world is at turn "
                                                     f"{self._ready}"))]
                return []
            case Over():
                self.over = msg
                waiting, self._waiting = self._waiting, []
                return [Fail(query, "the game is over") for query, _ in waiting]
        raise TypeError(f"not a message the environment takes: {msg!r}")

    def start(self) -> list[Effect]:
        """What it follows from the start (every STATUS with `follow`: to measure what taking the newest saves)."""
        return self._follow(Follow(moves=False, status=False))

    def listened(self, matching: bool) -> list[Effect]:
        """Whether someone subscribes to the UPD now: the environment follows the ENV phase's moves then."""
        following, self._listened = self._following(), matching
        return self._follow(following)

    def _following(self) -> Follow:
        return Follow(moves=self._listened, status=self._listened or self._all)

    def _follow(self, before: Follow) -> list[Effect]:
        return [] if (now := self._following()) == before else [now]

    def _status(self, status: Status) -> list[Effect]:
        if status.turn < self._ready:
            return []  # taken already (handed again as the newest), one before it, or the starts' (turn 0)
        self._unsynced = status
        self._ready, self._applied = status.turn + 1, False
        out: list[Effect] = []
        waiting, self._waiting = self._waiting, []
        for query, ask in waiting:  # taken as if they came now, but for the turns the world went past
            if ask.turn < self._ready:
                out += self._refuse(query, StaleTurn(f"ASK for turn {ask.turn} from {ask.sender}: the world "
                                                     f"went on to turn {self._ready}"))
            else:
                out += self.asked(query, ask)
        early, self._early = self._early, None
        if early is not None and early.turn == self._ready:
            out += self._apply(early)
        return out

    def _sync(self) -> None:
        """The drones where the last STATUS has them."""
        if self._unsynced is not None:
            self.env.sync(self._unsynced)
            self._unsynced = None

    def _apply(self, turn: Turn) -> list[Effect]:
        self._applied = True
        self._sync()
        try:
            changed = self.env.move(turn.moves)
        except RemoteInputError as err:
            return [Refusal(f"ENV phase of turn {turn.turn}", err)]
        if not self._listened:  # the report costs a record per cell: only for someone listening
            return []
        return [Report(Upd(turn=turn.turn, sender="ENV", cells=self.env.answer(changed)))]

    def _answer(self, query: object, ask: Ask) -> ReplyToQuery:
        if ask.turn != 0:
            self._sync()
        kinds, drones = self.env.survey(ask.cells, ask.around, drones=ask.turn != 0)
        return ReplyToQuery(query, Ans(turn=ask.turn, sender="ENV", kinds=kinds, drones=drones))

    @staticmethod
    def _refuse(query: object, err: RemoteInputError) -> list[Effect]:
        return [Fail(query, str(err)), Refusal("ENV/ASK", err)]
