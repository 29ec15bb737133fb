"""The D* Lite autopilot: behaviour, safety and determinism (no timing asserts).

Most tests fly over a tiny in-test grid oracle (a set of building cells, plus other drones), which
records every ASK, so the test can check what the pilot knew when it moved. Random cities come from
`World.generate`; `benchmarks.autopilot --quick` must run.
"""

from __future__ import annotations

import collections
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from entities.autopilots import make_autopilot
from entities.autopilots.base import Decision
from entities.autopilots.dstar import DStarPilot
from schema import Cell, CellInfo, CellKind, Note
from schema.messages import AROUND
from schema.tables import rank_steps, ranked_steps
from world.grid import World

STAY = (0, 0, 0)

# --------------------------------------------------------------------------- a tiny grid oracle


def _inside(c: Cell, size: Cell) -> bool:
    return all(0 <= c[i] < size[i] for i in range(3))


@dataclass
class Grid:
    """Building cells in a box world, other drones' positions, and a log of every ASK."""

    size: Cell
    blocked: set[Cell] = field(default_factory=set)
    drones: dict[Cell, tuple[str, ...]] = field(default_factory=dict)
    asks: list[dict[Cell, CellInfo]] = field(default_factory=list)

    def kind(self, c: Cell) -> CellKind:
        if not _inside(c, self.size):
            return CellKind.OUTSIDE
        return CellKind.BUILDING if c in self.blocked else CellKind.EMPTY

    def oracle(self, cells: tuple[Cell, ...]) -> dict[Cell, CellInfo]:
        answers = {c: CellInfo(pos=c, kind=self.kind(c), drones=self.drones.get(c, ())) for c in cells}
        self.asks.append(answers)
        return answers

    def bfs(self, start: Cell, goal: Cell, blocked: Iterable[Cell] | None = None) -> int | None:
        wall = self.blocked if blocked is None else set(blocked)
        if start in wall or goal in wall:
            return None
        dist = {start: 0}
        queue = collections.deque([start])
        while queue:
            c = queue.popleft()
            if c == goal:
                return dist[c]
            for d in AROUND:
                n = (c[0] + d[0], c[1] + d[1], c[2] + d[2])
                if _inside(n, self.size) and n not in wall and n not in dist:
                    dist[n] = dist[c] + 1
                    queue.append(n)
        return None


def box(x0: int, x1: int, y0: int, y1: int, z0: int, z1: int) -> set[Cell]:
    """All cells of the inclusive box."""
    return {(x, y, z) for x in range(x0, x1 + 1) for y in range(y0, y1 + 1) for z in range(z0, z1 + 1)}


def shell(lo: Cell, hi: Cell) -> set[Cell]:
    """The faces of the inclusive box lo..hi."""
    return box(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]) - box(
        lo[0] + 1, hi[0] - 1, lo[1] + 1, hi[1] - 1, lo[2] + 1, hi[2] - 1)


@dataclass
class Flight:
    path: list[Cell]
    decisions: list[Decision]
    asks: list[int]  # ASK round trips per step


def step_once(pilot: DStarPilot, grid: Grid, pos: Cell, target: Cell | None) -> tuple[Decision, int, set[Cell]]:
    """One step; returns the decision, the round trips and the cells it learnt EMPTY this step."""
    gen = pilot.step(pos, target)
    asks, empty = 0, set()
    try:
        cells = next(gen)
        while True:
            asks += 1
            answers = grid.oracle(cells)
            empty |= {c for c, info in answers.items() if info.kind is CellKind.EMPTY}
            cells = gen.send(answers)
    except StopIteration as stop:
        return stop.value, asks, empty


