"""The drones of a game as columns: the turn engine's state, one row per drone, in id order (also their
priority order: arbitration, observer). A swarm's turn touches every drone a few times: as numpy columns that
is a handful of array operations and a few dozen bytes per drone (as records: microseconds and hundreds of
bytes each)."""

from __future__ import annotations

import functools
import itertools
from array import array
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from schema import Cause, Cell, DroneState, Note, OrderTable, StatusTable
from schema.tables import MAX_DRONE, code_of, drone_number
from schema.tuning import SMALL_FLEET

ALIVE, DEAD, LOST = (code_of(s) for s in (DroneState.ALIVE, DroneState.DEAD, DroneState.LOST))
NONE, REACHED, UNREACHABLE, STUCK = (code_of(n) for n in (Note.NONE, Note.REACHED, Note.UNREACHABLE, Note.STUCK))
STATES, NOTES, CAUSES = tuple(DroneState), tuple(Note), tuple(Cause)


def cell_of(row: np.ndarray) -> Cell:
    x, y, z = row.tolist()
    return (x, y, z)


def nonzero(column: np.ndarray) -> bool:
    """Whether any of `column` is not 0 (a short one's read as a list: cheaper than a reduction)."""
    return any(column.tolist()) if len(column) <= SMALL_FLEET else bool(np.count_nonzero(column))


@dataclass(frozen=True, slots=True)
class DroneView:
    """One drone's state as the fleet holds it (a snapshot)."""

    pos: Cell
    state: DroneState
    target: Cell | None
    note: Note
    cause: Cause
    misses: int
    host: str | None
    autopilot: str


