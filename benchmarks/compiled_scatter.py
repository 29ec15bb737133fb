"""The scattered paths' search compiled: `lacam.Scatter` in Python against the same class running its compiled search
(coordinator/scatter.c, `coordinator.compiled`), the same paths (issue 37).

    dronesim bench compiled-scatter [--families F,...] [--seeds 5] [--agents 400] [--repeat 3] [--turn UNITS]
    dronesim bench compiled-scatter --exact [--seeds 5] [--repeat 3]

`--exact`: the exact search's joint moves instead (`exact.Exact._successors`, compiled in the same library as
`ex_successors`), on seeded rooms of 4 or 5 drones searched whole, Python against compiled: the same plans and units.

`--pibt`: the complete arbitration's search, its PIBT calls in Python (`arbiter.pibt`) against compiled (`pb_pibt`,
`lacam.pibt_compiled`): a whole world's search from the instance's start, `--calls` calls each way, the same nodes in
the same order (exit 1 if not); process CPU a call of the whole expansion (the node's candidates and the rest of the
call included: what a turn's work units buy), and of PIBT's own part.

Games run the compiled search where the machine can build it (a C compiler), Python's where it cannot: both must make
the very paths, rounds and work units, or a game's decisions would depend on the machine (exit 1 if not). Times:
process CPU of the whole scatter (`advance` to its end), Python and C alternated, the best of `--repeat`; and, as the
search makes it in a game (`lacam.SCATTER_WORK` units a turn, `--turn`), its turns and the longest one's time, C.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

import numpy as np

from benchmarks.swarm import movingai_instance
from coordinator import lacam
from coordinator.arbiter import OpenCells
from coordinator.compiled import scatter_library
from world import movingai
from world.search import flat_cells


def instance(family: str, agents: int, seed: int) -> tuple[lacam.Graph, np.ndarray, np.ndarray, np.ndarray]:
    """A benchmark instance's graph, its drones' open cells and goals (numbered) and their distance tables."""
    inst = movingai_instance(family, agents, seed)
    size = inst.grid.shape
    arb = lacam.Lacam()
    arb.prepare(size, OpenCells(inst.grid))
    graph, every = arb._graph, arb._every
    assert graph is not None and every is not None
    start = graph.index[flat_cells(np.array(inst.starts, np.int32), size)]
    goal = graph.index[flat_cells(np.array(inst.goals, np.int32), size)]
    return graph, start, goal, every[goal]


def searches(family: str, agents: int, seed: int, scatter: bool = False
             ) -> tuple[Callable[[], lacam.Search], OpenCells]:
    """A benchmark instance's whole world searches from its start (its graph and every distance table made once, here),
    each new, and its open cells."""
    inst = movingai_instance(family, agents, seed)
    size = inst.grid.shape
    open_ = OpenCells(inst.grid)
    arb = lacam.Lacam()
    arb.prepare(size, open_)
    graph, every = arb._graph, arb._every
    assert graph is not None and every is not None
    here = flat_cells(np.array(inst.starts, np.int32), size)
    aims = flat_cells(np.array(inst.goals, np.int32), size)
    return lambda: lacam.Search(graph, size, here, aims, aims, every[graph.index[aims]], scatter=scatter), open_


def room(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A seeded room of 5 x 4 cells, a quarter of them buildings, with 4 or 5 drones (the size of a rung of
    `lacam.Lacam`'s ladder): its open cells' neighbours and flat cells (`lacam.Graph`), the drones' open cells and
    goals (numbered)."""
    rng = np.random.default_rng(seed)
    while True:
        grid = (rng.random((5, 4)) < 0.25)[:, :, None]
        graph = lacam.Graph(OpenCells(grid), grid.shape)
        n = int(rng.integers(4, 6))
        if len(graph.cells) >= n + 4 and len(np.unique(graph.part)) == 1:
            cells = rng.permutation(len(graph.cells))
            return graph.near, graph.cells, cells[:n], rng.permutation(cells[:n])


def exact_moves(seeds: int, repeat: int) -> int:
    """`--exact`: Python's joint moves against the compiled ones, each room searched whole; exit 1 if a plan or the
    units differ."""
    from coordinator.exact import Exact

    print("| room | drones | open cells | configurations | units | Python ms | C ms | Python ÷ C | the same plan |")
    print("|---|---|---|---|---|---|---|---|---|")
    differ = 0
    for seed in range(1, seeds + 1):
        near, cells, start, goal = room(seed)
        ms: dict[bool, list[float]] = {True: [], False: []}
        out: dict[bool, tuple[object, int, int]] = {}
        for _ in range(repeat):
            for compiled in (False, True):
                search = Exact(near, cells, start, goal)
                if not compiled:
                    search.lib = None
                t0, units = time.process_time(), 0
                while search.plan is None and not search.unsolvable:
                    units += search.expand(1 << 40)
                ms[compiled].append(1000 * (time.process_time() - t0))
                plan = None if search.plan is None else search.plan.tolist()
                out[compiled] = (plan, units, sum(tree.count for tree in search.trees))
        same = out[True][:2] == out[False][:2]
        differ += not same
        print(f"| seed {seed} | {len(start)} | {len(cells)} | {out[False][2]:,} | {out[False][1]:,} | "
              f"{min(ms[False]):.0f} | {min(ms[True]):.1f} | {min(ms[False]) / min(ms[True]):.1f} | "
              f"{'yes' if same else 'NO'} |", flush=True)
    return 1 if differ else 0