def fly(pilot: DStarPilot, grid: Grid, start: Cell, target: Cell | None, limit: int = 2000,
        *, stop_on: tuple[Note, ...] = (Note.REACHED, Note.UNREACHABLE)) -> Flight:
    """Fly until a note in `stop_on` (or `limit` steps), checking safety at every move:
    one cell at most, inside the world, never a building, never another drone's cell, and only
    into a cell sensed EMPTY this step or earlier."""
    pos = start
    flight = Flight([pos], [], [])
    sensed: set[Cell] = set()
    for _ in range(limit):
        decision, asks, empty = step_once(pilot, grid, pos, target)
        sensed |= empty
        new = decision.pos
        assert sum(abs(a - b) for a, b in zip(new, pos)) <= 1, (pos, new)
        assert _inside(new, grid.size), new
        assert new not in grid.blocked, new
        if new != pos:
            assert new in sensed, f"moved into {new} without sensing it"
            assert new not in grid.drones, f"flew into a drone at {new}"
        assert asks <= 2
        flight.decisions.append(decision)
        flight.asks.append(asks)
        flight.path.append(new)
        pos = new
        if decision.note in stop_on or (pos == target and Note.REACHED in stop_on):
            break
    return flight


def moves(flight: Flight) -> int:
    return sum(a != b for a, b in zip(flight.path, flight.path[1:]))


# --------------------------------------------------------------------------- basics


def test_registry_and_trivial_cases() -> None:
    pilot = make_autopilot("dstar", world_size=(4, 4, 4))
    assert isinstance(pilot, DStarPilot) and pilot.name == "dstar"
    grid = Grid((4, 4, 4))
    # no target: its cell first, then its free neighbours (asked once: a drone at rest may be in another's way; it
    # once offered its own cell alone, knowing nothing, and nobody could pass it)
    decision, asks, _ = step_once(pilot, grid, (1, 1, 1), None)
    assert decision == Decision(pos=(1, 1, 1), ranked=rank_steps([STAY, *AROUND])) and asks == 1
    decision, asks, _ = step_once(pilot, grid, (1, 1, 1), None)
    assert decision.ranked == rank_steps([STAY, *AROUND]) and asks == 0
    # on its target, the same (its neighbours known by now: not asked again)
    decision, asks, _ = step_once(pilot, grid, (1, 1, 1), (1, 1, 1))
    assert decision == Decision(pos=(1, 1, 1), note=Note.REACHED, ranked=rank_steps([STAY, *AROUND])) and asks == 0
    parked = make_autopilot("dstar", world_size=(4, 4, 4))  # (knowing nothing: asked once, to be pushed aside)
    decision, asks, _ = step_once(parked, grid, (1, 1, 1), (1, 1, 1))
    assert decision == Decision(pos=(1, 1, 1), note=Note.REACHED, ranked=rank_steps([STAY, *AROUND])) and asks == 1
    decision, asks, _ = step_once(pilot, grid, (1, 1, 1), (1, 1, 1))
    assert decision.ranked == rank_steps([STAY, *AROUND]) and asks == 0
    decision, asks, _ = step_once(pilot, grid, (1, 1, 1), (9, 1, 1))  # outside the world: at rest, as above
    assert (decision.pos, decision.note, decision.ranked) == ((1, 1, 1), Note.UNREACHABLE, rank_steps([STAY, *AROUND]))


def test_open_world_flies_an_optimal_path() -> None:
    grid = Grid((10, 10, 10))
    flight = fly(DStarPilot(world_size=grid.size), grid, (0, 0, 0), (9, 7, 5))
    assert flight.path[-1] == (9, 7, 5)
    assert moves(flight) == 9 + 7 + 5
    assert flight.decisions[-1].note is Note.NONE  # arrives with the last move...
    decision, _, _ = step_once(DStarPilot(world_size=grid.size), grid, (9, 7, 5), (9, 7, 5))
    assert decision.note is Note.REACHED  # ... and reports REACHED on the target


# --------------------------------------------------------------------------- walls and dead ends


