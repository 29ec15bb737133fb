"""The environment's reports (UPD) of the ENV phases, checked against the coordinator's world (`Reports`). The ENV
phase is pipelined: the engine judges the moves at once with its own copy of the world (the buildings are static,
and both build it from the game's WorldSpec), so nothing waits for a report, which may come turns later; one that
disagrees with the world (the environment's world or drones differ from the coordinator's) is refused, counted."""

from __future__ import annotations

from schema import Cell, CellKind, MoveTable, Upd
from schema.errors import OutOfRange, StaleTurn, WrongSender
from schema.tuning import UPD_WINDOW
from world.grid import World


class Reports:
    """The ENV phases of `world` whose report is awaited (`due`: turn -> the moves it made), the last UPD_WINDOW."""

    def __init__(self, world: World) -> None:
        self.world = world
        self.due: dict[int, MoveTable] = {}

    def expect(self, turn: int, moves: MoveTable) -> None:
        """The ENV phase of `turn` made `moves`: its report is awaited (a few turns: nothing waits for it)."""
        self.due = {t: m for t, m in self.due.items() if t > turn - UPD_WINDOW} | {turn: moves}

    def kind(self, cell: Cell) -> CellKind:
        """What the world holds at `cell`, as a report says it."""
        if not self.world.contains(cell):
            return CellKind.OUTSIDE
        return CellKind.BUILDING if self.world.is_building(cell) else CellKind.EMPTY

    def check(self, msg: Upd) -> None:
        """The environment's report of a recent ENV phase: no longer awaited if it agrees with the world, else raise
        (and keep awaiting it)."""
        if msg.sender != "ENV":
            raise WrongSender(f"UPD from {msg.sender}")
        turn, moves = msg.turn, self.due.get(msg.turn)
        if moves is None:
            raise StaleTurn(f"UPD for turn {msg.turn}, which had no ENV phase awaiting its report")
        expected = {c: self.kind(c) for m in moves for c in (m.src, m.dst) if self.world.contains(c)}
        reported = {c.pos: c.kind for c in msg.cells}
        if reported != expected:
            wrong = sorted(c for c in expected.keys() | reported.keys() if reported.get(c) != expected.get(c))
            raise OutOfRange(f"UPD of turn {turn} disagrees with the world at {wrong[:5]}: the environment's "
                             "world or drones differ from the coordinator's")
        del self.due[turn]
