"""The seed's V1 "dumb" drone (seed spec, section 3.4).

Every turn it steps to the 6-connected neighbour closest (Euclidean) to its target and never senses anything: it can
fly straight into a building and die, exactly like the seed's C drone.

Choices the seed leaves open, fixed here:

* Ties between equally close neighbours are broken by `AROUND` order (schema.messages): +x, -x, +y, -y, +z, -z (the
  first one in that order wins).
* Only in-bounds neighbours are candidates, so the drone never leaves the world. Since the target lies inside the
  world, the closest in-bounds neighbour is always strictly closer than the current cell; a world of a single cell
  leaves no candidate and the drone hovers.
* No target: hover. On the target: stay and report ``Note.REACHED``.
"""

from __future__ import annotations

from typing import ClassVar

from schema import Cell, Note
from schema.messages import AROUND
from world.grid import in_bounds

from .base import Decision, Sensing


class V1Pilot:
    """Greedy, blind: one step towards the target per turn, no ASK ever."""

    name: ClassVar[str] = "v1"
    cooperative: ClassVar[bool] = False
    senses: ClassVar[bool] = False  # it flies blind

    def __init__(self, *, world_size: Cell) -> None:
        self.world_size: Cell = tuple(world_size)  # type: ignore[assignment]

    def step(self, pos: Cell, target: Cell | None) -> Sensing:
        """A generator that returns its decision before any yield: zero ASK round trips."""
        if target is None:
            return Decision(pos=pos)
        if pos == target:
            return Decision(pos=pos, note=Note.REACHED)
        x, y, z = pos
        candidates = [c for c in ((x + dx, y + dy, z + dz) for dx, dy, dz in AROUND) if in_bounds(c, self.world_size)]
        # min() keeps the first of equal keys, i.e. the AROUND order breaks ties. Squared Euclidean distance:
        # the same order as the distance, exact in integers.
        return Decision(pos=min(candidates, key=lambda c: sum((a - b) ** 2 for a, b in zip(c, target)), default=pos))
        yield  # unreachable; makes `step` a generator function, as the interface requires
