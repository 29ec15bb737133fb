"""Autopilot benchmark: every available autopilot on one seeded suite of worlds, in-process.

    python -m benchmarks.autopilot                 # full suite, prints the table
    dronesim bench autopilot --write        # ... and updates "## Autopilot benchmark" in BENCHMARKS.md
    python -m benchmarks.autopilot --quick         # a few small episodes (used by the tests)

Each episode is (world, start, target): a fresh pilot instance flies from start until it reaches the
target, crashes (a move into a building, out of the world, or further than one cell), says
UNREACHABLE (then it must keep hovering for a few more turns), or runs out of steps
(``4 * optimal + 100``; for unreachable targets a budget proportional to the world). The oracle is
`World.what_inside`; the optimum is `World.shortest_path_length` on the full map.

The suite: random cities (`World.generate`, denser than the default) of 10x10x10, 32x32x8 and
64x64x16 with random starts and targets (plus one target inside a building per world), and hand-made
hard cases built with `World.from_grid`: U-shaped walls and dead-end pockets, a serpentine of
full-height walls, enclosed targets (in the air and on the ground), a sealed start, targets inside
buildings, and a 64x64x16 world of long full-height walls.

Planning time is the wall time spent inside the autopilot's `step` generator (ASK answering
excluded), per step, on the 64x64x16 episodes.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks import add_write_args, command_line, replace_section
from entities.autopilots import REGISTRY, make_autopilot
from schema import Cell, Note
from world.grid import World

SECTION = "## Autopilot benchmark"
BIG = (64, 64, 16)
HOVER_CHECK = 3  # turns a pilot must keep hovering after saying UNREACHABLE


# --------------------------------------------------------------------------- the suite


@dataclass(frozen=True, slots=True)
class Episode:
    suite: str
    world: World
    start: Cell
    target: Cell
    optimal: int | None  # None: unreachable

    @property
    def limit(self) -> int:
        if self.optimal is not None:
            return 4 * self.optimal + 100
        nx, ny, nz = self.world.size
        return 8 * (nx + ny + nz) + 200


def _episode(suite: str, world: World, start: Cell, target: Cell) -> Episode:
    return Episode(suite, world, start, target, world.shortest_path_length(start, target))


def _cities(rng: np.random.Generator, size: Cell, worlds: int, per_world: int, *,
            footprint: int, cover: float) -> list[Episode]:
    """Random dense cities; random free start and target at least a third of the way across,
    plus one target inside a building per world."""
    nx, ny, nz = size
    suite = "x".join(map(str, size))
    mean_area = (footprint + 1) / 2 * (footprint + 1) / 2
    count = max(1, round(cover * nx * ny / mean_area))
    out: list[Episode] = []
    for _ in range(worlds):
        world = World.generate(size, rng, count=count, max_footprint=footprint, keep_free=())
        free = np.argwhere(~world.grid)
        solid = np.argwhere(world.grid)
        far = (nx + ny + nz) // 3
        made = 0
        while made < per_world:
            a = tuple(int(v) for v in free[rng.integers(len(free))])
            b = tuple(int(v) for v in free[rng.integers(len(free))])
            if sum(abs(p - q) for p, q in zip(a, b)) < far:
                continue
            out.append(_episode(suite, world, a, b))  # type: ignore[arg-type]
            made += 1
        if len(solid):
            a = tuple(int(v) for v in free[rng.integers(len(free))])
            b = tuple(int(v) for v in solid[rng.integers(len(solid))])
            out.append(_episode(suite, world, a, b))  # type: ignore[arg-type]
    return out


def _shell(grid: np.ndarray, lo: Cell, hi: Cell) -> None:
    """Walls (thickness 1) on every face of the box lo..hi inclusive."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    grid[x0:x1 + 1, y0:y1 + 1, z0:z1 + 1] = True
    grid[x0 + 1:x1, y0 + 1:y1, z0 + 1:z1] = False


