"""The MovingAI multi-agent path finding formats (Sturtevant, "Benchmarks for Grid-Based Pathfinding", and
Stern et al., "Multi-Agent Pathfinding: Definitions, Variants, and Benchmarks", SoCS 2019), read and written,
and generators of the standard map families in them. Pure: text in, text out, no files, no network.

``.map``::

    type octile
    height H
    width W
    map
    <H rows of W characters: '.' (also 'G', 'S') free; '@', 'O', 'T', 'W' blocked>

is a world 1 cell high: the character in row y, column x is the cell (x, y, 0).

``.scen``::

    version 1
    <bucket> TAB <map> TAB <width> TAB <height> TAB <start x> TAB <start y> TAB <goal x> TAB <goal y> TAB <optimal>

one agent a line (x is the column, y the row); the optimal length is the single-agent shortest path's, in
moves (4-connected, as our drones on one floor).

Generators (`FAMILIES`): the benchmark's standard 32 x 32 families, rebuilt here since nothing can be
downloaded: ``empty-32-32``, ``random-32-32-10`` and ``-20`` (that share of cells blocked at random),
``maze-32-32-2`` (a maze of corridors 2 cells wide), ``room-32-32-4`` (rooms of 3 x 3 cells behind walls,
doors between them: a spanning tree and a few more) and ``warehouse-32-32`` (rows of shelves with aisles
between and a free border): seeded, deterministic, every free cell connected to every other (anything cut
off is blocked). `scenario` draws agents' starts and goals on them, as the benchmark's random scenarios do.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np

from schema import UsageError
from schema.messages import MAX_CELLS

from .search import components, levels, padded_cell, padded_steps

#: Characters of a .map: free, and blocked (out of bounds, trees, water are all blocked for a drone).
FREE_CHARS = frozenset(".GS")
BLOCKED_CHARS = frozenset("@OTW")


# --------------------------------------------------------------------------- .map


def read_map(text: str) -> np.ndarray:
    """A .map's blocked cells: a bool array indexed [x, y] (width x height). UsageError if malformed."""
    lines = text.splitlines()
    header: dict[str, str] = {}
    k = 0
    while k < len(lines) and lines[k].strip() != "map":
        parts = lines[k].split()
        if len(parts) == 2:
            header[parts[0].lower()] = parts[1]
        elif parts:
            raise UsageError(f".map line {k + 1}: expected 'key value' or 'map', got {lines[k]!r:.60}")
        k += 1
    if k == len(lines):
        raise UsageError(".map: no 'map' line")
    if header.get("type") != "octile":
        raise UsageError(f".map: type must be octile, got {header.get('type')!r}")
    try:
        height, width = int(header["height"]), int(header["width"])
    except (KeyError, ValueError):
        raise UsageError(".map: needs integer 'height' and 'width'") from None
    if not (1 <= height <= 65536 and 1 <= width <= 65536):
        raise UsageError(f".map: {width} x {height} is not a size")
    if width * height > MAX_CELLS:  # (before its grid is allocated)
        raise UsageError(f".map: {width} x {height} exceeds the {MAX_CELLS} cells a world may have")
    rows = lines[k + 1:k + 1 + height]
    if len(rows) != height:
        raise UsageError(f".map: {height} rows announced, {len(rows)} given")
    grid = np.zeros((width, height), bool)
    for y, row in enumerate(rows):
        row = row.rstrip("\r")
        if len(row) != width:
            raise UsageError(f".map row {y}: {len(row)} characters, width is {width}")
        if bad := set(row) - FREE_CHARS - BLOCKED_CHARS:
            raise UsageError(f".map row {y}: unknown characters {''.join(sorted(bad))!r}")
        grid[:, y] = [c in BLOCKED_CHARS for c in row]
    return grid


def write_map(blocked: np.ndarray) -> str:
    """The .map text of a bool grid indexed [x, y] ('.' free, '@' blocked)."""
    width, height = blocked.shape
    rows = ("".join("@" if b else "." for b in blocked[:, y].tolist()) for y in range(height))
    return f"type octile\nheight {height}\nwidth {width}\nmap\n" + "\n".join(rows) + "\n"


def world_grid(blocked: np.ndarray) -> np.ndarray:
    """A .map's grid as a world's, 1 cell high: [x, y, 0]."""
    return blocked[:, :, None].copy()


# --------------------------------------------------------------------------- .scen


@dataclass(frozen=True, slots=True)
class Agent:
    """One line of a .scen."""

    bucket: int
    map: str
    width: int
    height: int
    start: tuple[int, int]
    goal: tuple[int, int]
    optimal: float


