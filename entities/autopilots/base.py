"""The autopilot interface: a pure, network-free decision procedure for one drone.

An autopilot's `step` is a generator. It yields the cells it wants to sense (an ASK, one or more
cells), receives a mapping cell -> CellInfo in return, may ask again, and finally returns a
`Decision`. The same generator is driven by an in-process oracle over a `World` (tests, benchmarks)
or by the Zenoh drone adapter (each yield is one ASK query to the environment). Because the world
is frozen during a turn's DRONES phase, both give identical decisions.

Autopilots keep their memory in the instance: one instance per drone, for the whole game.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Mapping
from dataclasses import dataclass
from typing import ClassVar, Protocol

from dronesim.schema import Cell, CellInfo, Note
from dronesim.schema.messages import AROUND

Answers = Mapping[Cell, CellInfo]
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
