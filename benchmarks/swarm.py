"""``dronesim bench swarm``: cooperative drones judged by multi-agent path finding (MAPF) metrics.

    dronesim bench swarm                    # the MovingAI families, 50-400 agents, a 3D city of 1000 drones
    dronesim bench swarm --quick            # a few small instances (for tests)
    dronesim bench swarm --write            # ... and updates "## Swarm benchmark" in BENCHMARKS.md
    dronesim bench swarm --city-distributed # only the distributed LRTA* cities (1000 and 10,000 drones, 3 runs)
    dronesim bench swarm --no-city-distributed  # everything but them

Every instance is played in process (dronesim/local.py: the same engine, environment and autopilots as a
distributed run, whose journal is the same) by D* drones, three ways side by side:

- ``fixed``: the former arbitration (`coordinator.arbiter.fixed`: one move per drone, a fixed priority);
- ``pibt``: PIBT over each drone's ranked candidates (`coordinator.arbiter.cooperate`, the one in force);
- ``pibt+map``: the same with every drone given the map at the start (D*'s `known`): an upper bound on what
  cooperation gives when the drones need not discover the walls.

Instances: the MovingAI 32 x 32 families (world/movingai.py: empty, random 10 % and 20 %, maze, rooms, a
warehouse), one map and one random scenario per family and seed, with 50, 100, 200 and 400 agents (the first
N of the scenario); and a 3D city (`World.generate`) with 1000 drones. The ground station gives every target at
turn 1 and says its plan is final; a game ends when every drone has arrived, has said UNREACHABLE, or at the
turn limit: on 32 x 32, 4 times the lower-bound makespan (the longest single-agent optimal path) and at least
256 (POGEMA's episode), as MAPF evaluations bound a run by a multiple of what it must at least take; the ISR at
turn 256 is reported too, and, for a game that reached its limit, how many agents off their goal were still
moving in its last 10 turns (a livelock, not a slow crowd, if the ISR did not grow meanwhile).

Metrics, as POGEMA reports them: CSR (1 if every agent is on its goal at the end, averaged over instances),
ISR (the share of agents on their goal at the end), sum of costs (each agent's cost is the turn after which it
stays on its goal; an agent not there at the end costs the game's length) and makespan (the largest cost), each
also divided by its lower bound (the sum, resp. the largest, of the single-agent optimal lengths); collisions
(deaths of VERTEX or SWAP: none may happen between cooperative drones); turns per second of the whole
in-process game (every drone's planning included); and the arbiter's CPU time per turn (process time inside
`Arbitration.arbiter`, the garbage collector held off: see `Timed`). POGEMA (benchmarks/pogema.py) is run at the
same agent counts in the same run: its steps per second with random actions on its 64 x 64 grid.

The distributed cities (`city_distributed`, its own subsection "Distributed cities (LRTA*)", which the table's
--write keeps): a 256 x 256 x 32 city of 1000 LRTA* drones in one swarm host and of 10,000 on two, through real
processes (benchmarks/games.py's `play_distributed`), each played three times, with turns per second, ISR/CSR,
collisions, the coordinator's arbitration CPU a turn, every process's CPU, and POGEMA with as many agents on
256 x 256 (its 64 x 64 cannot hold 10,000) in the same run.
"""

from __future__ import annotations

import argparse
import gc
import json
import logging
import os
import re
import sys
import tempfile
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from coordinator import arbiter, lacam
from coordinator.config import DroneSpec, GameConfig
from coordinator.journal import is_turn
from dronesim.local import Inputs, simulate
from entities.gcs import Plan
from schema import Cell, WorldSpec, drone_id
from schema.messages import Cause, DroneState
from schema.tables import RANK_STEPS, rank_steps
from world import movingai
from world.grid import World
from world.search import cells_of, components, padded_steps

from . import add_write_args, anchor, command_line, pogema, replace_section, replace_subsection

SECTION = "## Swarm benchmark"
AGENTS = (50, 100, 200, 400)
#: The 3D city: size, drones.
CITY = ((64, 64, 8), 1000)
QUICK_CITY = ((16, 16, 4), 40)
VARIANTS = ("fixed", "pibt", "pibt+map", "lacam")
#: POGEMA's episode on 32 x 32 (turns): the ISR at this turn is reported too.
TURNS_32 = 256
#: The turn limit on 32 x 32 is this many times the instance's lower-bound makespan (the longest single-agent
#: optimal path), and at least TURNS_32: the maze's longest paths are 184 moves, which 256 turns barely cover.
LIMIT_PER_MAKESPAN = 4
#: An agent not on its goal at the end that moved in the game's last this many turns was still moving.
RECENT = 10

LOG = logging.getLogger("dronesim.bench.swarm")


@dataclass(frozen=True, slots=True)
class Instance:
    """One MAPF instance: a world (blocked cells [x, y, z]) and each agent's start and goal."""

    name: str
    grid: np.ndarray
    starts: tuple[Cell, ...]
    goals: tuple[Cell, ...]
    optimal: tuple[int, ...]
    max_turns: int
    bridges: int  # edges of the free cells that lie on no cycle (`bridges`): 0 where PIBT's condition holds


@dataclass(frozen=True, slots=True)
class Outcome:
    """One instance played one way."""

    instance: str
    agents: int
    variant: str
    arrived: int
    soc: int
    makespan: int
    soc_lb: int
    makespan_lb: int
    collisions: int
    arrived_256: int  # on their goal at turn TURNS_32 (or at the end if the game ended before)
    moving: int  # not on their goal at the end but moved in the last RECENT turns (a game at its turn limit)
    turns: int
    seconds: float
    arbiter_cpu: float  # seconds of process time inside the arbiter, over the game
    arbitrated: int  # turns the arbiter ran
    arbiter_worst: float  # seconds of the arbiter's longest turn
    max_turns: int
    bridges: int  # edges on no cycle in the instance's free cells (0: PIBT's condition holds)

    @property
    def csr(self) -> float:
        return float(self.arrived == self.agents)

    @property
    def isr(self) -> float:
        return self.arrived / self.agents

    @property
    def limited(self) -> bool:
        """The game ended at its turn limit (not every agent arrived or said UNREACHABLE)."""
        return self.turns >= self.max_turns



