"""The role commands that take `--scenario FILE`: the application reads the scenario (`dronesim.scenario`) and
hands each role what it needs of it, so that no role imports the application."""

from __future__ import annotations

from coordinator import node
from entities import gcs_node

from .scenario import Scenario


def coordinator(argv: list[str]) -> int:
    return node.cli(argv, scenario=lambda path, **deadlines: Scenario.load(path, plan=False).game_config(**deadlines))


def gcs(argv: list[str]) -> int:
    return gcs_node.cli(argv, scenario_targets=lambda path: Scenario.load(path).targets)
