"""The complete arbitration (coordinator/lacam.py): a LaCAM search over the cooperative drones' configurations,
run by the coordinator over turns and committed a step a turn.

Small hard instances where PIBT alone pushes drones to and fro for ever or gives up (1-wide corridors with a
bay, doors, swaps) are solved; a provably unsolvable instance is recognised and ended; journals are the same in
every layout, `replay --verify` re-simulates them, and a resumed coordinator's search is the one that played."""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from coordinator import compiled, lacam
from coordinator.arbiter import OpenCells
from coordinator.config import DroneSpec, GameConfig
from coordinator.exact import Exact
from coordinator.resume import restore
from dronesim import replay
from dronesim.local import Inputs, Result, simulate
from entities.gcs import Plan
from schema import Cell, EndReason, WorldSpec
from world import movingai
from world.grid import World
from world.search import cells_of, flat_cells, padded_steps

LOG = logging.getLogger("test_lacam")
Drones = dict[str, tuple[Cell, Cell]]


def world_of(rows: list[str]) -> np.ndarray:
    """A grid [x, y, 0] from rows of text (row k is y = k; '#' a building)."""
    return np.array([[c == "#" for c in r] for r in rows]).T[:, :, None]


def config(grid: np.ndarray, drones: Drones, max_turns: int, using: str) -> GameConfig:
    world = World.from_grid(grid)
    return GameConfig(world=WorldSpec(size=world.size, cells=world.packed()), max_turns=max_turns, arbiter=using,
                      drones=tuple(DroneSpec(drone=d, start=s) for d, (s, _) in sorted(drones.items())))


def play(grid: np.ndarray, drones: Drones, max_turns: int = 200, using: str = "lacam", swarm: bool = False,
         arbiter: lacam.Lacam | None = None) -> Result:
    plan = Plan(tuple(sorted((1, d, t) for d, (_, t) in drones.items())))
    return simulate(config(grid, drones, max_turns, using), dict.fromkeys(drones, "dstar"), Inputs(plan=plan), LOG,
                    swarm=swarm, arbiter=arbiter)


#: Hard instances: (name, map rows, drones). PIBT (with giving way, the swap and the clear operation) does not
#: bring every drone home on any of them (its drones end saying UNREACHABLE); each has a solution.
HARD: list[tuple[str, list[str], Drones]] = [
    # D02 parked past the only bay: D01 must first step back to let it into the bay
    ("parked past the bay", ["###.######", ".........."],
     {"D01": ((0, 1, 0), (9, 1, 0)), "D02": ((5, 1, 0), (5, 1, 0))}),
    # two drones swap the ends of a 1-wide corridor with a pocket near each end, a third parked between
    ("swap past a parked drone", ["#.#####.#", "........."],
     {"D01": ((0, 1, 0), (8, 1, 0)), "D02": ((8, 1, 0), (0, 1, 0)), "D03": ((2, 1, 0), (2, 1, 0))}),
    # the same in a short corridor, the parked drone between the two pockets
    ("swap in a short corridor", ["#.#.#", "....."],
     {"D01": ((0, 1, 0), (4, 1, 0)), "D02": ((4, 1, 0), (0, 1, 0)), "D03": ((2, 1, 0), (2, 1, 0))}),
]

#: Two rooms joined by a 1-wide corridor three cells long (a door), the drones trading sides.
DOOR = (["..###..", ".......", "..###.."],
        {"D01": ((0, 0, 0), (6, 2, 0)), "D02": ((1, 0, 0), (5, 2, 0)), "D03": ((0, 1, 0), (6, 1, 0)),
         "D04": ((6, 0, 0), (0, 2, 0)), "D05": ((5, 0, 0), (1, 2, 0)), "D06": ((6, 1, 0), (0, 1, 0))})


@pytest.mark.parametrize("name, rows, drones", HARD, ids=[h[0] for h in HARD])
def test_hard_instances_are_solved_where_pibt_is_not(name: str, rows: list[str], drones: Drones) -> None:
    pibt = play(world_of(rows), drones, using="pibt")
    assert pibt.over.reason is not EndReason.ALL_REACHED, f"{name}: PIBT alone solved it ({pibt.over.text})"
    result = play(world_of(rows), drones)
    assert result.over.reason is EndReason.ALL_REACHED, f"{name}: {result.over.text}"
    assert not any(r.get("deaths") for r in result.records)
    assert result.over.turn <= 4 * max(8, len(rows[0]))  # within a few times the longest way


def test_a_door_between_two_rooms() -> None:
    rows, drones = DOOR
    result = play(world_of(rows), drones)
    assert result.over.reason is EndReason.ALL_REACHED, result.over.text
    # (the search's way may be a turn or two longer than PIBT's where PIBT finds one)
    assert result.over.turn <= play(world_of(rows), drones, using="pibt").over.turn + 2


#: A drone whose target it cannot reach (walled off, enclosed, or none) in another's way: each has a way home for the
#: other, and the game must end SETTLED naming the first alone. (Found by probing: its stand-in goal, its own cell,
#: made the search "prove" no solution, or hold two drones in one goal cell; and a D* drone that gave up offered its
#: own cell alone, so nothing could push it.)
AT_REST: list[tuple[str, np.ndarray, Drones]] = [
    ("walled-off target in a corridor", world_of(["......#."]).transpose(1, 0, 2),
     {"D01": ((0, 3, 0), (0, 7, 0)), "D02": ((0, 0, 0), (0, 4, 0))}),
    ("walled-off target beside a bay", world_of(["......#.", "##.#####"]).transpose(1, 0, 2),
     {"D01": ((0, 3, 0), (0, 7, 0)), "D02": ((0, 0, 0), (0, 5, 0))}),
]


@pytest.mark.parametrize("name", [name for name, _, _ in AT_REST])
def test_a_drone_that_cannot_reach_its_target_is_no_proof_and_steps_aside(name: str) -> None:
    _, grid, drones = next(case for case in AT_REST if case[0] == name)
    result = play(grid, drones, 100)
    assert (result.over.reason, result.over.text) == (EndReason.SETTLED, "targets reached, except unreachable for D01")
    assert result.over.turn < 20


def test_a_drone_that_gave_up_on_another_ones_target_steps_off_it() -> None:
    """D01's target is enclosed (walls round it and above), D02's is D01's start: D01's stand-in goal moves off
    D02's (`lacam.stand_ins`), else the goal configuration holds both in one cell and D02 never arrives."""
    grid = np.zeros((3, 3, 2), bool)
    grid[0, 1, 0] = grid[2, 1, 0] = grid[1, 0, 0] = grid[1, 2, 0] = grid[1, 1, 1] = True
    result = play(grid, {"D01": ((0, 0, 0), (1, 1, 0)), "D02": ((2, 2, 0), (0, 0, 0))}, 100)
    assert (result.over.reason, result.over.text) == (EndReason.SETTLED, "targets reached, except unreachable for D01")