def pibt_calls(families: list[str], seeds: int, agents: int, calls: int, repeat: int) -> int:
    """`--pibt`: the search's expansion with PIBT's calls in Python and compiled; exit 1 if the nodes differ."""
    print("| instance | calls | Python ms a call (PIBT's part) | C ms a call (PIBT's part) | Python ÷ C | "
          "the same nodes |")
    print("|---|---|---|---|---|---|")
    differ = 0
    for family in families:
        for seed in range(1, seeds + 1):
            new_search, open_ = searches(family, agents, seed)
            times: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
            nodes: dict[bool, list[bytes]] = {}
            for _ in range(repeat):
                for compiled in (False, True):
                    search = new_search()
                    if not compiled:
                        search._lib = None
                    spent = [0.0]
                    inner = lacam.pibt_compiled if compiled else lacam.pibt

                    def timed(*a: object, _f: object = inner, _s: list[float] = spent) -> object:
                        t = time.process_time()
                        out = _f(*a)  # type: ignore[operator]
                        _s[0] += time.process_time() - t
                        return out

                    setattr(lacam, "pibt_compiled" if compiled else "pibt", timed)
                    try:
                        t0 = time.process_time()
                        search.expand(1 << 62, open_, most=calls)
                        total = time.process_time() - t0
                    finally:
                        setattr(lacam, "pibt_compiled" if compiled else "pibt", inner)
                    times[compiled].append((1000 * total / search.expansions, 1000 * spent[0] / search.expansions))
                    nodes[compiled] = [k for k in search.explored]
            same = nodes[True] == nodes[False]
            differ += not same
            (py, py_own), (c, c_own) = min(times[False]), min(times[True])
            print(f"| {family} seed {seed}, {agents} drones | {calls} | {py:.2f} ({py_own:.2f}) | "
                  f"{c:.2f} ({c_own:.2f}) | {py / c:.1f} | {'yes' if same else 'NO'} |", flush=True)
    return 1 if differ else 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim bench compiled-scatter", description=__doc__.split("\n")[0])
    p.add_argument("--families", default=",".join(movingai.FAMILIES))
    p.add_argument("--seeds", type=int, default=5, help="seeds 1..N of each family (default 5)")
    p.add_argument("--agents", type=int, default=400)
    p.add_argument("--repeat", type=int, default=3, help="the best of this many timings each (default 3)")
    p.add_argument("--turn", type=int, default=lacam.SCATTER_WORK,
                   help=f"the units a turn makes (default lacam.SCATTER_WORK, {lacam.SCATTER_WORK})")
    p.add_argument("--exact", action="store_true", help="the exact search's joint moves instead (seeded rooms)")
    p.add_argument("--pibt", action="store_true", help="the search's PIBT calls instead (Python against compiled)")
    p.add_argument("--calls", type=int, default=200, help="--pibt: the calls of each search (default 200)")
    args = p.parse_args(argv)
    if scatter_library() is None:
        print("the compiled search cannot be had here (no C compiler, or DRONESIM_COMPILED=0)", file=sys.stderr)
        return 1
    if args.exact:
        return exact_moves(args.seeds, args.repeat)
    if args.pibt:
        return pibt_calls([f for f in args.families.split(",") if f], args.seeds, args.agents, args.calls, args.repeat)
    print("| instance | rounds | cells' units | Python ms | C ms | Python ÷ C | turns | longest turn, C ms | "
          "the same paths |")
    print("|---|---|---|---|---|---|---|---|---|")
    differ = 0
    for family in [f for f in args.families.split(",") if f]:
        for seed in range(1, args.seeds + 1):
            graph, start, goal, dist = instance(family, args.agents, seed)
            py_ms: list[float] = []
            c_ms: list[float] = []
            turn_ms: list[float] = []
            same = True
            for _ in range(args.repeat):
                made: dict[bool, lacam.Scatter] = {}
                spent: dict[bool, int] = {}
                for compiled, ms in ((False, py_ms), (True, c_ms)):
                    t0 = time.process_time()
                    made[compiled] = lacam.Scatter(graph, start, goal, dist, compiled=compiled)
                    spent[compiled] = made[compiled].advance(1 << 62)
                    ms.append(1000 * (time.process_time() - t0))
                spread, units, turns, longest = lacam.Scatter(graph, start, goal, dist), 0, 0, 0.0
                while not spread.done:
                    t0 = time.process_time()
                    units += spread.advance(args.turn)
                    longest = max(longest, time.process_time() - t0)
                    turns += 1
                turn_ms.append(1000 * longest)
                same = same and made[True].lib is not None and made[False].lib is None and \
                    (made[True].paths, made[True].round, spent[True]) == \
                    (made[False].paths, made[False].round, spent[False]) == (spread.paths, spread.round, units)
            differ += not same
            print(f"| {family} seed {seed}, {args.agents} drones | {made[False].round} | {spent[False]:,} | "
                  f"{min(py_ms):.0f} | {min(c_ms):.1f} | {min(py_ms) / min(c_ms):.1f} | {turns} | "
                  f"{min(turn_ms):.1f} | {'yes' if same else 'NO'} |", flush=True)
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
