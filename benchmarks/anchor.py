"""The LaCAM-class anchor of issue 37: pymapf's LaCAM (``pip install pymapf``: CBS, PIBT and LaCAM in pure
Python, Okumura's AAAI 2023 search with PIBT as its successor generator), run on the benchmark's own MovingAI
instances in the same run as our games.

It runs in a virtual environment of its own, made once under the user's cache directory
(``$XDG_CACHE_HOME/dronesim/pymapf-<version>``; PyPI must be reachable the first time), as POGEMA does
(benchmarks/pogema.py): the anchor's dependencies never meet ours. The conventions are the benchmark's: a grid
one cell high, 4-connected moves, vertex and swap conflicts forbidden, agents stay at their goals; an agent's
cost is the step after which it stays on its goal (pymapf trims the path there), the sum of costs and the
makespan as `benchmarks/swarm.py` counts ours, against the same lower bounds.
"""

from __future__ import annotations

import json
import subprocess
from dataclasses import dataclass
from pathlib import Path

from . import venvs
from .venvs import Unavailable

VERSION = "0.9.0"

#: Run inside the anchor's environment: for each instance (a JSON list on stdin), whether LaCAM solved it, its
#: sum of costs, makespan, wall-clock seconds and high-level expansions, as one JSON list.
_SCRIPT = """
import json, sys, time
import pymapf
from pymapf.algorithms.lacam import LaCAM

out = []
for inst in json.load(sys.stdin):
    rows = inst["rows"]  # rows[y][x]: 1 blocked
    grid = pymapf.GridMap(rows)
    agents = [pymapf.Agent(f"a{k}", (s[1], s[0]), (g[1], g[0])) for k, (s, g) in enumerate(zip(inst["starts"],
                                                                                            inst["goals"]))]
    problem = pymapf.MAPFProblem(grid, agents)
    t0 = time.perf_counter()
    sol = LaCAM(time_limit=inst["seconds"], max_expansions=10**7, seed=0).solve(problem)
    seconds = time.perf_counter() - t0
    if sol is None:
        out.append({"solved": False, "seconds": seconds})
        continue
    costs = [len(p) - 1 for p in sol.paths.values()]
    out.append({"solved": sol.is_valid(), "soc": sum(costs), "makespan": max(costs), "seconds": seconds,
                "expansions": sol.expansions})
print(json.dumps(out))
"""


@dataclass(frozen=True, slots=True)
class Result:
    solved: bool
    soc: int
    makespan: int
    seconds: float


def venv_dir() -> Path:
    return venvs.venv_dir(f"pymapf-{VERSION}")


def python() -> Path:
    """The interpreter of pymapf's environment, made (and pymapf installed) on first use."""
    return venvs.python(f"pymapf-{VERSION}", f"pymapf=={VERSION}", "pymapf")


def solve(instances: list[tuple[list[list[int]], list[tuple[int, int]], list[tuple[int, int]]]],
          seconds: float = 60.0) -> list[Result]:
    """pymapf's LaCAM on each instance: (rows[y][x] with 1 for blocked, starts and goals as (x, y)), each given
    `seconds` of wall-clock time (the anchor's own limit: an instance it does not solve in time is unsolved)."""
    exe = python()
    data = json.dumps([{"rows": rows, "starts": starts, "goals": goals, "seconds": seconds}
                       for rows, starts, goals in instances])
    try:
        done = subprocess.run([str(exe), "-c", _SCRIPT], input=data, capture_output=True, text=True,
                              timeout=120 + 2 * seconds * len(instances))
    except subprocess.TimeoutExpired:
        raise Unavailable("pymapf did not finish in time") from None
    if done.returncode != 0:
        tail = done.stderr.strip().splitlines()[-1:] or ["no output"]
        raise Unavailable(f"pymapf exited {done.returncode}: {tail[0]}")
    return [Result(bool(r["solved"]), int(r.get("soc", 0)), int(r.get("makespan", 0)), float(r["seconds"]))
            for r in json.loads(done.stdout.strip().splitlines()[-1])]
