"""Cooperative drones get past each other (docs/cooperation.md): whole games, in process (dronesim/local.py).

Head-on in a corridor with a bay (at every position) and with a second floor, a drone parked in a corridor
that steps aside and comes back, a crowd that drains through a door, a dead end that the drones say instead of
waiting forever, mixed autopilots, and random small worlds in every layout with the same journal, which
`replay --verify` reproduces and from which a coordinator resumes; and one game through real processes
(coordinator, environment, drones, ground station over a router) in two layouts.
"""

from __future__ import annotations

import json
import logging
import pathlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from coordinator import arbiter as arbiter_module
from coordinator.arbiter import STUCK, TIE_SPAN, Arbiter, cooperate, fixed
from coordinator.config import DroneSpec, GameConfig
from coordinator.engine import Engine
from coordinator.journal import dumps, read
from coordinator.resume import restore
from dronesim import replay
from dronesim.local import Inputs, Result, simulate
from entities.autopilots.dstar import DStarPilot
from entities.gcs import Plan, describe
from entities.web.model import view_of
from schema import Cell, DroneState, EndReason, Note, WorldSpec
from schema.tables import code_of
from tests.harness import embedded_router, journal_records, play_scenario
from world import movingai
from world.grid import World

LOG = logging.getLogger("test.cooperation")


def world_of(rows: list[str], floors: int = 1) -> np.ndarray:
    """A grid [x, y, z] from rows of text (row k is y = k; '#' a building), the same on every floor."""
    plane = np.array([[c == "#" for c in r] for r in rows]).T
    return np.repeat(plane[:, :, None], floors, axis=2)


def config(grid: np.ndarray, drones: dict[str, tuple[Cell, Cell, str]], max_turns: int = 300,
           using: str = "lacam") -> GameConfig:
    world = World.from_grid(grid)
    return GameConfig(world=WorldSpec(size=world.size, cells=world.packed()), max_turns=max_turns,
                      drones=tuple(DroneSpec(drone=d, start=s) for d, (s, _, _) in sorted(drones.items())),
                      arbiter=using)


def play(grid: np.ndarray, drones: dict[str, tuple[Cell, Cell, str]], max_turns: int = 300, *,
         swarm: bool = False, arbiter: Arbiter | None = None, keep_statuses: bool = False,
         using: str = "lacam") -> Result:
    """Every drone given its target at turn 1, the ground station's plan final at once; `using`: the game's
    arbitration (the complete search by default, "pibt" for PIBT alone); `arbiter`: another one in its place."""
    plan = Plan(tuple(sorted((1, d, t) for d, (_, t, _) in drones.items())))
    return simulate(config(grid, drones, max_turns, using), {d: a for d, (_, _, a) in drones.items()},
                    Inputs(plan=plan), LOG, swarm=swarm, arbiter=arbiter, keep_statuses=keep_statuses)


def true_verdict(result: Result, drones: dict[str, tuple[Cell, Cell, str]]) -> None:
    """The end of the game says where the drones are after its last turn (issue 33, 3): ALL_REACHED, every alive
    drone on its target; SETTLED, every alive one on it but those it names unreachable; the last STATUS (if
    kept) says REACHED for exactly the alive drones on their targets."""
    pos, gone = {d: s for d, (s, _, _) in drones.items()}, set()
    for r in result.records:
        pos |= {d: tuple(p) for d, p in r.get("moves", {}).items()}
        gone |= set(r.get("deaths", {})) | set(r.get("lost", ()))
    away = sorted(d for d, (_, t, _) in drones.items() if d not in gone and pos[d] != t)
    over = result.over
    if over.reason is EndReason.ALL_REACHED:
        assert not away, f"{over.text}, yet {away} are not on their targets"
    if over.reason is EndReason.SETTLED:
        named = set(over.text.rsplit("unreachable for ", 1)[1].split(", "))
        assert set(away) <= named, f"{over.text}, yet {sorted(set(away) - named)} are not on their targets"
    if result.statuses:
        for s in result.statuses[-1].drones:
            on = s.state is DroneState.ALIVE and s.pos == s.target
            assert (s.note is Note.REACHED) == on, f"the last STATUS says {s}"