def bridges(free: np.ndarray) -> int:
    """How many edges of the graph of `free` cells (6-connected) lie on no cycle: Tarjan's bridges, by an
    iterative depth-first search. PIBT's condition (every agent reaches its goal) is that there are none."""
    index = np.full(tuple(n + 2 for n in free.shape), -1, np.int64)  # padded: a cell's neighbours need no checks
    cells = np.flatnonzero(np.pad(free, 1))
    index.reshape(-1)[cells] = np.arange(len(cells))
    _, _, offsets = padded_steps(free.shape)
    near = index.reshape(-1)[cells[:, None] + np.array(offsets, np.int64)]
    adjacent = [[v for v in row if v >= 0] for row in near.tolist()]
    found, low, count, clock = [-1] * len(cells), [0] * len(cells), 0, 0
    for root in range(len(cells)):
        if found[root] >= 0:
            continue
        found[root] = low[root] = clock
        clock += 1
        stack = [(root, -1, iter(adjacent[root]))]
        while stack:
            u, parent, rest = stack[-1]
            for v in rest:
                if v == parent:
                    continue
                if found[v] < 0:
                    found[v] = low[v] = clock
                    clock += 1
                    stack.append((v, u, iter(adjacent[v])))
                    break
                low[u] = min(low[u], found[v])
            else:
                stack.pop()
                if parent >= 0:
                    low[parent] = min(low[parent], low[u])
                    count += low[u] > found[parent]
    return count


def movingai_instance(family: str, agents: int, seed: int) -> Instance:
    blocked = movingai.generate(family, seed)
    scen = movingai.scenario(blocked, agents, seed, f"{family}.map")
    cells = movingai.starts_and_goals(scen)
    optimal = tuple(int(a.optimal) for a in scen)
    grid = movingai.world_grid(blocked)
    return Instance(f"{family}", grid, tuple(s for s, _ in cells), tuple(g for _, g in cells),
                    optimal, max(TURNS_32, LIMIT_PER_MAKESPAN * max(optimal)), bridges(~grid))


def city_instance(size: Cell, agents: int, seed: int) -> Instance:
    """A 3D city with `agents` drones at random free cells with random free goals, every goal reachable."""
    rng = np.random.default_rng(seed)
    world = World.generate(size, rng)
    grid = np.asarray(world.grid)
    free = np.argwhere(~grid)
    starts: list[Cell] = [(x, y, z) for x, y, z in free[rng.permutation(len(free))[:agents]].tolist()]
    goals: list[Cell] = [(x, y, z) for x, y, z in free[rng.permutation(len(free))[:agents]].tolist()]
    optimal = [world.shortest_path_length(s, g) for s, g in zip(starts, goals)]
    keep = [k for k, o in enumerate(optimal) if o is not None]
    return Instance(f"city-{size[0]}-{size[1]}-{size[2]}", grid, tuple(starts[k] for k in keep),
                    tuple(goals[k] for k in keep), tuple(int(optimal[k] or 0) for k in keep), city_limit(size),
                    bridges(~grid))


class Traced(lacam.Lacam):
    """The complete arbitration that keeps a line each time its course changes (`--trace`): which search runs (the
    whole world's, a focused one: its radius and drones, none: PIBT's turn), whether it found the goal, its nodes,
    the plan's steps left and refiners, drones home, turns without a new high and the patience."""

    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []
        self._last: tuple[object, ...] = ()
        self._turn = 0

    def follow(self, size: Cell, before: np.ndarray, cooperative: np.ndarray, targets: np.ndarray,
               open_: arbiter.OpenCells | None, salt: int | None = None) -> np.ndarray | None:
        out = super().follow(size, before, cooperative, targets, open_, salt)
        s, st = self._search, self.state()
        kind = "PIBT" if out is None else "whole" if s is None or s.focus is None else \
            f"focus radius {s.focus[3]} drones {len(s.focus[0])}"
        course = (kind, st["found"], id(s), st["full"], st["unsolvable"])
        if course != self._last or self._turn % 20 == 0:
            left = 0 if s is None or s.plan is None else len(s.plan) - 1 - s.t
            self.lines.append(f"turn {self._turn}: {kind}, found {st['found']}, nodes {st['nodes']}, plan left {left}, "
                              f"refiners {st['refined']}, full {st['full']}, home {max(0, self._best)}, "
                              f"since {self._since}, patience {self._patience}")
            self._last = course
        self._turn += 1
        return out


def play(inst: Instance, variant: str, trace: bool = False) -> Outcome:
    world = World.from_grid(inst.grid)
    ids = [f"D{k + 1:02d}" for k in range(len(inst.starts))]
    config = GameConfig(world=WorldSpec(size=world.size, cells=world.packed()), max_turns=inst.max_turns,
                        drones=tuple(DroneSpec(drone=d, start=s) for d, s in zip(ids, inst.starts)))
    plan = Plan(tuple(sorted((1, d, g) for d, g in zip(ids, inst.goals))))
    complete = Traced() if trace else lacam.Lacam()
    timed = arbiter.Timed(arbiter.fixed if variant == "fixed" else complete if variant == "lacam" else
                          arbiter.cooperate)
    # the former D* never said it was stuck behind drones: it waited to the turn limit
    options = {"pibt": None, "lacam": None, "pibt+map": {"dstar": {"known": inst.grid}},
               "fixed": {"dstar": {"stuck_after": inst.max_turns + 1}}}[variant]
    t0 = time.perf_counter()
    result = simulate(config, dict.fromkeys(ids, "dstar"), Inputs(plan=plan), LOG, verify_env=False,
                      arbiter=timed, pilot_options=options)
    seconds = time.perf_counter() - t0
    if isinstance(complete, Traced) and variant == "lacam":
        print("\n".join(f"    {inst.name} {len(ids)}: {line}" for line in complete.lines), file=sys.stderr)
    costs, turns, collisions, at_256, last_move = _costs(result.records, ids, dict(zip(ids, inst.starts)),
                                                        dict(zip(ids, inst.goals)))
    arrived = sum(c is not None for c in costs)
    paid = [turns if c is None else c for c in costs]
    moving = sum(c is None and m > turns - RECENT for c, m in zip(costs, last_move))
    return Outcome(inst.name, len(ids), variant, arrived, sum(paid), max(paid), sum(inst.optimal), max(inst.optimal),
                   collisions, at_256, moving, turns, seconds, timed.cpu, timed.calls, timed.worst, inst.max_turns,
                   inst.bridges)


