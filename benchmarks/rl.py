"""RL benchmark: steps per second of `dronesim.pettingzoo.parallel_env`, both backends, beside POGEMA's.

    dronesim bench rl                       # 1, 16, 128 and 1000 drones, safe and random, three runs, and POGEMA
    dronesim bench rl --write               # the same, "## RL environment" in BENCHMARKS.md
    dronesim bench rl --quick --no-pogema   # a tiny subset (used by the tests)
    dronesim bench rl --few-gain --counts 1,16,64   # the few drones' episode over lists on beside off
    dronesim bench rl --ahead-gain --counts 1,128   # the zenoh backend's MOVES ahead on beside off (idem)

Each run measures, at every agent count, one after the other (the machine's speed drifts): POGEMA 1.4.0's
PettingZoo integration (`pogema.integrations.pettingzoo.parallel_env`, in its own cached virtual environment,
benchmarks/pogema.py: a 64x64 grid of obstacle density 0.3, observation radius 5, uniformly random actions,
agents staying on their targets) and our `parallel_env` with backend="local" (in this process, each step a
turn of the engine: the episode's rules over lists up to 64 drones, in arrays beyond) under two policies,
alternately in `--slices` slices of `--seconds` (on a
shared machine a burst of other work then slows all alike), then our backend="zenoh" (every step a turn of the
coordinator and environment processes, through a router in this process) under the safe policy. Ours: a
64x64x16 world generated from seed 1 and given (every episode on it, as POGEMA's map is one per seed),
observation radius 2 (a cube of 125 cells, POGEMA's 121), on_target="stay". The step calls are timed, after 20
warm-up steps (in every slice), for `--seconds` of stepping; with the random policy the resets too. POGEMA and
the local backend are timed in their process's CPU time (each is one process: other work on a shared machine
then slows neither), the zenoh backend by the wall clock (its step spans three processes).

Policies. "safe": random among the moves its observation shows to be safe (hover, or a free neighbour cell
next to no other drone), which never kills a drone (no building, no border, and no two drones can choose one
cell or swap): every step has all its agents, as POGEMA's, whose agents are only blocked where ours die.
"random": uniformly random actions, as POGEMA's; drones die, an episode ends when every drone has, and the
environment is reset then (timed: a reset is part of what a policy that dies costs). The table says how many
agents were acting at the end (safe) and how many episodes the random policy played.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import shlex
import sys
import time
from collections.abc import Callable

import numpy as np

from benchmarks import add_write_args, pogema, replace_section
from benchmarks.measure import busy_seconds, machine

SECTION = "## RL environment"
COUNTS = (1, 16, 128, 1000)
SIZE = (64, 64, 16)
RADIUS = 2
WARMUP = 20
#: POGEMA and the local backend are measured alternately, in this many slices of `--seconds` each.
SLICES = 4
#: Targets (issue "A PettingZoo environment"): local ≥ POGEMA at every count, zenoh ≥ 25 % of it at 128.
LOCAL_RATIO, ZENOH_RATIO, ZENOH_AT = 1.0, 0.25, 128


class SafeRandom:
    """Random among the actions an observation shows to be safe (see the module's docstring); needs an
    observation radius of at least 2 (the cells next to each neighbour cell)."""

    def __init__(self, radius: int, seed: int = 0) -> None:
        from dronesim.rl import ACTIONS

        if radius < 2:
            raise ValueError("SafeRandom needs an observation radius >= 2")
        side = 2 * radius + 1
        stride = np.array([side * side, side, 1])
        centre = (side ** 3) // 2
        deltas = np.array(ACTIONS[1:])
        self.cell = centre + deltas @ stride  # each move's destination
        around = [[centre + (d + e) @ stride for e in deltas if (d + e).any()] for d in deltas]
        self.around = np.array(around)  # (6, 5): the cells next to each destination, but the centre
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """An action (0..6) per row of `obs` ((m, cells + 3))."""
        from dronesim.rl import Seen

        free = obs[:, self.cell] == Seen.FREE
        lonely = (obs[:, self.around] != Seen.DRONE).all(axis=2)
        allowed = np.concatenate([np.ones((len(obs), 1), bool), free & lonely], axis=1)
        return np.argmax(self.rng.random(allowed.shape) * allowed, axis=1)


POLICIES = ("safe", "random")


def world():
    """The benchmark's world: generated from seed 1 (as `parallel_env(size=SIZE, seed=1)`'s first episode's)."""
    from world.grid import World

    return World.generate(SIZE, np.random.default_rng(1), keep_free=())


def ours(backend: str, n: int, seconds: float, few_drones: int | None = None, moves_ahead: bool = True,
         policy: str = "safe") -> tuple[float, int, int]:
    """Steps per second of our parallel_env with `n` drones on `backend` under `policy` (POLICIES), the agents
    acting at the end and the episodes reset; `few_drones`: the env's (None: its default; 0: the engine's path
    whatever the count); `moves_ahead`: the zenoh backend's (False: each MOVES waits for its drones' phase)."""
    from dronesim.pettingzoo import parallel_env

    env = parallel_env(num_drones=n, world=world(), obs_radius=RADIUS, on_target="stay", max_cycles=10**6, seed=1,
                       backend=backend)
    if few_drones is not None:
        env.few_drones = few_drones
    env.moves_ahead = moves_ahead
    safe = SafeRandom(RADIUS) if policy == "safe" else None
    # the local backend and POGEMA are one process each: their CPU time, which other work on a shared machine
    # does not inflate; the zenoh backend's step spans three processes: wall-clock time
    clock = time.process_time if backend == "local" else time.perf_counter
    try:
        rate, resets = stepping(env, safe, seconds, clock)
        return rate, len(env.agents), resets
    finally:
        env.close()


def stepping(env, safe: SafeRandom | None, seconds: float, clock: Callable[[], float],
             warmup: int = WARMUP) -> tuple[float, int]:
    """The benchmark's loop over `env` (reset with seed 1): its agents' actions from `safe`, or uniformly random
    from `default_rng(0)` (None), every episode reset when its drones are gone (timed with the steps), until
    `seconds` of `clock` after `warmup` steps (or, with `safe`, until no agent is left). Steps per second after the
    warm-up, and the resets. (Its source only needs numpy as `np`: `benchmarks.versus` runs it in an earlier tree.)"""
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=1)
    steps, spent, resets = 0, 0.0, 0
    while spent < seconds and (env.agents or safe is None):
        reset = 0.0
        if not env.agents:  # (random: every drone died; the reset is timed with the steps)
            t0 = clock()
            obs, _ = env.reset()
            reset = clock() - t0
            resets += 1
        agents = env.agents
        chosen = safe(np.stack([obs[a] for a in agents])) if safe is not None else rng.integers(0, 7, len(agents))
        actions = dict(zip(agents, chosen.tolist()))
        t0 = clock()
        obs = env.step(actions)[0]
        if steps >= warmup:
            spent += clock() - t0 + reset
        steps += 1
    return (steps - warmup) / spent if spent else float("nan"), resets