def deaths(result: Result) -> dict[str, str]:
    return {d: c for r in result.records for d, c in r.get("deaths", {}).items()}


def notes(result: Result) -> set[tuple[str, str]]:
    """Every (drone, note) said in the game."""
    return {(d, n) for r in result.records for d, n in r.get("notes", {}).items()}


def held_up(result: Result, *drones: str) -> None:
    """PIBT alone could not bring `drones` home (its turn limit), and they said so: STUCK, held up by the drones in
    their way, never UNREACHABLE (the static world has a way to every target here)."""
    assert result.over.reason is EndReason.TURN_LIMIT, result.over.text
    assert {(d, "STUCK") for d in drones} <= notes(result) and "UNREACHABLE" not in {n for _, n in notes(result)}
    assert not deaths(result)


def arrived(result: Result) -> None:
    assert result.over.reason is EndReason.ALL_REACHED, result.over.text
    assert not deaths(result)


# --------------------------------------------------------------------------- head-on in a corridor

CORRIDOR = 10


@pytest.mark.parametrize("bay", range(CORRIDOR))
def test_head_on_in_a_corridor_with_a_bay_anywhere(bay: int) -> None:
    rows = ["".join("." if x == bay else "#" for x in range(CORRIDOR)), "." * CORRIDOR]
    drones = {"D01": ((0, 1, 0), (CORRIDOR - 1, 1, 0), "dstar"), "D02": ((CORRIDOR - 1, 1, 0), (0, 1, 0), "dstar")}
    result = play(world_of(rows), drones)
    assert not deaths(result)
    if 0 < bay < CORRIDOR - 1:
        arrived(result)
        assert result.over.turn <= 4 * CORRIDOR
    else:  # a bay above an end of the corridor is above one drone's target: no way to pass, and they say so
        assert result.over.reason is EndReason.SETTLED, result.over.text


def test_the_former_arbitration_never_resolved_it() -> None:
    # what issue 17 found: with one move per drone and a fixed priority, both wait, side-step, come back
    rows = ["#####.####", ".........."]
    drones = {"D01": ((0, 1, 0), (9, 1, 0), "dstar"), "D02": ((9, 1, 0), (0, 1, 0), "dstar")}
    result = play(world_of(rows), drones, max_turns=100, arbiter=fixed)
    held_up(result, "D01", "D02")  # stuck: now they say so


@pytest.mark.parametrize("second", ["D01", "D02", "D03"])
def test_head_on_in_a_corridor_with_a_second_floor(second: str) -> None:
    # three drones, one of them coming the other way, in a corridor two floors high
    ends = {"D01": ((0, 0, 0), (9, 0, 0)), "D02": ((1, 0, 0), (8, 0, 0)), "D03": ((2, 0, 0), (7, 0, 0))}
    start, target = ends[second]
    ends[second] = ((9, 0, 1) if second != "D01" else (9, 0, 0), start)
    result = play(world_of(["." * 10], floors=2), {d: (s, t, "dstar") for d, (s, t) in ends.items()})
    arrived(result)


def test_parked_drone_steps_aside_and_comes_back() -> None:
    # D02 sits on its target in the middle of a corridor between two rooms; D01 crosses it.
    rows = ["...#######...",
            ".............",
            "...#######..."]
    drones = {"D01": ((0, 1, 0), (12, 1, 0), "dstar"), "D02": ((6, 1, 0), (6, 1, 0), "dstar")}
    result = play(world_of(rows), drones)
    arrived(result)
    assert any("D02" in r.get("moves", {}) for r in result.records), "D02 was never pushed aside"


