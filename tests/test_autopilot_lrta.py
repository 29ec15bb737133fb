"""The LRTA* autopilot (entities/autopilots/lrta.py): its ranks, its learning, unreachable targets said, and
its swarm form (`LrtaSwarm`) deciding exactly as one `LrtaPilot` per drone."""

from __future__ import annotations

import numpy as np
import pytest

from entities.autopilots import make_autopilot, make_swarm, run_step
from entities.autopilots.base import NO_ANSWER, drive
from entities.autopilots.lrta import Lookahead, LrtaPilot, LrtaSwarm, default_slack
from schema import Cell, CellInfo, CellKind, Note, UsageError
from schema.tables import code_of, ranked_steps


class Grid:
    def __init__(self, size: Cell, blocked: set[Cell] = frozenset()) -> None:  # type: ignore[assignment]
        self.size, self.blocked = size, frozenset(blocked)

    def kind(self, c: Cell) -> CellKind:
        if not all(0 <= c[i] < self.size[i] for i in range(3)):
            return CellKind.OUTSIDE
        return CellKind.BUILDING if c in self.blocked else CellKind.EMPTY

    def oracle(self, cells: tuple[Cell, ...]) -> dict[Cell, CellInfo]:
        return {c: CellInfo(pos=c, kind=self.kind(c)) for c in cells}


def _cells(pos: Cell, ranked: int) -> list[Cell]:
    return [(pos[0] + dx, pos[1] + dy, pos[2] + dz) for dx, dy, dz in ranked_steps(ranked)]


def test_registered_with_a_swarm_form():
    assert isinstance(make_autopilot("lrta", world_size=(4, 4, 4)), LrtaPilot)
    assert isinstance(make_swarm("lrta", world_size=(4, 4, 4), drones=[1, 2], least=1), LrtaSwarm)
    assert LrtaPilot.cooperative and LrtaPilot.senses


def test_ranks_closer_cells_first_the_longer_axis_first_then_staying_then_sideways_before_back_down_last():
    grid = Grid((9, 9, 3))
    pilot = LrtaPilot(world_size=grid.size)
    d, asks = run_step(pilot, (2, 4, 1), (7, 6, 1), grid.oracle)
    assert asks == 1 and d.note is Note.NONE
    # +x (5 to go) before +y (2 to go), both closer; then staying; then the others (all one farther), nearest the
    # target as the crow flies first: up (sideways), then -y, then straight back (-x); down last (off the cruise:
    # not in the target's column)
    assert _cells((2, 4, 1), d.ranked) == [(3, 4, 1), (2, 5, 1), (2, 4, 1), (2, 4, 2), (2, 3, 1), (1, 4, 1),
                                           (2, 4, 0)]
    assert d.pos == (3, 4, 1)
    assert pilot.learned == {}  # nothing learned where a neighbour is closer


def test_climbs_first_and_descends_last():
    grid = Grid((9, 9, 9))
    pilot = LrtaPilot(world_size=grid.size)
    # a target higher up: up first, then the level steps (the longer axis first)
    d, _ = run_step(pilot, (1, 1, 1), (5, 3, 4), grid.oracle)
    assert _cells((1, 1, 1), d.ranked)[:3] == [(1, 1, 2), (2, 1, 1), (1, 2, 1)]
    # a target lower down: level first (down is as close, but not before the target's column), then down
    d, _ = run_step(pilot, (1, 1, 6), (5, 3, 4), grid.oracle)
    assert _cells((1, 1, 6), d.ranked)[:3] == [(2, 1, 6), (1, 2, 6), (1, 1, 5)]
    # in the target's column: straight down
    d, _ = run_step(pilot, (5, 3, 6), (5, 3, 4), grid.oracle)
    assert d.pos == (5, 3, 5)


