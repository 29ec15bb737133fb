"""The exact search of the small puzzles (coordinator/exact.py): checked against a breadth-first search over joint
configurations written here independently (plain Python, every joint move), on seeded random corridors with bays
and small rooms: every solvable instance solved within 4x its least makespan, every unsolvable one proved (the game
ends "no solution" within a few turns, where LaCAM alone took hundreds: 509 turns for three drones reversing on a
1 x 12 path), the plan as short as the oracle's, each of its steps a legal joint move; a turn's work bounded."""

from __future__ import annotations

import itertools
import logging
import random
from collections import deque

import numpy as np
import pytest

from coordinator import exact, lacam
from coordinator.arbiter import OpenCells
from coordinator.config import DroneSpec, GameConfig
from dronesim.local import Inputs, simulate
from entities.gcs import Plan
from schema import EndReason, WorldSpec
from tests.test_lacam import Drones, play, world_of
from world.grid import World
from world.search import flat_cells

LOG = logging.getLogger("test_exact")
XY = tuple[int, int]


def oracle(rows: list[str], starts: list[XY], goals: list[XY | None]) -> int | None:
    """The least makespan from `starts` to a configuration with each drone on its goal (None: anywhere), or None if
    there is none: every joint move of every configuration, no two drones in a cell, no two trading cells."""
    free = {(x, y) for y, row in enumerate(rows) for x, c in enumerate(row) if c != "#"}
    near = {c: [c] + [(c[0] + dx, c[1] + dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))
                      if (c[0] + dx, c[1] + dy) in free] for c in free}
    first = tuple(starts)
    depth = {first: 0}
    queue = deque([first])
    while queue:
        cfg = queue.popleft()
        if all(g is None or c == g for c, g in zip(cfg, goals)):
            return depth[cfg]
        for nxt in itertools.product(*(near[c] for c in cfg)):
            if len(set(nxt)) < len(nxt) or nxt in depth:
                continue
            if any(nxt[i] == cfg[j] and nxt[j] == cfg[i] for i, j in itertools.combinations(range(len(cfg)), 2)):
                continue
            depth[nxt] = depth[cfg] + 1
            queue.append(nxt)
    return None


def corridor(rng: random.Random) -> list[str]:
    """A 1-wide corridor 5 to 12 long with 0 to 2 bays above it."""
    width = rng.randint(5, 12)
    top = ["#"] * width
    for b in rng.sample(range(width), rng.randint(0, 2)):
        top[b] = "."
    return ["".join(top), "." * width] if "." in top else ["." * width]


def room(rng: random.Random) -> list[str]:
    """A room 2-6 x 2-4, about 30 % of it buildings."""
    width, height = rng.randint(2, 6), rng.randint(2, 4)
    return ["".join("#" if rng.random() < 0.3 else "." for _ in range(width)) for _ in range(height)]


def instances(kind: str, seed: int, count: int) -> list[tuple[list[str], list[XY], list[XY]]]:
    rng = random.Random(seed)
    out = []
    while len(out) < count:
        rows = corridor(rng) if kind == "corridor" else room(rng)
        free = sorted((x, y) for y, row in enumerate(rows) for x, c in enumerate(row) if c == ".")
        if len(free) < 3:
            continue
        n = rng.randint(2, min(4, len(free) - 1))
        out.append((rows, rng.sample(free, n), rng.sample(free, n)))
    return out


@pytest.mark.parametrize("kind, seed", [("corridor", 1), ("corridor", 7), ("room", 3), ("room", 11)])
def test_small_puzzles_are_solved_or_proved_as_the_oracle_says(kind: str, seed: int) -> None:
    solved = proved = 0
    for rows, starts, goals in instances(kind, seed, 12):
        best = oracle(rows, starts, list(goals))
        drones: Drones = {f"D{i + 1:02d}": ((s[0], s[1], 0), (g[0], g[1], 0))
                          for i, (s, g) in enumerate(zip(starts, goals))}
        result = play(world_of(rows), drones, 1000)
        case = f"{rows} {starts} -> {goals}: least makespan {best}, {result.over.turn} {result.over.text}"
        if best is None:
            assert result.over.reason is not EndReason.ALL_REACHED, case
            assert result.over.turn <= 20, case  # (proved, not looped on)
            proved += 1
        else:
            assert result.over.reason is EndReason.ALL_REACHED, case
            assert result.over.turn <= 4 * max(best, 1), case
            solved += 1
        assert not any(r.get("deaths") for r in result.records), case
    assert solved and (proved or kind == "room"), (solved, proved)  # (both kinds met)