def hard_cases(quick: bool = False) -> list[Episode]:
    """Hand-made worlds where greedy flying fails."""
    out: list[Episode] = []

    # A U-shaped full-height wall opening towards the start: the drone must not get stuck inside.
    g = np.zeros((20, 20, 6), dtype=bool)
    g[12, 4:16, :] = True
    g[6:13, 4, :] = True
    g[6:13, 15, :] = True
    w = World.from_grid(g)
    out.append(_episode("hard", w, (2, 10, 0), (17, 10, 0)))
    out.append(_episode("hard", w, (9, 10, 3), (17, 9, 5)))  # starting inside the U

    # A dead-end pocket in 3D: a box open only towards the start, with room above and around.
    g = np.zeros((24, 24, 12), dtype=bool)
    g[14, 6:18, 0:8] = True  # back wall
    g[6:15, 6, 0:8] = True
    g[6:15, 17, 0:8] = True
    g[6:15, 6:18, 7] = True  # roof
    w = World.from_grid(g)
    out.append(_episode("hard", w, (1, 12, 2), (20, 12, 2)))
    out.append(_episode("hard", w, (10, 12, 3), (22, 12, 0)))

    # A serpentine: full-height walls with gaps at alternating ends.
    g = np.zeros((24, 16, 4), dtype=bool)
    for i, x in enumerate((4, 9, 14, 19)):
        g[x, :, :] = True
        if i % 2 == 0:
            g[x, 14:16, :] = False
        else:
            g[x, 0:2, :] = False
    w = World.from_grid(g)
    out.append(_episode("hard", w, (0, 0, 0), (23, 0, 3)))

    # Enclosed target in the air; enclosed target on the ground (a roofed well); a sealed start.
    g = np.zeros((12, 12, 12), dtype=bool)
    _shell(g, (4, 4, 4), (8, 8, 8))
    w = World.from_grid(g)
    out.append(_episode("hard", w, (0, 0, 0), (6, 6, 6)))
    out.append(_episode("hard", w, (6, 6, 6), (0, 11, 0)))  # the drone starts sealed in
    g = np.zeros((16, 16, 6), dtype=bool)
    g[5:10, 5:10, 0:3] = True
    g[6:9, 6:9, 0:2] = False
    w = World.from_grid(g)
    out.append(_episode("hard", w, (0, 0, 0), (7, 7, 0)))

    # Target inside a building.
    g = np.zeros((10, 10, 10), dtype=bool)
    g[4:7, 4:7, 0:5] = True
    w = World.from_grid(g)
    out.append(_episode("hard", w, (0, 0, 0), (5, 5, 2)))
    if quick:
        return out

    # A 64x64x16 maze: full-height walls across x with one small window each, at alternating
    # ends and heights, and partial walls across y making dead ends in between.
    g = np.zeros(BIG, dtype=bool)
    for x, (y0, z0) in zip((12, 28, 44), ((56, 12), (4, 1), (56, 6))):
        g[x, :, :] = True
        g[x, y0:y0 + 4, z0:z0 + 3] = False
    g[0:12, 32, :] = True  # dead end before the first window...
    g[0:6, 32, 0:12] = False
    g[13:26, 32, :] = True  # ... and between the windows
    g[29:44, 24, 0:14] = True
    g[45:64, 40, 4:16] = True
    w = World.from_grid(g)
    out.append(_episode("hard", w, (0, 0, 0), (63, 63, 15)))
    out.append(_episode("hard", w, (63, 0, 8), (0, 63, 0)))
    out.append(_episode("hard", w, (30, 30, 0), (5, 60, 12)))
    # A 64x64x16 target in a sealed room of that world.
    g2 = g.copy()
    _shell(g2, (50, 50, 0), (58, 58, 10))
    w = World.from_grid(g2)
    out.append(_episode("hard", w, (0, 0, 0), (54, 54, 3)))
    return out


def suite(seed: int, quick: bool = False) -> list[Episode]:
    rng = np.random.default_rng(seed)
    if quick:
        return _cities(rng, (10, 10, 10), 2, 2, footprint=3, cover=0.5) + hard_cases(quick=True)
    return (_cities(rng, (10, 10, 10), 20, 5, footprint=3, cover=0.5)
            + _cities(rng, (32, 32, 8), 10, 5, footprint=5, cover=0.45)
            + _cities(rng, BIG, 8, 5, footprint=7, cover=0.45)
            + hard_cases())


# --------------------------------------------------------------------------- running


@dataclass(slots=True)
class Result:
    episode: Episode
    reached: bool = False
    crashed: str = ""
    unreachable: bool = False  # said UNREACHABLE and kept hovering
    moves: int = 0
    steps: int = 0
    asks: int = 0
    cells: int = 0
    step_seconds: list[float] = field(default_factory=list)