def test_learns_in_a_dead_end_and_backs_out():
    # a pocket one floor high, open to the west, the target east of its end wall; the way is round the wall
    blocked = {(3, y, 0) for y in range(3)} | {(x, y, 0) for x in (1, 2) for y in (0, 2)}
    grid = Grid((6, 4, 1), blocked)
    pilot = LrtaPilot(world_size=grid.size)
    d, _ = run_step(pilot, (2, 1, 0), (4, 1, 0), grid.oracle)
    # at the wall: the only free neighbour is (1, 1, 0), h 3; it learns h(2, 1, 0) = 4 and leaves
    assert pilot.learned == {(2, 1, 0): 4}
    assert d.pos == (1, 1, 0) and _cells((2, 1, 0), d.ranked) == [(1, 1, 0), (2, 1, 0)]
    pos, seen = (1, 1, 0), 0
    while pos != (4, 1, 0) and seen < 40:
        d, _ = run_step(pilot, pos, (4, 1, 0), grid.oracle)
        pos, seen = d.pos, seen + 1
    assert pos == (4, 1, 0)
    assert pilot.h((2, 1, 0)) >= 4


def test_the_cube_is_revalued_by_its_shortest_ways_out():
    # radius 1 round (1, 1, 0) in a world one floor high: the cube's floor cells x, y in 0..2, its border 1 further
    look = Lookahead(1)
    cells = np.array([(1, 1, 0)]) + look.offsets
    target = np.array([(5, 1, 0)])
    h = np.abs(cells - target).sum(axis=1)[None, :]  # Manhattan everywhere, no world edge
    inner = cells[look.inner]
    wall = (inner[:, 0] == 2) & (inner[:, 1] >= 0) & (inner[:, 1] <= 1)  # (2, 0) and (2, 1) blocked, (2, 2) open
    free = (~wall & (inner[:, 2] == 0))[None, :]  # the floor only: the cells above and below are not free
    h[0, look.inner[inner.tolist().index([0, 2, 0])]] = 100  # a value learned before, above any way out
    new = look.revalue(np.array([(1, 1, 0)]), target, free, h)[0]
    value = {tuple(c): int(v) for c, v in zip(inner.tolist(), new.tolist())}
    # (1, 1, 0) goes round the wall by (1, 2), (2, 2) and leaves east to (3, 2, 0) (h 3): 6, Manhattan 4;
    # (2, 2, 0) is no farther than its Manhattan distance (4) and keeps it; the others through them or their
    # own border cells: (1, 0, 0) 7, (0, 0, 0) 8
    assert value[(1, 1, 0)] == 6 and value[(2, 2, 0)] == 4 and value[(1, 0, 0)] == 7 and value[(0, 0, 0)] == 8
    assert value[(0, 2, 0)] == 100  # never lowered
    assert value[(2, 1, 0)] == 3  # a wall keeps its value (its Manhattan distance)
    assert Lookahead(0).extra.size == 0 and Lookahead(2).inner.size == 125
    with pytest.raises(ValueError):
        Lookahead(-1)


def test_the_cube_fills_a_depression_sooner():
    # a wall across a floor-high strip, open only at its north end: the drone must fill the depression south
    wall = {(7, y, 0) for y in range(8)}
    grid = Grid((15, 9, 1), wall)
    turns = {}
    for radius in (0, 1, 2):
        pilot, pos, seen = LrtaPilot(world_size=grid.size, lookahead=radius), (3, 1, 0), 0
        while pos != (11, 1, 0) and seen < 2000:
            d, _ = run_step(pilot, pos, (11, 1, 0), grid.oracle)
            assert grid.kind(d.pos) is CellKind.EMPTY
            pos, seen = d.pos, seen + 1
        turns[radius] = seen
    assert turns[2] <= turns[1] < turns[0] < 2000, turns


def test_a_new_target_forgets_what_was_learned():
    grid = Grid((6, 3, 1), {(3, 1, 0)})
    pilot = LrtaPilot(world_size=grid.size)
    run_step(pilot, (2, 0, 0), (5, 0, 0), grid.oracle)
    run_step(pilot, (2, 1, 0), (5, 1, 0), grid.oracle)
    assert pilot.learned
    run_step(pilot, (0, 0, 0), (0, 2, 0), grid.oracle)
    assert pilot.learned == {}