def _range(values: list[float], fmt: str) -> str:
    lo, hi = min(values), max(values)
    return fmt.format(lo) if len(values) == 1 or fmt.format(lo) == fmt.format(hi) else \
        f"{fmt.format(lo)}–{fmt.format(hi)}"


def run(counts: tuple[int, ...], seconds: float, repeat: int, with_pogema: bool,
        slices: int = SLICES) -> tuple[str, bool, list[str]]:
    """(the table, whether every target was met, notes) over `repeat` runs: a row per agent count and policy."""
    rates: dict[tuple[str, int, str], list[float]] = {}  # (backend, agents, policy) -> a rate per run
    acting: dict[tuple[str, int, str], list[int]] = {}  # ... -> the agents acting at the end (safe)
    episodes: dict[int, list[int]] = {}  # agents -> episodes reset per run (random)
    notes: list[str] = []
    for r in range(repeat):
        for n in counts:  # side by side, within seconds of each other: the machine's speed drifts
            # POGEMA and the local backend's two policies alternate in `slices` slices each (a burst of other
            # work on the shared machine then slows all alike); each figure is the mean of its slices' rates
            pog: list[float] | None = [] if with_pogema else None
            pog_wall: list[float] = []  # (the zenoh backend's steps are timed by the wall clock: so are these)
            local: dict[str, list[float]] = {p: [] for p in POLICIES}
            resets = 0
            for _ in range(slices):
                if pog is not None:
                    try:
                        cpu, wall = pogema.parallel_rates([n], seconds / slices)[n]
                        pog.append(cpu)
                        pog_wall.append(wall)
                    except pogema.Unavailable as err:
                        notes.append(f"run {r + 1}, {n} agents: POGEMA not measured: {err}")
                        print(f"  POGEMA: {err}", file=sys.stderr)
                        pog = None
                for policy in POLICIES:
                    rate, left, reset = ours("local", n, seconds / slices, policy=policy)
                    local[policy].append(rate)
                    if policy == "safe":
                        acting.setdefault(("local", n, policy), []).append(left)
                    resets += reset
            if pog:
                rates.setdefault(("pogema", n, "random"), []).append(sum(pog) / len(pog))
                rates.setdefault(("pogema wall", n, "random"), []).append(sum(pog_wall) / len(pog_wall))
            episodes.setdefault(n, []).append(resets + slices)
            for policy in POLICIES:
                rates.setdefault(("local", n, policy), []).append(sum(local[policy]) / slices)
            rate, left, _ = ours("zenoh", n, seconds)
            rates.setdefault(("zenoh", n, "safe"), []).append(rate)
            acting.setdefault(("zenoh", n, "safe"), []).append(left)
            print(f"  run {r + 1}, {n} drones: local {rates[('local', n, 'safe')][-1]:.1f} (safe), "
                  f"{rates[('local', n, 'random')][-1]:.1f} (random), zenoh {rate:.1f} (safe) steps/s; POGEMA "
                  f"{rates.get(('pogema', n, 'random'), [float('nan')])[-1]:.1f}", file=sys.stderr, flush=True)
    head = ("agents", "policy", "POGEMA PettingZoo steps/s", "local steps/s", "local ÷ POGEMA", "zenoh steps/s",
            "zenoh ÷ POGEMA", "agents acting at the end (local / zenoh); episodes", "target")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    ok = True
    for n in counts:
        pog = rates.get(("pogema", n, "random"), [])
        for policy in POLICIES:
            ours_, zen = rates[("local", n, policy)], rates.get(("zenoh", n, policy), [])
            paired = len(pog) == repeat
            lr = [a / b for a, b in zip(ours_, pog)] if paired else []
            zr = [a / b for a, b in zip(zen, rates[("pogema wall", n, "random")])] if paired and zen else []
            verdicts = []
            if not paired:
                verdicts.append("not judged: POGEMA not measured in every run")
                ok = False
            else:
                met = min(lr) >= LOCAL_RATIO
                verdicts.append(f"local ≥ POGEMA: {'met' if met else 'UNMET'}")
                ok &= met
                if n == ZENOH_AT and zr:
                    met = min(zr) >= ZENOH_RATIO
                    verdicts.append(f"zenoh ≥ 25 % of POGEMA: {'met' if met else 'UNMET'}")
                    ok &= met
            end = (f"{min(acting[('local', n, policy)])} / {min(acting[('zenoh', n, policy)])} of {n}"
                   if policy == "safe" else f"{_range([float(e) for e in episodes[n]], '{:.0f}')} episodes a run")
            lines.append("| " + " | ".join([
                str(n), policy, _range(pog, "{:.1f}") if pog else "—", _range(ours_, "{:.1f}"),
                _range(lr, "{:.1f}x") if lr else "—", _range(zen, "{:.1f}") if zen else "—",
                _range(zr, "{:.2f}x") if zr else "—", end, "; ".join(verdicts)]) + " |")
    return "\n".join(lines), ok, notes


