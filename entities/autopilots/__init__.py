"""Autopilots, selectable by name (``--autopilot v1|seed|dstar``)."""

from __future__ import annotations

import importlib

from dronesim.schema import Cell, UsageError

from .base import Autopilot, Decision, Oracle, Sensing, fly_round, run_step

#: name -> (module, class). Modules are imported on first use.
REGISTRY: dict[str, tuple[str, str]] = {
    "v1": ("v1", "V1Pilot"),
    "seed": ("seed", "SeedPilot"),
    "dstar": ("dstar", "DStarPilot"),
}


def pilot_class(name: str) -> type[Autopilot]:
    """The autopilot class registered as `name` (UsageError if there is none)."""
    try:
        module, cls = REGISTRY[name]
    except KeyError:
        raise UsageError(f"unknown autopilot {name!r}; choose one of {', '.join(REGISTRY)}") from None
    return getattr(importlib.import_module(f"{__name__}.{module}"), cls)


def make_autopilot(name: str, *, world_size: Cell) -> Autopilot:
    """A fresh autopilot instance (one per drone) for a world of `world_size`."""
    return pilot_class(name)(world_size=world_size)


__all__ = ["Autopilot", "Decision", "Oracle", "Sensing", "REGISTRY", "fly_round", "make_autopilot", "pilot_class", "run_step"]