def test_at_rest_offers_its_cell_then_its_free_neighbours():
    grid = Grid((3, 3, 1), {(1, 0, 0)})
    pilot = LrtaPilot(world_size=grid.size)
    d, _ = run_step(pilot, (1, 1, 0), (1, 1, 0), grid.oracle)
    assert d.note is Note.REACHED and d.pos == (1, 1, 0)
    assert _cells((1, 1, 0), d.ranked) == [(1, 1, 0), (2, 1, 0), (0, 1, 0), (1, 2, 0)]
    d, _ = run_step(pilot, (1, 1, 0), None, grid.oracle)
    assert d.note is Note.NONE and _cells((1, 1, 0), d.ranked)[0] == (1, 1, 0)


def test_unreachable_targets_are_said():
    grid = Grid((5, 5, 1), {(4, 4, 0)})
    pilot = LrtaPilot(world_size=grid.size)
    assert run_step(pilot, (0, 0, 0), (4, 4, 0), grid.oracle)[0].note is Note.UNREACHABLE  # a building
    assert run_step(pilot, (0, 0, 0), (9, 0, 0), grid.oracle)[0].note is Note.UNREACHABLE  # outside
    boxed = Grid((3, 3, 1), {(0, 1, 0), (1, 0, 0)})
    assert run_step(LrtaPilot(world_size=boxed.size), (0, 0, 0), (2, 2, 0), boxed.oracle)[0].note is Note.UNREACHABLE


def test_a_walled_in_target_is_said_once_learning_passes_the_slack():
    # the target (4, 2, 0) in a closed ring of buildings: every way is shut, the drone learns until it says so
    ring = {(x, y, 0) for x in range(3, 6) for y in range(1, 4)} - {(4, 2, 0)}
    grid = Grid((7, 5, 1), ring)
    pilot = LrtaPilot(world_size=grid.size, slack=6)
    pos, notes = (0, 2, 0), []
    for _ in range(200):
        d, _ = run_step(pilot, pos, (4, 2, 0), grid.oracle)
        notes.append(d.note)
        assert grid.kind(d.pos) is CellKind.EMPTY
        if d.note is Note.UNREACHABLE:
            break
        pos = d.pos
    assert notes[-1] is Note.UNREACHABLE and Note.UNREACHABLE not in notes[:-1]
    assert pilot.h(pos) > abs(pos[0] - 4) + abs(pos[1] - 2) + 6
    assert default_slack((256, 256, 32)) == 2 * (256 + 256 + 32)


def test_the_swarm_refuses_strangers_and_twins():
    swarm = LrtaSwarm(world_size=(4, 4, 1), drones=[3, 5])
    with pytest.raises(UsageError, match=r"\[4\]"):
        drive(swarm.step(np.array([4]), np.zeros((1, 3)), np.full((1, 3), -1)), lambda c: np.zeros(len(c), np.uint8))
    with pytest.raises(UsageError):
        LrtaSwarm(world_size=(4, 4, 1), drones=[3, 3])