def _costs(records: list[dict], ids: list[str], starts: dict[str, Cell], goals: dict[str, Cell]
           ) -> tuple[list[int | None], int, int, int, list[int]]:
    """Each agent's cost (the turn after which it stays on its goal; None if not on it at the end), the game's
    length in turns, the collisions (VERTEX and SWAP deaths), how many agents were on their goal at turn
    TURNS_32 (or at the end, if sooner), and each agent's last move (its turn, 0: never moved)."""
    pos = {d: tuple(c) for d, c in starts.items()}
    since = {d: (0 if pos[d] == goals[d] else None) for d in ids}
    last = dict.fromkeys(ids, 0)
    turns = collisions = 0
    at_256 = None
    dead: set[str] = set()
    for r in records:
        if not is_turn(r):
            continue
        turns = r["turn"]
        for d, c in r.get("moves", {}).items():
            pos[d] = tuple(c)
            last[d] = turns
            since[d] = turns if pos[d] == goals[d] else None
        for d, cause in r.get("deaths", {}).items():
            dead.add(d)
            collisions += cause in ("VERTEX", "SWAP")
        if turns == TURNS_32:
            at_256 = sum(since[d] is not None and d not in dead for d in ids)
    costs = [None if d in dead else since[d] for d in ids]
    if at_256 is None:
        at_256 = sum(c is not None for c in costs)
    return costs, turns, collisions, at_256, [last[d] for d in ids]


# --------------------------------------------------------------------------- tables


def _row(cells: Iterable[object]) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


def table(outcomes: list[Outcome], pogema_sps: dict[int, float]) -> str:
    """One row per instance kind, agent count and variant (averaged over instances)."""
    head = ["instance", "edges on no cycle", "agents", "arbitration", "CSR", "ISR", f"ISR@{TURNS_32}", "turn limit",
            "moving at limit",
            "SoC", "SoC/LB", "makespan", "makespan/LB", "collisions", "turns/s", "arbiter ms/turn", "POGEMA steps/s"]
    lines = [_row(head), _row(["---"] * len(head))]
    groups: dict[tuple[str, int, str], list[Outcome]] = {}
    for o in outcomes:
        groups.setdefault((o.instance, o.agents, o.variant), []).append(o)
    for (name, agents, variant), group in groups.items():
        n = len(group)
        pog = pogema_sps.get(agents)
        lines.append(_row([
            name if n == 1 else f"{name} (x{n})", "/".join(sorted({str(o.bridges) for o in group})), agents, variant,
            f"{sum(o.csr for o in group) / n:.2f}", f"{100 * sum(o.isr for o in group) / n:.1f} %",
            f"{100 * sum(o.arrived_256 / o.agents for o in group) / n:.1f} %",
            "/".join(sorted({str(o.max_turns) for o in group})),
            sum(o.moving for o in group if o.limited) if any(o.limited for o in group) else "-",
            f"{sum(o.soc for o in group) / n:.0f}", f"{sum(o.soc / o.soc_lb for o in group) / n:.2f}",
            f"{sum(o.makespan for o in group) / n:.0f}", f"{sum(o.makespan / o.makespan_lb for o in group) / n:.2f}",
            sum(o.collisions for o in group),
            f"{sum(o.turns for o in group) / sum(o.seconds for o in group):.1f}",
            f"{1000 * sum(o.arbiter_cpu for o in group) / max(1, sum(o.arbitrated for o in group)):.2f}",
            "-" if pog is None else f"{pog:.0f}",
        ]))
    return "\n".join(lines)


def summary(outcomes: list[Outcome]) -> str:
    """Per variant: ISR over every agent of every instance, CSR over instances, and the worst arbiter turn."""
    out = []
    for v in VARIANTS:
        mine = [o for o in outcomes if o.variant == v]
        if not mine:
            continue
        agents = sum(o.agents for o in mine)
        held = [o for o in mine if o.bridges == 0]
        worst = min(mine, key=lambda o: o.isr)
        out.append(f"- `{v}`: ISR {100 * sum(o.arrived for o in mine) / agents:.2f} % of {agents} agents (at turn "
                   f"{TURNS_32}: {100 * sum(o.arrived_256 for o in mine) / agents:.2f} %), the lowest "
                   f"{100 * worst.isr:.1f} % ({worst.instance}, {worst.agents} agents); CSR "
                   f"{sum(o.csr for o in mine):.0f} of {len(mine)} instances, {sum(o.csr for o in held):.0f} of the "
                   f"{len(held)} where PIBT's condition holds (no edge on no cycle); "
                   f"{sum(o.collisions for o in mine)} collisions; {sum(o.limited for o in mine)} games ended at "
                   f"their turn limit, with {sum(o.moving for o in mine if o.limited)} agents off their goal still "
                   "moving")
    return "\n".join(out)


