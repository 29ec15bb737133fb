"""The LRTA* autopilot (entities/autopilots/lrta.py): its ranks, its learning, unreachable targets said, and
its swarm form (`LrtaSwarm`) deciding exactly as one `LrtaPilot` per drone."""

from __future__ import annotations

import numpy as np
import pytest

from entities.autopilots import make_autopilot, make_swarm, run_step
from entities.autopilots.base import NO_ANSWER, drive
from entities.autopilots.lrta import LrtaPilot, LrtaSwarm, default_slack
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


def test_ranks_closer_cells_first_the_longer_axis_first_then_staying_then_sideways_before_back():
    grid = Grid((9, 9, 3))
    pilot = LrtaPilot(world_size=grid.size)
    d, asks = run_step(pilot, (2, 4, 1), (7, 6, 1), grid.oracle)
    assert asks == 1 and d.note is Note.NONE
    # +x (5 to go) before +y (2 to go), both closer; then staying; then the others (all one farther), nearest the
    # target as the crow flies first: up and down (sideways), then -y, then straight back (-x) last
    assert _cells((2, 4, 1), d.ranked) == [(3, 4, 1), (2, 5, 1), (2, 4, 1), (2, 4, 2), (2, 4, 0), (2, 3, 1),
                                           (1, 4, 1)]
    assert d.pos == (3, 4, 1)
    assert pilot.learned == {}  # nothing learned where a neighbour is closer


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


def _equivalence(seed: int, size: Cell, n: int, turns: int, drop: float) -> None:
    """n drones flown by one LrtaSwarm and by one LrtaPilot each over a random world, both given the same
    positions and targets every turn (targets that change, some absent, some in buildings, some drones
    skipping turns as dead ones do; a share `drop` of the cells unanswered): the same moves, notes, rankings
    and learned values."""
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
    slack = int(rng.integers(0, 12))
    swarm = LrtaSwarm(world_size=size, drones=numbers, slack=slack)
    pilots = {d: LrtaPilot(world_size=size, slack=slack) for d in numbers}
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


@pytest.mark.parametrize("seed", range(16))
def test_the_swarm_decides_as_one_pilot_per_drone(seed):
    sizes = [(6, 6, 3), (9, 5, 4), (1, 1, 4), (1, 7, 2), (12, 12, 2), (5, 5, 5)]
    _equivalence(seed, sizes[seed % len(sizes)], n=1 + seed % 9 * 3, turns=60, drop=0.0 if seed % 2 else 0.05)
