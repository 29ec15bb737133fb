"""The environment's state (the seed's ENV): the static world plus where each drone is. Pure.

`answer` is the seed's whatInside for an ASK; `apply` is moveDrone, returning the changed cells
(the UPD); `sync` sets the drones from the observer's STATUS at the end of a turn (the dead and
lost are removed from the grid).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence

import numpy as np

from dronesim.schema import Cell, CellInfo, CellKind, Move, Status, WorldSpec
from dronesim.schema.messages import AROUND, asked_cells
from dronesim.schema.errors import OutOfRange, UnknownEntity

from .world import World, inside_rows, linear_rows


def build_world(spec: WorldSpec, starts: Iterable[Cell]) -> World:
    """The world a `WorldSpec` describes: the given cells, or generated from its seed keeping the starts free."""
    if spec.cells:
        return World.from_packed(spec.size, spec.cells)
    return World.generate(spec.size, np.random.default_rng(spec.seed), keep_free=tuple(starts))


#: Turns the environment keeps following STATUS after the last question about the drones.
FOLLOW_TURNS = 8


class Following:
    """Whether the environment needs the drones' positions turn by turn, i.e. follows STATUS: while someone
    listens to its UPD reports (made from the ENV phase's moves), while an ASK about the drones waits for
    its turn's STATUS, and for `turns` STATUS after the last ASK about the drones (one for turn 0 asks the
    static world). Otherwise nobody needs them: drone processes chart the static map and compose their
    answers themselves, so in most games the environment is asked nothing once the game runs, and a
    STATUS a turn would cost it (and the router) a message a turn for nothing."""

    def __init__(self, turns: int = FOLLOW_TURNS) -> None:
        self.turns = turns
        self.listened = False  # someone subscribes to UPD
        self._quiet: int | None = None  # STATUS since the last ASK about the drones (None: none yet)

    def asked(self) -> None:
        self._quiet = 0

    def status(self) -> None:
        if self._quiet is not None:
            self._quiet += 1

    def wanted(self, waiting: bool) -> bool:
        """`waiting`: an ASK waits for a STATUS."""
        return self.listened or waiting or (self._quiet is not None and self._quiet <= self.turns)


#: Up to this many cells, `survey` answers cell by cell rather than with numpy (whose fixed cost dominates).
SMALL = 48


class Environment:
    def __init__(self, world: World, drones: dict[str, Cell]) -> None:
        self.world = world
        self.drones: dict[str, Cell] = dict(drones)  # drone -> cell (only drones inside the world)
        self._occupants = self._index()

    def _index(self) -> dict[Cell, tuple[str, ...]]:
        cells: dict[Cell, list[str]] = defaultdict(list)
        for d, c in sorted(self.drones.items()):
            cells[c].append(d)
        self._occupied_linear = linear_rows(np.array(list(cells), np.int64).reshape(-1, 3), self.world.size)
        return {c: tuple(ds) for c, ds in cells.items()}

    def what_inside(self, cell: Cell) -> CellInfo:
        return self.world.what_inside(cell, self._occupants)

    def answer(self, cells: Iterable[Cell]) -> tuple[CellInfo, ...]:
        return tuple(self.world.what_inside(c, self._occupants) for c in cells)

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
        if len(cells) + 6 * len(around) <= SMALL:
            infos = self.answer(asked_cells(cells, around))
            pairs = tuple((n, d) for n, info in enumerate(infos) for d in info.drones) if drones else ()
            return bytes(info.kind for info in infos), pairs
        a = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
        if len(around):
            ring = np.asarray(around, dtype=np.int64).reshape(-1, 1, 3) + np.asarray(AROUND, dtype=np.int64)
            a = np.concatenate([a, ring.reshape(-1, 3)])
        inside = inside_rows(a, self.world.size)
        kinds = self.kinds(a, inside)
        if not drones or not self._occupants:
            return kinds.tobytes(), ()
        linear = np.where(inside, linear_rows(a, self.world.size), -1)
        occupied = self._occupied_linear
        hits = np.flatnonzero(np.isin(linear, occupied)).tolist()
        at = a[hits].tolist()
        pairs = tuple((n, d) for n, c in zip(hits, at) for d in self._occupants[tuple(c)])
        return kinds.tobytes(), pairs

    def apply(self, moves: Iterable[Move]) -> tuple[CellInfo, ...]:
        """Move the drones; return what is now in every changed cell (the UPD): see `move`."""
        return self.answer(self.move(moves))

    def move(self, moves: Iterable[Move]) -> list[Cell]:
        """Move the drones; return every changed cell (sources and in-world destinations), sorted.

        All moves are checked before any is applied: a move whose source is not where this
        environment has the drone is refused whole (`UnknownEntity` / `OutOfRange`).
        """
        moves = tuple(moves)
        for m in moves:
            if m.drone not in self.drones:
                raise UnknownEntity(f"move of {m.drone}, which is not in the world")
            if self.drones[m.drone] != m.src:
                raise OutOfRange(f"move of {m.drone} from {m.src}, but it is at {self.drones[m.drone]}")
        changed: set[Cell] = set()
        for m in moves:
            changed.add(m.src)
            if self.world.contains(m.dst):
                self.drones[m.drone] = m.dst
                changed.add(m.dst)
            else:
                del self.drones[m.drone]  # it left the world (the observer will say it died)
        self._occupants = self._index()
        return sorted(changed)

    def sync(self, status: Status) -> None:
        """Take the drones' positions from the observer's STATUS: alive ones in the world, others removed."""
        table = status.drones
        pos = table.column("pos")
        there = table.alive_mask() & inside_rows(pos, self.world.size)
        ids = table.ids()
        self.drones = {ids[i]: (x, y, z) for i, (x, y, z) in zip(np.flatnonzero(there).tolist(), pos[there].tolist())}
        self._occupants = self._index()
