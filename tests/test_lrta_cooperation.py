"""LRTA* drones (entities/autopilots/lrta.py) under the coordinator's PIBT arbiter: whole games in process
(dronesim/local.py) and one through real processes with the drones over two swarm hosts.

Head-on in a corridor with a bay, a crowd through a door, random small worlds in every layout with the same
journal (one pilot per drone or the swarm form over arrays), and a city played by real processes."""

from __future__ import annotations

import json
import logging
import pathlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from coordinator.config import DroneSpec, GameConfig
from coordinator.journal import read
from dronesim import replay
from dronesim.local import Inputs, Result, simulate
from entities.gcs import Plan
from schema import Cell, EndReason, WorldSpec
from tests.harness import embedded_router, journal_records, play_scenario
from world.grid import World

LOG = logging.getLogger("test.lrta")


def world_of(rows: list[str], floors: int = 1) -> np.ndarray:
    """A grid [x, y, z] from rows of text (row k is y = k; '#' a building), the same on every floor."""
    return np.repeat(np.array([[c == "#" for c in r] for r in rows]).T[:, :, None], floors, axis=2)


def play(grid: np.ndarray, drones: dict[str, tuple[Cell, Cell]], max_turns: int = 300, *,
         swarm: bool = False) -> Result:
    """LRTA* drones, every one given its target at turn 1; `swarm`: one host flying them with `LrtaSwarm`."""
    world = World.from_grid(grid)
    config = GameConfig(world=WorldSpec(size=world.size, cells=world.packed()), max_turns=max_turns,
                        drones=tuple(DroneSpec(drone=d, start=s) for d, (s, _) in sorted(drones.items())))
    plan = Plan(tuple(sorted((1, d, t) for d, (_, t) in drones.items())))
    return simulate(config, dict.fromkeys(drones, "lrta"), Inputs(plan=plan), LOG, swarm=swarm, swarm_min=1)


def collisions(result: Result) -> list[tuple[int, str, str]]:
    return [(r["turn"], d, c) for r in result.records for d, c in r.get("deaths", {}).items()]


CORRIDOR = 10


@pytest.mark.parametrize("bay", range(1, CORRIDOR - 1))
def test_head_on_in_a_corridor_with_a_bay(bay: int) -> None:
    rows = ["".join("." if x == bay else "#" for x in range(CORRIDOR)), "." * CORRIDOR]
    drones = {"D01": ((0, 1, 0), (CORRIDOR - 1, 1, 0)), "D02": ((CORRIDOR - 1, 1, 0), (0, 1, 0))}
    result = play(world_of(rows), drones)
    assert not collisions(result)
    assert result.over.reason is EndReason.ALL_REACHED, result.over.text
    assert result.over.turn <= 4 * CORRIDOR
    assert play(world_of(rows), drones, swarm=True).records == result.records


def test_a_crowd_drains_through_a_door() -> None:
    rows = ["....#....",
            "....#....",
            ".........",
            "....#....",
            "....#...."]
    left = [(x, y, 0) for x in range(2) for y in range(5)]
    right = [(8 - x, y, 0) for x in range(2) for y in range(5)]
    drones = {f"D{k + 1:02d}": (s, t) for k, (s, t) in enumerate(zip(left, right))}
    result = play(world_of(rows), drones)
    assert not collisions(result)
    assert result.over.reason is EndReason.ALL_REACHED, result.over.text


@st.composite
def small_games(draw):
    size = (draw(st.integers(3, 7)), draw(st.integers(2, 6)), draw(st.integers(1, 3)))
    rng = np.random.default_rng(draw(st.integers(0, 1 << 30)))
    grid = rng.random(size) < draw(st.sampled_from([0.0, 0.1, 0.25]))
    free = [tuple(int(v) for v in c) for c in np.argwhere(~grid)]
    if len(free) < 4:
        grid[:] = False
        free = [tuple(int(v) for v in c) for c in np.argwhere(~grid)]
    n = min(len(free) // 2, draw(st.integers(2, 8)))
    picks = rng.choice(len(free), 2 * n, replace=False)
    return grid, {f"D{k + 1:02d}": (free[picks[k]], free[picks[n + k]]) for k in range(n)}


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(small_games())
def test_property_random_small_worlds_no_collision_same_journal(game) -> None:
    grid, drones = game
    result = play(grid, drones, max_turns=80)
    assert not collisions(result)
    assert play(grid, drones, max_turns=80, swarm=True).records == result.records


@pytest.mark.integration
def test_a_city_through_real_processes_on_two_swarm_hosts(tmp_path: pathlib.Path) -> None:
    """LRTA* drones in a generated city, split over two swarm hosts (each flying its drones with `LrtaSwarm`),
    with the real coordinator, environment and ground station over a router: every drone home, no collision,
    and the journal the in-process game writes."""
    from benchmarks.swarm import city_scenario

    scenario = city_scenario((12, 12, 3), 12, 3, tmp_path)
    with embedded_router() as locator:
        journal, srv, procs = play_scenario(locator, tmp_path, scenario, "swarm", "--swarm-pilot-min", "1", hosts=2)
    records = journal_records(journal)
    assert records[-1]["reason"] == "ALL_REACHED", records[-1]
    assert not [d for r in records for d in r.get("deaths", {})]
    assert {p.name for p in procs} >= {"H01", "H02"}
    assert "arbitration:" in srv.text  # the coordinator's report of its arbitration's CPU (the benchmark reads it)
    assert len(json.loads(scenario.read_text())["drones"]) == 12
    config, autopilots = replay.header_config(records[0])
    assert set(autopilots.values()) == {"lrta"}
    assert replay.verify(str(journal), list(read(journal)), config, autopilots) is None  # in process: the same