def _search(rows: list[str], starts: list[XY], goals: list[XY | None]) -> tuple[exact.Exact, lacam.Graph]:
    grid = world_of(rows)
    size = grid.shape
    g = lacam.Graph(OpenCells(grid), size)

    def number(c: XY | None) -> int:
        return -1 if c is None else int(g.index[flat_cells(np.array([[c[0], c[1], 0]]), size)[0]])
    return exact.Exact(g.near, g.cells, np.array([number(c) for c in starts]),
                       np.array([number(c) for c in goals])), g


@pytest.mark.parametrize("seed", [2, 5])
def test_the_plan_is_as_short_as_the_oracles_and_every_step_is_a_legal_joint_move(seed: int) -> None:
    rng = random.Random(seed)
    for rows, starts, goals in instances("corridor", seed, 10) + instances("room", seed, 10):
        aims: list[XY | None] = list(goals)
        if rng.random() < 0.3:
            aims[0] = None  # (a drone without a goal: anywhere; the search from one end only)
        search, g = _search(rows, starts, aims)
        while search.found is None and not search.unsolvable:
            search.expand(lacam.WORK)
        best = oracle(rows, starts, aims)
        assert (search.found if search.found is not None else None) == best, (rows, starts, aims)
        if search.plan is None:
            continue
        plan = g.index[search.plan]  # (open cells, numbered)
        for a, b in zip(plan[:-1], plan[1:]):
            assert all(v == u or v in g.near[u] for u, v in zip(a, b))  # (a step or none)
            assert len(set(b.tolist())) == len(b)  # (no two in a cell)
            assert not any(b[i] == a[j] and b[j] == a[i] for i, j in itertools.combinations(range(len(a)), 2))
        home = [i for i, c in enumerate(aims) if c is not None]
        assert all(plan[-1][i] == g.index[flat_cells(np.array([[*aims[i], 0]]), g_size(rows))[0]] for i in home)  # type: ignore[misc]
        assert plan[0].tolist() == g.index[search.start].tolist()


def g_size(rows: list[str]) -> tuple[int, int, int]:
    return (len(rows[0]), len(rows), 1)


