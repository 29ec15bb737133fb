"""The simulator's 3D world, pure: a read-only boolean numpy grid indexed ``grid[x, y, z]``, True on building cells.

Every constructor (`World.generate`, the seed's random city; `from_buildings`, `from_grid`, `load` / `from_json`,
`from_packed`: the MAP message's bits) validates its input, so a `World` that exists is well formed. Bad local
input (arguments, files) raises `UsageError`.
"""

from __future__ import annotations

import json
import operator
import typing
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from schema import Cell, CellInfo, CellKind, UsageError
from schema.messages import AROUND, MAX_CELLS, MAX_COORD, WorldSpec, oversized

from .movingai import read_map, world_grid
from .search import components, levels, padded_cell, padded_steps

#: The JSON file's ``format`` and ``version`` values.
FORMAT = "dronesim-world"
FORMAT_VERSION = 1

#: Metres a cell, where a face maps cells to metres (ROS 2, Foxglove, MCAP, MAVLink) and is not told (--cell-size).
CELL_SIZE_M = 1.0

#: Default generation parameters (they decide the world: not tuning constants).
_DEFAULT_FOOTPRINT = 3
_DEFAULT_GROUND_COVER = 0.25  # expected fraction of ground cells under a building, before rejections
_ATTEMPTS_PER_BUILDING = 4
_CHUNK = 4096

#: Drawing labels (empty, building, target, trail, several drones, legend), by `compact`.
_LABELS = {
    False: ("EPT", "BLK", "TGT", "+++", "!!!", "legend: EPT empty, BLK building, TGT target, +++ trail, Dnn drone, "
            "!!! several drones; row = x, column = y, (0,0) top-left"),
    True: (".", "#", "X", "*", "!", "legend: . empty, # building, X target, * trail, digit = drone (last character "
           "of its id), ! several drones; row = x, column = y, (0,0) top-left"),
}


def inside_rows(cells: np.ndarray, size: Cell) -> np.ndarray:
    """Which rows of an (n, 3) integer array of cells are inside a world of `size` (negative coordinates,
    seen unsigned, are huge: one comparison checks both bounds)."""
    unsigned = cells.view(np.dtype(f"u{cells.itemsize}"))
    return np.asarray((unsigned < np.array(size, unsigned.dtype)).all(axis=1))


def linear_rows(cells: np.ndarray, size: Cell) -> np.ndarray:
    """The index in the C-ordered grid of each row's cell, as int64 (meaningful for inside cells)."""
    _, ny, nz = size
    return (cells[:, 0].astype(np.int64) * ny + cells[:, 1]) * nz + cells[:, 2]


def in_bounds(cell: Sequence[int], size: Cell) -> bool:
    return 0 <= cell[0] < size[0] and 0 <= cell[1] < size[1] and 0 <= cell[2] < size[2]


def pick_cell(rng: np.random.Generator, cells: np.ndarray, taken: np.ndarray) -> int:
    """A cell of `cells` (flat) not `taken`, drawn uniformly from `rng`; -1 if every one is taken."""
    k = len(cells)
    for _ in range(8):  # (most draws: the first try; a crowded component: the cells left, below)
        cell = int(cells[int(rng.random() * k)]) if k else -1
        if cell < 0 or not taken[cell]:
            return cell
    rest = cells[~taken[cells]]
    return int(rest[int(rng.random() * len(rest))]) if len(rest) else -1


def checked_int(value: object, what: str, error: type[UsageError] = UsageError) -> int:
    """`value` as a plain int (numpy integers accepted, bools and floats refused with `error`)."""
    if isinstance(value, bool):
        raise error(f"{what} must be an integer, got {value!r}")
    try:
        return operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        raise error(f"{what} must be an integer, got {value!r}") from None


def _at_least(value: object, what: str, least: int) -> int:
    number = checked_int(value, what)
    if number < least:
        raise UsageError(f"{what} must be >= {least}, got {number}")
    return number


def _cell(value: object, what: str = "cell") -> Cell:
    """`value` as a Cell of three plain ints."""
    try:
        x, y, z = typing.cast(Iterable[object], value)
    except (TypeError, ValueError):  # not iterable, or not 3 items
        raise UsageError(f"{what} must be 3 integers, got {value!r}") from None
    return (checked_int(x, what), checked_int(y, what), checked_int(z, what))