def test_u_shaped_wall_dead_end() -> None:
    # Full-height U opening towards the start: flying straight in is a dead end.
    size = (20, 20, 5)
    walls = box(12, 12, 4, 15, 0, 4) | box(6, 12, 4, 4, 0, 4) | box(6, 12, 15, 15, 0, 4)
    grid = Grid(size, walls)
    for start in ((2, 10, 0), (9, 10, 2)):  # in front of the U, and inside it
        flight = fly(DStarPilot(world_size=size), grid, start, (17, 10, 4))
        assert flight.path[-1] == (17, 10, 4)
        assert moves(flight) <= 2 * grid.bfs(start, (17, 10, 4))


def test_3d_pocket_needs_climbing_and_descending() -> None:
    # A roofed pocket open only towards the start; the target is under an overhang behind it.
    size = (16, 16, 8)
    walls = box(10, 10, 3, 12, 0, 5) | box(4, 10, 3, 3, 0, 5) | box(4, 10, 12, 12, 0, 5) | box(4, 10, 3, 12, 5, 5)
    walls |= box(11, 15, 0, 15, 3, 3) - {(15, 15, 3)}  # an overhang above the target
    grid = Grid(size, walls)
    start, target = (1, 8, 1), (13, 8, 0)
    flight = fly(DStarPilot(world_size=size), grid, start, target)
    assert flight.path[-1] == target
    assert moves(flight) <= 3 * grid.bfs(start, target)


def test_serpentine_of_walls() -> None:
    size = (17, 8, 3)
    walls: set[Cell] = set()
    for i, x in enumerate((3, 7, 11, 15)):
        gap = range(6, 8) if i % 2 == 0 else range(0, 2)
        walls |= {(x, y, z) for y in range(8) for z in range(3) if y not in gap}
    grid = Grid(size, walls)
    flight = fly(DStarPilot(world_size=size), grid, (0, 0, 0), (16, 0, 2))
    assert flight.path[-1] == (16, 0, 2)


def test_plan_matches_breadth_first_search_on_the_known_map() -> None:
    """D* Lite (with its diving tie-break) keeps the exact distance on what it knows: every step,
    its planned distance equals a BFS over the cells it has learnt are buildings."""
    rng = np.random.default_rng(5)
    for _ in range(40):
        size = tuple(int(v) for v in rng.integers(4, 11, size=3))
        blocked = {tuple(int(v) for v in c) for c in np.argwhere(rng.random(size) < 0.3)}
        free = [c for c in box(0, size[0] - 1, 0, size[1] - 1, 0, size[2] - 1) if c not in blocked]
        free.sort()
        start, target = free[rng.integers(len(free))], free[rng.integers(len(free))]
        grid = Grid(size, blocked)  # type: ignore[arg-type]
        pilot = DStarPilot(world_size=size)  # type: ignore[arg-type]
        pos = start
        for _ in range(400):
            decision, _, _ = step_once(pilot, grid, pos, target)
            if decision.note is not Note.NONE:
                break
            known = {c for a in grid.asks for c, info in a.items() if info.kind is not CellKind.EMPTY}
            assert pilot.distance == grid.bfs(pos, target, known)
            pos = decision.pos
        truth = grid.bfs(start, target)
        assert (decision.note is Note.UNREACHABLE) == (truth is None)
        assert truth is None or pos == target


def test_never_enters_a_building_in_random_cities() -> None:
    rng = np.random.default_rng(11)
    reached = declared = 0
    for i in range(30):
        size = ((10, 10, 10), (16, 16, 6), (12, 20, 4))[i % 3]
        world = World.generate(size, rng, count=int(0.2 * size[0] * size[1]), max_footprint=4, keep_free=())
        grid = Grid(size, {tuple(int(v) for v in c) for c in np.argwhere(world.grid)})  # type: ignore[arg-type]
        free = np.argwhere(~world.grid)
        cells = np.argwhere(np.ones(size, dtype=bool))
        start = tuple(int(v) for v in free[rng.integers(len(free))])
        target = tuple(int(v) for v in cells[rng.integers(len(cells))])  # sometimes a building
        optimal = world.shortest_path_length(start, target)
        flight = fly(DStarPilot(world_size=size), grid, start, target, limit=4 * (optimal or 100) + 100)  # type: ignore[arg-type]
        if optimal is None:
            assert flight.decisions[-1].note is Note.UNREACHABLE
            declared += 1
        else:
            assert flight.path[-1] == target
            reached += 1
    assert reached and declared  # both kinds were exercised


