"""The autopilot interface: a pure, network-free decision procedure for one drone.

An autopilot's `step` is a generator: it yields the cells it wants to sense, receives a mapping cell -> CellInfo,
may ask again, and returns a `Decision`. An oracle over a `World` drives it (`drive`: tests, benchmarks, the
in-process game), or the drone process's core (entities/drone.py: from its chart of the environment's map, or by
ASK); the world is frozen during a turn's DRONES phase, so both decide the same.

A process's drones are flown together as one plan, a generator of the same kind whose driver answers its questions
and which returns the turn's moves: `fly_pilots` (one pilot per drone, a round of every drone's questions at a time)
or `fly_swarm` (a swarm pilot over arrays). An autopilot keeps its memory in the instance: one instance per drone,
for the whole game.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Iterable, Mapping, Sequence
from dataclasses import dataclass
from itertools import repeat
from typing import Any, ClassVar, Protocol, TypeVar

import numpy as np

from schema import Cell, CellInfo, Note, StepTable, UsageError
from schema.tables import code_of, drone_number
from world.grid import linear_rows

Q = TypeVar("Q")
A = TypeVar("A")
R = TypeVar("R")
Answers = Mapping[Cell, CellInfo]
#: The kind a swarm pilot is given for a cell nobody answered (see `fly_swarm`).
NO_ANSWER = 255
Sensing = Generator[tuple[Cell, ...], Answers, "Decision"]
Oracle = Callable[[tuple[Cell, ...]], Answers]
#: A process's turn for drones flown one pilot each (`fly_round`, `fly_pilots`): their questions, then the moves (R).
PilotsPlan = Generator[dict[str, tuple[Cell, ...]], Mapping[str, Answers], R]
#: A swarm pilot's turn (`SwarmPilot.step`).
SwarmSensing = Generator[np.ndarray, np.ndarray, tuple[np.ndarray, ...]]


@dataclass(frozen=True, slots=True, kw_only=True)
class Decision:
    """Where the drone goes this turn (its own cell to hover) and what it reports."""

    pos: Cell
    note: Note = Note.NONE
    #: A cooperative drone's candidate cells for the arbiter, best first, as steps packed by
    #: `schema.tables.rank_steps` (0: none; the arbiter then takes `pos` or keeps the drone where it is).
    ranked: int = 0


class Autopilot(Protocol):
    """One drone's pilot. `name` is what the command line selects (``--autopilot NAME``)."""

    name: ClassVar[str]
    #: True if the drone gives way to other drones when the coordinator arbitrates moves.
    cooperative: ClassVar[bool]
    #: True if its `step` asks about cells (yields): its process then answers them from a chart of the environment's
    #: map, or by ASK (entities/drone.py). False: it flies blind, asking nothing.
    senses: ClassVar[bool]

    def __init__(self, *, world_size: Cell, **options: Any) -> None:
        """A pilot for a world of `world_size` (`options`: the autopilot's own)."""

    def step(self, pos: Cell, target: Cell | None) -> Sensing:
        """Decide this turn's move from `pos` towards `target` (None: no target yet, hover)."""
        ...


class SwarmPilot(Protocol):
    """One pilot for all the drones of a swarm host, over arrays (`autopilots.SWARMS`): the same decisions as one
    autopilot per drone."""

    def step(self, drones: np.ndarray, pos: np.ndarray, target: np.ndarray) -> SwarmSensing:
        """The moves of the drones numbered `drones`, standing at `pos` ((n, 3)) with `target` ((n, 3), (-1, -1, -1)
        for none): returns (new cells (n, 3), note codes (n,) uint8 as in a StepTable), and a cooperative pilot its
        drones' rankings too ((n,) uint32 packed as `schema.tables.rank_steps`: a MOVES's `ranked` column). It may
        yield once an (m, 3) array of cells, and receives their CellKind codes ((m,) uint8, `NO_ANSWER` for a cell
        not answered)."""
        ...