def read_scen(text: str) -> list[Agent]:
    """A .scen's agents, in order. UsageError if malformed."""
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if not lines or lines[0].split() not in (["version", "1"], ["version", "1.0"]):
        raise UsageError(".scen: the first line must be 'version 1'")
    agents = []
    for n, line in enumerate(lines[1:], 2):
        parts = line.rstrip("\r").split("\t")
        if len(parts) != 9:
            parts = line.split()
        if len(parts) != 9:
            raise UsageError(f".scen line {n}: 9 tab-separated fields expected, got {len(parts)}")
        try:
            bucket, width, height, sx, sy, gx, gy = (int(parts[i]) for i in (0, 2, 3, 4, 5, 6, 7))
            optimal = float(parts[8])
        except ValueError:
            raise UsageError(f".scen line {n}: numbers expected, got {line!r:.80}") from None
        for x, y in ((sx, sy), (gx, gy)):
            if not (0 <= x < width and 0 <= y < height):
                raise UsageError(f".scen line {n}: ({x}, {y}) is outside the {width} x {height} map")
        agents.append(Agent(bucket, parts[1], width, height, (sx, sy), (gx, gy), optimal))
    return agents


def write_scen(agents: Iterable[Agent]) -> str:
    """The .scen text of `agents` (the optimal length written as an integer when it is one)."""
    out = ["version 1"]
    for a in agents:
        opt = f"{a.optimal:.8g}" if a.optimal != int(a.optimal) else str(int(a.optimal))
        out.append("\t".join(map(str, (a.bucket, a.map, a.width, a.height, *a.start, *a.goal))) + f"\t{opt}")
    return "\n".join(out) + "\n"


def distances(blocked: np.ndarray, source: tuple[int, int]) -> np.ndarray:
    """Moves from `source` to every cell of a [x, y] grid, 4-connected (-1: unreachable or blocked): a world 1 cell
    high's breadth-first search (`world.search.levels`: its ±z neighbours are the border, never open)."""
    width, height = blocked.shape
    dist = np.full(width * height, -1, np.int64)
    if blocked[source]:
        return dist.reshape(width, height)
    open_ = np.pad(~blocked[:, :, None], 1).ravel()
    size = (width, height, 1)
    _, _, steps = padded_steps(size)
    index = np.full(len(open_), -1, np.int64)  # each padded cell's cell of the map (row-major [x, y])
    index.reshape(width + 2, height + 2, 3)[1:-1, 1:-1, 1] = np.arange(width * height).reshape(width, height)
    for d, reached in enumerate(levels(open_, [padded_cell((*source, 0), size)], steps)):
        dist[index[reached]] = d
    return dist.reshape(width, height)