def run_episode(pilot: object, ep: Episode) -> Result:
    world = ep.world
    res = Result(ep)

    def oracle(cells: tuple[Cell, ...]) -> dict:
        return {c: world.what_inside(c) for c in cells}

    pos = ep.start
    hover_left = -1
    clock = time.perf_counter
    for _ in range(ep.limit + HOVER_CHECK):
        gen = pilot.step(pos, ep.target)  # type: ignore[attr-defined]
        spent = 0.0
        t0 = clock()
        try:
            cells = next(gen)
            spent += clock() - t0
            while True:
                res.asks += 1
                res.cells += len(cells)
                answers = oracle(cells)
                t0 = clock()
                cells = gen.send(answers)
                spent += clock() - t0
        except StopIteration as stop:
            spent += clock() - t0
            decision = stop.value
        res.steps += 1
        res.step_seconds.append(spent)
        new = decision.pos
        if sum(abs(a - b) for a, b in zip(new, pos)) > 1:
            res.crashed = "jump"
        elif not world.contains(new):
            res.crashed = "outside"
        elif world.is_building(new):
            res.crashed = "building"
        if res.crashed:
            break
        if hover_left >= 0:  # after UNREACHABLE: must stay put and keep saying so
            if new != pos or decision.note is not Note.UNREACHABLE:
                res.unreachable = False
                break
            hover_left -= 1
            if hover_left == 0:
                break
            continue
        if decision.note is Note.UNREACHABLE:
            if new == pos:
                res.unreachable = True
                hover_left = HOVER_CHECK
            continue
        if new != pos:
            res.moves += 1
        pos = new
        if pos == ep.target:
            res.reached = True
            break
        if res.steps >= ep.limit:
            break
    return res


