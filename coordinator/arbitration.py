"""The arbitration of cooperative drones as the engine runs it (`Arbitration`): the arbiter in force, each drone's
priority, the world's open cells as the arbiters read them, and the search's work before a game and in a replayed
turn. The arbiters themselves: coordinator/lacam.py (the search, the default) and coordinator/arbiter.py (PIBT, and
the former fixed rule for the benchmark)."""

from __future__ import annotations

import numpy as np

from world.grid import World

from . import arbiter, lacam
from .fleet import STUCK, UNREACHABLE, Fleet
from .journal import TurnLog


class Arbitration:
    """The cooperative drones' arbitration over the game's `world` for `n` drones: `arbiter`, the search
    (lacam.Lacam) for `name` "lacam", else arbiter.cooperate (PIBT); the adapter may wrap or replace it (arbiter.Timed,
    arbiter.fixed). `priority`: each drone's (`age`), a function of the journaled turns."""

    def __init__(self, name: str, world: World, n: int) -> None:
        self.arbiter: arbiter.Arbiter = lacam.Lacam() if name == "lacam" else arbiter.cooperate
        self.world = world
        self.priority = np.zeros(n, np.int64)  # each drone's for the arbitration (`age`)
        self.gave_way = np.zeros(n, bool)  # who gave way this turn (`decide`)
        self._open: arbiter.OpenCells | None = None  # the world's open cells (PIBT's swap; made once needed)

    def open_cells(self) -> arbiter.OpenCells:
        """The world's open cells as the arbiter reads them (made once needed)."""
        if self._open is None:
            self._open = arbiter.OpenCells(self.world.grid)
        return self._open

    def prepare(self, fleet: Fleet) -> None:
        """The game starts: the arbiter makes what it needs of the static world before the turns (lacam.Lacam's
        graph and distance tables: outside the turns' budget, and the same decisions whenever they are made). Not
        in a game without a cooperative drone, which never arbitrates (an RL episode's: its reset would build the
        world's graph, some 20 ms on 64x64x16, every ~40 steps)."""
        prepare = getattr(self.arbiter, "prepare", None)
        if prepare is not None and fleet.cooperating:
            prepare(self.world.size, self.open_cells())

    def decide(self, fleet: Fleet, alive: np.ndarray, before: np.ndarray, proposed: np.ndarray, ranked: np.ndarray,
               turn: int, log: TurnLog) -> np.ndarray:
        """`proposed`, the moves of the `alive` rows (cells `before`, `ranked` candidates), after the cooperative
        drones' arbitration in `turn`; journaled in `log`: who did not get its first choice ("yielded") and who
        gave way ("gave_way": their priority resets, `age`)."""
        final, yielded, gave_way = self.arbiter(self.world.size, before, proposed, ranked, fleet.cooperative[alive],
                                                self.priority[alive], fleet.target[alive], self.open_cells(), turn)
        self.gave_way[alive] = gave_way
        if np.count_nonzero(gave_way) or np.count_nonzero(yielded):
            log.arbitration([fleet.ids[i] for i in alive[gave_way].tolist()],
                            [fleet.ids[i] for i in alive[yielded].tolist()])
        return final

    def follow(self, fleet: Fleet, alive: np.ndarray, turn: int) -> None:
        """A journaled turn replayed (`Engine.resume`), before its moves: the arbitration's search does its work as
        when the turn was played (its state is a function of the drones' cells and targets: coordinator/lacam.py)."""
        follow = getattr(self.arbiter, "follow", None)
        if follow is not None and np.count_nonzero(fleet.cooperative[alive]):
            follow(self.world.size, fleet.pos[alive], fleet.cooperative[alive], fleet.target[alive],
                   self.open_cells(), turn)

    def age(self, fleet: Fleet, alive: np.ndarray, gave_way: list[int] | None = None) -> None:
        """The priorities after a turn of the `alive` rows: 0 for a drone at rest (on its target or without one) or
        that gave way this turn (`gave_way` rows, else the arbiter's), arbiter.STUCK for one that says UNREACHABLE or
        STUCK (held up by drones for long), arbiter.TIE_SPAN more for each other (PIBT's rule), plus a tie-break below
        TIE_SPAN: its Manhattan distance to its target when it left rest (PIBT2's, the long trips first).
        `Engine.resume` replays it turn by turn."""
        if gave_way is not None:
            self.gave_way[gave_way] = True
        target = fleet.target  # (every row, then the alive ones: fewer operations than selecting first)
        home = (target[:, 0] < 0) | (fleet.pos == target).all(axis=1)
        stuck = ~home & ((fleet.note == UNREACHABLE) | (fleet.note == STUCK)) & ~self.gave_way
        prio, span = self.priority, arbiter.TIE_SPAN
        far = np.minimum(np.abs(fleet.pos.astype(np.int64) - target).sum(axis=1), span - 1)
        moving = np.where(prio < span, span + far, prio + span)  # leaving rest now: its tie-break is taken now
        self.priority[alive] = np.where(home | self.gave_way, 0, np.where(stuck, arbiter.STUCK, moving))[alive]
        if np.count_nonzero(self.gave_way):
            self.gave_way[:] = False
