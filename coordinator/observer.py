"""The observer's rules (the seed's OBS): pure functions deciding which drones die in a turn.

A drone dies when it leaves the world, enters a building cell, shares a cell with another drone
(vertex conflict) or swaps cells with another drone (swap conflict). Causes are checked in that
order and the first that applies is the one recorded.

`judge` decides for a whole swarm at once, over columns (numpy arrays, one row per alive drone, in id
order); `deaths` says the same over mappings from drone ids to cells.
"""

from __future__ import annotations

from collections.abc import Mapping, Set

import numpy as np

from dronesim.schema import Cause, Cell
from dronesim.schema.tables import code_of

_OUTSIDE, _BUILDING, _VERTEX, _SWAP = (code_of(c) for c in (Cause.OUTSIDE, Cause.BUILDING, Cause.VERTEX, Cause.SWAP))
_CAUSES = tuple(Cause)


def inside(cell: Cell, size: Cell) -> bool:
    return 0 <= cell[0] < size[0] and 0 <= cell[1] < size[1] and 0 <= cell[2] < size[2]


def inside_rows(cells: np.ndarray, size: Cell) -> np.ndarray:
    """Which rows of an (n, 3) array of cells are inside the world."""
    return ((cells >= 0) & (cells < np.asarray(size))).all(axis=1)


def judge(size: Cell, before: np.ndarray, after: np.ndarray, building: np.ndarray) -> np.ndarray:
    """The cause of death of each alive drone (`Cause` codes, as in a STATUS table; 0 = NONE).

    `before` and `after`: each alive drone's cell at the start and end of the turn, (n, 3), rows in id
    order (the priority order: when several drones enter one cell, the last in id order is the one
    remembered as entering it, for the swap rule); `building`: whether its `after` cell is a building.
    """
    n = len(after)
    cause = np.zeros(n, np.uint8)
    if not n:
        return cause
    out = ~inside_rows(after, size)
    cause[out] = _OUTSIDE
    hit = building & ~out
    cause[hit] = _BUILDING
    free = ~(out | hit)
    nx, ny, nz = size
    # cells as one integer each (outside cells get a number of their own that no inside cell has)
    key = np.where(out, -1 - np.arange(n), (after[:, 0] * ny + after[:, 1]) * nz + after[:, 2]).astype(np.int64)
    src = ((before[:, 0] * ny + before[:, 1]) * nz + before[:, 2]).astype(np.int64)
    cells, inverse, counts = np.unique(np.where(free, key, -1 - n - np.arange(n)), return_inverse=True,
                                       return_counts=True)
    cause[free & (counts[inverse] > 1)] = _VERTEX
    moved = np.flatnonzero((after != before).any(axis=1))
    if len(moved):
        # the drone remembered as entering each cell: the last mover (in id order) whose `after` it is
        rev = moved[::-1]
        entered, first = np.unique(key[rev], return_index=True)
        enterer = rev[first]
        at = np.searchsorted(entered, src[moved])
        at[at == len(entered)] = 0
        other = np.where(entered[at] == src[moved], enterer[at], -1)
        swap = (other >= 0) & (other != moved)
        swap[swap] = (before[other[swap]] == after[moved[swap]]).all(axis=1)
        pair = np.concatenate([moved[swap], other[swap]])
        pair = pair[cause[pair] == 0]
        cause[pair] = _SWAP
    return cause


def deaths(
    size: Cell,
    before: Mapping[str, Cell],
    after: Mapping[str, Cell],
    buildings: Set[Cell],
) -> dict[str, Cause]:
    """Which of the drones alive at the start of the turn die, and why (`judge` over mappings).

    `before` and `after` hold every alive drone's cell at the start and end of the turn (a hovering
    drone has the same cell in both); `buildings` holds the building cells among the `after` cells
    (the environment reports them in its UPD).
    """
    order = sorted(after)
    if not order:
        return {}
    b = np.array([before[d] for d in order], np.int64)
    a = np.array([after[d] for d in order], np.int64)
    cause = judge(size, b, a, np.array([after[d] in buildings for d in order], bool))
    return {order[i]: _CAUSES[c] for i, c in enumerate(cause.tolist()) if c}