def arbiter_alone(counts: Iterable[int], repeats: int = 21) -> dict[int, float]:
    """The arbiter's process time per turn (ms, median of `repeats`) on its own, for each drone count: a dense
    cube of drones (one in three cells taken), each ranking all 7 of its steps in a random order, random
    priorities, each drone's target another's cell, the cube's open cells (the swap's and the clear operation's
    corridor tests, the retreats' hindrance), a salt for the tie-breaks (the turn's, in a game) — a turn of
    conflicts everywhere, many push chains."""
    rng = np.random.default_rng(1)
    out = {}
    for n in counts:
        side = round((3 * n) ** (1 / 3)) + 1
        flat = rng.permutation(side ** 3)[:n]
        before = (np.stack(np.unravel_index(flat, (side, side, side)), axis=1) + 1).astype(np.int32)
        ranked = np.array([rank_steps(RANK_STEPS[k] for k in rng.permutation(len(RANK_STEPS))) for _ in range(n)],
                          np.uint32)
        priority = rng.integers(0, 50, n)
        targets = before[rng.permutation(n)]
        size = (side + 2,) * 3
        world = arbiter.OpenCells(np.zeros(size, bool))
        spent = []
        for turn in range(1, repeats + 1):
            t0 = time.process_time()
            arbiter.cooperate(size, before, before, ranked, np.ones(n, bool), priority, targets, world, turn)
            spent.append(time.process_time() - t0)
        out[n] = 1000 * sorted(spent)[len(spent) // 2]
    return out


# --------------------------------------------------------------------------- distributed city games

#: The distributed city games (`--city-distributed`): world size, drones, swarm hosts (processes).
CITY_GAMES: tuple[tuple[Cell, int, int], ...] = (((256, 256, 32), 1000, 1), ((256, 256, 32), 10_000, 2))
QUICK_CITY_GAMES: tuple[tuple[Cell, int, int], ...] = (((16, 16, 4), 40, 2),)
#: Their autopilot: LRTA* (entities/autopilots/lrta.py), flown by each host's swarm form.
CITY_PILOT = "lrta"
#: Turns played before the measured ones (the swarm hosts chart the map meanwhile).
CITY_WARMUP = 5
#: Each game is played this many times (a target must hold over at least three runs).
CITY_RUNS = 3
#: POGEMA's side of a 1000- or 10,000-agent game: its 64 x 64 map at density 0.3 has 2,867 free cells, too few for
#: 10,000 agents (each needs a cell and a target), so both counts are measured on 256 x 256 (45,875 free cells).
POGEMA_CITY_SIZE = 256

CITY_LEGEND = (
    "Each game through real processes on loopback (benchmarks/games.py's `play_distributed`): a `dronesim router`, the "
    "coordinator, the environment and the swarm hosts (`dronesim drone --autopilot lrta --host Hnn`, the drones "
    "split in id order, each host flying its own with `LrtaSwarm`), this process the scripted ground station. "
    "A city of `World.generate` (seed 1), drones at random free cells with random free targets given at turn 1, "
    "every target reachable; the game runs until every drone has arrived or 4 x the largest side + 64 turns. "
    "turns/s: 1 / the mean time between consecutive STATUS over the turns after the first "
    f"{CITY_WARMUP}; ISR/CSR: on their target in the last STATUS; collisions: deaths of VERTEX or SWAP; arbiter "
    "ms/turn: the coordinator's process time in the arbitration (its log), every turn; CPU: user + system time of "
    "each process over the measured turns; POGEMA 1.4.0 in process with as many agents, random actions, density "
    f"0.3, on {POGEMA_CITY_SIZE}x{POGEMA_CITY_SIZE} (its 64x64 cannot hold 10,000 agents), in the same run. "
    "The machine: 2 cores, shared with other work (the load average at each game's start is in the table).")


@dataclass(frozen=True, slots=True)
class CityGame:
    """One distributed city game (benchmarks/games.py's `play_distributed`) and what it gave."""

    size: Cell
    drones: int
    hosts: int
    run: int
    turns_per_s: float
    measured: int  # turns measured (after CITY_WARMUP)
    arrived: int  # on their target at the end
    collisions: int  # deaths of VERTEX or SWAP
    alive: int
    arbiter_ms: float | None  # the coordinator's CPU in the arbitration, per turn (its log)
    cpu: dict[str, float]  # process -> CPU ms per measured turn
    over: str
    error: str
    load: float  # the machine's load average (1 min) when the game started
    arbiter_worst_ms: float | None = None  # the coordinator's longest turn in the arbitration, CPU (its log)

    @property
    def isr(self) -> float:
        return self.arrived / self.drones


def reachable(grid: np.ndarray, start: Cell) -> np.ndarray:
    """The free cells (not `grid`) connected to `start`, a free cell (6-connectivity), as a bool array of grid's
    shape: its component (`world.search.components`)."""
    return components(grid, np.array([start])).reshape(grid.shape) >= 0


def city_limit(size: Cell) -> int:
    """A city game's turn limit: 4 x its largest side + 64."""
    return 4 * max(size) + 64


def city_trips(size: Cell, drones: int, seed: int) -> tuple[World, np.ndarray, np.ndarray]:
    """A generated city and `drones` trips in it: starts and targets ((drones, 3) each) at random free cells,
    starts distinct, targets distinct, every target reachable (all in the free cells connected to the top
    floor's first free cell)."""
    rng = np.random.default_rng(seed)
    world = World.generate(size, rng)
    grid = np.asarray(world.grid)
    top = np.argwhere(~grid[:, :, -1])[0]
    free = np.argwhere(reachable(grid, (int(top[0]), int(top[1]), size[2] - 1)))
    return world, free[rng.permutation(len(free))[:drones]], free[rng.permutation(len(free))[:drones]]


def lrta_alone(size: Cell, drones: int, radii: Iterable[int], limit: int) -> str:
    """The trips of the distributed city flown by `LrtaSwarm` with nobody in the way (each drone alone: the
    pilot's own quality, without the crowd), for each cube radius: a table in Markdown."""
    from entities.autopilots.base import drive
    from entities.autopilots.lrta import LrtaSwarm

    world, starts, goals = city_trips(size, drones, 1)
    grid = np.asarray(world.grid)
    manhattan = np.abs(starts - goals).sum(axis=1)
    rows = []
    for radius in radii:
        swarm = LrtaSwarm(world_size=size, drones=range(1, drones + 1), lookahead=radius)
        pos, home = starts.astype(np.int64), np.full(drones, -1)
        for turn in range(1, limit + 1):
            live = np.flatnonzero(home < 0)
            if not len(live):
                break
            pos[live] = drive(swarm.step(live + 1, pos[live], goals[live]),
                              lambda cells: grid[tuple(cells.T)].astype(np.uint8))[0]
            home[live[(pos[live] == goals[live]).all(axis=1)]] = turn
        done, limit_game = home >= 0, city_limit(size)
        longest = f"{int(home.max())}" if done.all() else f"not home in {limit} turns ({int((~done).sum())})"
        rows.append([radius, longest, f"{home[done].sum() / manhattan[done].sum():.3f}",
                     int((~done).sum() + (home > limit_game).sum()), f"{swarm.kept / drones:.1f}"])
    head = ["cube radius", "longest trip (turns)", "turns ÷ Manhattan (trips home)",
            f"over {city_limit(size)} turns (the game's limit)", "values learned a drone"]
    return "\n".join([_row(head), _row(["---"] * len(head)), *(_row(r) for r in rows)])


def city_scenario(size: Cell, drones: int, seed: int, folder: Path, pilot: str = CITY_PILOT) -> Path:
    """A scenario file of a generated city (saved beside it) with `drones` drones of autopilot `pilot` (LRTA*) on
    `city_trips`, each target given at turn 1; the turn limit as the in-process city's."""
    world, starts_a, goals_a = city_trips(size, drones, seed)
    starts, goals = starts_a.tolist(), goals_a.tolist()
    world_file = folder / f"city-{seed}.json"
    world.save(world_file)
    ids = [drone_id(k + 1) for k in range(drones)]
    scenario = {"format": "dronesim-scenario", "version": 1, "world": {"file": str(world_file)},
                "drones": [{"id": d, "start": s, "autopilot": pilot} for d, s in zip(ids, starts)],
                "targets": [f"{d}={x},{y},{z}@1" for d, (x, y, z) in zip(ids, goals)],
                "max_turns": city_limit(size) + 10}
    path = folder / f"city-{seed}-{drones}-{pilot}.json"
    path.write_text(json.dumps(scenario), encoding="utf-8")
    return path


def play_city(size: Cell, drones: int, hosts: int, run: int, folder: Path, pilot: str = CITY_PILOT) -> CityGame:
    """One distributed game (coordinator, environment, `hosts` swarm hosts of `pilot` (LRTA*) drones, a loopback
    router, this process as the ground station), played until every drone has arrived or the turn limit."""
    from . import games

    scenario = city_scenario(size, drones, 1, folder, pilot)
    logs = folder / f"{drones}-{run}"
    logs.mkdir(parents=True, exist_ok=True)
    limit = city_limit(size)
    load = os.getloadavg()[0]
    case = games.Case(drones=drones, size=size, warmup=CITY_WARMUP, turns=limit - CITY_WARMUP - 1)
    game = games.play_distributed(case, scenario, logs, variant=games.Variant(autopilot=pilot, hosts=hosts,
                                                                            statuses=False))
    found = re.search(r"arbitration: \d+ turns, ([\d.]+) ms of CPU a turn(?:, the longest ([\d.]+))?",
                      (logs / "coordinator.log").read_text(errors="replace"))
    status = game.last_status
    arrived = collisions = alive = 0
    if status is not None:
        rows = status.drones.rows  # type: ignore[attr-defined]
        on = rows["state"] == list(DroneState).index(DroneState.ALIVE)
        alive = int(on.sum())
        arrived = int((on & (rows["pos"] == rows["target"]).all(axis=1)).sum())
        collisions = int(np.isin(rows["cause"], [list(Cause).index(Cause.VERTEX), list(Cause).index(Cause.SWAP)]).sum())
    mean = sum(game.latencies) / len(game.latencies) if game.latencies else float("nan")
    return CityGame(size, drones, hosts, run, 1 / mean, len(game.latencies), arrived, collisions, alive,
                    float(found.group(1)) if found else None, {n: 1000 * v for n, v in game.cpu.items()},
                    game.over, game.error.splitlines()[0] if game.error else "", load,
                    float(found.group(2)) if found and found.group(2) else None)


def city_table(games: list[CityGame], pogema_sps: dict[int, float]) -> str:
    """One row per game played, then one per world and drone count: the range over the runs and the verdict."""
    head = ["city", "drones", "swarm hosts", "run", "turns/s", "turns measured", "ISR", "CSR", "collisions",
            "arbiter ms/turn", "CPU ms/turn coordinator / env / swarm hosts / router / ground station",
            f"POGEMA steps/s ({POGEMA_CITY_SIZE}x{POGEMA_CITY_SIZE}, same N)", "load (1 min) at start", "game over"]
    lines = [_row(head), _row(["---"] * len(head))]
    for g in games:
        cpu = g.cpu
        swarms = " + ".join(f"{cpu[n]:.1f}" for n in sorted(cpu) if n.startswith("swarm"))
        pog = pogema_sps.get(g.drones)
        lines.append(_row([_size(g.size), g.drones, g.hosts, g.run, f"{g.turns_per_s:.1f}", g.measured,
                           f"{100 * g.isr:.1f} %", f"{float(g.arrived == g.drones):.0f}", g.collisions,
                           "-" if g.arbiter_ms is None else f"{g.arbiter_ms:.2f}",
                           " / ".join([*(f"{cpu.get(n, float('nan')):.1f}" for n in ("coordinator", "env")), swarms,
                                       *(f"{cpu.get(n, float('nan')):.1f}" for n in ("router", "bench"))]),
                           "-" if pog is None else f"{pog:.1f}", f"{g.load:.1f}", g.error or g.over]))
    return "\n".join(lines)


def city_verdicts(games: list[CityGame]) -> str:
    """Each game's turns per second over its runs (the range) against the issue's target."""
    out = []
    for size, drones, hosts in dict.fromkeys((g.size, g.drones, g.hosts) for g in games):
        rates = [g.turns_per_s for g in games if (g.size, g.drones) == (size, drones) and not g.error]
        target = CITY_TARGETS.get(drones)
        verdict = "" if target is None or not rates else (
            f" (target ≥ {target}: {'met in every run' if min(rates) >= target else 'NOT met'})")
        span = f"{min(rates):.1f}–{max(rates):.1f}" if rates else "no run finished"
        out.append(f"- {_size(size)}, {drones} drones, {hosts} swarm host{'s' * (hosts > 1)}: {span} turns/s over "
                   f"{len(rates)} run{'s' * (len(rates) != 1)}{verdict}")
    return "\n".join(out)


#: The issue's targets: drones -> turns per second.
CITY_TARGETS = {1000: 50.0, 10_000: 10.0}
CITY_SECTION = "### Distributed cities (LRTA*)"


def _size(size: Cell) -> str:
    return "x".join(map(str, size))


def city_distributed(quick: bool, runs: int, with_pogema: bool) -> tuple[list[CityGame], dict[int, float]]:
    """Play the distributed city games (`runs` times each, alternated) and POGEMA at the same agent counts."""
    plan = QUICK_CITY_GAMES if quick else CITY_GAMES
    games: list[CityGame] = []
    with tempfile.TemporaryDirectory(prefix="dronesim-city-") as tmp:
        for run in range(1, runs + 1):
            for size, drones, hosts in plan:
                g = play_city(size, drones, hosts, run, Path(tmp))
                games.append(g)
                print(f"  city {_size(size)} {drones} drones / {hosts} hosts, run {run}: {g.turns_per_s:.1f} turns/s "
                      f"over {g.measured} turns, ISR {100 * g.isr:.1f} %, {g.collisions} collisions, arbiter "
                      f"{g.arbiter_ms} ms/turn, {g.error or g.over}", file=sys.stderr, flush=True)
    pogema_sps: dict[int, float] = {}
    if with_pogema:
        try:
            pogema_sps = pogema.steps_per_second(sorted({d for _, d, _ in plan}), 2.0, POGEMA_CITY_SIZE)
        except pogema.Unavailable as err:
            print(f"POGEMA not measured: {err}", file=sys.stderr)
    return games, pogema_sps


# --------------------------------------------------------------------------- the LaCAM-class anchor

ANCHOR_SECTION = "### LaCAM: the complete arbitration and its anchor"
#: The anchor's instances: the densest of every family, on seeds 1-5; the anchor's time limit an instance.
ANCHOR_AGENTS = (400,)
ANCHOR_SEEDS = 5
ANCHOR_SECONDS = 120.0
ANCHOR_LEGEND = (
    "Each instance played in process by D* drones with the complete arbitration (`lacam`, coordinator/lacam.py, "
    "the default) and with PIBT alone (`pibt`), and solved by the anchor, pymapf's LaCAM (Okumura, AAAI 2023), in "
    "its own virtual environment (benchmarks/anchor.py), on the same instances and conventions (4-connected, "
    "vertex and swap conflicts forbidden, agents stay at their goals, an agent's cost the turn after which it "
    "stays on its goal). home: drones on their goal at the end; SoC and makespan (a game not finished counts "
    "its length); s: wall-clock seconds of our whole in-process game (every drone's D* included) and of the "
    "anchor's solve; lacam ms/turn: process time in the arbitration a turn, mean and the longest turn.")


def anchor_compare(families: list[str], agents: tuple[int, ...], seeds: int, seconds: float,
                   variants: tuple[str, ...] = ("lacam", "pibt"), only: tuple[int, ...] = (),
                   trace: bool = False) -> tuple[str, str]:
    """Each instance played by our drones with each of `variants` and solved by the anchor (benchmarks/anchor.py,
    pymapf's LaCAM, in its own environment): a table, one row an instance, and the summary lines."""
    head = ["instance", "agents", "seed", "SoC LB", "makespan LB"]
    for v in variants:
        head += [f"{v} home", f"{v} SoC", f"{v} makespan", f"{v} s"]
    head += ["lacam ms/turn mean / max", "anchor solved", "anchor SoC", "anchor makespan", "anchor s"]
    lines = [_row(head), _row(["---"] * len(head))]
    done: list[tuple[dict[str, Outcome], anchor.Result | None]] = []
    for family in families:
        for n in agents:
            for seed in only or range(1, seeds + 1):
                inst = movingai_instance(family, n, seed)
                ours = {v: play(inst, v, trace) for v in variants}
                g = inst.grid[:, :, 0]
                rows = [[int(g[x, y]) for x in range(g.shape[0])] for y in range(g.shape[1])]
                theirs: anchor.Result | None = None
                try:  # (--anchor-seconds 0: ours alone, as the anchor's figures are in an earlier run)
                    if seconds > 0:
                        theirs = anchor.solve([(rows, [s[:2] for s in inst.starts], [t[:2] for t in inst.goals])],
                                              seconds)[0]
                except anchor.Unavailable as err:
                    print(f"anchor not measured: {err}", file=sys.stderr)
                done.append((ours, theirs))
                first = ours[variants[0]]
                row: list[object] = [family, n, seed, first.soc_lb, first.makespan_lb]
                for v in variants:
                    o = ours[v]
                    row += [f"{o.arrived}/{o.agents}", o.soc, o.makespan, f"{o.seconds:.1f}"]
                lc = ours.get("lacam", first)
                row += [f"{1000 * lc.arbiter_cpu / max(1, lc.arbitrated):.1f} / {1000 * lc.arbiter_worst:.1f}"]
                row += (["-"] * 4 if theirs is None else
                        [str(theirs.solved).lower(), theirs.soc if theirs.solved else "-",
                         theirs.makespan if theirs.solved else "-", f"{theirs.seconds:.1f}"])
                lines.append(_row(row))
                print(f"  {lines[-1]}", file=sys.stderr, flush=True)
    out = []
    for v in variants:
        mine = [o[v] for o, _ in done]
        both = [(o[v], a) for o, a in done if a is not None and a.solved and o[v].csr]
        ratio = sum(o.soc / a.soc for o, a in both) / max(1, len(both))
        out.append(f"- `{v}`: CSR {sum(o.csr for o in mine):.0f} of {len(mine)}, ISR "
                   f"{100 * sum(o.arrived for o in mine) / max(1, sum(o.agents for o in mine)):.2f} %, within 4 x the "
                   f"lower-bound makespan {sum(bool(o.csr) and o.makespan <= 4 * o.makespan_lb for o in mine)}; "
                   "sum of costs "
                   f"{ratio:.2f} x the anchor's on the {len(both)} instances both solved; the longest arbitration "
                   f"turn {1000 * max((o.arbiter_worst for o in mine), default=0):.1f} ms")
    anchors = [a for _, a in done if a is not None]
    out.append(f"- anchor (pymapf {anchor.VERSION} LaCAM, {seconds:g} s an instance): solved "
               f"{sum(a.solved for a in anchors)} of {len(anchors)}, "
               f"{sum(a.seconds for a in anchors) / max(1, len(anchors)):.1f} s an instance")
    return "\n".join(lines), "\n".join(out)


def search_alone(cases: list[tuple[str, int]], turns: int = 40) -> dict[tuple[str, int], tuple[float, float, float]]:
    """The complete arbitration's search on its own, per turn of its budget (`lacam.WORK`): for each (family or
    "city", drones), the search started at the instance's start (its graph and distance tables made beforehand,
    untimed), `turns` turns of its work each followed by its step; process time a turn in ms: mean, 95th
    percentile, longest (the garbage collector held off, as `arbiter.Timed` does)."""
    out = {}
    for family, n in cases:
        inst = city_instance(CITY[0], n, 1) if family == "city" else movingai_instance(family, n, 1)
        size: Cell = inst.grid.shape
        open_ = arbiter.OpenCells(inst.grid)
        search = lacam.Lacam()
        pos, goals, coop = np.array(inst.starts, np.int32), np.array(inst.goals, np.int32), np.ones(n, bool)
        while search.follow(size, pos, coop, goals, open_) is None or not search.busy:
            pass  # (the tables made a turn's work at a time, the drones holding: an unbounded turn would also search
            # to the goal and refine the plan without end)
        spent = []
        gc.disable()
        try:
            for turn in range(turns):
                t0 = time.process_time()
                plan = search.follow(size, pos, coop, goals, open_, turn)
                spent.append(time.process_time() - t0)
                assert plan is not None
                pos = cells_of(plan, size)
        finally:
            gc.enable()
        ms = 1000 * np.array(spent)
        out[(family, n)] = (float(ms.mean()), float(np.percentile(ms, 95)), float(ms.max()))
    return out


# --------------------------------------------------------------------------- main


def instances(quick: bool, seeds: int, agents: tuple[int, ...], families: list[str], city: bool
              ) -> list[Instance]:
    out = [movingai_instance(f, n, seed) for seed in range(1, seeds + 1) for f in families for n in agents]
    if city:
        size, n = QUICK_CITY if quick else CITY
        out.append(city_instance(size, n, 1))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="dronesim bench swarm", description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small instances (for tests)")
    parser.add_argument("--agents", default=",".join(map(str, AGENTS)), help="agent counts on the 32x32 maps")
    parser.add_argument("--families", default=",".join(movingai.FAMILIES), help="MovingAI families to play")
    parser.add_argument("--seeds", type=int, default=1, help="instances per family and agent count (default 1)")
    parser.add_argument("--variants", default=",".join(VARIANTS), help=f"among {', '.join(VARIANTS)}")
    parser.add_argument("--no-city", action="store_true", help="skip the 3D city of 1000 drones")
    parser.add_argument("--no-pogema", action="store_true", help="do not run POGEMA")
    parser.add_argument("--city-distributed", action=argparse.BooleanOptionalAction, default=None,
                        help="--city-distributed: only the distributed city games (LRTA*, real processes); "
                             "--no-city-distributed: skip them (default: play everything)")
    parser.add_argument("--city-runs", type=int, default=CITY_RUNS, help=f"runs of each distributed city game "
                                                                          f"(default {CITY_RUNS})")
    parser.add_argument("--anchor", action="store_true",
                        help="only the complete arbitration (lacam) and PIBT (--variants: those) against the "
                             "LaCAM-class anchor (pymapf, in its own environment) on the densest instances "
                             f"({'/'.join(map(str, ANCHOR_AGENTS))} agents) of every family, seeds 1-{ANCHOR_SEEDS} "
                             "(--agents, --seeds, --families narrow it)")
    parser.add_argument("--anchor-seconds", type=float, default=ANCHOR_SECONDS,
                        help="the anchor's time an instance (0: not run)")
    parser.add_argument("--city-dstar", action="store_true",
                        help="only the 64x64x8 city of 1000 D* drones through real processes (one swarm host, the "
                             "default arbitration: the complete search), --city-runs times")
    parser.add_argument("--search-alone", action="store_true",
                        help="only the complete arbitration's search on its own: ms a turn of its budget at 400 "
                             "drones on the densest families and 1000 drones in the 64x64x8 city")
    parser.add_argument("--lrta-alone", action="store_true",
                        help="only the distributed city's 10,000 trips flown by LRTA* drones each alone, for cube "
                             "radii 0-2 (the pilot's own quality, docs/cooperation.md)")
    parser.add_argument("--seed", type=int, action="append", default=[],
                        help="with --anchor: only this seed (repeatable), e.g. one failing instance alone")
    parser.add_argument("--trace", action="store_true",
                        help="with --anchor: print the complete arbitration's course (which search runs when, "
                             "found, nodes, the plan left, refiners, home, patience) on stderr, a line a change")
    add_write_args(parser)
    args = parser.parse_args(argv)
    agents = (10, 20) if args.quick else tuple(int(a) for a in args.agents.split(","))
    families = [f for f in args.families.split(",") if f]
    variants = [v for v in args.variants.split(",") if v]
    bad = [v for v in variants if v not in VARIANTS] + [f for f in families if f not in movingai.FAMILIES]
    if bad:
        print(f"unknown: {', '.join(bad)}", file=sys.stderr)
        return 2
    if args.lrta_alone:
        size, drones = (QUICK_CITY_GAMES if args.quick else CITY_GAMES)[-1][:2]
        print(lrta_alone(size, drones, (0, 1, 2), limit=6000))
        return 0
    t_start = time.perf_counter()
    if args.city_dstar:
        size, drones = QUICK_CITY if args.quick else CITY
        with tempfile.TemporaryDirectory(prefix="dronesim-city-") as tmp:
            for run in range(1, max(1, args.city_runs) + 1):
                g = play_city(size, drones, 1, run, Path(tmp), "dstar")
                print(f"- city {_size(size)}, {drones} D* drones, run {run} (load {g.load:.1f} at its start): "
                      f"{g.turns_per_s:.1f} turns/s over {g.measured} turns, {g.arrived} of {drones} home "
                      f"({g.alive} alive), {g.collisions} collisions; the arbitration {g.arbiter_ms} ms of CPU a turn, "
                      f"the longest {g.arbiter_worst_ms}; {g.error or g.over}", flush=True)
        return 0
    if args.search_alone:
        dense = ("room-32-32-4", "random-32-32-20", "maze-32-32-2", "warehouse-32-32")
        cases = [("room-32-32-4", 50)] if args.quick else [(f, 400) for f in dense] + [("city", 1000)]
        for (family, n), (mean, p95, worst) in search_alone(cases).items():
            print(f"- {family}, {n} drones: {mean:.1f} ms a turn on average, 95th percentile {p95:.1f}, longest "
                  f"{worst:.1f}")
        return 0
    if args.anchor:
        chosen = agents if "--agents" in (argv or sys.argv) else (10,) if args.quick else ANCHOR_AGENTS
        seeds = args.seeds if "--seeds" in (argv or sys.argv) else 1 if args.quick else ANCHOR_SEEDS
        played = tuple(variants) if "--variants" in (argv or sys.argv) else ("lacam", "pibt")
        body_table, lines = anchor_compare(families, chosen, seeds, args.anchor_seconds, played, tuple(args.seed),
                                           args.trace)
        print()
        print(body_table)
        print()
        print(lines)
        if args.write:
            body = (f"{command_line('swarm', argv, time.perf_counter() - t_start)}\n\n{ANCHOR_LEGEND}\n\n"
                    f"{body_table}\n\n{lines}\n")
            replace_subsection(args.output, SECTION, ANCHOR_SECTION, body)
            print(f"\nwrote {ANCHOR_SECTION!r} in {args.output}")
        return 0
    city_games: list[CityGame] = []
    city_pogema: dict[int, float] = {}
    if args.city_distributed is not False:
        city_games, city_pogema = city_distributed(args.quick, max(1, args.city_runs), not args.no_pogema)
        city_body = (f"{city_table(city_games, city_pogema)}\n\n{city_verdicts(city_games)}")
        print()
        print(city_body)
        if args.write:
            body = (f"{command_line('swarm', argv, time.perf_counter() - t_start)}\n\n{CITY_LEGEND}\n\n{city_body}\n")
            replace_subsection(args.output, SECTION, CITY_SECTION, body)
            print(f"\nwrote {CITY_SECTION!r} in {args.output}")
        if args.city_distributed:
            return 0 if all(not g.error and g.collisions == 0 for g in city_games) else 1
    todo = instances(args.quick, args.seeds, agents, families, not args.no_city)
    outcomes = []
    for inst in todo:
        for v in variants:
            o = play(inst, v)
            outcomes.append(o)
            print(f"  {inst.name} {o.agents} {v}: ISR {100 * o.isr:.1f} % (at {TURNS_32}: "
                  f"{100 * o.arrived_256 / o.agents:.1f} %, moving at the end {o.moving}), "
                  f"SoC/LB {o.soc / o.soc_lb:.2f}, "
                  f"{o.turns} turns in {o.seconds:.1f} s, arbiter {1000 * o.arbiter_cpu / max(1, o.arbitrated):.2f} "
                  "ms/turn", file=sys.stderr, flush=True)
    counts = sorted({o.agents for o in outcomes})
    pogema_sps: dict[int, float] = {}
    if not args.no_pogema:
        try:
            pogema_sps = pogema.steps_per_second(counts, 1.0)
        except pogema.Unavailable as err:
            print(f"POGEMA not measured: {err}", file=sys.stderr)
    body_table = table(outcomes, pogema_sps)
    alone = arbiter_alone((100, 1000) if args.quick else (1000, 2000, 5000, 10000))
    lines = summary(outcomes) + "\n- the arbiter alone (a dense cube of drones, conflicts everywhere), ms/turn: " + \
        ", ".join(f"{n} drones {ms:.2f}" for n, ms in alone.items())
    print()
    print(body_table)
    print()
    print(lines)
    if args.write:
        body = (
            f"{command_line('swarm', argv, time.perf_counter() - t_start)}\n\n"
            "Every instance played in process by D* drones (the journal is the one a distributed run writes), three "
            "ways: `fixed` the former arbitration (one move per drone, fixed priority), `pibt` PIBT over the drones' "
            "ranked candidates (in force), `pibt+map` the same with the map known from the start. MovingAI 32x32 "
            "families generated by world/movingai.py (seeded), the first N agents of one random scenario each; "
            "a 3D city of World.generate. Edges on no cycle: the edges of the free cells' graph that lie on no "
            "cycle (bridges; 0: PIBT's condition holds, where every drone must arrive). CSR/ISR: on the goal at "
            "the end; SoC and makespan with their ratio to the "
            "lower bound (sum and max of single-agent optimal lengths); turns/s of the whole in-process game "
            "(every drone's D* planning included, one process); arbiter ms/turn: process time inside the "
            "arbitration; POGEMA steps/s: POGEMA 1.4.0 with as many agents, random actions, 64x64, same run. "
            f"Turn limit on 32x32: {LIMIT_PER_MAKESPAN} x the lower-bound makespan, at least {TURNS_32}; "
            f"ISR@{TURNS_32}: on the goal at turn {TURNS_32} (POGEMA's episode); moving at limit: in games that "
            f"reached their turn limit, agents off their goal that moved in the last {RECENT} turns.\n\n"
            f"{body_table}\n\n{lines}\n"
        )
        replace_section(args.output, SECTION, body, keep=(CITY_SECTION, ANCHOR_SECTION))
        print(f"\nwrote {SECTION!r} in {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
