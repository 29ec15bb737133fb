"""Instructions a turn of each process of a `dronesim bench perf` game, this tree against an earlier one.

    dronesim bench instructions a5dcef0^ --row '^128 drones @ 64x64x16' [--roles coordinator,env,drone]

Wall-clock turns/s on a shared 2-core machine move by 10 to 25 % from run to run (BENCHMARKS.md); the instructions a
process executes do not (valgrind's callgrind counts them, whatever else the machine does). Each tree (REV extracted
with `git archive`, as `benchmarks.versus` does, and HEAD) plays the row's game of its own `dronesim bench perf`
twice, to `--turns` A and B measured turns, with the chosen processes under callgrind (a wrapper stands in for the
Python interpreter the benchmark starts its processes with); a role's figure is (its instructions in the longer game −
in the shorter) ÷ (B − A): the turns' cost, its start-up and imports cancelled. The router's role counts every router
process (the floor rows' too, whose work does not grow with the turns). The ground station (the benchmark's own
process) is not measured. Under callgrind a process runs 30 to 50 times slower: timers that fire by the clock (a
phase's deadline, a paced put) may fire more often than in a real game. A process's start-up varies by up to tens of
millions of instructions (its threads' timing: seen up to 40M for a router), hence the long second game: over 600
turns, up to ~70k a turn.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.versus import HERE, extract

ROLES = ("coordinator", "env", "drone", "router")

#: The interpreter the benchmark starts its processes with: under callgrind if its `dronesim` subcommand is a role.
WRAPPER = """#!/bin/sh
for role in $DRONESIM_CG_ROLES; do
  if [ "$3" = "$role" ]; then
    exec env PYTHONHASHSEED=0 valgrind --tool=callgrind --callgrind-out-file=/dev/null {python} "$@" \
      2>>"$DRONESIM_CG_OUT/$role.log"
  fi
done
exec {python} "$@"
"""

#: Runs a tree's `dronesim bench perf` with the wrapper as `sys.executable`.
RUNNER = """
import runpy, sys
sys.executable = sys.argv[1]
sys.argv = ["dronesim", "bench", "perf", "--no-pogema", *sys.argv[2:]]
runpy.run_module("dronesim", run_name="__main__")
"""


def collected(log: Path) -> int:
    """The instructions callgrind counted in every process that wrote to `log` (0 if none did)."""
    return sum(map(int, re.findall(r"Collected : (\d+)", log.read_text()))) if log.exists() else 0


def play(tree: Path, wrapper: Path, row: str, turns: int, roles: list[str], out: Path) -> dict[str, int]:
    """Instructions of each role over one game of `row` to `turns` measured turns, in `tree`."""
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    env = {**os.environ, "PYTHONPATH": str(tree), "DRONESIM_CG_ROLES": " ".join(roles), "DRONESIM_CG_OUT": str(out)}
    done = subprocess.run([sys.executable, "-c", RUNNER, str(wrapper), "--only", row, "--turns", str(turns)],
                          cwd=tree, env=env, capture_output=True, text=True)
    if done.returncode != 0 or not re.search(r"\| 0/0/0 \|", done.stdout):
        raise RuntimeError(f"the game of {row!r} in {tree} did not end cleanly:\n{(done.stdout + done.stderr)[-2000:]}")
    return {role: collected(out / f"{role}.log") for role in roles}


def per_turn(tree: Path, wrapper: Path, row: str, short: int, long: int, roles: list[str], tmp: Path) -> dict:
    a = play(tree, wrapper, row, short, roles, tmp / "short")
    b = play(tree, wrapper, row, long, roles, tmp / "long")
    return {role: (b[role] - a[role]) / (long - short) for role in roles}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="dronesim bench instructions", description=__doc__.split("\n\n")[0])
    ap.add_argument("rev", help="the earlier revision (a commit of this repository)")
    ap.add_argument("--row", required=True, help="a regex of one game row of `dronesim bench perf`")
    ap.add_argument("--roles", default=",".join(ROLES), help=f"processes measured, of {', '.join(ROLES)}")
    ap.add_argument("--turns", default="20,620", help="the two games' measured turns, A,B")
    args = ap.parse_args(argv)
    roles = [r for r in args.roles.split(",") if r]
    short, long = map(int, args.turns.split(","))
    if not set(roles) <= set(ROLES) or not 0 < short < long:
        ap.error(f"--roles among {', '.join(ROLES)}; --turns A,B with 0 < A < B")
    if shutil.which("valgrind") is None:
        print("benchmarks.instructions: valgrind is not installed", file=sys.stderr)
        return 2
    started = time.time()
    with tempfile.TemporaryDirectory(prefix="instructions-") as name:
        tmp = Path(name)
        wrapper = tmp / "python"
        wrapper.write_text(WRAPPER.format(python=sys.executable))
        wrapper.chmod(0o755)
        trees = {}
        for label, rev in (("before", args.rev), ("after", "HEAD")):
            (tmp / label).mkdir()
            try:
                trees[label] = (extract(rev, tmp / label), tmp / label)
            except subprocess.CalledProcessError:
                print(f"benchmarks.instructions: {rev!r} is not a revision of {HERE}", file=sys.stderr)
                return 2
        try:
            figures = {label: per_turn(tree, wrapper, args.row, short, long, roles, tmp / f"{label}-out")
                       for label, (_, tree) in trees.items()}
        except RuntimeError as err:
            print(f"benchmarks.instructions: {err}", file=sys.stderr)
            return 1
    print(f"Command: `dronesim bench instructions {' '.join(argv if argv is not None else sys.argv[1:])}`; "
          f"before {trees['before'][0][:7]}, after {trees['after'][0][:7]}; {time.time() - started:.0f} s.\n")
    print("| process | instructions a turn before | after | after ÷ before |")
    print("|---|---|---|---|")
    for role in roles:
        b, a = figures["before"][role], figures["after"][role]
        print(f"| {role} | {b / 1000:,.1f}k | {a / 1000:,.1f}k | {a / b:.3f} |" if b > 0 else
              f"| {role} | {b / 1000:,.1f}k | {a / 1000:,.1f}k | — |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