# --------------------------------------------------------------------------- unreachable


def _hovers(pilot: DStarPilot, grid: Grid, pos: Cell, target: Cell, turns: int = 5) -> None:
    for _ in range(turns):
        decision, _, _ = step_once(pilot, grid, pos, target)
        assert (decision.pos, decision.note) == (pos, Note.UNREACHABLE)
        assert ranked_steps(decision.ranked)[0] == STAY  # at rest: it may be pushed aside, never drawn away


def test_enclosed_target_is_unreachable_and_the_drone_hovers() -> None:
    size = (12, 12, 12)
    grid = Grid(size, shell((4, 4, 4), (8, 8, 8)))
    pilot = DStarPilot(world_size=size)
    flight = fly(pilot, grid, (0, 0, 0), (6, 6, 6), limit=500)
    assert flight.decisions[-1].note is Note.UNREACHABLE
    assert len(flight.path) < 200  # said so, rather than looping
    _hovers(pilot, grid, flight.path[-1], (6, 6, 6))


def test_enclosed_target_on_the_ground() -> None:
    size = (10, 10, 4)
    grid = Grid(size, box(3, 7, 3, 7, 0, 2) - box(4, 6, 4, 6, 0, 1))  # a roofed well
    pilot = DStarPilot(world_size=size)
    flight = fly(pilot, grid, (0, 0, 0), (5, 5, 0), limit=500)
    assert flight.decisions[-1].note is Note.UNREACHABLE
    _hovers(pilot, grid, flight.path[-1], (5, 5, 0))


def test_sealed_start_is_unreachable() -> None:
    size = (8, 8, 8)
    grid = Grid(size, shell((2, 2, 2), (4, 4, 4)))
    flight = fly(DStarPilot(world_size=size), grid, (3, 3, 3), (7, 7, 7), limit=100)
    assert flight.decisions[-1].note is Note.UNREACHABLE
    assert set(flight.path) == {(3, 3, 3)}


def test_target_inside_a_building_is_unreachable_at_once() -> None:
    size = (10, 10, 10)
    grid = Grid(size, box(4, 6, 4, 6, 0, 4))
    pilot = DStarPilot(world_size=size)
    flight = fly(pilot, grid, (0, 0, 0), (5, 5, 2), limit=50)
    assert len(flight.decisions) == 1  # the first ASK includes the target
    assert (flight.decisions[0].pos, flight.decisions[0].note) == ((0, 0, 0), Note.UNREACHABLE)
    _hovers(pilot, grid, (0, 0, 0), (5, 5, 2))


def test_resumes_with_a_new_target() -> None:
    size = (12, 12, 12)
    grid = Grid(size, shell((4, 4, 4), (8, 8, 8)))
    pilot = DStarPilot(world_size=size)
    flight = fly(pilot, grid, (0, 0, 0), (6, 6, 6), limit=500)
    assert flight.decisions[-1].note is Note.UNREACHABLE
    pos = flight.path[-1]
    again = fly(pilot, grid, pos, (11, 11, 11))
    assert again.path[-1] == (11, 11, 11)
    # The map learnt for the first target is kept: going back around the shell is direct.
    back = fly(pilot, grid, (11, 11, 11), (0, 0, 0))
    assert back.path[-1] == (0, 0, 0) and moves(back) == grid.bfs((11, 11, 11), (0, 0, 0))
    # A target changed in mid-flight is followed.
    mid = fly(pilot, grid, (0, 0, 0), (11, 0, 0), limit=5, stop_on=())
    rest = fly(pilot, grid, mid.path[-1], (0, 11, 11))
    assert rest.path[-1] == (0, 11, 11)


