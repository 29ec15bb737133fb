"""The observer's rules (the seed's OBS): pure functions deciding which drones die in a turn.

A drone dies when it leaves the world, enters a building cell, shares a cell with another drone
(vertex conflict) or swaps cells with another drone (swap conflict). Causes are checked in that
order and the first that applies is the one recorded.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Set

from dronesim.schema import Cause, Cell


def inside(cell: Cell, size: Cell) -> bool:
    return 0 <= cell[0] < size[0] and 0 <= cell[1] < size[1] and 0 <= cell[2] < size[2]


def deaths(
    size: Cell,
    before: Mapping[str, Cell],
    after: Mapping[str, Cell],
    buildings: Set[Cell],
) -> dict[str, Cause]:
    """Which of the drones alive at the start of the turn die, and why.

    `before` and `after` hold every alive drone's cell at the start and end of the turn (a hovering
    drone has the same cell in both); `buildings` holds the building cells among the `after` cells
    (the environment reports them in its UPD).
    """
    dead: dict[str, Cause] = {}
    order = sorted(after)
    by_cell: dict[Cell, list[str]] = defaultdict(list)
    for d in order:
        cell = after[d]
        if not inside(cell, size):
            dead[d] = Cause.OUTSIDE
        elif cell in buildings:
            dead[d] = Cause.BUILDING
        else:
            by_cell[cell].append(d)
    for ds in by_cell.values():
        if len(ds) > 1:
            for d in ds:
                dead[d] = Cause.VERTEX
    arriving = {after[d]: d for d in order if after[d] != before[d]}
    for d in order:
        src, dst = before[d], after[d]
        other = arriving.get(src)
        if src != dst and other is not None and other != d and before[other] == dst:
            for x in (d, other):
                dead.setdefault(x, Cause.SWAP)
    return dead
