"""The role commands that take `--scenario FILE`: the application reads the scenario (`dronesim.scenario`) and
hands each role what it needs of it, so that no role imports the application."""

from __future__ import annotations

from coordinator import node
from coordinator.config import GameConfig
from entities import gcs_node

from .scenario import Scenario


def game_of_scenario(path: str, **deadlines: object) -> GameConfig:
    """The game a scenario file describes, as the coordinator reads it (its targets are the ground station's)."""
    return Scenario.load(path, plan=False).game_config(**deadlines)


def coordinator(argv: list[str]) -> int:
    return node.cli(argv, scenario=game_of_scenario)


def plan_of_scenario(path: str) -> tuple[tuple[str, ...], int | None]:
    """A scenario file's targets and lifelong seed, as the ground station reads them."""
    scenario = Scenario.load(path)
    return scenario.targets, scenario.lifelong


def gcs(argv: list[str]) -> int:
    return gcs_node.cli(argv, scenario_plan=plan_of_scenario)