def _equivalence(seed: int, size: Cell, n: int, turns: int, drop: float) -> int:
    """n drones flown by one LrtaSwarm and by one LrtaPilot each over a random world, both given the same
    positions and targets every turn (targets that change, some absent, some in buildings, some drones
    skipping turns as dead ones do; a share `drop` of the cells unanswered; cubes of radius 1 or 2 revalued):
    the same moves, notes, rankings and learned values. Returns how many cubes the swarm revalued."""
    rng = np.random.default_rng(seed)
    nx, ny, nz = size
    cells = [(x, y, z) for x in range(nx) for y in range(ny) for z in range(nz)]
    blocked = {cells[i] for i in rng.choice(len(cells), len(cells) // 4, replace=False)}
    grid = Grid(size, blocked)
    free = [c for c in cells if c not in blocked]
    n = min(n, len(free))
    numbers = sorted(rng.choice(np.arange(1, 200), n, replace=False).tolist())
    pos = {d: free[i] for d, i in zip(numbers, rng.choice(len(free), n, replace=False))}
    target: dict[int, Cell | None] = {d: None for d in numbers}
    slack, lookahead = int(rng.integers(0, 12)), 1 + seed % 2
    swarm = LrtaSwarm(world_size=size, drones=numbers, slack=slack, lookahead=lookahead)
    pilots = {d: LrtaPilot(world_size=size, slack=slack, lookahead=lookahead) for d in numbers}
    revalued = [0]
    look = swarm.look.revalue
    swarm.look.revalue = lambda *a: (revalued.__setitem__(0, revalued[0] + len(a[0])), look(*a))[1]  # type: ignore
    lost: set[Cell] = set()
    calls: list[int] = []

    def kinds(asked: np.ndarray) -> np.ndarray:
        calls.append(len(asked))
        return np.array([NO_ANSWER if c in lost else grid.kind(c) for c in map(tuple, asked.tolist())], np.uint8)

    def oracle(cs: tuple[Cell, ...]) -> dict[Cell, CellInfo]:
        return {c: CellInfo(pos=c, kind=grid.kind(c)) for c in cs if c not in lost}

    for turn in range(turns):
        for d in numbers:
            if rng.random() < 0.08:
                target[d] = None if rng.random() < 0.1 else cells[int(rng.integers(len(cells)))]
        flying = [d for d in numbers if rng.random() > 0.1]
        lost.clear()
        lost.update(c for c in cells if rng.random() < drop)
        calls.clear()
        new, note, ranked = drive(swarm.step(np.array(flying, dtype=np.int64),
                                             np.array([pos[d] for d in flying]).reshape(-1, 3),
                                             np.array([target[d] or (-1, -1, -1) for d in flying]).reshape(-1, 3)),
                                  kinds)
        assert len(calls) <= 1
        for i, d in enumerate(flying):
            dec, _ = run_step(pilots[d], pos[d], target[d], oracle)
            got = (tuple(new[i].tolist()), int(note[i]), int(ranked[i]))
            assert got == (dec.pos, code_of(dec.note), dec.ranked), (seed, turn, d)
            # where it goes: its first choice, or, as the arbiter may give it, another cell it offered
            offered = _cells(pos[d], dec.ranked)
            pos[d] = offered[0] if rng.random() < 0.7 else offered[int(rng.integers(len(offered)))]
        for d in numbers:
            if pilots[d]._target is not None:
                assert swarm.learned(d) == pilots[d].learned, (seed, turn, d)
    return revalued[0]


@pytest.mark.parametrize("seed", range(16))
def test_the_swarm_decides_as_one_pilot_per_drone(seed, monkeypatch):
    monkeypatch.setattr(LrtaSwarm, "FORGET_AFTER", 4 + seed % 3 * 20)  # former trips' values dropped often
    sizes = [(6, 6, 3), (9, 5, 4), (1, 1, 4), (1, 7, 2), (12, 12, 2), (5, 5, 5)]
    _equivalence(seed, sizes[seed % len(sizes)], n=1 + seed % 9 * 3, turns=60, drop=0.0 if seed % 2 else 0.05)


def test_the_swarm_revalues_cubes_as_one_pilot_per_drone():
    assert _equivalence(99, (12, 12, 2), n=25, turns=60, drop=0.0) > 0  # the equivalence did revalue cubes


def test_the_swarm_forgets_former_trips(monkeypatch):
    # a wall across a strip; one drone sent to and fro across it: each trip learns, and former trips are dropped
    monkeypatch.setattr(LrtaSwarm, "FORGET_AFTER", 16)
    grid = Grid((15, 9, 1), {(7, y, 0) for y in range(8)})
    swarm = LrtaSwarm(world_size=grid.size, drones=[1])
    pos, sizes = np.array([(3, 1, 0)]), []
    for trip in range(12):
        target = np.array([(11, 1, 0)] if trip % 2 == 0 else [(3, 1, 0)])
        for _ in range(300):
            if (pos == target).all():
                break
            pos, _, _ = drive(swarm.step(np.array([1]), pos, target),
                              lambda c: np.array([grid.kind(x) for x in map(tuple, c.tolist())], np.uint8))
        assert (pos == target).all()
        sizes.append(swarm.kept)
    assert sizes[0] > 16 and max(sizes) <= 2 * sizes[0], sizes  # without forgetting: one trip's values more each time
    assert len(swarm.learned(1)) == sizes[-1]  # what is kept is the current trip's