@pytest.mark.parametrize("bay", [3, 5, 7])
def test_parked_drone_in_a_corridor_with_a_bay(bay: int) -> None:
    # D02 is parked beside the bay (it steps in), before it (it is pushed to it, then comes back), or behind
    # D01's way in: there it would have to move towards D01 first, which PIBT's greedy steps never do, and
    # D01 says it is stuck (docs/cooperation.md, "Where it is complete"); the search (the default) finds that way.
    rows = ["".join("." if x == bay else "#" for x in range(10)), "." * 10]
    drones = {"D01": ((0, 1, 0), (9, 1, 0), "dstar"), "D02": ((5, 1, 0), (5, 1, 0), "dstar")}
    if bay < 5:
        held_up(play(world_of(rows), drones, max_turns=150, using="pibt"), "D01")
        result = play(world_of(rows), drones)
        assert not deaths(result)
        arrived(result)
        return
    result = play(world_of(rows), drones, using="pibt")
    assert not deaths(result)
    arrived(result)
    assert any(r.get("moves", {}).get("D02") == [bay, 0, 0] for r in result.records)


def test_a_crowd_drains_through_a_door() -> None:
    # 16 drones in a 4 x 4 room leave it through one door for targets spread over the hall beyond.
    rows = ["......#.........",
            "......#.........",
            "...............",
            "......#.........",
            "......#........."]
    rows = [r.ljust(16, ".") for r in rows]
    starts = [(x, y, 0) for x in range(1, 5) for y in range(0, 5) if (x, y) != (4, 2)][:16]
    targets = [(x, y, 0) for x in range(8, 16, 2) for y in range(0, 5)][:16]
    drones = {f"D{k + 1:02d}": (s, t, "dstar") for k, (s, t) in enumerate(zip(starts, targets))}
    result = play(world_of(rows), drones, max_turns=200)
    arrived(result)


# --------------------------------------------------------------------------- PIBT's swap

SWAPS = {
    # a dead-end corridor off a small room: D01 goes to its end, D02 comes out
    "dead end": (["...#######", "..........", "...#######"],
                 {"D01": ((2, 1, 0), (9, 1, 0), "dstar"), "D02": ((5, 1, 0), (0, 1, 0), "dstar")}),
    # head-on in a corridor crossed by another one in its middle
    "crossing": (["####.####", ".........", "####.####"],
                 {"D01": ((0, 1, 0), (8, 1, 0), "dstar"), "D02": ((8, 1, 0), (0, 1, 0), "dstar")}),
}


