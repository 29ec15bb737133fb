"""This tree against an earlier revision, side by side in one run: the RL environment and whole games.

    dronesim bench versus REV [--counts 1,16,128,1000] [--seconds 2] [--repeat 3] [--games 16,128,1000]

REV (a commit of this repository from before issue 34's restructuring on, `RL_PROBE`) is extracted with
`git archive` into a temporary folder. Every figure is measured in a fresh process of each tree, in the order
before, after, after, before within each repeat, so that the machine's drift over a few seconds weighs on both
sides alike; a repeat's ratio is after ÷ before of the two means, and the table gives each ratio's range over
the repeats (issue 34: "no row may get worse beyond noise").

- RL rows: `RL_PROBE` in each tree (the loop of `benchmarks.rl.ours("local", n, seconds, policy=...)`), the local
  backend's steps per second of CPU time under the safe and the random policy, episodes reset (BENCHMARKS.md, "RL
  environment").
- Game rows: `dronesim up --swarm --drones N --size 64,64,16 --lifelong --turn-period 0 --max-turns T` (a new
  target for each drone home, so that the game plays to its limit; the router, the
  coordinator, the environment, a swarm host and the scripted ground station in processes of their own), the CPU
  seconds of the whole process tree per turn played (wall-clock turns/s moves with the other work on a shared machine;
  the CPU the game needs does not), and `dronesim replay --verify` of its journal (the same bytes from either tree:
  journals must not change): the same turns
  played again in one process, CPU per turn.
"""

from __future__ import annotations

import argparse
import inspect
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from benchmarks.measure import machine
from benchmarks.rl import stepping
from coordinator.journal import is_turn
from coordinator.journal import read as journal_read

HERE = Path(__file__).resolve().parents[1]
#: The RL probe: the benchmark's loop as this tree has it (`benchmarks.rl.stepping`, its source handed over) over
#: each tree's own `parallel_env` on the benchmark's world, with its safe or uniformly random policy, episodes reset
#: and timed with the steps, CPU time. It needs of a tree only what every tree since issue 34's restructuring began
#: has (`parallel_env(world=...)`, `benchmarks.rl`'s `SafeRandom`, `RADIUS`, `SIZE`, `WARMUP`; `World` from
#: world/grid.py, or entities/world.py before the floors): a tree from before the random policy's rows is measured
#: on them too.
RL_PROBE = """
import sys, time
import numpy as np
from benchmarks.rl import RADIUS, SIZE, WARMUP, SafeRandom
from dronesim.pettingzoo import parallel_env
try:
    from entities.world import World
except ImportError:
    from world.grid import World
n, seconds, policy, source = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3], sys.argv[4]
scope = {"np": np, "WARMUP": WARMUP, "SafeRandom": SafeRandom}
exec(compile("from __future__ import annotations\\n" + source, "stepping", "exec"), scope)
env = parallel_env(num_drones=n, world=World.generate(SIZE, np.random.default_rng(1), keep_free=()),
                   obs_radius=RADIUS, on_target="stay", max_cycles=10**6, seed=1, backend="local")
print(scope["stepping"](env, SafeRandom(RADIUS) if policy == "safe" else None, seconds, time.process_time)[0])
env.close()
"""