def test_a_turn_of_the_exact_search_spends_its_work_at_most() -> None:
    """Four drones trading the ends of a corridor with two bays: each call spends at most the work it is given (but
    one configuration's at least), and the search ends."""
    search, _ = _search(["##.##.##", "........"], [(0, 1), (1, 1), (7, 1), (6, 1)], [(7, 1), (6, 1), (0, 1), (1, 1)])
    calls = 0
    while search.found is None and not search.unsolvable:
        spent = search.expand(40)
        assert 0 < spent <= 40 or spent <= 1 + max(1, 7 ** 4 // exact.A_UNIT)
        calls += 1
    assert search.found == 15 and calls > 1


def test_fits_bounds_the_candidates() -> None:
    near = lacam.Graph(OpenCells(world_of(["." * 12])), (12, 1, 1)).near
    assert exact.fits(near, 3) and not exact.fits(near, 3, 100) and not exact.fits(near, 0)
    assert not exact.fits(near, 13)  # (more drones than cells)


def _line(cells: int) -> np.ndarray:
    """The moves of a corridor of `cells` open cells numbered along it (itself, then its neighbours)."""
    return np.array([[c, c - 1 if c else -1, c + 1 if c + 1 < cells else -1] for c in range(cells)])


def test_settle_brings_each_drone_home_as_early_as_it_can_and_keeps_the_plan_legal() -> None:
    """A way as short as any in steps may wait for nothing or step out and back: `settle` makes each drone's way
    again, home as early as it can be, the plan as long and legal."""
    # drone 0 waits two steps then walks 0 -> 2; drone 1, parked at 5, steps out to 4 and back for nothing
    plan = np.array([[0, 5], [0, 4], [0, 5], [1, 5], [2, 5]])
    assert exact.settle(plan, _line(6))[0].tolist() == [[0, 5], [1, 5], [2, 5], [2, 5], [2, 5]]
    # drone 1 follows drone 0 along the corridor, a step behind at best: as it was
    plan = np.array([[1, 0], [2, 1], [3, 2], [4, 3]])
    assert exact.settle(plan, _line(5))[0].tolist() == plan.tolist()


def test_a_short_trip_is_not_stretched_to_the_plans_length() -> None:
    """Two drones in an open 3 x 3 room: the far one needs 4 steps, the near one 1; the near one is home at step 1
    (the way the search found may have it wander until the last step)."""
    search, g = _search(["...", "...", "..."], [(0, 0), (1, 1)], [(2, 2), (1, 0)])
    while search.found is None:
        search.expand(lacam.WORK)
    plan = g.index[search.plan]
    assert len(plan) == 5 and (plan[1:, 1] == plan[-1, 1]).all()


#: The instances of BENCHMARKS.md's "LaCAM: small puzzles searched whole": (name, rows, drones, least makespan or
#: None for no solution). LaCAM alone took 509, 521 and over 3,000 turns to the first three's proofs and 76 turns
#: to the last.
NAMED: list[tuple[str, list[str], Drones, int | None]] = [
    ("three drones reversing on a 1 x 12 path", ["............"],
     {"D01": ((0, 0, 0), (2, 0, 0)), "D02": ((1, 0, 0), (1, 0, 0)), "D03": ((2, 0, 0), (0, 0, 0))}, None),
    ("a corridor of 9 with a bay", ["#.#######", "........."],
     {"D01": ((0, 1, 0), (8, 1, 0)), "D02": ((8, 1, 0), (0, 1, 0)), "D03": ((4, 1, 0), (4, 1, 0))}, None),
    ("four drones on a corridor of 11 with two bays", ["##.#######.", "..........."],
     {"D01": ((2, 1, 0), (7, 1, 0)), "D02": ((0, 1, 0), (2, 1, 0)), "D03": ((10, 1, 0), (5, 1, 0)),
      "D04": ((7, 1, 0), (10, 1, 0))}, None),
    ("a four-drone swap past two bays", [".##.########", "............"],
     {"D01": ((1, 1, 0), (11, 1, 0)), "D02": ((6, 1, 0), (0, 1, 0)), "D03": ((7, 1, 0), (6, 1, 0)),
      "D04": ((11, 1, 0), (3, 0, 0))}, 17),
]


@pytest.mark.parametrize("name", [n for n, _, _, _ in NAMED])
def test_the_named_puzzles(name: str) -> None:
    _, rows, drones, best = next(case for case in NAMED if case[0] == name)
    assert oracle(rows, [s[:2] for s, _ in drones.values()], [t[:2] for _, t in drones.values()]) == best
    result = play(world_of(rows), drones, 3000)
    LOG.info("%s: %s at turn %d", name, result.over.text, result.over.turn)
    if best is None:  # (LaCAM's first, `lacam.EXACT_AFTER` turns without progress, then the exact search)
        assert result.over.text.startswith("no solution") and result.over.turn <= 20, result.over
    else:
        assert result.over.reason is EndReason.ALL_REACHED and result.over.turn <= 2 * best, result.over


def test_a_proof_ends_the_game_only_once_the_ground_stations_plan_is_final() -> None:
    """Targets with no solution (two drones must pass in a closed 1 x 5 corridor), corrected at turn 4, the plan
    final only then: the proof of the first targets does not end the game (found probing: it ended at turn 1)."""
    world = World.from_grid(np.zeros((1, 5, 1), bool))
    config = GameConfig(world=WorldSpec(size=world.size, cells=world.packed()), max_turns=100,
                        drones=(DroneSpec(drone="D01", start=(0, 0, 0)), DroneSpec(drone="D02", start=(0, 4, 0))))
    plan = Plan(((1, "D01", (0, 3, 0)), (1, "D02", (0, 1, 0)), (4, "D01", (0, 1, 0)), (4, "D02", (0, 3, 0))))
    result = simulate(config, dict.fromkeys(("D01", "D02"), "dstar"), Inputs(plan=plan), LOG)
    assert result.over.reason is EndReason.ALL_REACHED and 4 <= result.over.turn <= 8, result.over  # (not before the
    # plan is final; then each drone at most 3 steps from its new target, where the search's moves on the first
    # targets left it)


def test_two_drones_given_one_target_in_a_crowd_are_proved_at_once() -> None:
    """Too many drones for the exact search, two of them given one target: no configuration has both home, said
    without a search (LaCAM ran to the turn limit on such games)."""
    rows = ["......"] * 6
    drones: Drones = {f"D{i + 1:02d}": ((i, 0, 0), (5 - i, 5, 0)) for i in range(6)}
    drones["D07"] = ((0, 2, 0), (0, 5, 0))  # (D06's target too)
    result = play(world_of(rows), drones, 200)
    assert result.over.text.startswith("no solution") and result.over.turn <= 3, result.over
    assert not any(r.get("deaths") for r in result.records)


def test_a_search_that_runs_out_reached_each_configuration_once() -> None:
    """Each level is checked for repeats against the level before and itself only (the configurations' graph is
    undirected): an exhausted search counts every configuration it can reach once. Drone 0 cannot pass drone 1 in a
    closed corridor of 12 (drone 1's goal: anywhere), so it reaches every pair of cells with drone 0 first: 66. Each
    call spends the work it is given at most."""
    search, _ = _search(["." * 12], [(0, 0), (2, 0)], [(11, 0), None])
    while not search.unsolvable:
        assert search.expand(lacam.WORK // 50) <= lacam.WORK // 50
    assert len(search.explored) == 66


#: Five drones on a corridor of 12 with two bays (least makespan 17): beyond `exact.fits`' bound (the drones block
#: each other's moves: its joint moves are far fewer), tried within `exact.TRY`; LaCAM had not brought them home in
#: 500 turns.
TRIED: tuple[list[str], Drones] = (
    ["###.#######.", "............"],
    {"D01": ((1, 1, 0), (9, 1, 0)), "D02": ((3, 1, 0), (8, 1, 0)), "D03": ((11, 1, 0), (11, 1, 0)),
     "D04": ((6, 1, 0), (4, 1, 0)), "D05": ((10, 1, 0), (3, 0, 0))})


def test_a_puzzle_beyond_the_bound_is_tried_whole_and_brought_home() -> None:
    rows, drones = TRIED
    grid = world_of(rows)
    near = lacam.Graph(OpenCells(grid), grid.shape).near
    assert not exact.fits(near, len(drones)) and exact.tried(near, len(drones))
    result = play(grid, drones, 500)
    assert result.over.reason is EndReason.ALL_REACHED and result.over.turn <= 4 * 17, result.over


def test_a_try_that_gives_up_hands_over_to_lacam(monkeypatch: pytest.MonkeyPatch) -> None:
    """A tried exact search that spends its units without an end gives up: LaCAM's search from where the drones held,
    and no exact search again for these targets."""
    monkeypatch.setattr(lacam, "TRY", 3 * lacam.WORK)  # (three turns)
    rows, drones = TRIED
    arb = lacam.Lacam()
    kinds: list[str] = []
    original = arb.follow

    def follow(*args: object) -> object:
        out = original(*args)  # type: ignore[arg-type]
        kinds.append(type(arb._search).__name__)
        return out
    monkeypatch.setattr(arb, "follow", follow)
    play(world_of(rows), drones, 40, arbiter=arb)
    kinds = [k for k in kinds if k != "NoneType"]  # (turns without a search: PIBT's)
    assert "Exact" in kinds, kinds  # (LaCAM's first; stuck, the exact search; given up, LaCAM's again)
    last = len(kinds) - 1 - kinds[::-1].index("Exact")
    assert kinds[last + 1:] and set(kinds[last + 1:]) == {"Search"}, kinds


def test_drones_that_make_progress_never_wait_for_an_exact_search() -> None:
    """Two drones crossing an open 10 x 10 x 4 world (a puzzle `exact.fits` admits): LaCAM's steps from the first
    turn, home in their shortest ways' turns (an exact search from the start held them 40 turns: the compose game)."""
    grid = np.zeros((10, 10, 4), bool)
    drones: Drones = {"D01": ((0, 0, 0), (9, 9, 0)), "D02": ((2, 0, 0), (9, 0, 0))}
    near = lacam.Graph(OpenCells(grid), grid.shape).near
    assert exact.fits(near, 2)
    result = play(grid, drones, 60)
    assert result.over.reason is EndReason.ALL_REACHED and result.over.turn <= 18 + 2, result.over


def test_a_drone_whose_target_is_cut_off_is_no_obstacle_to_a_proof() -> None:
    """Two columns apart: D02's target is in the other, D01's is D02's cell, and the two cannot trade places in
    theirs. LaCAM's stand-in goal proves nothing and a focused search never covers the other column: the exact search
    of every cell the drones can reach proves it (found probing: the game ran to its turn limit)."""
    drones: Drones = {"D01": ((0, 0, 0), (0, 1, 0)), "D02": ((0, 1, 0), (2, 1, 0))}
    result = play(world_of([".#.", ".#."]), drones, 200)
    assert result.over.text.startswith("no solution") and result.over.turn <= 20, result.over


@pytest.mark.parametrize("kind, seed", [("corridor", 5), ("room", 9)])
def test_the_compiled_joint_moves_are_pythons(kind: str, seed: int) -> None:
    """`Exact._successors` compiled (coordinator/scatter.c's `ex_successors`, where the machine can build it) makes the
    configurations Python's makes, with the same parents, level after level, and the whole search the same plan: a
    game's decisions never depend on which ran."""
    from coordinator import compiled

    if compiled.scatter_library() is None:
        pytest.skip(f"no compiled search here: no C compiler on the PATH, or {compiled.ENV}=0")
    for rows, starts, goals in instances(kind, seed, 12):
        grid = world_of(rows)
        size = grid.shape
        graph = lacam.Graph(OpenCells(grid), size)  # type: ignore[arg-type]
        start = graph.index[flat_cells(np.array([(x, y, 0) for x, y in starts]), size)]  # type: ignore[arg-type]
        goal = graph.index[flat_cells(np.array([(x, y, 0) for x, y in goals]), size)]  # type: ignore[arg-type]
        plans = []
        for lib in (True, False):
            search = exact.Exact(graph.near, graph.cells, start, goal)
            assert search.lib is not None
            if not lib:
                search.lib = None
            cfg = np.asarray(start, np.int64)[None, :]
            for _ in range(3):  # (a few levels, every configuration of each)
                codes, parents = search._successors(cfg)
                python = search._successors_python(cfg)
                assert np.array_equal(codes, python[0]) and np.array_equal(parents, python[1])
                cfg = search._cfg(codes)
            while search.found is None and not search.unsolvable:
                search.expand(1 << 30)
            while search.found is not None and search.plan is None:
                search.expand(1 << 30)
            plans.append(None if search.plan is None else search.plan.tolist())
        assert plans[0] == plans[1]


def test_the_joint_moves_benchmark_plays_python_against_compiled(capsys: pytest.CaptureFixture[str]) -> None:
    """`dronesim bench compiled-scatter --exact`: a seeded room searched whole by each, the same plan and units (its
    exit code says so)."""
    from benchmarks import compiled_scatter
    from coordinator import compiled

    if compiled.scatter_library() is None:
        pytest.skip(f"no compiled search here: no C compiler on the PATH, or {compiled.ENV}=0")
    assert compiled_scatter.main(["--exact", "--seeds", "1", "--repeat", "1"]) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| seed")]
    assert len(rows) == 1 and rows[0].endswith("| yes |"), rows
