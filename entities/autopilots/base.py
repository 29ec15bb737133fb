"""The autopilot interface: a pure, network-free decision procedure for one drone.

An autopilot's `step` is a generator. It yields the cells it wants to sense (an ASK, one or more
cells), receives a mapping cell -> CellInfo in return, may ask again, and finally returns a
`Decision`. The same generator is driven by an in-process oracle over a `World` (tests, benchmarks)
or by the Zenoh drone adapter (each yield is one ASK query to the environment). Because the world
is frozen during a turn's DRONES phase, both give identical decisions.

Autopilots keep their memory in the instance: one instance per drone, for the whole game.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Iterable, Mapping
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from dronesim.schema import Cell, CellInfo, Note, StepTable
from dronesim.schema.tables import code_of, drone_number
from dronesim.schema.messages import AROUND

Answers = Mapping[Cell, CellInfo]
#: The kind a swarm pilot is given for a cell nobody answered (see `fly_swarm`).
NO_ANSWER = 255
Sensing = Generator[tuple[Cell, ...], Answers, "Decision"]
Oracle = Callable[[tuple[Cell, ...]], Answers]

#: The 6-connectivity moves, in a fixed order (+x, -x, +y, -y, +z, -z).
STEPS6: tuple[Cell, ...] = AROUND  # +x, -x, +y, -y, +z, -z


@dataclass(frozen=True, slots=True, kw_only=True)
class Decision:
    """Where the drone goes this turn (its own cell to hover) and what it reports."""

    pos: Cell
    note: Note = Note.NONE


class Autopilot(Protocol):
    """One drone's pilot. `name` is what the command line selects (``--autopilot NAME``)."""

    name: ClassVar[str]
    #: True if the drone gives way to other drones when the coordinator arbitrates moves.
    cooperative: ClassVar[bool]
    #: True if it senses by ASK (its process then asks ahead for its drones' neighbourhoods).
    senses: ClassVar[bool]

    def step(self, pos: Cell, target: Cell | None) -> Sensing:
        """Decide this turn's move from `pos` towards `target` (None: no target yet, hover)."""
        ...


class SwarmPilot(Protocol):
    """One pilot for all the drones of a swarm host, over arrays (`autopilots.SWARMS`): the same
    decisions as one autopilot per drone."""

    def step(self, drones: np.ndarray, pos: np.ndarray, target: np.ndarray,
             kinds: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """The moves of the drones numbered `drones`, standing at `pos` ((n, 3)) with `target` ((n, 3),
        (-1, -1, -1) for none): (new cells (n, 3), note codes (n,) as in a StepTable). `kinds` answers
        an (m, 3) array of cells with their CellKind codes (`NO_ANSWER` for a cell not answered)."""
        ...


def add(a: Cell, b: Cell) -> Cell:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def neighbours6(pos: Cell) -> tuple[Cell, ...]:
    return tuple(add(pos, d) for d in STEPS6)


def in_bounds(cell: Cell, size: Cell) -> bool:
    return 0 <= cell[0] < size[0] and 0 <= cell[1] < size[1] and 0 <= cell[2] < size[2]


def run_step(pilot: Autopilot, pos: Cell, target: Cell | None, oracle: Oracle) -> tuple[Decision, int]:
    """Drive one `step` to its decision with `oracle` answering every ASK.

    Returns the decision and the number of ASK round trips it took.
    """
    gen = pilot.step(pos, target)
    asks = 0
    try:
        cells = next(gen)
        while True:
            asks += 1
            cells = gen.send(oracle(cells))
    except StopIteration as stop:
        decision = stop.value
    if not isinstance(decision, Decision):
        raise TypeError(f"{type(pilot).__name__}.step returned {decision!r}, not a Decision")
    return decision, asks


def fly_round(
    steps: Mapping[str, Sensing],
    ask_all: Callable[[dict[str, tuple[Cell, ...]]], Mapping[str, Answers]],
) -> dict[str, Decision]:
    """Drive several drones' `step` generators together: each round gathers every pending ASK and
    answers them all at once (`ask_all`, concurrent on the network), so a turn takes as many
    sequential ASK round trips as the most inquisitive drone, not the sum over drones."""
    decisions: dict[str, Decision] = {}
    pending: dict[str, tuple[Cell, ...]] = {}
    for d, gen in steps.items():
        try:
            pending[d] = next(gen)
        except StopIteration as stop:
            decisions[d] = stop.value
    while pending:
        answers = ask_all(pending)
        nxt: dict[str, tuple[Cell, ...]] = {}
        for d, cells in pending.items():
            try:
                nxt[d] = steps[d].send(answers[d])
            except StopIteration as stop:
                decisions[d] = stop.value
        pending = nxt
    for d, dec in decisions.items():
        if not isinstance(dec, Decision):
            raise TypeError(f"the autopilot of {d} returned {dec!r}, not a Decision")
    return decisions


def steps_of(decisions: Mapping[str, Decision]) -> StepTable:
    """A MOVES's steps: each decision's cell and note, in drone order."""
    ids = sorted(decisions)
    decided = [decisions[d] for d in ids]
    n = len(ids)
    return StepTable.build(drone=np.fromiter(map(drone_number, ids), np.uint16, n),
                           pos=np.array([d.pos for d in decided], np.int32).reshape(n, 3),
                           note=np.fromiter((code_of(d.note) for d in decided), np.uint8, n))


def fly_pilots(pilots: Mapping[str, Autopilot], orders: Iterable[tuple[str, Cell, Cell | None]],
               ask_all: Callable[[dict[str, tuple[Cell, ...]]], Mapping[str, Answers]], *,
               host: str | None) -> StepTable | dict[str, Decision]:
    """One autopilot per drone (`pilots`), flown together (`fly_round`) on its (drone, cell, target) orders:
    a swarm host's MOVES steps, or a lone drone's decision."""
    decisions = fly_round({d: pilots[d].step(pos, target) for d, pos, target in orders}, ask_all)
    return steps_of(decisions) if host else decisions


def fly_swarm(swarm: SwarmPilot, rows: np.ndarray, kinds: Callable[[np.ndarray], np.ndarray]) -> StepTable:
    """A swarm pilot's moves for the orders `rows` (an OrderTable's), the cells it asks about answered by `kinds`."""
    pos, note = swarm.step(rows["drone"], rows["pos"], rows["target"], kinds)
    return StepTable.build(drone=rows["drone"], pos=pos.astype(np.int32), note=note)