def test_a_lifelong_game_goes_on_when_its_targets_have_no_solution() -> None:
    """Two drones in a 1 x 5 corridor drawn targets that would have them pass each other: no solution for those
    targets, which a game ends on (SETTLED); a lifelong game plays on to its limit (its drones' next tasks)."""
    world = World.from_grid(np.zeros((1, 5, 1), bool))
    config = GameConfig(world=WorldSpec(size=world.size, cells=world.packed()), max_turns=60, lifelong=True,
                        drones=(DroneSpec(drone="D01", start=(0, 0, 0)), DroneSpec(drone="D02", start=(0, 4, 0))))
    plan = Plan(((1, "D01", (0, 3, 0)), (1, "D02", (0, 1, 0))))  # (they must pass each other: impossible)
    result = simulate(config, dict.fromkeys(("D01", "D02"), "dstar"), Inputs(plan=plan), LOG)
    assert result.over.reason is EndReason.TURN_LIMIT and result.over.turn == 60


def test_the_search_proves_a_swap_in_a_closed_corridor_unsolvable_and_finds_one_with_a_bay() -> None:
    for rows, solvable in ((["....."], False), (["..#..", "....."], True)):
        grid = world_of(rows)
        size: Cell = grid.shape  # type: ignore[assignment]
        y = len(rows) - 1
        before = np.array([(0, y, 0), (4, y, 0)], np.int32)
        targets = before[::-1].copy()
        search = lacam.Lacam()
        open_ = OpenCells(grid)
        cells = before
        for turn in range(1, 40):
            plan = search.follow(size, cells, np.ones(2, bool), targets, open_, turn)
            if plan is None:  # (a turn of PIBT's: the world's graph is made)
                continue
            nxt = np.array([[int(v) for v in c] for c in cells_of(plan, size)], np.int32)
            assert np.abs(nxt - cells).sum(axis=1).max() <= 1 and len({tuple(c) for c in nxt.tolist()}) == 2
            assert not ((nxt[0] == cells[1]).all() and (nxt[1] == cells[0]).all()), "a swap"
            cells = nxt
            if search.unsolvable or (cells == targets).all():
                break
        assert search.unsolvable is not solvable
        assert bool((cells == targets).all()) is solvable


