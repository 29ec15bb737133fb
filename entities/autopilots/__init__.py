"""Autopilots, selectable by name (``--autopilot NAME``, a `REGISTRY` key)."""

from __future__ import annotations

import importlib
from collections.abc import Sequence

from schema import Cell, UsageError
from schema.tuning import SWARM_MIN

from .base import Autopilot, SwarmPilot, run_step

#: name -> class, in the module of that name (imported on first use).
REGISTRY: dict[str, str] = {"v1": "V1Pilot", "seed": "SeedPilot", "dstar": "DStarPilot", "lrta": "LrtaPilot"}
#: A drone's autopilot unless told (`--autopilot`, a scenario's drone without one), and the cooperative one where
#: drones must give way to each other by default (a MovingAI instance, the RL expert).
DEFAULT = "seed"
COOPERATIVE = "dstar"
#: name -> class of the autopilots that also come as one pilot for a whole swarm, over arrays (same decisions as
#: one instance per drone; a swarm host flies its drones with it).
SWARMS: dict[str, str] = {"seed": "SeedSwarm", "lrta": "LrtaSwarm"}


def _load(name: str, cls: str) -> type:
    return getattr(importlib.import_module(f"{__name__}.{name}"), cls)


def pilot_class(name: str) -> type[Autopilot]:
    """The autopilot class registered as `name` (UsageError if there is none)."""
    try:
        return _load(name, REGISTRY[name])
    except KeyError:
        raise UsageError(f"unknown autopilot {name!r}; choose one of {', '.join(REGISTRY)}") from None


def make_autopilot(name: str, *, world_size: Cell, **options: object) -> Autopilot:
    """A fresh autopilot instance (one per drone) for a world of `world_size` (`options`: the autopilot's own)."""
    return pilot_class(name)(world_size=world_size, **options)


def make_swarm(name: str, *, world_size: Cell, drones: Sequence[int], least: int = SWARM_MIN) -> SwarmPilot | None:
    """One pilot for the drones numbered `drones` (a swarm's), or None if autopilot `name` has no swarm form or they
    are fewer than `least`."""
    pilot_class(name)  # UsageError if there is no such autopilot
    if name not in SWARMS or len(drones) < least:
        return None
    return _load(name, SWARMS[name])(world_size=world_size, drones=drones)


__all__ = ["REGISTRY", "SWARMS", "SWARM_MIN", "make_autopilot", "make_swarm", "pilot_class", "run_step"]