def few_gain(counts: tuple[int, ...], seconds: float, repeat: int) -> str:
    """The few drones' episode's gain (docs/performance.md): local steps/s with its rules over lists (`FewEpisode`,
    the default up to EPISODE_FEW_DRONES drones) and without (`few_drones = 0`: `Episode`, in arrays); both step
    through the engine's turn."""
    from dronesim.rl_few import FEW_MAX

    return _gain(counts, repeat, ("episode over lists", lambda n: ours("local", n, seconds, FEW_MAX)[0]),
                 ("episode in arrays", lambda n: ours("local", n, seconds, 0)[0]), "{:.1f}x")


def ahead_gain(counts: tuple[int, ...], seconds: float, repeat: int) -> str:
    """MOVES ahead's gain (docs/performance.md): zenoh steps/s with each step's MOVES sent with its DONE (the
    default) and after its drones' phase is announced."""
    return _gain(counts, repeat, ("MOVES ahead", lambda n: ours("zenoh", n, seconds)[0]),
                 ("MOVES after the phase", lambda n: ours("zenoh", n, seconds, moves_ahead=False)[0]), "{:.2f}x")


def _gain(counts: tuple[int, ...], repeat: int, on: tuple[str, Callable[[int], float]],
          off: tuple[str, Callable[[int], float]], fmt: str) -> str:
    """A mechanism on beside off: steps/s of each, alternated on, off, on, off at each count, `repeat` pairs;
    each ratio is taken within a pair."""
    lines = [f"| agents | {on[0]} steps/s | {off[0]} steps/s | gain |", "|---|---|---|---|"]
    for n in counts:
        ons, offs = [], []
        for _ in range(repeat):
            ons.append(on[1](n))
            offs.append(off[1](n))
        lines.append(f"| {n} | {_range(ons, '{:.0f}')} | {_range(offs, '{:.0f}')} | "
                     f"{_range([a / b for a, b in zip(ons, offs)], fmt)} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="dronesim bench rl", description=__doc__.split("\n")[0])
    parser.add_argument("--counts", default=",".join(map(str, COUNTS)), help="agent counts (default 1,16,128,1000)")
    parser.add_argument("--seconds", type=float, default=2.0, help="seconds of stepping per measure (default 2)")
    parser.add_argument("--repeat", type=int, default=3, help="runs; the table gives each figure's range (default 3)")
    parser.add_argument("--quick", action="store_true", help="1 and 16 drones, 0.3 s each, one run (for the tests)")
    parser.add_argument("--no-pogema", dest="pogema", action="store_false",
                        help="do not measure POGEMA (installed once into a cached virtual environment)")
    parser.add_argument("--slices", type=int, default=SLICES,
                        help=f"POGEMA and the local backend alternate in this many slices (default {SLICES})")
    parser.add_argument("--few-gain", action="store_true",
                        help="only the local backend, the few drones' episode over lists on and off (performance.md)")
    parser.add_argument("--ahead-gain", action="store_true",
                        help="only the zenoh backend, MOVES ahead on and off (docs/performance.md)")
    add_write_args(parser)
    args = parser.parse_args(argv)
    try:
        counts = tuple(int(c) for c in args.counts.split(","))
    except ValueError:
        parser.error("--counts takes integers separated by commas")
    if args.quick:
        counts, args.seconds, args.repeat = (1, 16), 0.3, 1
    if args.repeat < 1 or args.seconds <= 0 or min(counts) < 1 or args.slices < 1:
        parser.error("--repeat, --seconds, --slices and the counts must be positive")
    if args.few_gain or args.ahead_gain:
        print((few_gain if args.few_gain else ahead_gain)(counts, args.seconds, args.repeat))
        return 0
    started, load, busy = time.monotonic(), os.getloadavg()[0], busy_seconds()
    table, ok, notes = run(counts, args.seconds, args.repeat, args.pogema, args.slices)
    seconds = time.monotonic() - started
    (t0, m0), (t1, m1) = busy, busy_seconds()
    others = max(0.0, (t1 - t0) - (m1 - m0)) / max(seconds, 1e-9)  # cores other work used meanwhile
    print()
    print(table)
    print(f"\n{seconds:.0f} s; load average (1 min) before the run {load:.2f}; other processes used {others:.2f} "
          "cores on average during the run", file=sys.stderr)
    for note in notes:
        print(note, file=sys.stderr)
    if args.write:
        mach = machine()
        cmd = "dronesim bench rl " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
        body = (
            f"Command: `{cmd.strip()}`, run {_dt.date.today().isoformat()} on {mach['cpu']} ({mach['arch']}, "
            f"nproc = {mach['nproc']}), Python {mach['python']}, eclipse-zenoh {mach['zenoh']}, "
            f"{seconds:.0f} s in all. Load average (1 min) before the run {load:.2f}; other processes used "
            f"{others:.2f} cores on average during the run"
            + (" (other work ran alongside: absolute numbers are pessimistic, ratios are taken within seconds)."
               if others > 0.2 else ".") + "\n\n"
            "Targets (issues \"A PettingZoo environment\" and \"Train with the tools RL researchers use\"): the "
            "local backend ≥ POGEMA's PettingZoo integration at every agent count, under the safe policy and under "
            "uniformly random actions (resets included), the zenoh backend ≥ 25 % of it at 128 agents, in the same "
            "run.\n\n"
            f"{table}\n\n"
            f"Legend. Steps per second of `parallel_env(...).step` alone (local and POGEMA: per second of their "
            "process's CPU time, which other work on a shared machine does not inflate; zenoh: wall clock, its "
            "step spans three processes, and its ratio is to POGEMA's wall-clock rate over the same steps), after "
            f"{WARMUP} warm-up steps, "
            f"{args.seconds:g} s of stepping per figure; POGEMA and the local backend's two policies alternate in "
            f"{args.slices} slices of it (a new environment each, the figure the mean of their rates), so that a "
            "burst of other work slows all alike; with several runs, each figure is the range over the runs and "
            "each ratio is taken within a run. POGEMA: 1.4.0's `pogema.integrations.pettingzoo."
            "parallel_env` in its own virtual environment, 64x64 grid, density 0.3, observation radius 5, random "
            "actions, on_target \"nothing\" (its agents never die: no reset). Ours: a 64x64x16 world generated from "
            "seed 1 and given (every episode on it, as POGEMA's map), observation radius 2 (125 cells), "
            "on_target \"stay\"; policy \"safe\": random safe actions (benchmarks/rl.py: no drone dies, so every "
            "step has all its agents), \"random\": uniformly random actions, drones die, and an episode whose "
            "drones have all died is reset, the reset timed with the steps (the episodes column); local = in this "
            "process, each step a turn of the engine (`Engine.play`; the episode's rules over lists up to 64 drones, "
            "`dronesim/rl_few.py`, in arrays beyond), zenoh = each step a turn of the coordinator and "
            "environment processes through a router in this process (the step's DONE and MOVES sent at once: one "
            "round trip).\n"
            + "".join(f"\n{note}\n" for note in notes)
        )
        replace_section(args.output, SECTION, body)
        print(f"\nwrote {SECTION!r} in {args.output}")
    return 0 if ok or not args.pogema else 1


if __name__ == "__main__":
    raise SystemExit(main())
