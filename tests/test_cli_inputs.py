"""Bad command-line values and user files end the command with one clear line and exit 2 (a `UsageError`, or
argparse's refusal), before any process starts or anything of their size is allocated: never a traceback, a
crash mid-game or a silent misreading."""

from __future__ import annotations

import argparse
import json
import pathlib
import socket

import pytest

from coordinator import node as coordinator
from coordinator.config import DroneSpec, GameConfig
from coordinator.journal import read
from dronesim import up
from dronesim.roles import game_of_scenario
from dronesim.scenario import FORMAT, Scenario, movingai_scenario
from entities import gcs_node
from entities.drone_node import cli as drone_cli
from schema import MalformedMessage, UsageError, WorldSpec
from schema.errors import seconds
from schema.messages import MAX_CELLS
from schema.tuning import MAX_WAIT_S
from world import movingai
from world.grid import World

#: An integer longer than Python converts from text (4300 digits), and arrays nested deeper than its parser
#: recurses: `json.loads` raised ValueError and RecursionError, not JSONDecodeError.
BIG_INT = "9" * 5000
DEEP = "[" * 100_000 + "]" * 100_000


def coordinator_game(*argv: str) -> GameConfig:
    return coordinator.game_config(coordinator.build_parser().parse_args(list(argv)), game_of_scenario)


@pytest.fixture
def no_processes(monkeypatch: pytest.MonkeyPatch) -> None:
    """`dronesim up` refuses before it starts anything: its `play` (the router, the processes) fails the test."""
    def play(args: argparse.Namespace, creds: object) -> int:
        raise AssertionError("dronesim up started the game's processes")
    monkeypatch.setattr(up, "play", play)


def run_up(*argv: str) -> int:
    return up.cli(["--insecure", "--quiet", *argv])


# --------------------------------------------------------------------------- C1: the world's own checks


@pytest.mark.parametrize("argv", [["--seed", "-1"], ["--seed", "99999999999999999999"],
                                  ["--size", "1000000000,10,10"]])