def extract(rev: str, into: Path) -> str:
    """Revision `rev` of this repository as files under `into`; its full commit id."""
    commit = subprocess.run(["git", "-C", str(HERE), "rev-parse", "--verify", f"{rev}^{{commit}}"],
                            capture_output=True, text=True, check=True).stdout.strip()
    archive = subprocess.run(["git", "-C", str(HERE), "archive", commit], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return commit


def run_in(tree: Path, argv: list[str]) -> tuple[str, float]:
    """`argv` run with `tree` first on the import path and as the working folder: its output and the CPU
    seconds (user + system) of it and every process it waited for."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run(argv, cwd=tree, env=env, capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} in {tree} exited {done.returncode}:\n{done.stderr[-2000:]}")
    return done.stdout, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def rl_rate(n: int, seconds: float, policy: str) -> Callable[[Path], float]:
    source = inspect.getsource(stepping)

    def measure(tree: Path) -> float:
        out, _ = run_in(tree, [sys.executable, "-c", RL_PROBE, str(n), str(seconds), policy, source])
        return float(out.split()[-1])
    return measure


def played(journal: Path) -> int:
    """The turns a journal holds (a game may end before its turn limit: every drone home, or dead)."""
    return sum(1 for record in journal_read(journal) if is_turn(record))


def game_cpu(n: int, turns: int, journal: Path) -> Callable[[Path], float]:
    """CPU ms per turn played of a whole distributed game (every process), `n` drones; writes `journal`."""
    def measure(tree: Path) -> float:
        journal.unlink(missing_ok=True)
        _, cpu = run_in(tree, [sys.executable, "-m", "dronesim", "up", "--swarm", "--drones", str(n), "--size",
                               "64,64,16", "--lifelong", "--turn-period", "0", "--max-turns", str(turns), "--quiet",
                               "--journal", str(journal)])
        return 1000 * cpu / max(1, played(journal))
    return measure


def replay_cpu(journal: Path) -> Callable[[Path], float]:
    """CPU ms per turn of `dronesim replay --verify` of `journal` (written by the game rows, read as it is now)."""
    turns = max(1, played(journal))

    def measure(tree: Path) -> float:
        _, cpu = run_in(tree, [sys.executable, "-m", "dronesim", "replay", "--verify", str(journal)])
        return 1000 * cpu / turns
    return measure


def ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x]


def measure_rows(args: argparse.Namespace, before: Path, after: Path, tmp: Path) -> list[tuple[str, str, list[tuple]]]:
    """Every row: (name, unit, each repeat's (before, after, after ÷ before))."""
    rows: list[tuple[str, str, list[tuple]]] = []
    for n in ints(args.counts):
        for policy in ("safe", "random"):
            name = f"RL local, {n} agent{'s' * (n > 1)}, {policy}"
            rows.append((name, "steps/s (CPU)", side_by_side(rl_rate(n, args.seconds, policy), before, after,
                                                             args.repeat)))
            print(f"{name}: done", file=sys.stderr)
    for n in ints(args.games):
        journal = tmp / f"game-{n}.jsonl"
        name = f"game, {n} drones @ 64x64x16, up to {args.turns} turns"
        rows.append((name + ", every process", "CPU ms/turn", side_by_side(
            game_cpu(n, args.turns, journal), before, after, args.repeat)))
        rows.append((name + ", replay --verify", "CPU ms/turn", side_by_side(
            replay_cpu(journal), before, after, args.repeat)))
        print(f"{name}: done", file=sys.stderr)
    return rows


def side_by_side(measure: Callable[[Path], float], before: Path, after: Path, repeat: int) -> list[tuple]:
    """`repeat` times (before, after, after, before): the two means and after ÷ before."""
    out = []
    for _ in range(repeat):
        b1, a1, a2, b2 = measure(before), measure(after), measure(after), measure(before)
        out.append(((b1 + b2) / 2, (a1 + a2) / 2, (a1 + a2) / (b1 + b2)))
    return out


def span(values: list[float], fmt: str) -> str:
    return f"{fmt.format(min(values))}–{fmt.format(max(values))}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="dronesim bench versus", description=__doc__.split("\n\n")[0])
    ap.add_argument("rev", help="the earlier revision (a commit of this repository)")
    ap.add_argument("--counts", default="1,16,128,1000", help="RL agent counts ('' for none)")
    ap.add_argument("--seconds", type=float, default=2.0, help="seconds of stepping per RL figure")
    ap.add_argument("--games", default="16,128,1000", help="drones of the whole games ('' for none)")
    ap.add_argument("--turns", type=int, default=300, help="turns of each whole game")
    ap.add_argument("--repeat", type=int, default=3, help="repeats (the table gives each ratio's range)")
    args = ap.parse_args(argv)
    started = time.time()
    with tempfile.TemporaryDirectory(prefix="versus-") as tmp:
        before, after = Path(tmp) / "before", Path(tmp) / "after"
        before.mkdir()
        after.mkdir()
        try:
            old = extract(args.rev, before)
            new = extract("HEAD", after)
        except subprocess.CalledProcessError as err:
            print(f"bench versus: {args.rev!r} is not a revision of {HERE} ({(err.stderr or b'').strip()[:200]!r})",
                  file=sys.stderr)
            return 2
        if subprocess.run(["git", "-C", str(HERE), "diff", "--quiet", "HEAD"]).returncode:
            print("(the working tree differs from HEAD: HEAD is measured)", file=sys.stderr)
        try:
            rows = measure_rows(args, before, after, Path(tmp))
        except RuntimeError as err:  # (a tree that cannot run a probe: an older CLI, a missing name)
            print(f"bench versus: {err}", file=sys.stderr)
            return 1
    m = machine()
    print(f"Command: `dronesim bench versus {' '.join(argv if argv is not None else sys.argv[1:])}`; before "
          f"{old[:7]}, after {new[:7]}; {m.get('cpu', '?')}, {time.time() - started:.0f} s, load average (1 min) "
          f"at the end {os.getloadavg()[0]:.1f}.\n")
    print("| row | unit | before | after | after ÷ before (each repeat) | better is |")
    print("|---|---|---|---|---|---|")
    for name, unit, results in rows:
        fmt = "{:.0f}" if unit.startswith("steps") else "{:.2f}"
        print(f"| {name} | {unit} | {span([r[0] for r in results], fmt)} | {span([r[1] for r in results], fmt)} | "
              f"{span([r[2] for r in results], '{:.2f}')} | {'higher' if unit.startswith('steps') else 'lower'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