# --------------------------------------------------------------------------- other drones


def test_side_steps_a_drone_it_can_see() -> None:
    size = (6, 6, 6)
    grid = Grid(size)
    pilot = DStarPilot(world_size=size)
    planned = fly(DStarPilot(world_size=size), Grid(size), (0, 0, 0), (5, 3, 2)).path
    grid.drones = {planned[1]: ("D07",)}  # another drone on the first cell of the plan
    decision, _, _ = step_once(pilot, grid, (0, 0, 0), (5, 3, 2))
    assert decision.pos not in (planned[1], (0, 0, 0))  # another move just as short
    flight = fly(pilot, grid, decision.pos, (5, 3, 2))
    assert flight.path[-1] == (5, 3, 2) and moves(flight) == 5 + 3 + 2 - 1


def test_waits_behind_a_drone_in_a_corridor_and_never_remembers_it() -> None:
    size = (6, 1, 1)
    grid = Grid(size, drones={(1, 0, 0): ("D02",)})
    pilot = DStarPilot(world_size=size)
    for _ in range(4):
        decision, _, _ = step_once(pilot, grid, (0, 0, 0), (5, 0, 0))
        assert (decision.pos, decision.note) == ((0, 0, 0), Note.NONE)  # waits, does not give up
        assert ranked_steps(decision.ranked) == ((1, 0, 0), STAY)  # and offers the arbiter the cell ahead
    grid.drones = {}
    flight = fly(pilot, grid, (0, 0, 0), (5, 0, 0))
    assert flight.path == [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0), (5, 0, 0)]


def test_drone_on_the_target_is_waited_for() -> None:
    size = (3, 3, 3)
    grid = Grid(size, drones={(2, 0, 0): ("D03",)})
    pilot = DStarPilot(world_size=size)
    decision, _, _ = step_once(pilot, grid, (1, 0, 0), (2, 0, 0))
    assert decision.pos != (2, 0, 0) and decision.note is Note.NONE


# --------------------------------------------------------------------------- determinism, sensing


def test_deterministic() -> None:
    rng = np.random.default_rng(3)
    world = World.generate((16, 16, 8), rng, count=60, max_footprint=4, keep_free=((0, 0, 0),))
    blocked = {tuple(int(v) for v in c) for c in np.argwhere(world.grid)}
    runs = []
    for _ in range(2):
        grid = Grid((16, 16, 8), set(blocked))  # type: ignore[arg-type]
        flight = fly(DStarPilot(world_size=(16, 16, 8)), grid, (0, 0, 0), (15, 15, 3))
        runs.append((flight.path, [tuple(a) for a in grid.asks]))
    assert runs[0] == runs[1]


def test_sensing_is_bounded() -> None:
    size = (32, 32, 8)
    rng = np.random.default_rng(8)
    world = World.generate(size, rng, count=150, max_footprint=5, keep_free=((0, 0, 0), (31, 31, 0)))
    grid = Grid(size, {tuple(int(v) for v in c) for c in np.argwhere(world.grid)})  # type: ignore[arg-type]
    pilot = DStarPilot(world_size=size)
    flight = fly(pilot, grid, (0, 0, 0), (31, 31, 0))
    assert flight.path[-1] == (31, 31, 0)
    assert max(flight.asks) <= 2
    assert max(len(a) for a in grid.asks) <= 6 + 1 + pilot.lookahead
    assert all(_inside(c, size) for a in grid.asks for c in a)  # never asks outside the world


# --------------------------------------------------------------------------- the benchmark


def test_benchmark_quick_runs(capsys: pytest.CaptureFixture[str]) -> None:
    root = str(Path(__file__).resolve().parents[1])
    if root not in sys.path:
        sys.path.insert(0, root)
    from benchmarks.autopilot import main

    assert main(["--quick"]) == 0
    out = capsys.readouterr().out
    assert "| dstar | 100.0 %" in out