def _size(value: object) -> Cell:
    size = _cell(value, "world size")
    if not all(1 <= s <= MAX_COORD for s in size):
        raise UsageError(f"world sizes must be in 1..{MAX_COORD}, got {size}")
    if size[0] * size[1] * size[2] > MAX_CELLS:  # (before anything of that size is allocated)
        raise UsageError(oversized(size))
    return size


@dataclass(frozen=True, slots=True, kw_only=True)
class Building:
    """The seed's box building: base corner ``(x, y)`` on the ground, `length` cells along x,
    `width` along y, and `height` along z (it fills ``z = 0 .. height - 1``)."""

    x: int
    y: int
    length: int
    width: int
    height: int

    def __post_init__(self) -> None:
        for name, lo in (("x", 0), ("y", 0), ("length", 1), ("width", 1), ("height", 1)):
            value = checked_int(getattr(self, name), f"building {name}")
            if not lo <= value <= MAX_COORD:
                raise UsageError(f"building {name} must be in {lo}..{MAX_COORD}, got {value}")
            object.__setattr__(self, name, value)

    def is_inside(self, cell: Cell) -> bool:
        """The seed's ``isInside``: whether `cell` is one of this building's cells."""
        cx, cy, cz = cell
        return self.x <= cx < self.x + self.length and self.y <= cy < self.y + self.width and 0 <= cz < self.height

    def intersects(self, other: Building) -> bool:
        """The seed's ``intersect``: whether the two boxes share at least one cell (touching faces
        do not count). Both rise from z = 0, so they intersect iff their footprints overlap."""
        return (self.x < other.x + other.length and other.x < self.x + self.length
                and self.y < other.y + other.width and other.y < self.y + self.width)

    def fits_in(self, size: Cell) -> bool:
        return self.x + self.length <= size[0] and self.y + self.width <= size[1] and self.height <= size[2]

    def as_list(self) -> list[int]:
        """``[x, y, length, width, height]``, the JSON form."""
        return [self.x, self.y, self.length, self.width, self.height]


def _heightmap(size: Cell, buildings: tuple[Building, ...]) -> np.ndarray:
    """The (nx, ny) height of the building standing on each ground cell (0: none); `UsageError` if a building
    leaves the world or two intersect."""
    nx, ny, _ = size
    heights = np.zeros((nx, ny), dtype=np.int64)
    owner = np.full((nx, ny), -1, dtype=np.int64)
    for i, b in enumerate(buildings):
        if not isinstance(b, Building):
            raise UsageError(f"building #{i} must be a Building, got {b!r}")
        if not b.fits_in(size):
            raise UsageError(f"building #{i} {b.as_list()} does not fit in a world of size {list(size)}")
        fp = owner[b.x:b.x + b.length, b.y:b.y + b.width]
        if (taken := fp[fp >= 0]).size:
            j = int(taken[0])
            raise UsageError(f"building #{i} {b.as_list()} intersects building #{j} {buildings[j].as_list()}")
        fp[...] = i
        heights[b.x:b.x + b.length, b.y:b.y + b.width] = b.height
    return heights


def _fill(heights: np.ndarray, nz: int) -> np.ndarray:
    """The boolean grid of a heightmap: cell (x, y, z) is building iff z < heights[x, y]."""
    return np.arange(nz)[None, None, :] < heights[:, :, None]


def _frozen(grid: np.ndarray, *, fresh: bool = False) -> np.ndarray:
    """A read-only C-ordered boolean copy of `grid`; with `fresh` (an array nobody else holds), `grid`
    itself when it is one already: a world's array exists once, even while it is being built."""
    if not (fresh and grid.dtype == bool and grid.flags.c_contiguous):
        grid = np.array(grid, dtype=bool, order="C", copy=True)
    grid.flags.writeable = False
    return grid