class SwarmBase:
    """What the swarm forms share: the world's `size`, their drones' numbers (sorted, `_drones`) and the number of
    cells of the world (`_cells`: a drone's memory is keyed by its row or trip × `_cells` + a cell's index)."""

    def __init__(self, *, world_size: Cell, drones: Sequence[int]) -> None:
        """`drones`: the numbers of the drones flown (D01 is 1); UsageError if one is given twice."""
        self.size: Cell = (int(world_size[0]), int(world_size[1]), int(world_size[2]))
        self._drones = np.array(sorted(drones), dtype=np.int64)
        if len(np.unique(self._drones)) != len(self._drones):
            raise UsageError("a swarm flies each drone once")
        self._cells = self.size[0] * self.size[1] * self.size[2]

    def _rows(self, drones: Sequence[int] | np.ndarray) -> np.ndarray:
        """The rows of `drones` in `_drones` (UsageError naming those not in the swarm)."""
        numbers, drones = self._drones, np.asarray(drones, dtype=np.int64)
        rows = np.searchsorted(numbers, drones)
        if len(drones) and (rows.max() >= len(numbers) or (numbers[rows] != drones).any()):
            strangers = sorted(set(drones.tolist()) - set(numbers.tolist()))
            raise UsageError(f"drones {strangers} are not in this swarm")
        return rows

    def _memory_of(self, memory: dict[int, int], first: int) -> dict[Cell, int]:
        """The entries of `memory` keyed from `first` × `_cells` (a drone's row or trip), by cell."""
        _, ny, nz = self.size
        low = first * self._cells
        return {(i // (ny * nz), i // nz % ny, i % nz): v for k, v in memory.items()
                if low <= k < low + self._cells for i in (k - low,)}

    def _keys(self, first: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """The memory keys ((k, m)) of `k` drones' `cells` ((k, m, 3); meaningful for inside cells), the drones' keys
        starting at `first` × `_cells` ((k,): their rows or trips)."""
        return (first * self._cells)[:, None] + linear_rows(cells.reshape(-1, 3), self.size).reshape(cells.shape[:2])

    @staticmethod
    def _lookup(memory: dict[int, int], keys: np.ndarray) -> np.ndarray:
        """The values of `keys` in `memory` (-1 for those not in it), as int64."""
        return np.fromiter(map(memory.get, keys.tolist(), repeat(-1)), dtype=np.int64, count=len(keys))

    def _orders(self, drones: np.ndarray, pos: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, ...]:
        """A step's arguments as arrays: the drones' rows, and `pos` and `target` as (n, 3) int64."""
        n = len(drones)
        return (self._rows(drones), np.asarray(pos, dtype=np.int64).reshape(n, 3),
                np.asarray(target, dtype=np.int64).reshape(n, 3))


def drive(plan: Generator[Q, A, R], oracle: Callable[[Q], A]) -> R:
    """Run a sensing generator (an autopilot's step, a plan) to its end, `oracle` answering every question."""
    try:
        question = next(plan)
        while True:
            question = plan.send(oracle(question))
    except StopIteration as stop:
        return stop.value


def run_step(pilot: Autopilot, pos: Cell, target: Cell | None, oracle: Oracle) -> tuple[Decision, int]:
    """Drive one `step` to its decision with `oracle` answering every ASK: the decision, and the number of ASK round
    trips it took."""
    asks = 0

    def counted(cells: tuple[Cell, ...]) -> Answers:
        nonlocal asks
        asks += 1
        return oracle(cells)

    return drive(pilot.step(pos, target), counted), asks


def fly_round(steps: Mapping[str, Sensing]) -> PilotsPlan[dict[str, Decision]]:
    """Drive several drones' `step` generators together: each round yields every pending question at once ({drone:
    cells}) and receives every answer ({drone: answers}, asked concurrently on the network), so a turn takes as many
    sequential ASK round trips as the most inquisitive drone, not the sum over drones. Returns each drone's
    decision."""
    decisions: dict[str, Decision] = {}
    pending: Mapping[str, Answers | None] = dict.fromkeys(steps)  # what each drone is told (None: it starts)
    while pending:
        asking: dict[str, tuple[Cell, ...]] = {}
        for d, told in pending.items():
            try:
                asking[d] = next(steps[d]) if told is None else steps[d].send(told)
            except StopIteration as stop:
                decisions[d] = stop.value
        answers = (yield asking) if asking else {}
        pending = {d: answers[d] for d in asking}
    return decisions


def steps_of(decisions: Mapping[str, Decision]) -> StepTable:
    """A MOVES's steps: each decision's cell and note, in drone order."""
    return StepTable.pack((drone_number(d), *decisions[d].pos, code_of(decisions[d].note), decisions[d].ranked)
                          for d in sorted(decisions))


def fly_pilots(pilots: Mapping[str, Autopilot], orders: Iterable[tuple[str, Cell, Cell | None]], *,
               host: str | None) -> PilotsPlan[StepTable | dict[str, Decision]]:
    """The plan of one autopilot per drone (`pilots`), flown together (`fly_round`) on its (drone, cell, target)
    orders: returns a swarm host's MOVES steps, or a lone drone's decision."""
    decisions = yield from fly_round({d: pilots[d].step(pos, target) for d, pos, target in orders})
    return steps_of(decisions) if host else decisions


def fly_swarm(swarm: SwarmPilot, rows: np.ndarray) -> Generator[np.ndarray, np.ndarray, StepTable]:
    """The plan of a swarm pilot for the orders `rows` (an OrderTable's): its question, then the MOVES steps (with the
    rankings of a pilot that gives them)."""
    pos, note, *ranked = yield from swarm.step(rows["drone"], rows["pos"], rows["target"])
    cooperative = {"ranked": ranked[0]} if ranked else {}  # (a pilot without rankings: 0, none)
    return StepTable.build(drone=rows["drone"], pos=pos.astype(np.int32), note=note, **cooperative)
