"""``dronesim bench lifelong``: lifelong cooperative drones, their throughput in tasks per turn.

    dronesim bench lifelong              # 1000 and 10,000 LRTA* drones on a 256 x 256 warehouse, 500 turns, 3 runs
    dronesim bench lifelong --quick      # 40 drones on a 32 x 32 warehouse, 60 turns, one run (for tests)
    dronesim bench lifelong --write      # ... and records "## Lifelong benchmark" in BENCHMARKS.md

Lifelong MAPF as the League of Robot Runners measures it: each drone that reaches its target is given a new one,
and the measure is the tasks done (arrivals) per turn over the game. Every game is played in process
(dronesim/local.py: the same engine, environment and autopilots as a distributed run, `dronesim up --lifelong`,
whose journal is the same), the drones flown by their autopilot's swarm form, the targets drawn as the lifelong
ground station draws them (entities/tasks.py: a free cell of the drone's component, no other target, from a
Generator seeded with the seed and the turn), the default arbitration (coordinator/lacam.py: on these worlds the
search's distance tables would exceed its limit, so it plays PIBT, `arbiter.cooperate`, every turn).

The maps: a warehouse floor (world/movingai.py's `warehouse` at 256 x 256: shelves 1 x 6 in rows 3 apart, a cross
aisle every 7 cells; 47,560 free cells) or 20 % random obstacles (`--map random`, 52,326); the drones start at distinct
random free cells (seed 1). Each game is played `--runs` times (the same game: its tasks must agree; the times
vary). Reported: tasks done and tasks per turn; the arbitration's process time per turn (mean and longest turn,
`arbiter.Timed`, the garbage collector held off); the whole game's turns per second (every drone's planning,
the environment and the engine: wall clock); collisions (deaths); drones that said UNREACHABLE at the end; and
the machine's load average when each run started.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from coordinator import arbiter, lacam
from coordinator.config import DroneTable, GameConfig
from dronesim.local import Inputs, simulate
from entities.gcs import Plan
from entities.tasks import Tasks
from schema import DroneState, Note, WorldSpec, drone_id
from schema.tables import code_of
from world import movingai
from world.grid import World

from . import add_write_args, command_line, replace_section

SECTION = "## Lifelong benchmark"
DRONES = (1000, 10_000)
TURNS = 500
RUNS = 3
SIDE = 256
MAPS = {"warehouse": movingai.warehouse, "random": lambda side, rng: movingai.random_map(0.2, side, rng)}
AUTOPILOT = "lrta"

LOG = logging.getLogger("dronesim.bench.lifelong")
#: What the recorded table says (the module's doc after its commands, each paragraph on one line).
LEGEND = "\n\n".join(" ".join(part.split()) for part in (__doc__ or "").split("\n\n")[2:])


@dataclass(frozen=True, slots=True)
class Game:
    """One lifelong game played once."""

    map: str
    drones: int
    run: int
    turns: int
    tasks: int
    seconds: float
    arbiter_cpu: float  # seconds of process time in the arbitration, over the game
    arbiter_worst: float  # seconds, the longest turn's
    arbitrated: int  # turns arbitrated
    collisions: int  # drones dead at the end
    unreachable: int  # alive drones saying UNREACHABLE at the end
    load: float  # the load average (1 min) when the run started
    over: str

    @property
    def per_turn(self) -> float:
        return self.tasks / self.turns


def world_of(kind: str, side: int, seed: int = 1) -> World:
    """The map `kind` (MAPS) of `side` x `side`, one cell high, drawn with `seed`."""
    return World.from_grid(movingai.world_grid(MAPS[kind](side, np.random.default_rng(seed))))


def game(world: World, drones: int, turns: int, seed: int = 1) -> GameConfig:
    """A lifelong game of `drones` at distinct random free cells of `world` (drawn with `seed`), to `turns`."""
    free = np.argwhere(~world.grid)
    if len(free) < 2 * drones:
        raise SystemExit(f"{drones} drones need {2 * drones} free cells; the map has {len(free)}")
    starts = free[np.random.default_rng(seed).permutation(len(free))[:drones]]
    ids = [drone_id(k + 1) for k in range(drones)]
    return GameConfig(world=WorldSpec(size=world.size, cells=world.packed()),
                      drones=DroneTable(ids, starts.reshape(-1).tolist()), max_turns=turns, lifelong=True)


def play(kind: str, world: World, drones: int, turns: int, run: int, autopilot: str = AUTOPILOT) -> Game:
    config = game(world, drones, turns)
    timed = arbiter.Timed(lacam.Lacam())
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    result = simulate(config, {d.drone: autopilot for d in config.drones},
                      Inputs(plan=Plan(()), tasks=Tasks(world, 1)), LOG, verify_env=False, swarm=True,
                      arbiter=timed, journaled=False)
    seconds = time.perf_counter() - t0
    dead = unreachable = 0
    if result.final is not None:
        rows = result.final.drones.rows
        alive = rows["state"] == code_of(DroneState.ALIVE)
        dead = int(np.count_nonzero(~alive))
        unreachable = int(np.count_nonzero(alive & (rows["note"] == code_of(Note.UNREACHABLE))))
    return Game(kind, drones, run, result.over.turn, result.tasks, seconds, timed.cpu, timed.worst, timed.calls,
                dead, unreachable, load, f"{result.over.reason.value} at turn {result.over.turn}")


def _row(cells: Sequence[object]) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


def table(games: list[Game]) -> str:
    head = ["map", "drones", "run", "turns", "tasks done", "tasks/turn", "arbitration ms/turn (mean)",
            "arbitration ms (longest turn)", "turns/s (whole game)", "deaths", "UNREACHABLE at the end",
            "load (1 min) at start"]
    lines = [_row(head), _row(["---"] * len(head))]
    for g in games:
        lines.append(_row([g.map, g.drones, g.run, g.turns, g.tasks,
                           f"{g.per_turn:.2f}", f"{1000 * g.arbiter_cpu / max(1, g.arbitrated):.1f}",
                           f"{1000 * g.arbiter_worst:.1f}", f"{g.turns / g.seconds:.2f}", g.collisions,
                           g.unreachable, f"{g.load:.1f}"]))
    return "\n".join(lines)


def verdicts(games: list[Game]) -> str:
    """Per map and drone count: the throughput (the same in every run, or not) and the ranges of the times."""
    out = []
    for kind, drones in dict.fromkeys((g.map, g.drones) for g in games):
        mine = [g for g in games if (g.map, g.drones) == (kind, drones)]
        tasks = sorted({g.tasks for g in mine})
        same = "the same game in every run" if len(tasks) == 1 else f"NOT the same game: {tasks}"
        ms = [1000 * g.arbiter_cpu / max(1, g.arbitrated) for g in mine]
        rates = [g.turns / g.seconds for g in mine]
        out.append(f"- {kind}, {drones} drones, {mine[0].turns} turns: {mine[0].per_turn:.2f} tasks a turn ({same}, "
                   f"{len(mine)} run{'s' * (len(mine) > 1)}); the arbitration {min(ms):.1f}–{max(ms):.1f} ms a turn on "
                   f"average, its longest turn {1000 * min(g.arbiter_worst for g in mine):.1f}–"
                   f"{1000 * max(g.arbiter_worst for g in mine):.1f} ms; the whole game {min(rates):.2f}–"
                   f"{max(rates):.2f} turns/s; load {min(g.load for g in mine):.1f}–{max(g.load for g in mine):.1f}")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="dronesim bench lifelong", description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="40 drones on a 32 x 32 warehouse, 60 turns, one run")
    parser.add_argument("--drones", default=",".join(map(str, DRONES)), help="drone counts (default 1000,10000)")
    parser.add_argument("--turns", type=int, default=TURNS, help=f"turns a game (default {TURNS})")
    parser.add_argument("--runs", type=int, default=RUNS, help=f"runs of each game (default {RUNS})")
    parser.add_argument("--map", choices=tuple(MAPS), default="warehouse", help="the map (default warehouse)")
    parser.add_argument("--autopilot", default=AUTOPILOT, help=f"the drones' autopilot (default {AUTOPILOT})")
    add_write_args(parser)
    args = parser.parse_args(argv)
    side, counts, turns, runs = ((32, (40,), 60, 1) if args.quick else
                                 (SIDE, tuple(int(n) for n in args.drones.split(",")), args.turns, args.runs))
    t_start = time.perf_counter()
    world = world_of(args.map, side)
    games: list[Game] = []
    for run in range(1, runs + 1):
        for n in counts:
            g = play(f"{args.map}-{side}", world, n, turns, run, args.autopilot)
            games.append(g)
            print(f"  {g.map}, {n} drones, run {run}: {g.tasks} tasks in {g.turns} turns ({g.per_turn:.2f} a turn), "
                  f"arbitration {1000 * g.arbiter_cpu / max(1, g.arbitrated):.1f} ms/turn, {g.turns / g.seconds:.2f} "
                  f"turns/s, load {g.load:.1f}, {g.over}", file=sys.stderr, flush=True)
    body_table, lines = table(games), verdicts(games)
    print(body_table)
    print()
    print(lines)
    if args.write:
        body = (f"{command_line('lifelong', argv, time.perf_counter() - t_start)}\n\n"
                f"{LEGEND}\n\n{body_table}\n\n{lines}\n")
        replace_section(args.output, SECTION, body)
        print(f"\nwrote {SECTION!r} in {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
