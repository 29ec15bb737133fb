"""Searches over the world's cells: the one home of every breadth-first search the simulator runs.

The cells are numbered on the world padded by one cell on every side (a border that is never open), so that a
cell's 6 neighbours are additions of fixed offsets (`padded_steps`, in AROUND order) that need no bounds checks.
Two forms of one search:

- `levels`: in array operations, one level a step, over a flat grid of open cells that it closes as it visits
  them. For searches of a whole region: the world's components (`components`: an RL episode's layout, a lifelong
  game's tasks), the search's distance tables (coordinator/lacam.py), a shortest path (`World.shortest_path_length`),
  MovingAI's optimal lengths and connected maps (world/movingai.py).
- `breadth_first`: in Python, over the cells it reaches, stopping once it has reached the ones it needs. For small
  searches on a map of its own: a D* drone's way round another (entities/autopilots/dstar.py).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence

import numpy as np

from schema import Cell
from schema.messages import AROUND
from schema.tables import RANK_STEPS

#: A drone's moves in a turn, as steps (dx, dy, dz): staying, or one cell along an axis (6-connectivity).
STEPS = frozenset(RANK_STEPS)


def is_step(src: Sequence[int], dst: Sequence[int]) -> bool:
    """Whether a drone may move from cell `src` to `dst` in a turn (`STEPS`)."""
    return (dst[0] - src[0], dst[1] - src[1], dst[2] - src[2]) in STEPS


def step_lengths(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """`is_step` of rows of cells ((n, 3) arrays), as the moves' lengths: a move is a step where it is at most 1."""
    return np.abs(dst.astype(np.int64) - src).sum(axis=1)


def padded_steps(size: Cell) -> tuple[int, int, tuple[int, ...]]:
    """For a C-ordered grid of `size` with a border of one cell on every side (so that a cell's neighbours
    need no bounds checks): the strides of x and y, and each neighbour's offset, in AROUND order."""
    sy = size[2] + 2
    sx = (size[1] + 2) * sy
    return sx, sy, tuple(dx * sx + dy * sy + dz for dx, dy, dz in AROUND)


def padded_cell(cell: Sequence[int], size: Cell) -> int:
    """A cell's number on the padded grid (`padded_steps`)."""
    sx, sy, _ = padded_steps(size)
    return (cell[0] + 1) * sx + (cell[1] + 1) * sy + cell[2] + 1


def flat_cells(cells: np.ndarray, size: Cell) -> np.ndarray:
    """Cells ((n, 3), each coordinate in -1..size: one step off the world at most) as one integer each, on
    the world padded by one cell each side, so that a step is an addition (`padded_steps`)."""
    _, Y, Z = size
    c = cells.astype(np.int64) + 1
    return (c[:, 0] * (Y + 2) + c[:, 1]) * (Z + 2) + c[:, 2]


def cells_of(flat: np.ndarray, size: Cell) -> np.ndarray:
    """`flat_cells` undone: (n, 3) int32."""
    _, Y, Z = size
    xy, z = np.divmod(flat, Z + 2)
    x, y = np.divmod(xy, Y + 2)
    return (np.stack([x, y, z], axis=1) - 1).astype(np.int32)


def levels(open_: np.ndarray, sources: Iterable[int], steps: Sequence[int] | np.ndarray) -> Iterator[np.ndarray]:
    """The cells reached from `sources` (numbered on a padded grid, open), a level at a time: the sources, then
    each level's new cells (ascending), through the cells still open (True) in the flat bool array `open_`, which
    the search closes as it visits them (each cell is visited once; a caller stopping early leaves the rest open)."""
    frontier = np.fromiter(sources, np.int64)
    open_[frontier] = False
    offsets = np.asarray(steps, np.int64)
    while frontier.size:
        yield frontier
        nxt = (frontier[:, None] + offsets).ravel()
        frontier = np.unique(nxt[open_[nxt]])
        open_[frontier] = False


def components(grid: np.ndarray, seeds: np.ndarray, label: np.ndarray | None = None) -> np.ndarray:
    """The label of every cell (C order, -1: a building or a free cell reached from no seed): the free cells
    6-connected to each seed cell ((n, 3) array), labelled by the first seed of their component. `label`: the
    labels found so far (modified: a seed in a labelled component costs nothing; a new component's label is
    one more than the largest so far)."""
    free = np.pad(~grid, 1)  # a blocked border: flat neighbours need no bounds checks
    sx, sy, offsets = padded_steps(grid.shape)
    nx, ny, nz = grid.shape
    if label is None:
        label = np.full(grid.size, -1, np.int64)
    padded: np.ndarray | None = None  # (the padded labels: made once a new component is searched)
    for x, y, z in seeds.tolist():
        if label[(x * ny + y) * nz + z] >= 0 or grid[x, y, z]:
            continue  # in a component already labelled (or a building)
        if padded is None:
            padded = np.pad(label.reshape(grid.shape), 1, constant_values=-1).ravel()
            open_ = free.ravel() & (padded < 0)
        mark = int(label.max()) + 1
        for cells in levels(open_, [(x + 1) * sx + (y + 1) * sy + z + 1], offsets):
            padded[cells] = mark
        label[:] = padded.reshape(free.shape)[1:-1, 1:-1, 1:-1].ravel()
    return label


def breadth_first(cells: Sequence[int], wall: int, steps: Sequence[int], source: int, *, closed: int = -1,
                  until: Iterable[int] | None = None) -> dict[int, int]:
    """Each cell reached from `source` (numbered on a padded grid) and its distance, in Python: through the cells
    of `cells` (a map's, one value a cell) that are not `wall`, nor `closed`. With `until`, the level on which the
    last of those cells is reached (other than `source`) is the last; without, every cell reachable is."""
    dist = {source: 0}
    frontier = [source]
    need = None if until is None else set(until)
    while frontier and (need is None or need):
        nxt: list[int] = []
        for c in frontier:
            dc = dist[c] + 1
            for d in steps:
                p = c + d
                if p in dist or p == closed or cells[p] == wall:
                    continue
                dist[p] = dc
                if need is not None:
                    need.discard(p)
                nxt.append(p)
        frontier = nxt
    return dist