def _pct(values: Sequence[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


@dataclass(slots=True)
class Summary:
    name: str
    reachable: int
    reached: int
    false_unreachable: int
    crashes: int
    unreachable: int
    detected: int
    ratios: list[float]
    asks_per_step: float
    cells_per_step: float
    big_ms: list[float]


def summarise(name: str, results: list[Result]) -> Summary:
    reach = [r for r in results if r.episode.optimal is not None]
    unreach = [r for r in results if r.episode.optimal is None]
    ratios = [r.moves / r.episode.optimal for r in reach if r.reached and r.episode.optimal]
    steps = sum(r.steps for r in results) or 1
    big = [s * 1e3 for r in results if r.episode.world.size == BIG for s in r.step_seconds]
    return Summary(
        name=name,
        reachable=len(reach),
        reached=sum(r.reached for r in reach),
        false_unreachable=sum(r.unreachable for r in reach),
        crashes=sum(bool(r.crashed) for r in results),
        unreachable=len(unreach),
        detected=sum(r.unreachable for r in unreach),
        ratios=ratios,
        asks_per_step=sum(r.asks for r in results) / steps,
        cells_per_step=sum(r.cells for r in results) / steps,
        big_ms=big,
    )


def table(summaries: list[Summary]) -> str:
    head = ("| autopilot | success on reachable | crashes | unreachable detected | path/optimal median / mean / p90 "
            "| ASK round trips per step | cells asked per step | planning ms median / p90 (64x64x16) |")
    rows = [head, "|" + "---|" * 8]
    for s in summaries:
        succ = f"{100 * s.reached / s.reachable:.1f} % ({s.reached}/{s.reachable})" if s.reachable else "-"
        if s.false_unreachable:
            succ += f", {s.false_unreachable} wrongly unreachable"
        det = f"{s.detected}/{s.unreachable}" if s.unreachable else "-"
        if s.ratios:
            ratio = f"{statistics.median(s.ratios):.2f} / {statistics.fmean(s.ratios):.2f} / {_pct(s.ratios, 90):.2f}"
        else:
            ratio = "-"
        ms = f"{statistics.median(s.big_ms):.3f} / {_pct(s.big_ms, 90):.3f}" if s.big_ms else "-"
        rows.append(f"| {s.name} | {succ} | {s.crashes} | {det} | {ratio} | {s.asks_per_step:.2f} "
                    f"| {s.cells_per_step:.1f} | {ms} |")
    return "\n".join(rows)


def suite_table(names: list[str], results: dict[str, list[Result]]) -> str:
    """Per suite: success on reachable and mean path/optimal of each autopilot."""
    suites = list(dict.fromkeys(r.episode.suite for r in next(iter(results.values()))))
    rows = ["| suite | episodes (unreachable) | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    for su in suites:
        cells = []
        for n in names:
            rs = [r for r in results[n] if r.episode.suite == su]
            reach = [r for r in rs if r.episode.optimal is not None]
            ratios = [r.moves / r.episode.optimal for r in reach if r.reached and r.episode.optimal]
            mean = f", path {statistics.fmean(ratios):.2f}x" if ratios else ""
            cells.append(f"{sum(r.reached for r in reach)}/{len(reach)} reached{mean}")
        rs = [r for r in results[names[0]] if r.episode.suite == su]
        unreach = sum(r.episode.optimal is None for r in rs)
        rows.append(f"| {su} | {len(rs)} ({unreach}) | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def _factory(name: str) -> Callable[[Cell], object] | None:
    """A pilot maker, or None (with a printed note) if the autopilot cannot be imported."""
    base, _, variant = name.partition(":")
    try:
        make_autopilot(base, world_size=(2, 2, 2))
    except Exception as exc:  # noqa: BLE001 - report any import/construction failure and go on
        print(f"note: autopilot {base!r} skipped: {type(exc).__name__}: {exc}", file=sys.stderr)
        return None
    if not variant:
        return lambda size: make_autopilot(base, world_size=size)
    # Ablations of dstar: "dstar:la=0,rounds=1".
    from entities.autopilots.dstar import DStarPilot

    opts = dict(kv.split("=") for kv in variant.split(","))
    la = int(opts.get("la", DStarPilot.LOOKAHEAD))
    rounds = int(opts.get("rounds", 2))
    return lambda size: DStarPilot(world_size=size, lookahead=la, rounds=rounds)


def write_section(path: Path, body: str) -> None:
    """Replace (or append) this benchmark's section of `path`, leaving the others alone."""
    replace_section(path, SECTION, body)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="dronesim bench autopilot", description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, default=1, help="suite seed (default 1)")
    parser.add_argument("--quick", action="store_true", help="a few small episodes (for tests)")
    parser.add_argument("--autopilots", default=",".join(REGISTRY),
                        help="comma-separated names (default: all registered); dstar:la=N,rounds=R for ablations")
    parser.add_argument("--ablation", action="store_true",
                        help="also run dstar without look-ahead (la=0) and with one ASK round (rounds=1)")
    add_write_args(parser)
    args = parser.parse_args(argv)

    names = [n.strip() for n in args.autopilots.split(",") if n.strip()]
    if args.ablation:
        names += ["dstar:la=0,rounds=1", "dstar:rounds=1"]
    episodes = suite(args.seed, quick=args.quick)
    reachable = sum(e.optimal is not None for e in episodes)
    print(f"{len(episodes)} episodes ({reachable} reachable, {len(episodes) - reachable} unreachable), "
          f"seed {args.seed}")

    summaries: list[Summary] = []
    results: dict[str, list[Result]] = {}
    t_start = time.perf_counter()
    for name in names:
        factory = _factory(name)
        if factory is None:
            continue
        t0 = time.perf_counter()
        results[name] = [run_episode(factory(ep.world.size), ep) for ep in episodes]
        summaries.append(summarise(name, results[name]))
        print(f"  {name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    if not summaries:
        print("no autopilot could be run", file=sys.stderr)
        return 1
    main_table = table(summaries)
    detail = suite_table(list(results), results)
    print()
    print(main_table)
    print()
    print(detail)
    if args.write:
        body = (
            f"{command_line('autopilot', argv, time.perf_counter() - t_start)}\n\n"
            f"{len(episodes)} episodes, {reachable} reachable: random dense cities of 10x10x10, 32x32x8 and "
            "64x64x16 (random start and target, plus one target inside a building per world) and hand-made hard "
            "cases (U-shaped walls, a dead-end pocket, a serpentine, enclosed targets, a sealed start, targets "
            "inside buildings, 64x64x16 long walls). Step limit 4 x optimal + 100; path/optimal over reached "
            "episodes; planning time = time inside the autopilot's `step` generator per step, on the 64x64x16 "
            "episodes only; a crash is a move into a building, out of the world or further than one cell. "
            "`dstar:la=0,rounds=1` is D* Lite sensing only its 6 neighbours (the freespace planner without "
            "look-ahead); `dstar:rounds=1` senses ahead but never asks twice in a step.\n\n"
            f"{main_table}\n\nPer suite:\n\n{detail}\n"
        )
        write_section(args.output, body)
        print(f"\nwrote {SECTION!r} in {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