@dataclass(frozen=True, slots=True, kw_only=True, eq=False, repr=False)
class World:
    """A 3D grid world of size ``(nx, ny, nz)``; `buildings` lists the boxes it was made of (none for a
    world made from a raw grid)."""

    size: Cell
    grid: np.ndarray
    buildings: tuple[Building, ...] = ()

    def __post_init__(self) -> None:
        size = _size(self.size)
        object.__setattr__(self, "size", size)
        grid = self.grid
        if not isinstance(grid, np.ndarray) or grid.dtype != np.bool_:
            raise UsageError("the world grid must be a boolean numpy array")
        if grid.shape != size:
            raise UsageError(f"the world grid has shape {grid.shape}, expected {size}")
        buildings = tuple(self.buildings)
        object.__setattr__(self, "buildings", buildings)
        if buildings and not np.array_equal(_fill(_heightmap(size, buildings), size[2]), grid):
            raise UsageError("the world grid does not match its buildings")
        if grid.flags.writeable or not grid.flags.c_contiguous or grid.base is not None:
            object.__setattr__(self, "grid", _frozen(grid))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, World):
            return NotImplemented
        return self.size == other.size and self.buildings == other.buildings and np.array_equal(self.grid, other.grid)

    def __hash__(self) -> int:
        return hash((self.size, self.buildings, self.packed()))

    def __repr__(self) -> str:
        return f"World(size={self.size}, buildings={len(self.buildings)}, building_cells={int(self.grid.sum())})"

    @classmethod
    def generate(cls, size: Cell = (10, 10, 10), rng: np.random.Generator | int | None = None, *,
                 count: int | None = None, max_footprint: int | None = None, max_height: int | None = None,
                 keep_free: Iterable[Cell] = ((0, 0, 0),)) -> World:
        """A random city of non-intersecting box buildings; always succeeds, in bounded time.

        Draws only from `rng` (a Generator, or an int seed; default ``default_rng(0)``), so equal
        arguments and seed give the same world. Up to `count` buildings (default: about a quarter
        of the ground covered, e.g. 6 for size 10, 256 for 64x64), each with length and width in
        ``1..max_footprint`` (default 3) and height in ``1..max_height`` (default nz), at a uniform
        position. A candidate that would intersect a placed building or cover a `keep_free` cell
        (the start cells) is dropped; after ``4 * count + 32`` candidates it stops, so a crowded
        world simply gets fewer buildings.
        """
        size = _size(size)
        nx, ny, nz = size
        if not isinstance(rng, np.random.Generator):
            rng = np.random.default_rng(0 if rng is None else checked_int(rng, "seed"))
        footprint = _at_least(_DEFAULT_FOOTPRINT if max_footprint is None else max_footprint, "max_footprint", 1)
        top = _at_least(nz if max_height is None else max_height, "max_height", 1)
        max_len, max_wid, top = min(footprint, nx), min(footprint, ny), min(top, nz)
        if count is None:
            mean_area = (max_len + 1) / 2 * (max_wid + 1) / 2
            count = max(1, round(_DEFAULT_GROUND_COVER * nx * ny / mean_area))
        count = min(_at_least(count, "count", 0), nx * ny)  # every building needs at least one ground cell

        # limit[x, y]: the tallest building allowed on that ground cell; 0 once a building stands
        # there, and at most kz for a keep_free cell (x, y, kz), so that a building stops below it.
        limit = np.full((nx, ny), nz, dtype=np.int32)  # sizes are at most 65536
        for i, kf in enumerate(keep_free):
            kx, ky, kz = kept = _cell(kf, f"keep_free[{i}]")
            if not in_bounds(kept, size):
                raise UsageError(f"keep_free cell {kept} is outside the world {size}")
            limit[kx, ky] = min(limit[kx, ky], kz)

        placed: list[Building] = []
        heights = np.zeros((nx, ny), dtype=np.int32)
        attempts = _ATTEMPTS_PER_BUILDING * count + 32 if count else 0
        while attempts > 0 and len(placed) < count:
            n = min(attempts, _CHUNK)
            attempts -= n
            lengths = rng.integers(1, max_len + 1, size=n)
            widths = rng.integers(1, max_wid + 1, size=n)
            tops = rng.integers(1, top + 1, size=n)
            xs = rng.integers(0, nx - lengths + 1)
            ys = rng.integers(0, ny - widths + 1)
            for x, y, ln, wd, h in zip(xs.tolist(), ys.tolist(), lengths.tolist(), widths.tolist(), tops.tolist()):
                area = limit[x:x + ln, y:y + wd]
                if area.min() < h:
                    continue
                area[...] = 0
                heights[x:x + ln, y:y + wd] = h
                placed.append(Building(x=x, y=y, length=ln, width=wd, height=h))
                if len(placed) == count:
                    break
        return cls._trusted(size, _fill(heights, nz), tuple(placed))

    @classmethod
    def from_buildings(cls, size: Cell, buildings: Iterable[Building]) -> World:
        """A world made of explicit buildings; `UsageError` if one leaves the world or two intersect."""
        size = _size(size)
        buildings = tuple(buildings)
        return cls._trusted(size, _fill(_heightmap(size, buildings), size[2]), buildings)

    @classmethod
    def from_grid(cls, grid: np.ndarray) -> World:
        """A world from any 3D obstacle grid (bool, or integers 0/1), indexed [x, y, z]."""
        arr = np.asarray(grid)
        if arr.ndim != 3:
            raise UsageError(f"a world grid must be 3-dimensional, got shape {arr.shape}")
        if arr.dtype != np.bool_ and not (np.issubdtype(arr.dtype, np.integer) and np.isin(arr, (0, 1)).all()):
            raise UsageError(f"a world grid must be boolean or 0/1 integers, got dtype {arr.dtype}")
        return cls(size=_size(arr.shape), grid=_frozen(arr))

    @classmethod
    def from_packed(cls, size: Cell, data: bytes) -> World:
        """The inverse of `packed`: a raw-grid world from its size and packed bits."""
        size = _size(size)
        n = size[0] * size[1] * size[2]
        if not isinstance(data, (bytes, bytearray, memoryview)) or len(data) != (n + 7) // 8:
            raise UsageError(f"a packed world of size {size} needs {(n + 7) // 8} bytes")
        bits = np.unpackbits(np.frombuffer(bytes(data), dtype=np.uint8), count=n)
        return cls._trusted(size, bits.view(bool).reshape(size), ())  # 0/1 bytes: already booleans

    @classmethod
    def _trusted(cls, size: Cell, grid: np.ndarray, buildings: tuple[Building, ...]) -> World:
        """Without re-validating what the caller guarantees."""
        world = object.__new__(cls)
        object.__setattr__(world, "size", size)
        object.__setattr__(world, "grid", _frozen(grid, fresh=True))
        object.__setattr__(world, "buildings", buildings)
        return world

    def to_json(self) -> dict:
        """The JSON form: ``{"format": "dronesim-world", "version": 1, "size": [nx, ny, nz], ...}``
        with ``"buildings": [[x, y, length, width, height], ...]``, or, for a raw-grid world,
        ``"cells": [[x, y, z], ...]`` listing every building cell (C order)."""
        listed = ({"buildings": [b.as_list() for b in self.buildings]} if self.buildings
                  else {"cells": np.argwhere(self.grid).tolist()})
        return {"format": FORMAT, "version": FORMAT_VERSION, "size": list(self.size), **listed}

    @classmethod
    def from_json(cls, data: dict) -> World:
        """The inverse of `to_json`; `UsageError` naming the problem. Unknown extra keys (a comment) are ignored."""
        if not isinstance(data, dict):
            raise UsageError(f"a world must be a JSON object, got {type(data).__name__}")
        if missing := [key for key in ("format", "version", "size") if key not in data]:
            raise UsageError(f"a world needs the key {missing[0]!r}")
        if data["format"] != FORMAT:
            raise UsageError(f"format must be {FORMAT!r}, got {data['format']!r}")
        if type(data["version"]) is not int or data["version"] != FORMAT_VERSION:
            raise UsageError(f"unsupported world version {data['version']!r} (this build reads {FORMAT_VERSION})")
        size = _size(_json_ints(data["size"], 3, "size"))
        if ("buildings" in data) == ("cells" in data):
            raise UsageError("a world needs exactly one of the keys 'buildings' and 'cells'")
        key = "buildings" if "buildings" in data else "cells"
        if not isinstance(data[key], list):
            raise UsageError(f"{key} must be a list, got {type(data[key]).__name__}")
        if key == "buildings":
            buildings = []
            for i, item in enumerate(data[key]):
                x, y, ln, wd, h = _json_ints(item, 5, f"buildings[{i}]")
                buildings.append(Building(x=x, y=y, length=ln, width=wd, height=h))
            return cls.from_buildings(size, buildings)
        grid = np.zeros(size, dtype=bool)
        for i, item in enumerate(data[key]):
            cell = _json_ints(item, 3, f"cells[{i}]")
            if not in_bounds(cell, size):
                raise UsageError(f"cells[{i}] {cell} is outside the world of size {list(size)}")
            grid[tuple(cell)] = True
        return cls._trusted(size, grid, ())

    @classmethod
    def load(cls, path: str | Path) -> World:
        """Read a world file (see `to_json`), or a MovingAI .map (a world 1 cell high, world/movingai.py);
        `UsageError` if unreadable or invalid."""
        try:
            text = Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise UsageError(f"cannot read world file {str(path)!r}: {exc}") from None
        movingai = Path(path).suffix == ".map"
        try:
            data = None if movingai else json.loads(text)
        except (ValueError, RecursionError) as exc:  # (not JSON, an integer of 4300 digits, nested too deeply)
            raise UsageError(f"world file {str(path)!r} is not valid JSON: {json_problem(exc)}") from None
        try:
            return cls.from_grid(world_grid(read_map(text))) if movingai else cls.from_json(data)  # type: ignore[arg-type]
        except UsageError as exc:
            raise UsageError(f"world file {str(path)!r}: {exc}") from None

    def save(self, path: str | Path) -> None:
        """Write the world file, one building (or cell) per line; `UsageError` if unwritable."""
        *head, (key, items) = self.to_json().items()  # (the list comes last)
        rows = ",\n".join(f"  {json.dumps(item)}" for item in items)
        body = f"[\n{rows}\n]" if rows else "[]"
        text = f'{json.dumps(dict(head))[:-1]}, "{key}": {body}}}\n'
        try:
            Path(path).write_text(text, encoding="utf-8")
        except OSError as exc:
            raise UsageError(f"cannot write world file {str(path)!r}: {exc}") from None

    def contains(self, cell: Cell) -> bool:
        return in_bounds(cell, self.size)

    def is_building(self, cell: Cell) -> bool:
        """Whether `cell` is a building cell (False outside the world)."""
        return self.contains(cell) and bool(self.grid[cell[0], cell[1], cell[2]])

    def what_inside(self, cell: Cell, occupants: Mapping[Cell, tuple[str, ...]] = {}) -> CellInfo:
        """The seed's ``whatInside``: OUTSIDE beyond the bounds, else BUILDING or EMPTY, with the
        drones `occupants` places in that cell (sorted), whatever the kind."""
        cell = _cell(cell)
        kind = CellKind.OUTSIDE if not self.contains(cell) else CellKind.BUILDING if self.grid[cell] else CellKind.EMPTY
        return CellInfo(pos=cell, kind=kind, drones=tuple(sorted(occupants.get(cell, ()))))

    def free_neighbours(self, cell: Cell) -> tuple[Cell, ...]:
        """The in-bounds, non-building 6-neighbours of `cell`, in the order +x, -x, +y, -y, +z, -z."""
        x, y, z = _cell(cell)
        around = ((x + dx, y + dy, z + dz) for dx, dy, dz in AROUND)
        return tuple(n for n in around if self.contains(n) and not self.grid[n])

    def shortest_path_length(self, start: Cell, goal: Cell) -> int | None:
        """The number of 6-connected moves from `start` to `goal` through non-building cells,
        knowing the whole map; None if either cell is outside the world or a building, or if
        `goal` cannot be reached. Breadth-first, one numpy step per distance level."""
        start, goal = _cell(start, "start"), _cell(goal, "goal")
        if not self.contains(start) or not self.contains(goal) or self.grid[start] or self.grid[goal]:
            return None
        unseen = np.pad(~self.grid, 1).ravel()  # (padded: a cell's neighbours need no bounds checks)
        _, _, steps = padded_steps(self.size)
        g = padded_cell(goal, self.size)
        for distance, _ in enumerate(levels(unseen, [padded_cell(start, self.size)], steps)):
            if not unseen[g]:
                return distance
        return None

    def packed(self) -> bytes:
        """The grid as the MAP message's packed bits."""
        return np.packbits(self.grid.ravel(order="C")).tobytes()

    def draw(self, drones: Mapping[str, Cell] = {}, *, targets: Mapping[str, Cell] = {}, trail: Iterable[Cell] = (),
             floors: Iterable[int] | None = None, compact: bool | None = None) -> str:
        """The seed's ``drawEnv``: the `floors` (default all), bottom-up, each a block headed ``z = k`` with
        one row per x and one column per y, blocks separated by a blank line, then the legend (`_LABELS`).
        Full mode (default when nx and ny are <= 16): the seed's trigrams, a drone's id (columns widen for
        ids longer than 3 characters); compact mode: one character per cell, a drone's last id character.
        Drones hide targets, which hide trails, which hide buildings; cells outside the world are not drawn.
        """
        nx, ny, nz = self.size
        compact = nx > 16 or ny > 16 if compact is None else compact
        zs = list(range(nz)) if floors is None else sorted({checked_int(z, "floor") for z in floors})
        if bad := [z for z in zs if not 0 <= z < nz]:
            raise UsageError(f"floors {bad} are outside 0..{nz - 1}")

        # marks[z][(x, y)] = label, written in increasing priority.
        marks: dict[int, dict[tuple[int, int], str]] = {}

        def mark(cells: Iterable[Cell], label: str) -> None:
            for c in cells:
                x, y, z = _cell(c)
                if self.contains((x, y, z)):
                    marks.setdefault(z, {})[(x, y)] = label

        empty, block, target, trailed, several, legend = _LABELS[compact]
        mark(trail, trailed)
        mark(targets.values(), target)
        crowd: dict[Cell, list[str]] = {}
        for name, c in drones.items():
            crowd.setdefault(_cell(c, f"position of {name}"), []).append(str(name))
        for c, names in crowd.items():
            alone = (names[0][-1:] or "?") if compact else names[0]
            mark((c,), several if len(names) > 1 else alone)

        width = 1 if compact else max([3, *(len(v) for m in marks.values() for v in m.values())])
        blocks = []
        for z in zs:
            cells = np.where(self.grid[:, :, z], block, empty).astype(f"<U{width}")
            for (x, y), label in marks.get(z, {}).items():
                cells[x, y] = label
            rows = [("" if compact else " ").join(s.ljust(width) for s in row).rstrip() for row in cells.tolist()]
            blocks.append("\n".join([f"z = {z}", *rows]))
        return "\n\n".join([*blocks, legend])


