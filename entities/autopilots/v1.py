"""The seed's V1 "dumb" drone (seed spec, section 3.4).

Every turn it steps to the 6-connected neighbour closest (Euclidean) to its target and never
senses anything: it can fly straight into a building and die, exactly like the seed's C drone.

Choices the seed leaves open, fixed here:

* Ties between equally close neighbours are broken by `AROUND` order (schema.messages):
  +x, -x, +y, -y, +z, -z (the first one in that order wins).
* Only in-bounds neighbours are candidates, so the drone never leaves the world. Since the target
  lies inside the world, the closest in-bounds neighbour is always strictly closer than the
  current cell; a world of a single cell leaves no candidate and the drone hovers.
* No target: hover. On the target: stay and report ``Note.REACHED``.
"""

from __future__ import annotations

from typing import ClassVar

from schema import Cell, Note

from .base import Decision, Sensing, in_bounds, neighbours6


def _dist2(a: Cell, b: Cell) -> int:
    """Squared Euclidean distance: same ordering as the distance, exact in integers."""
    return (a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2


class V1Pilot:
    """Greedy, blind: one step towards the target per turn, no ASK ever."""

    name: ClassVar[str] = "v1"
    cooperative: ClassVar[bool] = False
    senses: ClassVar[bool] = False  # it flies blind

    def __init__(self, *, world_size: Cell) -> None:
        self.world_size: Cell = tuple(world_size)  # type: ignore[assignment]

    def decide(self, pos: Cell, target: Cell | None) -> Decision:
        """This turn's decision, computed without sensing."""
        if target is None:
            return Decision(pos=pos)
        if pos == target:
            return Decision(pos=pos, note=Note.REACHED)
        candidates = [c for c in neighbours6(pos) if in_bounds(c, self.world_size)]
        if not candidates:
            return Decision(pos=pos)
        # min() keeps the first of equal keys, i.e. the AROUND order breaks ties.
        return Decision(pos=min(candidates, key=lambda c: _dist2(c, target)))

    def step(self, pos: Cell, target: Cell | None) -> Sensing:
        """A generator that returns its decision before any yield: zero ASK round trips."""
        return self.decide(pos, target)
        yield  # unreachable; makes `step` a generator function, as the interface requires