def test_a_search_without_progress_hands_back_to_pibt_and_comes_back_with_more_patience(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A search that brings no new high of drones home for `stall` turns (twice as many each later time) gives the
    turns back to PIBT; a new one starts once PIBT has stalled `stall` turns (here the drones hold still in PIBT's
    turns): focused on the drones away where the distance tables are made at the start (`Lacam._focus`; here the
    whole world, which it covers), else of the whole world (here forced with PRECOMPUTE = 0); the patience doubling,
    a search eventually runs to the end: the swap with a bay is done."""
    for precompute in (lacam.PRECOMPUTE, 0):
        monkeypatch.setattr(lacam, "PRECOMPUTE", precompute)
        runs, pauses = _stalling()
        assert len(runs) >= 3 and runs[-1] > runs[0], runs  # handed back, and came back with more patience
        assert all(p == 2 for p in pauses[1:]), pauses  # each time PIBT held still for `stall` turns (after the tables)


def _stalling() -> tuple[list[int], list[int]]:
    """The swap with a bay under a search of a PIBT call a turn and a stall of 2 turns: the turns the search played in
    a row, and those between (PIBT's)."""
    grid = world_of(["....#....", "........."])  # a bay in the middle of a corridor 9 long: the swap needs 12 turns
    size: Cell = grid.shape  # type: ignore[assignment]
    before = np.array([(0, 1, 0), (8, 1, 0)], np.int32)
    targets = before[::-1].copy()
    search, open_, cells = lacam.Lacam(work=1, stall=2, small=0), OpenCells(grid), before  # (a PIBT call a turn)
    searching: list[bool] = []
    for turn in range(1, 200):
        plan = search.follow(size, cells, np.ones(2, bool), targets, open_, turn)
        searching.append(plan is not None)
        if plan is not None:
            cells = np.array([[int(v) for v in c] for c in cells_of(plan, size)], np.int32)
        if (cells == targets).all():
            break
    assert (cells == targets).all()
    runs = [len(r) for r in "".join("s" if s else "." for s in searching).split(".") if r]
    pauses = [len(p) for p in "".join("s" if s else "." for s in searching).strip(".").split("s") if p]
    return runs, pauses


def _swap(rows: list[str], search: lacam.Lacam, turns: int = 60) -> np.ndarray:
    """The two drones at the ends of the last row swap them under `search` (each turn's plan taken, or PIBT's
    turn: the drones hold still); their cells at the end."""
    grid = world_of(rows)
    size: Cell = grid.shape  # type: ignore[assignment]
    y = len(rows) - 1
    cells = np.array([(0, y, 0), (len(rows[-1]) - 1, y, 0)], np.int32)
    targets, open_ = cells[::-1].copy(), OpenCells(grid)
    for turn in range(1, turns):
        plan = search.follow(size, cells, np.ones(2, bool), targets, open_, turn)
        if plan is not None:
            cells = np.array([[int(v) for v in c] for c in cells_of(plan, size)], np.int32)
        if search.unsolvable or (cells == targets).all():
            break
    return cells


def test_a_search_that_fills_its_memory_hands_back_and_never_claims_a_proof() -> None:
    """A search holds `memory` entries at most (its configurations and queued constraints): one that reaches it
    stops, the turns go back to PIBT (`full` counts it), and it never says the instance is unsolvable; with the
    memory the proof needs, the same closed corridor is proved unsolvable."""
    small = lacam.Lacam(stall=2, memory=40, small=0)
    _swap(["....."], small)
    assert small.full >= 1 and not small.unsolvable
    assert small._search is None or small._search.held <= 40 + 3 * 2 + 7 * 2 * 2  # (one expansion past it at most)
    enough = lacam.Lacam(stall=2, small=0)
    _swap(["....."], enough)
    assert enough.unsolvable and enough.full == 0
    solved = lacam.Lacam(memory=1 << 10, small=0)  # (the bay: found well within it)
    assert (_swap(["..#..", "....."], solved) == np.array([(4, 1, 0), (0, 1, 0)])).all()


def test_the_constraints_pin_the_drones_away_first_then_those_nearest_them() -> None:
    """A node's low-level search pins first the drones away from their goals (highest priority first), then the
    drones on their goals, nearest to a drone away first: a parked drone beside one that must pass is pinned by
    the third constraint, not after every parked drone of higher priority (as by priority alone)."""
    grid = world_of(["........."])
    size: Cell = grid.shape  # type: ignore[assignment]
    cells = np.array([(0, 0, 0), (1, 0, 0), (6, 0, 0), (7, 0, 0), (8, 0, 0)], np.int32)
    goals = cells.copy()
    goals[3] = (2, 0, 0)  # drone 3 is away; drone 2 beside it, drones 0, 1 and 4 parked farther
    open_ = OpenCells(grid)
    search = lacam.Lacam(small=0)  # (LaCAM's search, not the exact one of a small puzzle)
    search.prepare(size, open_)
    s = search._start(size, flat_cells(cells, size), flat_cells(goals, size))
    assert s is not None
    pins = s._pins(s.at)
    assert pins[0] == 3 and set(pins[1:3]) == {2, 4} and pins[3:] == [1, 0], pins


def test_a_focused_search_moves_the_drones_near_those_away_and_never_claims_a_proof() -> None:
    """A search focused on the drones away (`Lacam._focus`: the drones within its radius of them or of their goals
    move, the others stand still as walls) that finds no way within its part of the world proves nothing: the
    arbitration never says the instance unsolvable on it, and a wider one, which reaches the bay, finds the way."""
    grid = world_of(["#############.###", "................."])  # the only bay at x = 13
    size: Cell = grid.shape  # type: ignore[assignment]
    cells = np.array([(0, 1, 0), (6, 1, 0), (16, 1, 0)], np.int32)
    goals = np.array([(6, 1, 0), (0, 1, 0), (16, 1, 0)], np.int32)  # a swap; drone 2 parked at the far end
    open_ = OpenCells(grid)
    search = lacam.Lacam(small=0)  # (LaCAM's search, not the exact one of a small puzzle)
    search.prepare(size, open_)
    here, aims = flat_cells(cells, size), flat_cells(goals, size)
    narrow = search._focus(size, here, aims, 4)
    assert narrow is not None and narrow.focus is not None
    assert narrow.focus[0].tolist() == [0, 1]  # drone 2 stands still, and the bay is out of reach
    while narrow.found is None and narrow.open:
        narrow.expand(1 << 20, open_)
    assert narrow.unsolvable and not search.unsolvable
    assert (narrow.whole(narrow.at.cfg) == here).all()
    wide = search._focus(size, here, aims, 8)
    assert wide is not None and wide.focus is not None and wide.focus[0].tolist() == [0, 1]
    while wide.found is None and wide.open:
        wide.expand(1 << 20, open_)
    assert wide.found is not None
    assert (wide.whole(wide.found.cfg) == aims).all()


def test_a_focused_search_takes_puzzles_apart_one_after_the_other() -> None:
    """Drones away in two places far apart: the focused search takes the piece of its part of the world with the
    fewest drones away, then the fewest cells (`Lacam._piece`), the other drones standing still; walked, the next
    search takes the other piece at once, and every drone gets home."""
    grid = world_of(["#" * 30, "." * 30])
    size: Cell = grid.shape  # type: ignore[assignment]
    cells = np.array([(0, 1, 0), (12, 1, 0), (29, 1, 0)], np.int32)
    goals = np.array([(1, 1, 0), (12, 1, 0), (27, 1, 0)], np.int32)  # drone 1 parked between the two away
    open_ = OpenCells(grid)
    search = lacam.Lacam()
    search.prepare(size, open_)
    here, aims = flat_cells(cells, size), flat_cells(goals, size)
    first = search._focus(size, here, aims, 4)
    assert first is not None and first.focus is not None and first.focus[0].tolist() == [0]  # (6 cells, not 7)
    coop = np.ones(3, bool)
    search._radius, search._key = 4, aims.tobytes()  # (as after a search of the whole world without progress)
    search._search = first
    pieces = []
    for turn in range(1, 12):
        plan = search.follow(size, cells, coop, goals, open_, turn)
        assert plan is not None
        s = search._search
        assert s is not None and s.focus is not None
        pieces.append(s.focus[0].tolist())
        cells = cells_of(plan, size).astype(np.int32)
        if (plan == aims).all():
            break
    assert (cells_of(plan, size) == goals).all()
    assert pieces[0] == [0] and pieces[-1] == [2], pieces


def _endgame(monkeypatch: pytest.MonkeyPatch, after: int) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Two drones trade places at the start of a corridor 32 long (a bay at x = 5), two others parked far away,
    under LaCAM's search (not the exact one), a few PIBT calls a turn: each turn's course ('s' the whole world's
    search, 'f' a focused one, '.' PIBT's turn: the drones hold still), the drones' cells at the end and their
    targets."""
    monkeypatch.setattr(lacam, "ENDGAME_AFTER", after)
    grid = world_of(["#####.##########################", "." * 32])
    size: Cell = grid.shape  # type: ignore[assignment]
    cells = np.array([(0, 1, 0), (3, 1, 0), (20, 1, 0), (31, 1, 0)], np.int32)
    targets = np.array([(3, 1, 0), (0, 1, 0), (20, 1, 0), (31, 1, 0)], np.int32)
    search, open_ = lacam.Lacam(work=200, small=0), OpenCells(grid)
    course: list[str] = []
    for turn in range(1, 300):
        plan = search.follow(size, cells, np.ones(4, bool), targets, open_, turn)
        s = search._search
        course.append("." if plan is None else "s" if s is None or s.focus is None else "f")
        if plan is not None:
            cells = cells_of(plan, size).astype(np.int32)
        if (cells == targets).all():
            break
    return course, cells, targets


def test_in_the_endgame_a_focused_search_starts_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """A few drones away among drones on their targets (`lacam.ENDGAME_SHARE`), no new high for `ENDGAME_AFTER`
    turns: the whole world's search, which has not found its goal, hands over to a search focused on them at once,
    without its patience's turns (`STALL`) nor PIBT's; the drones get home. Without the rule (ENDGAME_AFTER past the
    patience), the same search waits for both before focusing."""
    course, cells, targets = _endgame(monkeypatch, lacam.ENDGAME_AFTER)
    assert (cells == targets).all()
    assert "." not in course and "f" in course, "".join(course)
    assert course.index("f") <= lacam.ENDGAME_AFTER + 1, "".join(course)
    course, cells, targets = _endgame(monkeypatch, 1 << 20)
    assert "." in course and course.index("f") >= 2 * lacam.STALL, "".join(course)


#: Two drones trading places in a 1-wide passage between two 2 x 2 blocks, eight drones parked on their targets
#: around them (random-32-32-20 with 400 drones, seed 5, the part of its endgame that LaCAM's focus took in): the
#: passage's ends are cut off but for the block on the left, whose free cells let them pass.
CROWDED = (["##.#...###", "#....#...#", "##..#...##", "###.##.###"],
           [(4, 0, 0), (5, 0, 0), (2, 0, 0), (6, 0, 0), (2, 1, 0), (4, 1, 0), (6, 1, 0), (5, 2, 0), (6, 2, 0),
            (7, 2, 0)])


#: Three drones in a 1-wide line of three cells, each wanting the next one's cell (the first the last's), the line's
#: ends each held by a drone parked on its target, between two clusters of free and parked cells, each with a
#: 4-cycle (random-32-32-20 with 400 drones, seed 5, x 8-18 and y 0-5, the endgame left by more search a turn).
LINE = (["#..#...#...", "#....#...#.", "....#...##.", "#....#.....", "..###...#..", ".......#..."],
        [(4, 0, 0), (5, 0, 0), (6, 0, 0), (0, 5, 0), (1, 5, 0), (2, 0, 0), (2, 1, 0), (4, 1, 0), (4, 5, 0), (5, 2, 0),
         (5, 5, 0), (6, 1, 0), (6, 2, 0), (6, 4, 0), (6, 5, 0), (7, 2, 0), (7, 3, 0), (9, 0, 0), (9, 4, 0),
         (10, 4, 0), (10, 5, 0)])


def _crowded(turns: int = 40, puzzle: tuple[list[str], list[tuple[int, int, int]]] = CROWDED,
             trade: list[int] | None = None) -> tuple[bool, list[str]]:
    """A crowded puzzle (the crowded swap by default) played by the focused searches from its start (as after a
    search of the whole world without progress): every drone home within `turns`, and each turn's search (its kind
    and drones). The drones of `trade` (the first two by default) each want the next one's cell, the last the
    first's; the others are on their targets."""
    rows, parked = puzzle
    grid = world_of(rows)
    size: Cell = grid.shape  # type: ignore[assignment]
    cells = np.array(parked, np.int32)
    targets = cells.copy()
    trade = [0, 1] if trade is None else trade
    targets[trade] = targets[trade[1:] + trade[:1]]
    open_, coop = OpenCells(grid), np.ones(len(cells), bool)
    search = lacam.Lacam()
    search.prepare(size, open_)
    search._radius, search._key = lacam.FOCUS, flat_cells(targets, size).tobytes()
    kinds: list[str] = []
    for turn in range(1, turns):
        plan = search.follow(size, cells, coop, targets, open_, turn)
        s = search._search
        drones = 0 if s is None or s.focus is None else len(s.focus[0])
        kinds.append("PIBT" if plan is None or s is None else f"{type(s).__name__} {drones}")
        if plan is not None:
            cells = cells_of(plan, size).astype(np.int32)
        if (cells == targets).all():
            return True, kinds
    return False, kinds


def test_a_puzzle_in_a_crowd_is_solved_on_the_ladder_of_exact_searches() -> None:
    """The focused searches' ladder (`Lacam._rung_search`): parts that grow through free cells before parked drones
    (a parked drone's cell costs `RUNG_PARKED` moves), each searched whole while it is small; a part without a way
    gives way to the next at once. The crowded swap is solved by a part of 6 of its 10 drones (its least makespan:
    the exact search's), where the ball of the focus takes in all 10, too many joint moves for an exact search
    (LaCAM's, then: 18,539 PIBT calls in the game's endgame)."""
    home, kinds = _crowded()
    assert home, kinds
    assert all(k.startswith("Exact") for k in kinds) and "Exact 6" in kinds, kinds  # (home within 40 turns)
    rows, parked = CROWDED
    grid = world_of(rows)
    size: Cell = grid.shape  # type: ignore[assignment]
    search = lacam.Lacam()
    search.prepare(size, OpenCells(grid))
    here = flat_cells(np.array(parked, np.int32), size)
    aims = here.copy()
    aims[[0, 1]] = aims[[1, 0]]
    search._flat = lacam.EXACT_AFTER  # (no progress: an exact search where the puzzle is small)
    ball = search._focus(size, here, aims, lacam.FOCUS)
    assert isinstance(ball, lacam.Search) and ball.focus is None and len(ball.goals) == 10


def test_a_rung_too_big_to_search_whole_is_searched_a_side_at_a_time(monkeypatch: pytest.MonkeyPatch) -> None:
    """Three drones changing their order in a 1-wide line between two crowded clusters (`LINE`): the ladder's rung
    whose part takes in both clusters (8 drones on 16 cells, 518,918,400 placements) is too big for an exact search;
    its left side alone (the line and one cluster: 5 drones on 9 cells) is searched whole and has the way, every drone
    home within 30 turns. Without the sides (`Lacam._sides` giving none), the ladder ends there and LaCAM's focus does
    not find it in 60 turns (nor did the game's in 64)."""
    home, kinds = _crowded(30, LINE, [0, 1, 2])
    assert home, kinds
    assert "Exact 5" in kinds and not any(k.startswith("Search") for k in kinds), kinds
    monkeypatch.setattr(lacam.Lacam, "_sides", staticmethod(lambda seen, start, near: []))
    home, kinds = _crowded(60, LINE, [0, 1, 2])
    assert not home and any(k.startswith("Search") for k in kinds), kinds


def test_the_ladder_and_the_focus_end_where_the_drones_stand_in_several_components(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Drones in two components of the world (one alone in a 1-cell pocket), a puzzle without a way in the other: the
    ladder's parts stop growing at the seed's component, the focus's radius at its cells, and both end (the rungs once
    climbed for ever: a part never the cells of every drone's component; the focus's radius, doubled at each search
    without progress, walked cell ring by cell ring to 2^40), the game proving the puzzle has no way."""
    rows, starts, goals = ([".##.", "#..#", "..#."], [(0, 2, 0), (1, 1, 0), (3, 2, 0), (2, 1, 0)],
                           [(3, 0, 0), (0, 2, 0), (3, 2, 0), (2, 1, 0)])
    grid = world_of(rows)
    size: Cell = grid.shape  # type: ignore[assignment]
    search = lacam.Lacam()
    search.prepare(size, OpenCells(grid))
    here, aims = flat_cells(np.array(starts), size), flat_cells(np.array(goals), size)
    calls = 0
    piece = lacam.Lacam._piece

    def counted(seen: np.ndarray, near: np.ndarray, away: np.ndarray) -> np.ndarray:
        nonlocal calls
        calls += 1
        assert calls < 1000, "the ladder climbs for ever"
        return piece(seen, near, away)

    monkeypatch.setattr(lacam.Lacam, "_piece", staticmethod(counted))
    search._ladder()
    while search._rung:
        made = search._rung_search(size, here, aims)
        if made is None:
            break
        search._side += 1  # (as `follow` does when a rung has no way)
    assert search._rung == 0 and calls < 20
    monkeypatch.undo()
    unique, seen = np.unique, 0

    def counted_unique(*args: object, **kwargs: object) -> object:
        nonlocal seen
        seen += 1
        assert seen < 10_000, "the focus walks its radius for ever"
        return unique(*args, **kwargs)  # type: ignore[call-overload]

    monkeypatch.setattr(np, "unique", counted_unique)
    focused = search._focus(size, here, aims, 1 << 40)
    monkeypatch.undo()
    assert focused is None or focused.focus is None  # (the whole world's search: its component's every cell)
    drones = {f"D{i + 1:02d}": (s, g) for i, (s, g) in enumerate(zip(starts, goals))}
    result = play(grid, drones, 1000, "lacam")
    assert result.over.reason is EndReason.SETTLED and result.over.turn < 50, result.over


def test_a_turn_of_the_search_spends_its_budget_at_most(monkeypatch: pytest.MonkeyPatch) -> None:
    """The search's PIBT calls a turn: as many as `work` units hold (one at least), never more; the turns that make
    the scattered paths (`Scatter`, as the search starts: `SCATTER_WORK` units a turn, a path at least) make none, the
    drones holding; where the distance tables are not made at the game's start (a world too big: here made so), a
    turn makes those its units hold (one at least) and the search starts the turn after the last, PIBT playing
    meanwhile."""
    rows, drones = DOOR
    grid = world_of(rows)
    size: Cell = grid.shape  # type: ignore[assignment]
    n = len(drones)
    cells = np.array([s for s, _ in drones.values()], np.int32)
    targets = np.array([t for _, t in drones.values()], np.int32)
    coop, open_ = np.ones(n, bool), OpenCells(grid)
    full = max(1, (n + n // lacam.FIXED + lacam.CALL) // lacam.SHARE)  # (a call where every drone chooses: the first
    # ones here)
    start = cells
    for work, scatter, spread in [(1, False, 0), (2 * full, False, 0), (3 * full - 1, False, 0), (4 * full, False, 0),
                                  (4 * full, True, lacam.SCATTER_WORK), (4 * full, True, 1)]:
        monkeypatch.setattr(lacam, "CROWD", n if scatter else lacam.CROWD)  # (the scatter: a crowd of 6 drones)
        monkeypatch.setattr(lacam, "SCATTER_WORK", spread)  # (1: a path a turn)
        search, cells = lacam.Lacam(work=work, scatter=scatter), start
        calls, held = [], []
        for turn in range(1, 30):
            before = search.expansions
            plan = search.follow(size, cells, coop, targets, open_, turn)  # (the tables made before the turns)
            assert plan is not None
            calls.append(search.expansions - before)
            s = search._search
            if s is not None and s.found is not None:
                calls.pop()  # (walking the plan found: no call)
                break
            guiding = isinstance(s, lacam.Search) and s._scatter is not None
            if calls[-1] == 0:
                assert scatter and (guiding or s is not None and s.guide is not None), turn
                held.append(bool((cells_of(plan, size) == cells).all()))
            else:
                assert search.spent <= work or calls[-1] == 1, (work, turn, search.spent)
            cells = cells_of(plan, size).astype(np.int32)
        if scatter:
            k = calls.index(4)
            assert k >= 1 and calls[:k] == [0] * k and calls[k:] == [4] * len(calls[k:]) and held == [True] * k, calls
            assert len(calls) - k >= 3, calls
            assert k % n == 0 and k >= n if spread == 1 else k == 1, calls  # (6 drones' paths, a round or more: in
            # one turn, or a path a turn)
            assert s is not None and s.scattered > 0 and s.guide is not None
        else:
            assert calls[0] == max(1, work // full), calls
    monkeypatch.setattr(lacam, "PRECOMPUTE", 0)
    search, cells = lacam.Lacam(work=1), start
    made = []
    while search.follow(size, cells, coop, targets, open_, len(made)) is None:
        made.append(len(search._tables))
    assert made == list(range(1, len({tuple(t) for t in targets.tolist()}) + 1))  # (a table a turn, then the search)


def _room_crowd() -> tuple[Cell, OpenCells, np.ndarray, np.ndarray]:
    """100 drones in room-32-32-4 (seed 1): the world's size and open cells, the drones' cells and targets (flat)."""
    blocked = movingai.generate("room-32-32-4", 1)
    cells = movingai.starts_and_goals(movingai.scenario(blocked, 100, 1, "room-32-32-4.map"))
    grid = movingai.world_grid(blocked)
    size: Cell = grid.shape  # type: ignore[assignment]
    open_ = OpenCells(grid)
    here = flat_cells(np.array([s for s, _ in cells], np.int32), size)
    aims = flat_cells(np.array([g for _, g in cells], np.int32), size)
    return size, open_, here, aims


def _found(size: Cell, open_: OpenCells, here: np.ndarray, aims: np.ndarray) -> lacam.Search:
    """A whole world's search, unguided (`scatter=False`), expanded until it has found the goal."""
    search = lacam.Lacam(scatter=False)
    search.prepare(size, open_)
    s = search._start(size, here, aims)
    assert s is not None
    while s.found is None:
        s.expand(lacam.WORK, open_)
    assert isinstance(s, lacam.Search)
    return s


def _refined_walk(size: Cell, open_: OpenCells, here: np.ndarray, aims: np.ndarray) -> tuple[list[np.ndarray], int]:
    """The drones' configurations walking a found search's plan, a turn's refinement (`Search.refine`) before
    each step, and the first solution's length (the search unguided, `scatter=False`: the refiners' own gain; guided by
    scattered paths, its first solution here is 74 steps, 80 unguided, and no refiner finds a shorter one)."""
    s = _found(size, open_, here, aims)
    walked = [s.where()]
    while True:
        s.refine(lacam.WORK, open_)
        if s.t == len(s.plan if s.plan is not None else ()) - 1:
            return walked, s.first
        walked.append(s.step())


def test_a_found_plan_is_refined_while_the_drones_walk_it() -> None:
    """LaCAM's first solution (PIBT's chain) in a crowd of rooms joined by 1-wide doors is long; refining searches
    from configurations of the plan ahead of the drones make it shorter while they walk it (`Search.refine`):
    every step a valid move of every drone (to a neighbour or staying, no two in a cell, no swap), the walk ends
    with every drone home, shorter than the first solution, and is the same in every run."""
    size, open_, here, aims = _room_crowd()
    walked, first = _refined_walk(size, open_, here, aims)
    assert (walked[0] == here).all() and (walked[-1] == aims).all()
    assert len(walked) - 1 < first, (len(walked) - 1, first)
    steps = set(padded_steps(size)[2]) | {0}
    for a, b in zip(walked, walked[1:]):
        assert set((b - a).tolist()) <= steps and all(open_[int(u)] for u in b)
        assert len(np.unique(b)) == len(b)
        back = dict(zip(b.tolist(), a.tolist()))  # (who came into a cell: no two drones traded theirs)
        assert not any(back.get(u) == v and u != v for u, v in zip(a.tolist(), b.tolist()))
    again, _ = _refined_walk(size, open_, here, aims)
    assert len(again) == len(walked) and all((x == y).all() for x, y in zip(again, walked))


def test_a_refiner_whose_tables_would_not_be_copied_in_a_turn_is_not_made(monkeypatch: pytest.MonkeyPatch) -> None:
    """A refining search over some drones copies their distance tables over its part of the world; where that copy
    would hold more than `PRECOMPUTE` entries (1000 drones in the 64 x 64 x 8 city: 56 MB, a turn of 150 ms), no such
    refiner is made and the plan is walked as it is (here `PRECOMPUTE` made small, after the game's tables): every
    drone home, no refiner over a part of the world."""
    size, open_, here, aims = _room_crowd()
    s = _found(size, open_, here, aims)
    monkeypatch.setattr(lacam, "PRECOMPUTE", 1000)
    refused, made = [], []
    real = lacam.Search._refiner

    def watched(self: lacam.Search, ahead: int, number: int) -> lacam.Search | None:
        out = real(self, ahead, number)
        (refused if out is None else made).append(out)
        return out

    monkeypatch.setattr(lacam.Search, "_refiner", watched)
    where = s.where()
    while s.plan is None or s.t < len(s.plan) - 1:
        s.refine(lacam.WORK, open_)
        where = s.step()
    assert (where == aims).all()
    assert refused and all(r is not None and r.focus is None for r in made), (len(refused), len(made))


#: Two rooms joined by two 1-wide doors, at y = 0 and y = 6; drones cross both ways near the top door.
DOORS = [".........", "....#....", "....#....", "....#....", "....#....", "....#....", "........."]
CROSSING = ([(0, 1, 0), (1, 1, 0), (2, 1, 0), (3, 1, 0), (5, 2, 0), (6, 2, 0), (7, 2, 0), (8, 2, 0)],
            [(5, 1, 0), (6, 1, 0), (7, 1, 0), (8, 1, 0), (0, 2, 0), (1, 2, 0), (2, 2, 0), (3, 2, 0)])


def _scattered(margin: int) -> tuple[lacam.Scatter, list[set[int]]]:
    """The scattered paths of the drones crossing between DOORS' rooms, and the doors (y) each path goes through."""
    grid = world_of(DOORS)
    size: Cell = grid.shape  # type: ignore[assignment]
    arb = lacam.Lacam()
    arb.prepare(size, OpenCells(grid))
    g, every = arb._graph, arb._every
    assert g is not None and every is not None
    here = g.index[flat_cells(np.array(CROSSING[0], np.int32), size)]
    aims = g.index[flat_cells(np.array(CROSSING[1], np.int32), size)]
    scatter = lacam.Scatter(g, here, aims, every[aims], margin)
    while not scatter.done:
        scatter.advance(1)
    doors = [{y for x, y, _ in cells_of(g.cells[np.array(p)], size).tolist() if x == 4} for p in scatter.paths]
    return scatter, doors


def test_scattered_paths_spread_two_flows_over_two_doors() -> None:
    """LaCAM3's scattered paths (`Scatter`): the drones' paths, planned one after the other against the others' in
    space and time, for a few rounds: two flows crossing each other's way through the nearer door are spread, one
    going round by the other door (a detour within the margin), and then meet nowhere. Limited to the shortest ways
    (margin 0), every path takes the nearer door and they meet."""
    scatter, doors = _scattered(lacam.MARGIN)
    assert doors[:4] == [{0}] * 4 and doors[4:] == [{6}] * 4 or doors[:4] == [{6}] * 4 and doors[4:] == [{0}] * 4
    assert scatter.last == 0 and all(len(p) >= 2 for p in scatter.paths)
    shortest, doors = _scattered(0)
    assert doors == [{0}] * 8 and shortest.last > 0
    again, _ = _scattered(lacam.MARGIN)
    assert again.paths == scatter.paths  # (deterministic: the rounds' orders drawn from their numbers)


@pytest.mark.parametrize("family,agents,seed,margin", [("room-32-32-4", 80, 3, lacam.MARGIN),
                                                        ("maze-32-32-2", 60, 1, lacam.MARGIN),
                                                        ("random-32-32-20", 120, 2, lacam.MARGIN),
                                                        ("warehouse-32-32", 200, 4, 0), ("empty-32-32", 150, 5, 3)])
def test_the_compiled_scatter_makes_the_paths_python_makes_whole_or_a_turn_at_a_time(family, agents, seed,
                                                                                     margin) -> None:
    """`Scatter` compiled (coordinator/scatter.c, where the machine can build it) and in Python make the very paths,
    rounds and work units, whole or `SCATTER_WORK` units a turn (or a path a turn): a game's decisions never depend on
    which ran."""
    from benchmarks.compiled_scatter import instance

    if compiled.scatter_library() is None:
        pytest.skip(f"no compiled search here: no C compiler on the PATH, or {compiled.ENV}=0")
    graph, start, goal, dist = instance(family, agents, seed)
    py = lacam.Scatter(graph, start, goal, dist, margin, compiled=False)
    spent = py.advance(1 << 62)
    assert py.lib is None and sum(map(len, py.paths)) > agents  # (paths were made: not empty lists)
    for turn in (1 << 62, lacam.SCATTER_WORK, 1):
        c = lacam.Scatter(graph, start, goal, dist, margin)
        assert c.lib is not None
        units = turns = 0
        while not c.done:
            units += c.advance(turn)
            turns += 1
        assert (c.paths, c.round, c.last, units) == (py.paths, py.round, py.last, spent), turn
        assert turn != 1 or turns == agents * c.round  # (a path a turn)
        assert c.ctx is None  # (its memory freed once the paths are out)


def _pibt_case(rng: np.random.Generator) -> tuple[list[int], list[list[int]], list[int], list[int], OpenCells,
                                                  list[int], list[int], tuple[int, int, int]]:
    """A random crowd for PIBT's call in a small world of corridors and dead ends (a third of the cells buildings):
    each drone's candidates its open neighbours and its cell in a random order (-1 after the last), some drones
    taken to cells of their own, the others choosing in a random order (some left out: the order's end), targets
    for some (the swap's and the retreats')."""
    size = (int(rng.integers(3, 9)), int(rng.integers(3, 9)), 1)
    blocked = rng.random(size) < 0.33
    open_ = OpenCells(blocked)
    shape = (size[0] + 2, size[1] + 2, size[2] + 2)
    cells = np.flatnonzero(open_.array()[:shape[0] * shape[1] * shape[2]])
    n = int(rng.integers(1, min(len(cells), 14) + 1)) if len(cells) else 0
    here = rng.permutation(cells)[:n].tolist()
    steps = [int(d) for d in lacam.padded_steps(size)[2]]
    cand = []
    for c in here:
        row = [c] + [c + d for d in steps if open_[c + d] or rng.random() < 0.1]
        rng.shuffle(row)
        cand.append(row + [-1] * (7 - len(row)))
    taken = [-1] * n
    free = [c for c in cells.tolist() if c not in here]
    for i in range(n):
        if rng.random() < 0.15 and free:
            taken[i] = free.pop(int(rng.integers(len(free))))
    order = [i for i in rng.permutation(n).tolist() if taken[i] < 0 and rng.random() < 0.9]
    goal = [int(rng.choice(cells)) if rng.random() < 0.7 else -1 for _ in range(n)]
    return here, cand, order, taken, open_, steps, goal, shape


def test_the_compiled_pibt_call_is_pythons() -> None:
    """PIBT's call compiled (`pb_pibt` in coordinator/scatter.c, `lacam.pibt_compiled`) gives the next cells and the
    drones that gave way `arbiter.pibt` gives, with the swap and the retreats' aims and without, on 3,000 random
    crowds in worlds of corridors and dead ends (where the swap and the clear operation change the outcome): the
    search's decisions never depend on which ran."""
    if compiled.scatter_library() is None:
        pytest.skip(f"no compiled search here: no C compiler on the PATH, or {compiled.ENV}=0")
    from coordinator.arbiter import pibt

    lib = compiled.scatter_library()
    rng = np.random.default_rng(37)
    swapped = 0
    for case in range(3000):
        here, cand, order, taken, open_, steps, goal, shape = _pibt_case(rng)
        if not here:
            continue
        world = None if case % 4 == 0 else (open_, steps, goal)
        aims = None if case % 3 == 0 else (goal, shape)
        want = pibt(here, cand, order, taken, world, aims)
        got = lacam.pibt_compiled(lib, np.array(here), np.array(cand), order, taken, None if world is None else open_,
                                  np.array(steps, np.int64), np.array(goal), None if aims is None else np.array(goal),
                                  shape)
        assert got is not None
        assert (got[0].tolist(), got[1]) == (list(want[0]), want[1]), case
        swapped += world is not None and want != pibt(here, cand, order, taken, None, aims)
    assert swapped > 20  # (the swap and the clear operation changed the call's outcome: 45 times here)


def test_the_compiled_pibt_call_refuses_cells_off_its_range() -> None:
    """A cell beyond the flat cells it was given (a caller's bug) is never indexed by the compiled call: it says so
    (None), and the search then runs Python's."""
    if compiled.scatter_library() is None:
        pytest.skip(f"no compiled search here: no C compiler on the PATH, or {compiled.ENV}=0")
    here, cand, order, taken, open_, steps, goal, shape = _pibt_case(np.random.default_rng(3))
    lib = compiled.scatter_library()
    args = (np.array(steps, np.int64), np.array(goal), np.array(goal), shape)
    assert lacam.pibt_compiled(lib, np.array(here), np.array(cand), order, taken, open_, *args) is not None
    far = shape[0] * shape[1] * shape[2]
    for bad_here, bad_cand in (([far] + here[1:], cand), (here, [[far] + row[1:] for row in cand])):
        assert lacam.pibt_compiled(lib, np.array(bad_here), np.array(bad_cand), order, taken, open_, *args) is None


def test_the_compiled_candidates_are_pythons() -> None:
    """A node's candidates compiled (`pb_candidates`, `Search._candidates_compiled`: the drones' own order by their
    tables, the arbiter's reordering with the hindrance and the node's tie-breaks, the scattered path's next cell first)
    are Python's, on every node of a guided whole world's search of a crowded room and of random obstacles."""
    if compiled.scatter_library() is None:
        pytest.skip(f"no compiled search here: no C compiler on the PATH, or {compiled.ENV}=0")
    from benchmarks.compiled_scatter import searches

    checked = 0
    for family in ("room-32-32-4", "random-32-32-20"):
        new_search, open_ = searches(family, 150, 2, scatter=True)
        search = new_search()
        while search.guide is None:
            search.expand(1 << 62, open_)
        search.expand(1 << 62, open_, most=60)
        assert search._lib is not None
        for node in list(search.explored.values()):
            got = search._candidates(node)
            search._lib = None
            want = search._candidates(node)
            search._lib = compiled.scatter_library()
            assert np.array_equal(got, want), (family, node.number)
            checked += 1
    assert checked > 100


def test_a_game_plays_the_same_with_the_search_compiled_or_in_python(monkeypatch) -> None:
    """A crowded game's every turn is the same with the search's compiled parts (the scattered paths, PIBT's calls and
    the nodes' candidates, the exact search's joint moves) and with Python's alone (`DRONESIM_COMPILED=0`): a journal
    never depends on the machine's C compiler."""
    if compiled.scatter_library() is None:
        pytest.skip(f"no compiled search here: no C compiler on the PATH, or {compiled.ENV}=0")
    from benchmarks.swarm import movingai_instance

    inst = movingai_instance("room-32-32-4", 120, 3)
    world = World.from_grid(inst.grid)
    ids = [f"D{k + 1:02d}" for k in range(len(inst.starts))]
    config = GameConfig(world=WorldSpec(size=world.size, cells=world.packed()), max_turns=70,
                        drones=tuple(DroneSpec(drone=d, start=s) for d, s in zip(ids, inst.starts)))
    plan = Plan(tuple(sorted((1, d, g) for d, g in zip(ids, inst.goals))))
    games, calls = [], []
    for env in ("1", "0"):
        monkeypatch.setenv(compiled.ENV, env)
        compiled.scatter_library.cache_clear()
        arb = lacam.Lacam()
        games.append(simulate(config, dict.fromkeys(ids, "dstar"), Inputs(plan=plan), logging.getLogger("t"),
                              verify_env=False, arbiter=arb).records)
        calls.append(arb.expansions)
    compiled.scatter_library.cache_clear()
    assert games[0] == games[1] and len(games[0]) > 70
    assert calls[0] == calls[1] > 100  # (the search ran: its PIBT calls, the same)


def test_the_search_with_pibt_compiled_makes_the_same_nodes(capsys: pytest.CaptureFixture[str]) -> None:
    """`dronesim bench compiled-scatter --pibt`: a whole world's search, its PIBT calls in Python and compiled, the
    same nodes in the same order (its exit code says so)."""
    from benchmarks import compiled_scatter

    if compiled.scatter_library() is None:
        pytest.skip(f"no compiled search here: no C compiler on the PATH, or {compiled.ENV}=0")
    assert compiled_scatter.main(["--pibt", "--families", "room-32-32-4", "--seeds", "1", "--agents", "100",
                                  "--calls", "40", "--repeat", "1"]) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| room")]
    assert len(rows) == 1 and rows[0].endswith("| yes |"), rows


def test_the_compiled_search_is_off_where_the_environment_says_so_and_python_then_plans(monkeypatch) -> None:
    """`DRONESIM_COMPILED=0`: no library, `Scatter` runs Python's search (the same paths)."""
    monkeypatch.setenv(compiled.ENV, "0")
    compiled.scatter_library.cache_clear()
    try:
        assert compiled.scatter_library() is None
        scatter, doors = _scattered(lacam.MARGIN)
        assert scatter.lib is None and scatter.last == 0 and doors[0] in ({0}, {6})
    finally:
        monkeypatch.delenv(compiled.ENV)
        compiled.scatter_library.cache_clear()


def test_a_cached_library_that_does_not_load_is_built_again(tmp_path, monkeypatch) -> None:
    """A file in the cache where the library should be that is not one (cut short, overwritten) is built again in
    its place, never a reason to run Python's search for ever."""
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler on the PATH: nothing to build")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    compiled.scatter_library.cache_clear()
    try:
        lib = compiled.scatter_library()
        assert lib is not None
        (built,) = (tmp_path / "dronesim").glob("scatter-*.so")
        built.unlink()  # (a new file: the loaded one stays mapped as it was)
        built.write_bytes(b"not a library")
        loads = "from coordinator import compiled; raise SystemExit(compiled.scatter_library() is None)"
        done = subprocess.run([sys.executable, "-c", loads], cwd=Path(__file__).resolve().parents[1], timeout=300,
                              capture_output=True, text=True, env={**os.environ, "XDG_CACHE_HOME": str(tmp_path)})
        assert done.returncode == 0 and built.read_bytes()[:4] == b"\x7fELF", done.stderr  # (a new process: this one
        # holds the first library under that name)
    finally:
        compiled.scatter_library.cache_clear()


def test_a_library_shipped_in_the_package_is_loaded_first_and_one_that_does_not_load_is_not_shipped(
        tmp_path, monkeypatch, capsys) -> None:
    """The Docker image's runtime has no C compiler: its build puts the library in the package's folder
    (`compiled.ship`, from the wheelhouse docker/offline.sh builds it into: `--build`), and that one is loaded with no
    compiler and no cache. A file there that is no library is never shipped (nor a half-copied one left), and one
    shipped that does not load (another machine's) is passed over for a library built here."""
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler on the PATH: nothing to build or ship")
    wheelhouse, package, cache = tmp_path / "wheelhouse", tmp_path / "package", tmp_path / "cache"
    package.mkdir()
    stale = wheelhouse / "scatter-0000000000000000.so"  # (an older source's library)
    wheelhouse.mkdir()
    stale.write_bytes(b"old")
    assert compiled.main(["--build", str(wheelhouse)]) == 0
    assert compiled.main(["--build", str(wheelhouse)]) == 0  # (there already: not built again)
    said = capsys.readouterr().out.splitlines()
    assert said[0].startswith("compiled: built") and said[1].endswith("is there") and not stale.exists()
    (name,) = [f.name for f in wheelhouse.glob("scatter-*.so")]
    monkeypatch.setenv("PATH", str(tmp_path / "nobin"))  # (no compiler from here on)
    assert compiled.ship(wheelhouse, package) == package / name
    monkeypatch.setattr(compiled, "SHIPPED", package)
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
    compiled.scatter_library.cache_clear()
    try:
        lib = compiled.scatter_library()
        assert lib is not None and lib._name == str(package / name) and not cache.exists()
        other, elsewhere = tmp_path / "other", tmp_path / "elsewhere"
        other.mkdir()
        elsewhere.mkdir()
        (other / name).write_bytes(b"not a library")
        assert compiled.ship(other, elsewhere) is None
        assert list(elsewhere.iterdir()) == []  # (nothing shipped, no part left)
        (package / name).unlink()  # (a new file: the loaded one stays mapped as it was)
        (package / name).write_bytes(b"not a library")
        monkeypatch.undo()
        monkeypatch.setattr(compiled, "SHIPPED", package)
        monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
        loads = ("import sys; from pathlib import Path; from coordinator import compiled; "
                 "compiled.SHIPPED = Path(sys.argv[1]); lib = compiled.scatter_library(); "
                 "raise SystemExit(lib is None or not lib._name.startswith(sys.argv[2]))")
        done = subprocess.run([sys.executable, "-c", loads, str(package), str(cache)], timeout=300, capture_output=True,
                              text=True, cwd=Path(__file__).resolve().parents[1],
                              env={**os.environ, "XDG_CACHE_HOME": str(cache)})
        assert done.returncode == 0, done.stderr  # (a new process: built in the cache instead)
    finally:
        compiled.scatter_library.cache_clear()


def test_a_cache_folder_others_may_write_is_not_used(tmp_path, monkeypatch) -> None:
    """The compiled library is loaded from this user's own cache folder only: one others may write (a library
    there could be anyone's) is passed over for a temporary folder of this process's."""
    shared = tmp_path / "dronesim"
    shared.mkdir(mode=0o777)
    shared.chmod(0o777)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert compiled._cache() is None
    shared.chmod(0o700)
    assert compiled._cache() == shared


def test_the_search_tries_a_drones_scattered_next_cell_first(monkeypatch: pytest.MonkeyPatch) -> None:
    """The search's configuration generator (`Search._candidates`) puts a drone's next cell on its scattered path
    first, while the node is within HORIZON times its path's length; without the scatter (`Lacam(scatter=False)`),
    the cells nearest its goal come first; a drone off its path (here: beyond its horizon) is not guided; fewer drones
    than `CROWD` are not guided either."""
    grid = world_of(DOORS)
    size: Cell = grid.shape  # type: ignore[assignment]
    open_ = OpenCells(grid)
    here, aims = (flat_cells(np.array(c, np.int32), size) for c in CROSSING)
    arb = lacam.Lacam()
    arb.prepare(size, open_)
    s = arb._start(size, here, aims)
    assert s is not None and s.guide is None  # (8 drones: no crowd)
    monkeypatch.setattr(lacam, "CROWD", len(here))
    firsts = {}
    for scatter in (True, False):
        arb = lacam.Lacam(scatter=scatter)
        arb.prepare(size, open_)
        s = _guided(arb._start(size, here, aims), open_)
        assert s is not None and (s.guide is not None) == scatter
        firsts[scatter] = s._candidates(s.at)[:, 0]
    assert s.guide is None
    arb = lacam.Lacam()
    arb.prepare(size, open_)
    s = _guided(arb._start(size, here, aims), open_)
    assert s is not None and s.guide is not None
    table, index = s.guide
    ahead = table[np.arange(len(here)), index[here]]
    assert (firsts[True] == ahead).all() and (firsts[True] != firsts[False]).any()
    far = lacam.Node(s.at.cfg, None, s.at.prio, 0)
    far.depth = lacam.HORIZON * int(s.horizon.max()) + 1
    assert (s._candidates(far)[:, 0] == firsts[False]).all()


def _guided(s: lacam.Search | Exact | None, open_: OpenCells) -> lacam.Search | Exact | None:
    """`s` once its scattered paths are made (the turns that make them: `Search.expand`), if it makes any."""
    while isinstance(s, lacam.Search) and s._scatter is not None:
        s.expand(lacam.WORK, open_)
    return s


@pytest.mark.parametrize("crowd", [lacam.CROWD, 1], ids=["unguided", "scattered"])
def test_same_journal_in_every_layout_and_run(crowd: int, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(lacam, "CROWD", crowd)  # (1: the search guided by scattered paths, a crowd of one)
    rows, drones = HARD[1][1], HARD[1][2]
    first = play(world_of(rows), drones)
    assert play(world_of(rows), drones).records == first.records
    assert play(world_of(rows), drones, swarm=True).records == first.records


@pytest.mark.parametrize("crowd", [lacam.CROWD, 1], ids=["unguided", "scattered"])
def test_a_resumed_coordinator_has_the_search_that_played(crowd: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The search's state is a function of the journal: a coordinator restored after any turn (resume.py
    replays each turn's work) holds the same search as the one that played that turn, and plays on alike; with
    the scattered paths too (made again by the replay of the turn that made them)."""
    monkeypatch.setattr(lacam, "CROWD", crowd)
    rows, drones = DOOR
    grid = world_of(rows)
    states: list[dict] = []

    class Watched(lacam.Lacam):
        def __call__(self, *args: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # type: ignore[override]
            out = super().__call__(*args)  # type: ignore[arg-type]
            s = self._search
            states.append({**self.state(), "at": None if s is None else s.where().tolist(),
                           "guided": s is not None and s.guide is not None})
            return out

    result = play(grid, drones, arbiter=Watched())
    assert result.over.reason is EndReason.ALL_REACHED
    records = result.records
    cfg = config(grid, drones, 200, "lacam")
    assert replay.verify("game", records, cfg, dict.fromkeys(drones, "dstar")) is None
    turns = [r for r in records if r.get("record") == "turn"]
    for cut in range(1, len(turns)):
        resumed = restore(cfg, records[:cut + 1], LOG)
        arb = resumed.arbitration.arbiter
        assert isinstance(arb, lacam.Lacam)
        s = arb._search
        assert {**arb.state(), "at": None if s is None else s.where().tolist(),
                "guided": s is not None and s.guide is not None} == states[cut - 1], f"turn {cut}"
    assert any(st["guided"] for st in states) == (crowd <= len(drones))


def test_flat_cells_round_trip() -> None:
    size = (3, 4, 2)
    cells = np.array([(0, 0, 0), (2, 3, 1), (1, 2, 0)], np.int32)
    assert (cells_of(flat_cells(cells, size), size) == cells).all()