class Regions:
    """The components of a world's free cells (6-connected), labelled as cells in them are asked about
    (`labels`), with each one's cells (`members`): where a drone at a cell can go."""

    def __init__(self, world: World) -> None:
        self.world = world
        self.label = np.full(world.grid.size, -1, np.int64)  # each cell's component, -1: not reached yet (`components`)
        self._members: dict[int, np.ndarray] = {}

    def labels(self, flat: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """The component of each cell (flat cells `flat`, the same as an (n, 3) array `cells`), labelling new ones
        (-1: a building)."""
        comp = self.label[flat]
        if np.count_nonzero(comp < 0):
            components(self.world.grid, cells[comp < 0], self.label)
            comp = self.label[flat]
        return comp

    def members(self, comp: int) -> np.ndarray:
        """The flat cells of component `comp` (ascending)."""
        cells = self._members.get(comp)
        if cells is None:
            cells = self._members[comp] = np.flatnonzero(self.label == comp)
        return cells


def json_problem(exc: Exception) -> str:
    """What is wrong with a file `json.loads` refused: its ValueError (not JSON; an integer longer than Python
    converts, 4300 digits), or its RecursionError (arrays or objects nested too deeply), said in one line."""
    if isinstance(exc, RecursionError):
        return "its arrays or objects are nested too deeply"
    return str(exc).split("; use sys.set_int_max_str_digits")[0]  # (an integer's: not the advice that follows)


def _json_ints(value: object, n: int, what: str) -> list[int]:
    if not isinstance(value, list) or len(value) != n or any(type(v) is not int for v in value):
        raise UsageError(f"{what} must be a list of {n} integers, got {value!r}")
    return value


def build_world(spec: WorldSpec, starts: Iterable[Cell]) -> World:
    """The world a `WorldSpec` describes: the given cells, or generated from its seed keeping the starts free."""
    if spec.cells:
        return World.from_packed(spec.size, spec.cells)
    return World.generate(spec.size, np.random.default_rng(spec.seed), keep_free=tuple(starts))
