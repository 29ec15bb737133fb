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


def make_autopilot(name: str, *, world_size: Cell) -> Autopilot:
    """A fresh autopilot instance (one per drone) for a world of `world_size`."""
    try:
        module, cls = REGISTRY[name]
    except KeyError:
        raise UsageError(f"unknown autopilot {name!r}; choose one of {', '.join(REGISTRY)}") from None
    pilot_cls = getattr(importlib.import_module(f"{__name__}.{module}"), cls)
    return pilot_cls(world_size=world_size)


__all__ = ["Autopilot", "Decision", "Oracle", "Sensing", "REGISTRY", "fly_round", "make_autopilot", "run_step"]
