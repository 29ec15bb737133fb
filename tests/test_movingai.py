"""MovingAI .map / .scen (world/movingai.py): read, write, the generated families, and a game from them."""

from __future__ import annotations

import json
import logging
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from dronesim import child_env
from dronesim.local import Inputs, simulate
from dronesim.scenario import Scenario, movingai_scenario
from schema import EndReason, UsageError
from world import movingai
from world.grid import World

MAP = """type octile
height 3
width 5
map
..@..
.T.W.
O....
"""


def test_read_map_x_is_the_column_y_the_row() -> None:
    blocked = movingai.read_map(MAP)
    assert blocked.shape == (5, 3)
    assert {tuple(c) for c in np.argwhere(blocked).tolist()} == {(2, 0), (1, 1), (3, 1), (0, 2)}


def test_map_round_trip_and_world_file(tmp_path: pathlib.Path) -> None:
    blocked = movingai.read_map(MAP)
    assert np.array_equal(movingai.read_map(movingai.write_map(blocked)), blocked)
    path = tmp_path / "tiny.map"
    path.write_text(MAP)
    world = World.load(path)  # a .map is a world 1 cell high
    assert world.size == (5, 3, 1) and world.is_building((2, 0, 0)) and not world.is_building((0, 0, 0))


@pytest.mark.parametrize("text,match", [
    (MAP.replace("octile", "tile"), "octile"),
    (MAP.replace("height 3", "height x"), "height"),
    (MAP.replace("..@..", "..@.."[:4]), "width"),
    (MAP.replace("O....", "O..?."), "unknown"),
    (MAP.replace("map\n", "mop\n"), "map"),
    ("\n".join(MAP.splitlines()[:-1]), "rows"),
])
def test_malformed_maps_are_refused(text: str, match: str) -> None:
    with pytest.raises(UsageError, match=match):
        movingai.read_map(text)


SCEN = "version 1\n0\ttiny.map\t5\t3\t0\t0\t4\t2\t6\n1\ttiny.map\t5\t3\t4\t0\t0\t1\t7.5\n"


def test_scen_round_trip() -> None:
    agents = movingai.read_scen(SCEN)
    assert agents[0] == movingai.Agent(0, "tiny.map", 5, 3, (0, 0), (4, 2), 6.0)
    assert agents[1].optimal == 7.5
    assert movingai.write_scen(agents) == SCEN


@pytest.mark.parametrize("text", ["version 2\n", "0\tm\t5\t3\t0\t0\t4\t2\t6\n",
                                  "version 1\n0\tm\t5\t3\t0\t0\t9\t2\t6\n", "version 1\n0\tm\t5\t3\t0\t0\n",
                                  "version 1\n0\tm\t5\t3\tx\t0\t4\t2\t6\n"])
def test_malformed_scens_are_refused(text: str) -> None:
    with pytest.raises(UsageError):
        movingai.read_scen(text)


@pytest.mark.parametrize("family", list(movingai.FAMILIES))
def test_generated_families_are_seeded_connected_and_round_trip(family: str) -> None:
    blocked = movingai.generate(family, 11)
    assert blocked.shape == (32, 32)
    assert np.array_equal(movingai.generate(family, 11), blocked)  # deterministic
    free = np.argwhere(~blocked)
    assert len(free) >= 400
    reach = movingai.distances(blocked, tuple(free[0]))
    assert (reach[~blocked] >= 0).all(), "a free cell is cut off"
    assert np.array_equal(movingai.read_map(movingai.write_map(blocked)), blocked)
    agents = movingai.scenario(blocked, 100, 3, f"{family}.map")
    assert len({a.start for a in agents}) == len({a.goal for a in agents}) == 100
    for a in agents[:10]:
        assert movingai.distances(blocked, a.start)[a.goal] == a.optimal
    assert movingai.read_scen(movingai.write_scen(agents)) == agents


def test_the_random_families_block_their_share() -> None:
    assert abs(movingai.generate("random-32-32-10", 1).sum() - 102) <= 10
    assert abs(movingai.generate("random-32-32-20", 1).sum() - 205) <= 40  # what was cut off, blocked too


def test_a_movingai_instance_is_played(tmp_path: pathlib.Path) -> None:
    blocked = movingai.generate("room-32-32-4", 2)
    (tmp_path / "room.map").write_text(movingai.write_map(blocked))
    (tmp_path / "room.scen").write_text(movingai.write_scen(movingai.scenario(blocked, 30, 5, "room.map")))
    data = movingai_scenario(tmp_path / "room.map", tmp_path / "room.scen", 25, max_turns=300)
    scenario = Scenario.from_json(data)
    assert len(scenario.drones) == 25 and scenario.world.size == (32, 32, 1)
    result = simulate(scenario.game_config(), scenario.autopilots, Inputs(plan=scenario.plan()),
                      logging.getLogger("test.movingai"))
    assert result.over.reason is EndReason.ALL_REACHED, result.over.text
    with pytest.raises(UsageError, match="agents"):
        movingai_scenario(tmp_path / "room.map", tmp_path / "room.scen", 31)


@pytest.mark.integration
def test_dronesim_up_plays_a_movingai_instance(tmp_path: pathlib.Path) -> None:
    """`dronesim up --world X.map --scen X.scen --agents N`: real processes over an embedded router."""
    blocked = movingai.generate("random-32-32-10", 4)
    (tmp_path / "r.map").write_text(movingai.write_map(blocked))
    (tmp_path / "r.scen").write_text(movingai.write_scen(movingai.scenario(blocked, 20, 4, "r.map")))
    journal = tmp_path / "r.jsonl"
    out = subprocess.run([sys.executable, "-m", "dronesim", "up", "--world", str(tmp_path / "r.map"), "--scen",
                          str(tmp_path / "r.scen"), "--agents", "8", "--swarm", "--quiet", "--journal", str(journal)],
                         capture_output=True, text=True, timeout=300, env=child_env())
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    records = [json.loads(line) for line in journal.read_text().splitlines()]
    assert len(records[0]["drones"]) == 8 and {d["autopilot"] for d in records[0]["drones"]} == {"dstar"}
    assert records[-1]["reason"] == "ALL_REACHED", records[-1]
    bad = subprocess.run([sys.executable, "-m", "dronesim", "up", "--scen", str(tmp_path / "r.scen")],
                         capture_output=True, text=True, timeout=60, env=child_env())
    assert bad.returncode == 2 and "--scen needs --world" in bad.stderr