def _without_swap(size: Cell, *args: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The arbitration in force without the world's cells: PIBT with no swap."""
    return cooperate(size, *args[:6])  # type: ignore[arg-type]


@pytest.mark.parametrize("case", sorted(SWAPS))
def test_swap_leads_the_other_drone_to_a_junction(case: str) -> None:
    """With PIBT's swap the drone of higher priority walks back to the nearest junction, pulling the other one
    after it, and they pass there: both home in 12 turns; without it, the one going deeper pushes the other to
    the end (or to the far side of the crossing) first, gives way there and is pushed all the way back (17 and 22
    turns)."""
    rows, drones = SWAPS[case]
    result = play(world_of(rows), drones, max_turns=100)
    arrived(result)
    assert result.over.turn <= 12
    slower = play(world_of(rows), drones, max_turns=100, arbiter=_without_swap)
    arrived(slower)
    assert slower.over.turn > 12


#: A dead end two cells deep (x = 2, y = 1..2) off an open row: two targets in it.
POCKET = ["......", "##.###", "##.###"]


@pytest.mark.parametrize("start", [(2, 1, 0), (2, 0, 0)])
def test_two_targets_in_a_dead_end_entered_in_the_wrong_order(start: Cell) -> None:
    """D02 is home on (2, 1), or just outside, before D01 reaches the dead end's far cell (2, 2) beyond it.
    PIBT alone pushes D02 to the end, gives way, is pushed back out and pushes again, for ever (D01 says it is
    STUCK); with the swap pulling a drone off its target that blocks a deeper one, and the clear
    operation (a drone next to a dead end lets the one going deeper in first), both are home in 6 turns."""
    drones = {"D01": ((0, 0, 0), (2, 2, 0), "dstar"), "D02": (start, (2, 1, 0), "dstar")}
    result = play(world_of(POCKET), drones, max_turns=100)
    arrived(result)
    assert result.over.turn <= 8
    held_up(play(world_of(POCKET), drones, max_turns=100, arbiter=_without_swap), "D01")


# --------------------------------------------------------------------------- neighbouring targets: going round

#: A ring of one-cell corridors round a block; D01's target (2, 0) and D02's (3, 0) are next to each other on
#: its top side, and each drone comes along it from the side of the other's target.
RING = [".......", ".#####.", "......."]
NEIGHBOURS = {"D01": ((6, 0, 0), (2, 0, 0), "dstar"), "D02": ((0, 0, 0), (3, 0, 0), "dstar")}


def test_neighbouring_targets_one_drone_goes_round(monkeypatch: pytest.MonkeyPatch) -> None:
    """The one home first is pushed off by the other going through to its own target, comes back and pushes
    that one off in turn, for ever (each arrival looks like progress: neither ever says it is stuck). Pushed
    off its target a third time, a drone that finds a drone in its way near its target goes round the ring
    instead (D02: 8 moves longer, within the bound; D01's way round, 10 longer, is not taken), and both are
    home in 30 turns; without that rule they never are."""
    result = play(world_of(RING), NEIGHBOURS, max_turns=100, using="pibt")
    arrived(result)
    assert result.over.turn <= 40
    monkeypatch.setattr(DStarPilot, "PUSHED_OFF", 10 ** 6)
    assert play(world_of(RING), NEIGHBOURS, max_turns=100, using="pibt").over.reason is EndReason.TURN_LIMIT
    arrived(play(world_of(RING), NEIGHBOURS, max_turns=100))  # the search needs no such rule


# --------------------------------------------------------------------------- tie-breaks

#: A corridor with a two-cell bay above its middle (a 2 x 2 block): D03 parked in the block's corner, D01 and
#: D04 coming in from the ends to the bay's cells, D02 leaving the bay for the right end.
BAY = ["#..#", "....", "####"]
BLOCK = {"D01": ((0, 1, 0), (1, 0, 0), "dstar"), "D02": ((1, 0, 0), (3, 1, 0), "dstar"),
         "D03": ((1, 1, 0), (1, 1, 0), "dstar"), "D04": ((3, 1, 0), (2, 0, 0), "dstar")}


def test_a_loop_round_a_block_is_left(monkeypatch: pytest.MonkeyPatch) -> None:
    """Pushed drones stepping back into their pushers' way, their sides in the same order at every turn, push
    each other round the block for ever. Retreating off the way to the pusher's target (`_out_of_the_way`),
    every drone is home in 6 turns; with the cell straight ahead of the pusher as the only one avoided, the
    sides drawn from the turn (`arbiter.tie_breaks`) still end the loop, in 17 turns."""
    result = play(world_of(BAY), BLOCK, max_turns=120)
    arrived(result)
    assert result.over.turn <= 8

    def same_sides(*args: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return cooperate(*args[:8])  # type: ignore[arg-type]  # (no salt: the drones' own order)
    out_of_the_way = arbiter_module._out_of_the_way
    monkeypatch.setattr(arbiter_module, "_out_of_the_way",
                        lambda mine, src, enters, leaves, aim: out_of_the_way(mine, src, enters, leaves, None))
    result = play(world_of(BAY), BLOCK, max_turns=120)
    arrived(result)
    assert result.over.turn <= 20
    assert play(world_of(BAY), BLOCK, max_turns=120, arbiter=same_sides).over.reason is EndReason.TURN_LIMIT


def test_the_longer_trip_goes_first_among_drones_away_as_long() -> None:
    """Priorities (`Arbitration.age`): the turns away from rest first, then the distance to the target when the drone
    left rest (PIBT2's initial distance), then the id: D02, with the longer trip, outranks D01."""
    drones = {"D01": ((0, 0, 0), (3, 0, 0), "dstar"), "D02": ((0, 2, 0), (7, 2, 0), "dstar"),
              "D03": ((5, 1, 0), (5, 1, 0), "dstar")}
    grid = world_of(["........"] * 3)
    records = play(grid, drones, max_turns=3).records
    first = restore(config(grid, drones, 3), records[:2], LOG).arbitration.priority.tolist()
    assert first == [TIE_SPAN + 2, TIE_SPAN + 6, 0]  # one turn away; 2 and 6 moves from the targets then
    later = restore(config(grid, drones, 3), records[:3], LOG).arbitration.priority.tolist()
    assert later == [2 * TIE_SPAN + 2, 2 * TIE_SPAN + 6, 0]  # the tie-break kept until they rest


# --------------------------------------------------------------------------- where nobody can pass


@pytest.mark.parametrize("using", ["pibt", "lacam"])
def test_a_dead_end_is_said_not_waited_for(using: str) -> None:
    # a corridor closed at both ends, no passing place: the search proves at once that no way exists and ends the
    # game; PIBT alone cannot prove it: both drones say they are STUCK (never UNREACHABLE: each target has a way in
    # the static world, the other drone is in it) and the game goes on to its turn limit
    drones = {"D01": ((0, 0, 0), (9, 0, 0), "dstar"), "D02": ((9, 0, 0), (0, 0, 0), "dstar")}
    result = play(world_of(["." * 10]), drones, max_turns=150, using=using)
    if using == "pibt":
        held_up(result, "D01", "D02")
        return
    assert result.over.reason is EndReason.SETTLED, result.over.text
    assert "D01" in result.over.text and "D02" in result.over.text and "no solution" in result.over.text
    assert result.over.turn < 20 and not deaths(result)


@pytest.mark.parametrize("using", ["pibt", "lacam"])
def test_a_target_behind_a_drone_parked_at_a_dead_end(using: str) -> None:
    drones = {"D01": ((0, 0, 0), (8, 0, 0), "dstar"), "D02": ((9, 0, 0), (9, 0, 0), "dstar")}
    result = play(world_of(["." * 10]), drones, using=using)
    assert result.over.reason is EndReason.ALL_REACHED  # reachable: D02 is pushed along... and back
    drones = {"D01": ((0, 0, 0), (9, 0, 0), "dstar"), "D02": ((8, 0, 0), (8, 0, 0), "dstar")}
    result = play(world_of(["." * 10]), drones, max_turns=150, using=using)
    if using == "pibt":  # never, and PIBT cannot prove it: D01 says it is held up
        held_up(result, "D01")
    else:  # the search proves it
        assert result.over.reason is EndReason.SETTLED and "D01" in result.over.text and "no solution" in \
            result.over.text


#: A corridor (y = 1) with a pocket above x = 4..6, reached only through the corridor cells below it.
CROWDED = ["####...#####", "............"]


@pytest.mark.parametrize("pilot", ["dstar", "lrta"])
@pytest.mark.parametrize("using", ["lacam", "pibt"])
def test_a_crowd_that_blocks_a_corridor_for_a_while_is_waited_for_never_unreachable(pilot: str, using: str) -> None:
    """Issue 37: UNREACHABLE only where the static world has no way, never because of other drones. Three drones
    that nobody can push (the seed's V1, parked on their targets) fill the corridor for 110 turns, longer than D*'s
    `stuck_after` (64 here); D01 and D02 wait behind them. A D* drone says STUCK meanwhile (held up: its priority is
    arbiter.STUCK), an LRTA* drone nothing (drones never enter its values); neither ever says UNREACHABLE, the game
    does not settle on them, and once the crowd steps into the pocket both pass and arrive."""
    crowd = {f"D0{k}": ((x, 1, 0), (x, 1, 0), "v1") for k, x in ((3, 4), (4, 5), (5, 6))}
    drones = {"D01": ((0, 1, 0), (10, 1, 0), pilot), "D02": ((1, 1, 0), (11, 1, 0), pilot), **crowd}
    leave = 110
    plan = Plan(tuple(sorted([(1, d, t) for d, (_, t, _) in drones.items()] +
                             [(leave, d, (s[0], 0, 0)) for d, (s, _, _) in crowd.items()])))
    grid = world_of(CROWDED)
    result = simulate(config(grid, drones, 300, using), {d: a for d, (_, _, a) in drones.items()},
                      Inputs(plan=plan), LOG)
    arrived(result)
    said = notes(result)
    assert "UNREACHABLE" not in {n for _, n in said}
    if pilot == "dstar":
        assert {("D01", "STUCK"), ("D02", "STUCK")} <= said
    waited = [r["turn"] for r in result.records if r.get("moves", {}).get("D01", [0])[0] > 3]
    assert waited and waited[0] > leave and result.over.turn < leave + 40  # it passed once they left, not before


# --------------------------------------------------------------------------- mixed games


def test_mixed_autopilots_cooperative_drones_only_die_with_others() -> None:
    rng = np.random.default_rng(4)
    grid = rng.random((12, 12, 2)) < 0.15
    free = [tuple(int(v) for v in c) for c in np.argwhere(~grid)]
    picks = rng.choice(len(free), 24, replace=False)
    pilots = ["dstar", "seed", "v1"] * 4
    drones = {f"D{k + 1:02d}": (free[picks[k]], free[picks[12 + k]], pilots[k]) for k in range(12)}
    result = play(grid, drones, max_turns=150)
    coop = {d for d, (_, _, a) in drones.items() if a == "dstar"}
    for r in result.records:
        for d, cause in r.get("deaths", {}).items():
            if d in coop and cause in ("VERTEX", "SWAP"):
                partners = [e for e in r["deaths"] if e != d and e not in coop]
                assert partners, f"turn {r['turn']}: cooperative {d} died ({cause}) with no other drone"
    reached = {d for d in coop if not deaths(result).get(d)}
    assert reached, "every cooperative drone died"


# --------------------------------------------------------------------------- random small worlds


@st.composite
def small_games(draw):
    size = (draw(st.integers(3, 6)), draw(st.integers(2, 5)), draw(st.integers(1, 2)))
    seed = draw(st.integers(0, 1 << 30))
    rng = np.random.default_rng(seed)
    grid = rng.random(size) < draw(st.sampled_from([0.0, 0.1, 0.25]))
    free = [tuple(int(v) for v in c) for c in np.argwhere(~grid)]
    n = min(len(free) // 2, draw(st.integers(2, 7)))
    if n < 2:
        grid[:] = False
        free = [tuple(int(v) for v in c) for c in np.argwhere(~grid)]
        n = 2
    picks = rng.choice(len(free), 2 * n, replace=False)
    pilots = draw(st.lists(st.sampled_from(["dstar", "dstar", "seed"]), min_size=n, max_size=n))
    drones = {f"D{k + 1:02d}": (free[picks[k]], free[picks[n + k]], pilots[k]) for k in range(n)}
    return grid, drones


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(small_games())
def test_property_random_small_worlds(game) -> None:
    grid, drones = game
    coop = {d for d, (_, _, a) in drones.items() if a == "dstar"}
    result = play(grid, drones, max_turns=120)
    for r in result.records:
        for d, cause in r.get("deaths", {}).items():
            if d in coop and cause in ("VERTEX", "SWAP"):
                assert any(e not in coop for e in r["deaths"] if e != d), f"cooperative {d} killed by one of its own"
    true_verdict(result, drones)
    assert play(grid, drones, max_turns=120, swarm=True).records == result.records  # the same in every layout


def test_a_push_on_the_last_turn_is_no_false_verdict() -> None:
    """Issue 33 (3), found among random small worlds: at turn 105, D01, stuck (UNREACHABLE), pushes D03 off its
    target (PIBT lends it D03's cell); D03 had said REACHED as it planned. The game ended SETTLED "targets
    reached, except unreachable for D01" with D03 off its target. The end reads where the drones are: the game
    goes on, D01 pushes through and every drone reaches its target (a true ALL_REACHED); the ground stations
    show the last STATUS, whose notes are the positions'."""
    grid = np.zeros((5, 2, 2), bool)
    for c in [(0, 1, 0), (1, 0, 1), (1, 1, 0), (2, 0, 1), (2, 1, 1), (4, 0, 0)]:
        grid[c] = True
    drones = {"D01": ((2, 0, 0), (0, 1, 1), "dstar"), "D02": ((2, 1, 0), (3, 0, 1), "seed"),
              "D03": ((0, 0, 0), (0, 0, 1), "dstar")}
    result = play(grid, drones, max_turns=120, keep_statuses=True)
    pushed = [r["turn"] for r in result.records if r.get("notes", {}).get("D03") == "REACHED"
              and r.get("moves", {}).get("D03") not in (None, [0, 0, 1])]
    assert pushed, "D03 is never pushed off its target after saying REACHED: the test is void"
    true_verdict(result, drones)
    assert result.over.reason is EndReason.ALL_REACHED, result.over.text
    last = result.statuses[-1]
    assert [describe(s) for s in last.drones] == [f"{d} at {t}: reached its target, target {t}"
                                                  for d, (_, t, _) in sorted(drones.items())]
    assert {view_of(s) for s in last.drones} == {"reached"}


# --------------------------------------------------------------------------- journal: replay and resume


@pytest.mark.parametrize("using", ["pibt", "lacam"])
def test_a_cooperative_game_replays_and_resumes(tmp_path: pathlib.Path, using: str) -> None:
    rows = ["###.######", ".........."]
    drones = {"D01": ((0, 1, 0), (9, 1, 0), "dstar"), "D02": ((9, 1, 0), (0, 1, 0), "dstar"),
              "D03": ((5, 1, 0), (5, 1, 0), "dstar")}
    result = play(world_of(rows), drones, using=using)
    arrived(result)
    # the head-on meeting was resolved by giving way (PIBT), or by the search (no drone gives way)
    assert any("gave_way" in r for r in result.records) == (using == "pibt")
    path = tmp_path / "game.jsonl"
    path.write_text("".join(dumps(r) + "\n" for r in result.records))
    records = list(read(path))
    cfg = config(world_of(rows), drones, using=using)
    autopilots = {d: a for d, (_, _, a) in drones.items()}
    assert replay.verify(str(path), records, cfg, autopilots) is None, "replay --verify disagrees"
    assert (records[0].get("arbiter") == "pibt") == (using == "pibt")
    # a coordinator resumed after any turn has the priorities PIBT's rule gives from the journal alone
    for cut in range(2, len(records) - 1):
        resumed = restore(cfg, records[:cut], LOG)
        assert resumed.arbitration.priority.tolist() == _priorities(records[:cut], cfg), f"after {cut - 1} turns"
        assert cut > 2 or any(resumed.arbitration.priority), "nobody away from its target after the first turn?"


def _priorities(records: list[dict], cfg: GameConfig) -> list[int]:
    """The priorities after the journal's turns, recomputed here from PIBT's rule and the journal alone: the
    turns away from rest, then (below TIE_SPAN) the Manhattan distance to the target when the drone left rest;
    STUCK for a drone that says UNREACHABLE away from its target, 0 at home or for one that gave way."""
    ids = sorted(d.drone for d in cfg.drones)
    pos = {d.drone: tuple(d.start) for d in cfg.drones}
    target: dict[str, tuple] = {}
    note: dict[str, str] = {}
    away = dict.fromkeys(ids, 0)
    tie = dict.fromkeys(ids, 0)
    stuck = dict.fromkeys(ids, False)
    for r in records[1:]:
        target.update({d: tuple(c) for d, c in r.get("targets", {}).items()})
        pos.update({d: tuple(c) for d, c in r.get("moves", {}).items()})
        note.update(r.get("notes", {}))
        for d in ids:
            home = d not in target or pos[d] == target[d] or d in r.get("gave_way", ())
            stuck[d] = not home and note.get(d) == "UNREACHABLE"
            if not (home or stuck[d]) and not away[d]:
                tie[d] = sum(abs(a - b) for a, b in zip(pos[d], target[d]))
            away[d] = 0 if home or stuck[d] else away[d] + 1
    return [away[d] * TIE_SPAN + tie[d] if away[d] else STUCK if stuck[d] else 0 for d in ids]


def test_a_drone_that_says_unreachable_away_from_its_target_goes_before_those_at_home() -> None:
    """PIBT's priorities (`Arbitration.age`): a drone stuck away from its target (UNREACHABLE) waits behind every
    drone on its way, but goes before those at home, so that once they all rest it pushes through."""
    drones = {"D01": ((0, 1, 0), (0, 1, 0), "dstar"), "D02": ((2, 1, 0), (9, 1, 0), "dstar"),
              "D03": ((4, 1, 0), (8, 1, 0), "dstar"), "D04": ((6, 1, 0), (7, 1, 0), "dstar")}
    engine = Engine(config(world_of(["..........", ".........."]), drones), LOG)
    fleet, alive = engine.fleet, engine.fleet.alive_rows()
    fleet.aim(np.arange(4), np.array([g for _, g, _ in drones.values()]))
    fleet.note[[2, 3]] = code_of(Note.UNREACHABLE)
    engine.arbitration.age(fleet, alive)
    priority = engine.arbitration.priority
    assert priority.tolist() == [0, TIE_SPAN + 7, STUCK, STUCK]  # at home, on its way (7 to go), stuck
    assert 0 < STUCK < TIE_SPAN
    fleet.note[2] = code_of(Note.NONE)  # D03 gets closer again: it leaves rest, its tie-break taken now
    engine.arbitration.age(fleet, alive)
    assert priority.tolist() == [0, 2 * TIE_SPAN + 7, TIE_SPAN + 4, STUCK]


# --------------------------------------------------------------------------- through real processes


@pytest.mark.integration
def test_head_on_with_a_bay_through_real_processes_in_two_layouts(tmp_path: pathlib.Path) -> None:
    """A .map corridor with a bay, a parked drone and two meeting head-on, played by the real coordinator,
    environment, drone processes (one per drone, then one swarm host) and ground station over a router: the
    same journal both ways, every drone home, and `replay --verify` re-simulates it."""
    rows = ["###.######", ".........."]
    (tmp_path / "corridor.map").write_text(movingai.write_map(world_of(rows)[:, :, 0]))
    drones = {"D01": ((0, 1, 0), (9, 1, 0)), "D02": ((9, 1, 0), (0, 1, 0)), "D03": ((5, 1, 0), (5, 1, 0))}
    scenario = tmp_path / "corridor.json"
    scenario.write_text(json.dumps({
        "format": "dronesim-scenario", "version": 1, "world": {"file": "corridor.map"}, "max_turns": 100,
        "drones": [{"id": d, "start": list(s), "autopilot": "dstar"} for d, (s, _) in drones.items()],
        "targets": [f"{d}={t[0]},{t[1]},{t[2]}" for d, (_, t) in drones.items()]}))
    with embedded_router() as locator:
        journals = [play_scenario(locator, tmp_path, scenario, layout)[0] for layout in ("processes", "swarm")]
    assert journals[0].read_bytes() == journals[1].read_bytes()
    records = journal_records(journals[0])
    assert records[-1]["reason"] == "ALL_REACHED", records[-1]
    assert any("gave_way" in r or "yielded" in r for r in records)
    config, autopilots = replay.header_config(records[0])
    assert replay.verify(str(journals[0]), list(read(journals[0])), config, autopilots) is None
