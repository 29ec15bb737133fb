"""The observer's rules (the seed's OBS): pure functions deciding which drones die in a turn.

A drone dies when it leaves the world, enters a building cell, shares a cell with another drone (vertex
conflict) or swaps cells with another drone (swap conflict), the first of these that applies being its cause.
When several drones enter one cell, the last in id order is the one remembered as entering it (swap rule).

`judge` decides for a whole swarm at once, over columns: the engine's observer of many drones. `deaths` is the same
rules drone by drone, over mappings: the reference that tests/test_observer.py holds `judge` to (a property test),
and the observer of a few drones' turn (`deaths_of_moves`: the rules run only when someone may die).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Sequence, Set
from typing import Protocol, TypeVar

import numpy as np

from schema import Cause, Cell
from schema.tables import code_of
from world.grid import in_bounds, inside_rows, linear_rows

_OUTSIDE, _BUILDING, _VERTEX, _SWAP = (code_of(c) for c in (Cause.OUTSIDE, Cause.BUILDING, Cause.VERTEX, Cause.SWAP))
K = TypeVar("K", str, int)  # what `deaths` knows a drone by: its id, or its row
_K = TypeVar("_K", contravariant=True)


class Where(Protocol[_K]):
    """Each drone's cell by what `deaths` knows it by: a mapping, or a list by row."""

    def __getitem__(self, key: _K, /) -> Cell: ...


def judge(size: Cell, before: np.ndarray, after: np.ndarray, building: np.ndarray,
          alive: np.ndarray | None = None) -> np.ndarray:
    """The cause of death of each drone (`Cause` codes, as in a STATUS table; 0 = NONE). `before` and `after`: each
    drone's cell at the start and end of the turn, (n, 3) C-ordered integers, rows in id order; `building`: whether
    its `after` cell is a building; `alive`: the drones alive at the start of the turn (None: every row), the others
    taking no part (cause 0). Every array the rules make has the n rows, whoever is alive or moves: numpy keeps up to
    7 freed buffers of each size under 1 KiB, and masks of a size that changed with each death or each turn's movers
    would pile up there (docs/performance.md, Memory). (A few drones' turn is judged drone by drone:
    `deaths_of_moves`.)"""
    n = len(after)
    rows = np.arange(n)
    live = np.ones(n, bool) if alive is None else alive
    cause = np.zeros(n, np.uint8)
    inside = inside_rows(after, size)
    out = live & ~inside
    hit = live & inside & building
    cause[out] = _OUTSIDE
    cause[hit] = _BUILDING
    # each cell as one integer; a drone outside, in a building or not alive gets a number no other drone has
    key, nowhere = linear_rows(after, size), -1 - rows
    alone = np.where(live & inside & ~hit, key, nowhere)
    order = np.argsort(alone, kind="stable")
    same = alone[order[1:]] == alone[order[:-1]]
    if np.count_nonzero(same):
        cause[order[1:][same]] = cause[order[:-1][same]] = _VERTEX
    moving = live & (after != before).any(axis=1)
    if np.count_nonzero(moving) < 2:
        return cause  # a swap takes two movers
    entering = np.where(moving & inside, key, nowhere)  # outside, or not moving: a cell no drone comes from
    # the drone remembered as entering each cell: the last mover (in id order) whose `after` it is
    entered, first = np.unique(entering[::-1], return_index=True)
    enterer = n - 1 - first
    src = linear_rows(before, size)
    at = np.minimum(np.searchsorted(entered, src), len(entered) - 1)
    other = np.where(moving & (entered[at] == src), enterer[at], -1)  # the mover entering each mover's cell
    swap = (other >= 0) & (other != rows) & (src[other] == entering)  # ... and coming from where it goes
    if np.count_nonzero(swap):
        pair = np.concatenate([rows[swap], other[swap]])
        cause[pair[cause[pair] == 0]] = _SWAP
    return cause


def deaths_of_moves(size: Cell, solid: np.ndarray | memoryview, before: Where[K], after: Mapping[K, Cell],
                    moved: Sequence[K], found: tuple[bool, set[Cell]] | None = None) -> dict[K, Cause]:
    """`deaths`, for drones of which `moved` changed cell (`solid`: the world's buildings, flat in C order), with
    the rules run only if someone may die: one left the world or entered a building, or two ended in one cell or
    swapped cells (most turns, nobody). `found`: whether one of `moved` left the world and the building cells they
    entered, if the caller knows them (None: found here)."""
    if found is None:
        nx, ny, nz = size
        outside, buildings = False, set()
        for d in moved:
            x, y, z = cell = after[d]
            if not (0 <= x < nx and 0 <= y < ny and 0 <= z < nz):
                outside = True
            elif solid[(x * ny + y) * nz + z]:
                buildings.add(cell)
    else:
        outside, buildings = found
    if outside or buildings or len(after) > 1 and _meet(before, after, moved):
        return deaths(size, before, after, buildings)
    return {}


def _meet(before: Where[K], after: Mapping[K, Cell], moved: Sequence[K]) -> bool:
    """Whether two drones end in one cell, or two movers swap cells."""
    if len(set(after.values())) < len(after):
        return True
    entering = {after[d]: d for d in moved}  # (one each: no two end in one cell)
    for d in moved:  # (a loop: a generator's every item costs a call)
        e = entering.get(before[d])
        if e is not None and before[e] == after[d]:
            return True
    return False


def deaths(size: Cell, before: Where[K], after: Mapping[K, Cell], buildings: Set[Cell]) -> dict[K, Cause]:
    """Which of the drones alive at the start of the turn die, and why: the rules drone by drone. `before` and
    `after`: every alive drone's cell at the start and end of the turn (a hovering drone's are the same);
    `buildings`: the building cells among the `after` cells."""
    dead: dict[K, Cause] = {}
    order = sorted(after)
    by_cell: dict[Cell, list[K]] = defaultdict(list)
    for d in order:
        cell = after[d]
        if not in_bounds(cell, size):
            dead[d] = Cause.OUTSIDE
        elif cell in buildings:
            dead[d] = Cause.BUILDING
        else:
            by_cell[cell].append(d)
    dead.update((d, Cause.VERTEX) for ds in by_cell.values() if len(ds) > 1 for d in ds)
    arriving = {after[d]: d for d in order if after[d] != before[d]}
    for d in order:
        src, dst = before[d], after[d]
        other = arriving.get(src)
        if src != dst and other is not None and other != d and before[other] == dst:
            for x in (d, other):
                dead.setdefault(x, Cause.SWAP)
    return dead
