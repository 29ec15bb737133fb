"""RL benchmark: steps per second of `dronesim.pettingzoo.parallel_env`, both backends, beside POGEMA's.

    dronesim bench rl                       # 1, 16, 128 and 1000 drones, local and zenoh, and POGEMA
    dronesim bench rl --repeat 3 --write    # three runs, ranges, "## RL environment" in BENCHMARKS.md
    dronesim bench rl --quick --no-pogema   # a tiny subset (used by the tests)
    dronesim bench rl --few-gain --counts 1,16,64   # the drone-by-drone path on beside off (performance.md)
    dronesim bench rl --ahead-gain --counts 1,128   # the zenoh backend's MOVES ahead on beside off (idem)

Each run measures, at every agent count, one after the other (the machine's speed drifts): POGEMA 1.4.0's
PettingZoo integration (`pogema.integrations.pettingzoo.parallel_env`, in its own cached virtual environment,
benchmarks/pogema.py: a 64x64 grid of obstacle density 0.3, observation radius 5, uniformly random actions,
agents staying on their targets) and our `parallel_env` with backend="local" (in this process: drone by drone
up to 64 drones, else the engine), alternately in `--slices` slices of `--seconds` (on a shared machine a
burst of other work then slows both alike), then our backend="zenoh" (every step a turn of the coordinator and
environment processes, through a router in this process). Ours: a 64x64x16 generated world, observation
radius 2 (a cube of 125 cells, POGEMA's 121), on_target="stay". Only the step calls are timed, after 20
warm-up steps (in every slice), for `--seconds` of stepping.

Our drones die where POGEMA's agents would only be blocked, so random actions would empty the world within
a few dozen steps: the policy here is random among the moves its observation shows to be safe (hover, or a
free neighbour cell next to no other drone), which never kills a drone (no building, no border, and no two
drones can choose one cell or swap). The table says how many agents were still acting at the end.
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
from benchmarks.perf import busy_seconds, machine

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


def ours(backend: str, n: int, seconds: float, few_drones: int | None = None,
         moves_ahead: bool = True) -> tuple[float, int]:
    """Steps per second of our parallel_env with `n` drones on `backend`, and the agents acting at the end;
    `few_drones`: the env's (None: its default; 0: the engine's path whatever the count); `moves_ahead`: the
    zenoh backend's (False: each MOVES waits for its drones' phase)."""
    from dronesim.pettingzoo import parallel_env

    env = parallel_env(num_drones=n, size=SIZE, obs_radius=RADIUS, on_target="stay", max_cycles=10**6, seed=1,
                       backend=backend)
    if few_drones is not None:
        env.few_drones = few_drones
    env.moves_ahead = moves_ahead
    policy = SafeRandom(RADIUS)
    try:
        obs, _ = env.reset(seed=1)
        steps, spent = 0, 0.0
        while spent < seconds and env.agents:
            agents = env.agents
            actions = dict(zip(agents, policy(np.stack([obs[a] for a in agents])).tolist()))
            t0 = time.perf_counter()
            obs = env.step(actions)[0]
            if steps >= WARMUP:
                spent += time.perf_counter() - t0
            steps += 1
        return (steps - WARMUP) / spent if spent else float("nan"), len(env.agents)
    finally:
        env.close()


def _range(values: list[float], fmt: str) -> str:
    lo, hi = min(values), max(values)
    return fmt.format(lo) if len(values) == 1 or fmt.format(lo) == fmt.format(hi) else \
        f"{fmt.format(lo)}–{fmt.format(hi)}"


def run(counts: tuple[int, ...], seconds: float, repeat: int, with_pogema: bool,
        slices: int = SLICES) -> tuple[str, bool, list[str]]:
    """(the table, whether every target was met, notes) over `repeat` runs."""
    rates: dict[tuple[str, int], list[float]] = {}
    acting: dict[tuple[str, int], list[int]] = {}
    notes: list[str] = []
    for r in range(repeat):
        for n in counts:  # the three side by side, within seconds of each other: the machine's speed drifts
            # POGEMA and the local backend alternate in `slices` slices each (a burst of other work on the
            # shared machine then slows both alike); each figure is the mean of its slices' rates
            pog: list[float] | None = [] if with_pogema else None
            local: list[float] = []
            for _ in range(slices):
                if pog is not None:
                    try:
                        pog.append(pogema.parallel_steps_per_second([n], seconds / slices)[n])
                    except pogema.Unavailable as err:
                        notes.append(f"run {r + 1}, {n} agents: POGEMA not measured: {err}")
                        print(f"  POGEMA: {err}", file=sys.stderr)
                        pog = None
                rate, left = ours("local", n, seconds / slices)
                local.append(rate)
            if pog:
                rates.setdefault(("pogema", n), []).append(sum(pog) / len(pog))
            measured = [("local", sum(local) / len(local), left), ("zenoh", *ours("zenoh", n, seconds))]
            for backend, rate, left in measured:
                rates.setdefault((backend, n), []).append(rate)
                acting.setdefault((backend, n), []).append(left)
                print(f"  run {r + 1}: {backend} {n} drones: {rate:.1f} steps/s "
                      f"(POGEMA {rates.get(('pogema', n), [float('nan')])[-1]:.1f})", file=sys.stderr, flush=True)
    head = ("agents", "POGEMA PettingZoo steps/s", "local steps/s", "local ÷ POGEMA", "zenoh steps/s",
            "zenoh ÷ POGEMA", "agents acting at the end (local / zenoh)", "target")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    ok = True
    for n in counts:
        pog = rates.get(("pogema", n), [])
        local, zen = rates[("local", n)], rates[("zenoh", n)]
        paired = len(pog) == repeat
        lr = [a / b for a, b in zip(local, pog)] if paired else []
        zr = [a / b for a, b in zip(zen, pog)] if paired else []
        verdicts = []
        if not paired:
            verdicts.append("not judged: POGEMA not measured in every run")
            ok = False
        else:
            met = min(lr) >= LOCAL_RATIO
            verdicts.append(f"local ≥ POGEMA: {'met' if met else 'UNMET'}")
            ok &= met
            if n == ZENOH_AT:
                met = min(zr) >= ZENOH_RATIO
                verdicts.append(f"zenoh ≥ 25 % of POGEMA: {'met' if met else 'UNMET'}")
                ok &= met
        acting_at_end = f"{min(acting[('local', n)])} / {min(acting[('zenoh', n)])} of {n}"
        lines.append("| " + " | ".join([
            str(n), _range(pog, "{:.1f}") if pog else "—", _range(local, "{:.1f}"),
            _range(lr, "{:.1f}x") if lr else "—", _range(zen, "{:.1f}"), _range(zr, "{:.2f}x") if zr else "—",
            acting_at_end, "; ".join(verdicts)]) + " |")
    return "\n".join(lines), ok, notes


def few_gain(counts: tuple[int, ...], seconds: float, repeat: int) -> str:
    """The drone-by-drone path's gain (docs/performance.md): local steps/s with it (`FewEpisode`, the default
    up to EPISODE_FEW_DRONES drones) and without (`few_drones = 0`: `Episode` over the engine)."""
    from dronesim.rl_few import FEW_MAX

    return _gain(counts, repeat, ("drone by drone", lambda n: ours("local", n, seconds, FEW_MAX)[0]),
                 ("engine's path", lambda n: ours("local", n, seconds, 0)[0]), "{:.1f}x")


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
    parser.add_argument("--repeat", type=int, default=1, help="runs; the table gives each figure's range (default 1)")
    parser.add_argument("--quick", action="store_true", help="1 and 16 drones, 0.3 s each (for the tests)")
    parser.add_argument("--no-pogema", dest="pogema", action="store_false",
                        help="do not measure POGEMA (installed once into a cached virtual environment)")
    parser.add_argument("--slices", type=int, default=SLICES,
                        help=f"POGEMA and the local backend alternate in this many slices (default {SLICES})")
    parser.add_argument("--few-gain", action="store_true",
                        help="only the local backend, its drone-by-drone path on and off (docs/performance.md)")
    parser.add_argument("--ahead-gain", action="store_true",
                        help="only the zenoh backend, MOVES ahead on and off (docs/performance.md)")
    add_write_args(parser)
    args = parser.parse_args(argv)
    try:
        counts = tuple(int(c) for c in args.counts.split(","))
    except ValueError:
        parser.error("--counts takes integers separated by commas")
    if args.quick:
        counts, args.seconds = (1, 16), 0.3
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
            "Targets (issue \"A PettingZoo environment\"): the local backend ≥ POGEMA's PettingZoo integration at "
            "every agent count, the zenoh backend ≥ 25 % of it at 128 agents, in the same run.\n\n"
            f"{table}\n\n"
            f"Legend. Steps per second of `parallel_env(...).step` alone, after {WARMUP} warm-up steps, "
            f"{args.seconds:g} s of stepping per figure; POGEMA and the local backend alternate in {args.slices} "
            "slices of it (a new environment each, the figure the mean of their rates), so that a burst of other "
            "work slows both alike; with several runs, each figure is the range over the runs and each ratio is "
            "taken within a run. POGEMA: 1.4.0's `pogema.integrations.pettingzoo."
            "parallel_env` in its own virtual environment, 64x64 grid, density 0.3, observation radius 5, random "
            "actions, on_target \"nothing\". Ours: a generated 64x64x16 world, observation radius 2 (125 cells), "
            "on_target \"stay\", random safe actions (benchmarks/rl.py: no drone dies, so every step has all "
            "its agents); local = in this process (drone by drone up to 64 drones, `dronesim/rl_few.py`, else the "
            "engine), zenoh = each step a turn of the coordinator and "
            "environment processes through a router in this process (the step's DONE and MOVES sent at once: one "
            "round trip).\n"
            + "".join(f"\n{note}\n" for note in notes)
        )
        replace_section(args.output, SECTION, body)
        print(f"\nwrote {SECTION!r} in {args.output}")
    return 0 if ok or not args.pogema else 1


if __name__ == "__main__":
    raise SystemExit(main())