class Fleet:
    """Every drone of a game: where it is, its state, target, note and cause (as in a STATUS), how many
    DRONES deadlines in a row it missed, and who flies it with which autopilot. `starts`: (id, start cell)
    pairs, the ids checked already (`GameConfig`)."""

    def __init__(self, starts: Iterable[tuple[str, Cell]]) -> None:
        pairs = sorted(starts)
        self.ids: tuple[str, ...] = tuple(d for d, _ in pairs)
        self.index: dict[str, int] = {d: i for i, d in enumerate(self.ids)}
        n = len(self.ids)
        self.numbers = np.array([drone_number(d) for d in self.ids], np.uint16)
        self._pos = np.array([c for _, c in pairs], np.int32).reshape(n, 3)  # (`pos`)
        self.state = np.empty(n, np.uint8)
        self.state.fill(ALIVE)
        self.target = np.empty((n, 3), np.int32)  # (np.full: three times the time of a small fleet's empty + fill)
        self.target.fill(-1)
        self.note = np.zeros(n, np.uint8)
        self.done = np.zeros(n, bool)  # on its target at the end of a turn since that target was given (a task done)
        self.cause = np.zeros(n, np.uint8)
        self.misses = np.zeros(n, np.int32)
        self.missing = False  # whether some drone's misses are not 0 (`count_misses`)
        self.small = n <= SMALL_FLEET  # its columns are read whole (`column`, `whole`)
        # the states and notes as memoryviews: read as lists without numpy's fixed cost per call (`whole`, `codes`)
        self._states, self._notes = self.state.data, self.note.data
        #: A small fleet's cells as (x, y, z) tuples, kept from turn to turn while no one reads the array: a turn of
        #: a few drones reads and moves them in Python (`whole`, `move`) with no list rebuilt and no array item
        #: written, and `pos` writes the array from them when it is read (docs/performance.md). None: the array
        #: holds them (a large fleet's always; a small one's after `pos` was read, until `whole` reads it again).
        self._cells: list[Cell] | None = None
        self._flat = self._pos.reshape(-1).data  # (the array's items, a view: written from `_cells`)
        self.host: list[str | None] = [None] * n
        self.host_code = np.empty(n, np.int16)  # index of its host in `hosts`, -1: none
        self.host_code.fill(-1)
        self.hosts: dict[str, int] = {}
        self.autopilot: list[str] = [""] * n
        self.cooperative = np.zeros(n, bool)
        self.cooperating = 0  # how many drones are cooperative (`learn`)

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def pos(self) -> np.ndarray:
        """Each drone's cell, (n, 3) int32, in row order: the array itself (a caller may write it). A small fleet's
        cells moved as tuples since it was last read are written to it first, and the array holds them from then on
        (`_cells`)."""
        cells = self._cells
        if cells is not None:
            self._cells = None
            self._flat[:] = array("i", itertools.chain.from_iterable(cells))
        return self._pos

    def restart(self, starts: np.ndarray | list[Cell]) -> None:
        """The same drones, flown as they are, at the start of a new game: at `starts` (a cell per row), alive,
        without target, note, cause or missed deadline (as a fleet just made; `Engine.restart`)."""
        self._cells = None
        self._pos[:] = starts
        self.state.fill(ALIVE)
        self.target.fill(-1)
        for column in (self.note, self.done, self.cause, self.misses):
            column.fill(0)
        self.missing = False

    @functools.cached_property
    def row_of_number(self) -> np.ndarray:
        """Each drone number's row, -1 for a number not of this game (made once read: a 256 KiB table)."""
        rows = np.full(MAX_DRONE + 1, -1, np.int32)
        rows[self.numbers] = np.arange(len(self.ids), dtype=np.int32)
        return rows

    def count_misses(self, took: np.ndarray, alive: np.ndarray) -> None:
        """The DRONES deadlines missed in a row after a turn: 0 for a drone whose move was taken (`took`, a mask),
        one more for an `alive` one (a mask) whose was not."""
        self.misses[:] = np.where(took, 0, self.misses + alive)
        self.missing = bool(np.count_nonzero(self.misses))

    def column(self, column: np.ndarray, rows: list[int]) -> list:
        """The values of one of the fleet's columns (or an array of its rows) at `rows`, as Python values (a cell:
        a list): the whole column read when the fleet is small, a few rows' selection costing more."""
        if self.small:
            values = column.tolist()
            return [values[i] for i in rows]
        return column.take(rows, 0).tolist()

    def whole(self) -> tuple[list[int], list[Cell]] | None:
        """A small fleet's states and cells as lists (`cells`); None: a large fleet's (`column` reads a few rows of
        them)."""
        if not self.small:
            return None
        cells = self._cells  # (kept from the last turn, most turns: `cells`, without its call)
        return self._states.tolist(), self.cells() if cells is None else cells

    def cells(self) -> list[Cell]:
        """Each drone's cell as an (x, y, z) tuple, in row order: a small fleet's own list, current until a turn
        moves a drone (`move` changes its items) or `pos` is read (then a new one is made when next asked for): read
        it, never change it."""
        cells = self._cells
        if cells is None:  # (the array holds them: read once, kept until someone reads the array)
            cells = list(map(tuple, self._pos.tolist()))  # type: ignore[arg-type]
            if self.small:
                self._cells = cells
        return cells

    def states(self) -> list[int]:
        """Each drone's state code, as a list (read through the memoryview: no numpy call)."""
        return self._states.tolist()

    def codes(self) -> list[int]:
        """Each drone's Note code, as a list (read through the memoryview: no numpy call)."""
        return self._notes.tolist()

    def move(self, rows: list[int], cells: Mapping[int, Cell]) -> None:
        """Drone rows `rows` are now at their `cells` (a small fleet's, after `whole`: its list's items; else the
        array's rows, one by one: a selection of rows costs as much as a dozen rows' items)."""
        kept = self._cells
        if kept is not None:
            for i in rows:
                kept[i] = cells[i]
            return
        items = self._flat
        for i in rows:
            k = 3 * i
            items[k], items[k + 1], items[k + 2] = cells[i]

    def alive_rows(self) -> np.ndarray:
        return (self.state == ALIVE).nonzero()[0]

    def notes(self) -> np.ndarray:
        """Each drone's note as the STATUS (and so the end of the game, OVER, every ground station) says it,
        from where the drones are now, after the turn's moves: REACHED whenever an alive drone is on its target
        and only then. A drone says REACHED as it plans, before the arbitration, which may push it off its
        target (PIBT lends a parked drone's cell to one with a higher priority): off it, an alive drone that
        said REACHED has NONE. Otherwise what the drone said (UNREACHABLE, STUCK, NONE)."""
        alive = self.state == ALIVE
        on = alive & (self.pos == self.target).all(axis=1)
        return np.where(on, REACHED, np.where(alive & (self.note == REACHED), NONE, self.note)).astype(np.uint8)

    def status(self) -> StatusTable:
        rows = StatusTable.empty(len(self))
        rows["drone"], rows["pos"], rows["state"] = self.numbers, self.pos, self.state
        rows["target"], rows["note"], rows["cause"] = self.target, self.notes(), self.cause
        return StatusTable(rows)

    def orders(self, rows: np.ndarray) -> OrderTable:
        """The orders of the drones in `rows`: where each is and where it must go."""
        table = OrderTable.empty(len(rows))
        table["drone"], table["pos"], table["target"] = self.numbers[rows], self.pos[rows], self.target[rows]
        return OrderTable(table)

    def fly(self, rows: list[int], host: str, autopilot: str, cooperative: bool) -> None:
        """`host` flies the drones of `rows` with `autopilot`."""
        for i in rows:
            self.host[i] = host
        self.host_code[rows] = self.hosts.setdefault(host, len(self.hosts))
        self.learn(rows, autopilot, cooperative)

    def learn(self, rows: list[int], autopilot: str, cooperative: bool) -> None:
        """The drones of `rows` are flown with `autopilot` (cooperative or not)."""
        for i in rows:
            self.autopilot[i] = autopilot
        self.cooperative[rows] = cooperative
        self.cooperating = int(np.count_nonzero(self.cooperative))

    def unhost(self, i: int) -> None:
        self.host[i], self.host_code[i] = None, -1

    def aim(self, rows: int | np.ndarray, targets: Cell | np.ndarray) -> None:
        """New targets for a drone (a row and a cell) or several (rows and an (n, 3) array of cells)."""
        self.target[rows] = targets
        self.note[rows] = 0  # Note.NONE: a new target, nothing said of it yet
        self.done[rows] = False

    def tasks_done(self) -> int:
        """How many alive drones are on their targets for the first time since they were given (after a turn's
        moves): the tasks this turn completed (`done` notes them)."""
        on = (self.state == ALIVE) & (self.target[:, 0] >= 0) & (self.pos == self.target).all(axis=1)
        new = on & ~self.done
        self.done |= on
        return int(np.count_nonzero(new))

    def end(self, i: int, state: DroneState, cause: Cause) -> None:
        self.state[i], self.cause[i] = code_of(state), code_of(cause)


class Drones(Mapping[str, DroneView]):
    """The fleet read drone by drone: id -> `DroneView` (for callers that look at a few drones)."""

    def __init__(self, fleet: Fleet) -> None:
        self._fleet = fleet

    def __getitem__(self, d: str) -> DroneView:
        f, i = self._fleet, self._fleet.index[d]
        target = None if f.target[i, 0] < 0 else cell_of(f.target[i])
        return DroneView(pos=cell_of(f.pos[i]), state=STATES[f.state[i]], target=target, note=NOTES[f.note[i]],
                         cause=CAUSES[f.cause[i]], misses=int(f.misses[i]), host=f.host[i],
                         autopilot=f.autopilot[i])

    def __iter__(self) -> Iterator[str]:
        return iter(self._fleet.ids)

    def __len__(self) -> int:
        return len(self._fleet)