def test_a_world_the_message_refuses_is_a_usage_error(argv: list[str], no_processes: None,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(UsageError, match="bad world"):
        coordinator_game(*argv)
    assert coordinator.cli(argv) == 2  # `dronesim coordinator`: before it opens a session
    assert run_up("--targets", "1,1,0", *argv) == 2  # `dronesim up`: before any process starts
    assert "dronesim up: bad world:" in capsys.readouterr().err


# --------------------------------------------------------------------------- C2: JSON that json.loads chokes on


@pytest.mark.parametrize("text", [BIG_INT, DEEP], ids=["5000-digit integer", "nested 100000 deep"])
def test_a_scenario_or_world_file_json_cannot_hold_is_a_usage_error(tmp_path: pathlib.Path, text: str) -> None:
    scenario = tmp_path / "s.json"
    scenario.write_text(f'{{"format": "{FORMAT}", "version": 1, "max_turns": {text}}}')
    with pytest.raises(UsageError, match="cannot read scenario"):
        Scenario.load(scenario)
    with pytest.raises(UsageError, match="cannot read scenario"):
        Scenario.load(scenario, plan=False)  # (the coordinator's reading)
    world = tmp_path / "w.json"
    world.write_text(f'{{"format": "dronesim-world", "version": 1, "size": [4, 4, {text}], "cells": []}}')
    with pytest.raises(UsageError, match="is not valid JSON"):
        World.load(world)
    journal = tmp_path / "j.jsonl"
    journal.write_text(f'{{"record": "header", "turn": {text}}}\n')
    with pytest.raises(UsageError, match="not a journal record"):
        list(read(journal))


def test_a_world_file_of_deep_json_fails_the_command_with_exit_2(tmp_path: pathlib.Path, no_processes: None,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "w.json").write_text(DEEP)
    assert run_up("--world", str(tmp_path / "w.json"), "--targets", "1,1,0") == 2
    assert "nested too deeply" in capsys.readouterr().err


# --------------------------------------------------------------------------- C3: the cells a world may have


def test_a_world_has_at_most_max_cells() -> None:
    assert WorldSpec(size=(512, 512, 64)).size == (512, 512, 64)  # `dronesim bench perf`'s generated world
    for size in [(512, 512, 65), (65536, 65536, 65536)]:
        with pytest.raises(MalformedMessage, match="cells a world may have"):
            WorldSpec(size=size)
    with pytest.raises(UsageError, match="cells a world may have"):
        coordinator_game("--size", "65536,65536,65536")
    with pytest.raises(UsageError, match="cells a world may have"):
        World.from_json({"format": "dronesim-world", "version": 1, "size": [65536, 65536, 65536], "cells": []})
    wide = 4096  # a .map of MAX_CELLS + 1 cells (4096 x 4097), refused from its header
    with pytest.raises(UsageError, match="cells a world may have"):
        movingai.read_map(f"type octile\nheight {MAX_CELLS // wide + 1}\nwidth {wide}\nmap\n"
                          + "\n" * (MAX_CELLS // wide + 1))


def test_a_huge_world_file_is_refused_before_it_is_allocated(tmp_path: pathlib.Path, no_processes: None) -> None:
    path = tmp_path / "huge.json"
    path.write_text(json.dumps({"format": "dronesim-world", "version": 1, "size": [65536] * 3, "cells": []}))
    with pytest.raises(UsageError, match="cells a world may have"):
        World.load(path)
    assert run_up("--world", str(path), "--targets", "1,1,0") == 2
    assert run_up("--size", "65536,65536,65536", "--targets", "1,1,0") == 2


# --------------------------------------------------------------------------- C4: waits, finite and bounded


@pytest.mark.parametrize("value", ["inf", "-inf", "nan", "1e300", str(MAX_WAIT_S + 1), "-1", "soon"])
def test_a_wait_flag_takes_seconds_from_0_to_a_day(value: str, capsys: pytest.CaptureFixture[str]) -> None:
    parsers = {"coordinator": coordinator.build_parser(), "up": up.build_parser()}
    flags = {"coordinator": ["--phase-deadline", "--phase-cap", "--gcs-deadline", "--admit-deadline",
                             "--gcs-grace", "--link-grace", "--pace", "--lease"],
             "up": ["--pace", "--phase-deadline"]}
    for name, parser in parsers.items():
        for flag in flags[name]:
            with pytest.raises(SystemExit) as exit_:
                parser.parse_args([flag, value])
            assert exit_.value.code == 2, (name, flag)
            assert f"argument {flag}:" in capsys.readouterr().err
    for flag in ["--connect-timeout", "--grace"]:  # every entity's (network/membership.py)
        with pytest.raises(SystemExit) as exit_:
            drone_cli(["--id", "D01", flag, value])
        assert exit_.value.code == 2
    with pytest.raises(argparse.ArgumentTypeError):
        seconds(value)


def test_seconds_takes_0_to_a_day() -> None:
    assert [seconds(v) for v in ("0", "0.5", "86400")] == [0.0, 0.5, MAX_WAIT_S]


@pytest.mark.parametrize("field", ["phase_deadline", "phase_cap", "gcs_deadline", "admit_deadline", "env_grace",
                                   "link_grace", "gcs_grace"])
@pytest.mark.parametrize("value", [float("inf"), float("nan"), 1e300, MAX_WAIT_S + 1])
def test_a_game_config_refuses_a_wait_beyond_a_day(field: str, value: float) -> None:
    drones = (DroneSpec(drone="D01", start=(0, 0, 0)),)
    with pytest.raises(UsageError):
        GameConfig(world=WorldSpec(size=(4, 4, 4)), drones=drones, **{field: value})
    assert getattr(GameConfig(world=WorldSpec(size=(4, 4, 4)), drones=drones, **{field: MAX_WAIT_S}),
                   field) == MAX_WAIT_S


@pytest.mark.parametrize("value", ["inf", "nan", "-1", "1e300"])
def test_the_web_ground_stations_linger_is_bounded(value: str, caplog: pytest.LogCaptureFixture) -> None:
    assert gcs_node.cli(["--web", "127.0.0.1:0", "--replay", "missing.jsonl", "--linger", value]) == 2
    assert "--linger must be in 0..86400" in caplog.text


# --------------------------------------------------------------------------- C5: --agents


def test_agents_must_be_at_least_one(tmp_path: pathlib.Path, no_processes: None,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    blocked = movingai.generate("empty-32-32", 1)
    (tmp_path / "e.map").write_text(movingai.write_map(blocked))
    (tmp_path / "e.scen").write_text(movingai.write_scen(movingai.scenario(blocked, 4, 1, "e.map")))
    for agents in (0, -1):
        with pytest.raises(UsageError, match="agents must be >= 1"):
            movingai_scenario(tmp_path / "e.map", tmp_path / "e.scen", agents)
        assert run_up("--world", str(tmp_path / "e.map"), "--scen", str(tmp_path / "e.scen"),
                      "--agents", str(agents)) == 2
        assert "--agents must be >= 1" in capsys.readouterr().err


# --------------------------------------------------------------------------- C6: the ground station's inputs


def test_the_ground_stations_inputs_are_checked_before_the_game_starts(tmp_path: pathlib.Path, no_processes: None,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "latin1.txt").write_bytes(b"\xff\xfe1,1,0\n")
    (tmp_path / "other.txt").write_text("D05=1,1,0\n")
    (tmp_path / "inside.txt").write_text("1,1,99\n")
    cases = {("--targets", "nan,1,0"): "bad target",
             ("--targets", "D02=1,1,0"): "the plan names D02",
             ("--script", str(tmp_path / "missing.txt")): "cannot read the target script",
             ("--script", str(tmp_path / "latin1.txt")): "cannot read the target script",
             ("--script", str(tmp_path / "other.txt")): "the plan names D05",
             ("--script", str(tmp_path / "inside.txt")): "bad target",
             ("--web", "127.0.0.1:99999"): "bad --web port",
             ("--web", "nowhere.invalid:0"): "cannot serve the web ground station",
             ("--lifelong", "--web", "127.0.0.1:0"): "--lifelong is the scripted ground station's"}
    for argv, why in cases.items():
        assert run_up(*argv) == 2, argv
        err = capsys.readouterr().err
        assert why in err and err.count("\n") == 1, (argv, err)


def test_a_taken_web_port_is_refused_before_the_game_starts(no_processes: None,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        assert run_up("--web", f"127.0.0.1:{taken.getsockname()[1]}") == 2
    assert "cannot serve the web ground station" in capsys.readouterr().err


def test_a_scenarios_extra_targets_are_checked(tmp_path: pathlib.Path, no_processes: None) -> None:
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"format": FORMAT, "version": 1, "world": {"size": [8, 8, 2], "seed": 1},
                                "drones": [{"id": "D01", "start": [0, 0, 0]}], "targets": ["D01=7,7,0"]}))
    assert run_up("--scenario", str(path), "--targets", "D03=1,1,0") == 2


def test_a_ground_station_that_refuses_its_input_is_dronesim_ups_usage_error(
        capsys: pytest.CaptureFixture[str]) -> None:
    """A refusal the checks could not foresee (a port taken meanwhile): the ground station says why and exits 2,
    `supervise` stops the game, and `dronesim up` exits 2 too (it was 1, "processes failed")."""
    assert up.ending({"GCS": 2, "SRV": 143, "ENV": 143, "D01": 143}) == 2
    assert "GCS refused its input" in capsys.readouterr().err
    assert up.ending({"D01": 2, "SRV": 0, "GCS": 0, "ENV": 0}) == 1  # a drone's failure is not the command's usage
    assert up.ending({"SRV": 1, "GCS": 2}) == 1  # the coordinator failed first: the station's 2 follows from it
    assert up.ending({"SRV": 0, "GCS": 0}) == 0