def scenario(blocked: np.ndarray, agents: int, seed: int, map_name: str = "") -> list[Agent]:
    """`agents` agents with distinct random free starts and distinct random free goals, each goal reachable
    from its start (the generators connect every free cell), in buckets of 10 by optimal length as the
    MovingAI random scenarios are. UsageError if the map has fewer free cells than agents."""
    width, height = blocked.shape
    free = np.argwhere(~blocked)
    if len(free) < agents:
        raise UsageError(f"{agents} agents do not fit in {len(free)} free cells")
    rng = np.random.default_rng(seed)
    starts = free[rng.permutation(len(free))[:agents]]
    goals = free[rng.permutation(len(free))[:agents]]
    out = []
    for (sx, sy), (gx, gy) in zip(starts.tolist(), goals.tolist()):
        d = int(distances(blocked, (sx, sy))[gx, gy])
        if d < 0:
            raise UsageError(f"({gx}, {gy}) cannot be reached from ({sx}, {sy}): the map is not connected")
        out.append(Agent(d // 4, map_name, width, height, (sx, sy), (gx, gy), float(d)))
    return out


# --------------------------------------------------------------------------- generators


def _connected(blocked: np.ndarray) -> np.ndarray:
    """`blocked` with every free cell outside the largest 4-connected free region blocked too."""
    free = np.argwhere(~blocked)
    if not len(free):
        return blocked
    label = components(blocked[:, :, None], np.column_stack([free, np.zeros(len(free), np.int64)]))
    sizes = np.bincount(label[label >= 0])
    out = blocked.copy()
    out[(label.reshape(blocked.shape) != int(np.argmax(sizes))) & ~blocked] = True
    return out


def empty(size: int, rng: np.random.Generator) -> np.ndarray:
    return np.zeros((size, size), bool)


def random_map(share: float, size: int, rng: np.random.Generator) -> np.ndarray:
    blocked = np.zeros(size * size, bool)
    blocked[rng.permutation(size * size)[:round(share * size * size)]] = True
    return _connected(blocked.reshape(size, size))


def maze(width: int, size: int, rng: np.random.Generator) -> np.ndarray:
    """Corridors `width` cells wide between walls 1 cell thick (a depth-first maze: a spanning tree)."""
    pitch = width + 1
    n = (size - 1) // pitch  # maze cells per side
    blocked = np.ones((size, size), bool)
    seen = np.zeros((n, n), bool)
    stack = [(0, 0)]
    seen[0, 0] = True
    blocked[1:1 + width, 1:1 + width] = False
    while stack:
        cx, cy = stack[-1]
        options = [(cx + dx, cy + dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))
                   if 0 <= cx + dx < n and 0 <= cy + dy < n and not seen[cx + dx, cy + dy]]
        if not options:
            stack.pop()
            continue
        nx, ny = options[int(rng.integers(len(options)))]
        seen[nx, ny] = True
        x0, x1 = sorted((1 + cx * pitch, 1 + nx * pitch))
        y0, y1 = sorted((1 + cy * pitch, 1 + ny * pitch))
        blocked[x0:x1 + width, y0:y1 + width] = False  # the new cell and the wall between them
        stack.append((nx, ny))
    return blocked


def rooms(room: int, size: int, rng: np.random.Generator) -> np.ndarray:
    """Rooms of (room - 1) x (room - 1) free cells behind walls 1 cell thick, a door (one cell) between each
    pair of rooms of a random spanning tree, plus doors between a fifth of the other neighbouring pairs."""
    n = size // room  # rooms per side
    blocked = np.zeros((size, size), bool)
    for k in range(1, n):
        blocked[k * room - 1, :] = True
        blocked[:, k * room - 1] = True
    walls = [((cx, cy), (cx + dx, cy + dy)) for cx in range(n) for cy in range(n)
             for dx, dy in ((1, 0), (0, 1)) if cx + dx < n and cy + dy < n]
    order = rng.permutation(len(walls)).tolist()
    parent = list(range(n * n))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    extra: list[int] = []
    for k in order:
        (ax, ay), (bx, by) = walls[k]
        ra, rb = find(ax * n + ay), find(bx * n + by)
        if ra != rb:
            parent[ra] = rb
        elif len(extra) < len(walls) // 5:
            extra.append(k)
        else:
            continue
        door = int(rng.integers(room - 1))
        if bx > ax:  # the wall at x = bx * room - 1, a door somewhere along room ay's side
            blocked[bx * room - 1, ay * room + door] = False
        else:
            blocked[ax * room + door, by * room - 1] = False
    return _connected(blocked)


def warehouse(size: int, rng: np.random.Generator) -> np.ndarray:
    """Shelves 1 cell deep and 6 long, in rows 3 cells apart (aisles of 2), with a free border of 3 cells
    and a cross aisle every 7 cells: a warehouse floor (the random draw only shifts the cross aisles)."""
    blocked = np.zeros((size, size), bool)
    shift = int(rng.integers(3))
    xs = np.arange(3, size - 3)
    blocked[np.ix_(xs[(xs - 3 - shift) % 7 != 6], np.arange(3, size - 3, 3))] = True
    return _connected(blocked)


#: name -> (side, generator): the families `dronesim bench swarm` plays.
FAMILIES: dict[str, tuple[int, Callable[[int, np.random.Generator], np.ndarray]]] = {
    "empty-32-32": (32, empty),
    "random-32-32-10": (32, partial(random_map, 0.10)),
    "random-32-32-20": (32, partial(random_map, 0.20)),
    "maze-32-32-2": (32, partial(maze, 2)),
    "room-32-32-4": (32, partial(rooms, 4)),
    "warehouse-32-32": (32, warehouse),
}


def generate(family: str, seed: int) -> np.ndarray:
    """The blocked cells ([x, y]) of a map of `family`, drawn with `seed`."""
    if family not in FAMILIES:
        raise UsageError(f"unknown map family {family!r}; choose one of {', '.join(FAMILIES)}")
    side, make = FAMILIES[family]
    return make(side, np.random.default_rng(seed))


def starts_and_goals(agents: Sequence[Agent]) -> list[tuple[tuple[int, int, int], tuple[int, int, int]]]:
    """Each agent's start and goal as world cells (z = 0)."""
    return [((*a.start, 0), (*a.goal, 0)) for a in agents]
