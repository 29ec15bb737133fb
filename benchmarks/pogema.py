"""POGEMA, the anchor of issue "Performance": an in-process grid multi-agent simulator, measured on this
machine in the same run as our games.

POGEMA (``pip install pogema``) pins numpy < 2 and pydantic 1, so it runs in a virtual environment of its
own, made once under the user's cache directory (``$XDG_CACHE_HOME/dronesim/pogema-<version>``, about 110 MB;
PyPI must be reachable the first time). Its scenario is the one the issue quotes: a 64x64 grid, obstacle
density 0.3, observation radius 5, every agent taking a uniformly random action every step; agents stay on
the grid when they reach their target (``on_target="nothing"``), so every step moves all of them, as every
turn of our 1000-drone games moves most drones.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from . import venvs
from .venvs import Unavailable

VERSION = "1.4.0"
SIZE = 64
DENSITY = 0.3
OBS_RADIUS = 5

#: Run inside POGEMA's environment: steps per second for each agent count, as one JSON object.
_SCRIPT = """
import json, sys, time
import numpy as np
from pogema import GridConfig, pogema_v0

agents, seconds, size, density, radius = json.loads(sys.argv[1])
rng = np.random.default_rng(0)
out = {}
for n in agents:
    env = pogema_v0(grid_config=GridConfig(size=size, num_agents=n, density=density, obs_radius=radius,
                                           seed=1, max_episode_steps=10**9, on_target="nothing"))
    env.reset(seed=1)
    for _ in range(20):  # warm-up
        env.step(rng.integers(0, 5, size=n).tolist())
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        env.step(rng.integers(0, 5, size=n).tolist())
        steps += 1
    out[n] = steps / (time.perf_counter() - t0)
print(json.dumps(out))
"""


def venv_dir() -> Path:
    return venvs.venv_dir(f"pogema-{VERSION}")


def python() -> Path:
    """The interpreter of POGEMA's environment, made (and POGEMA installed) on first use."""
    return venvs.python(f"pogema-{VERSION}", f"pogema=={VERSION}", "pogema")


#: Run inside POGEMA's environment: steps per second of its PettingZoo integration (`parallel_env`, a dict of
#: actions per step) for each agent count, timing the step calls alone (the random actions are drawn before) in
#: the process's CPU time (`dronesim bench rl` times our local backend so too: other work on a shared machine
#: does not count) and by the wall clock: [CPU rate, wall rate].
_PARALLEL_SCRIPT = """
import json, sys, time
import numpy as np
from pogema import GridConfig
from pogema.integrations.pettingzoo import parallel_env

agents, seconds, size, density, radius = json.loads(sys.argv[1])
rng = np.random.default_rng(0)
out = {}
for n in agents:
    env = parallel_env(GridConfig(size=size, num_agents=n, density=density, obs_radius=radius, seed=1,
                                  max_episode_steps=10**9, on_target="nothing"))
    env.reset(seed=1)
    steps, spent, wall = 0, 0.0, 0.0
    while spent < seconds:
        actions = dict(zip(env.agents, rng.integers(0, 5, size=len(env.agents)).tolist()))
        t0, w0 = time.process_time(), time.perf_counter()
        env.step(actions)
        if steps >= 20:  # after a warm-up
            spent += time.process_time() - t0
            wall += time.perf_counter() - w0
        steps += 1
    out[n] = [(steps - 20) / spent, (steps - 20) / wall]
print(json.dumps(out))
"""


def steps_per_second(agents: list[int], seconds: float = 2.0, size: int = SIZE) -> dict[int, float]:
    """POGEMA's steps per second with each number of `agents` (random actions, `size` x `size` (64 x 64),
    in-process)."""
    return _run(_SCRIPT, agents, seconds, size)


def parallel_steps_per_second(agents: list[int], seconds: float = 2.0) -> dict[int, float]:
    """The steps per CPU second of POGEMA's PettingZoo integration with each number of `agents` (the same
    scenario as `steps_per_second`; step calls alone)."""
    return {n: cpu for n, (cpu, _) in parallel_rates(agents, seconds).items()}


def parallel_rates(agents: list[int], seconds: float = 2.0) -> dict[int, tuple[float, float]]:
    """`parallel_steps_per_second`'s CPU rates, each with the same steps' wall-clock rate."""
    return {n: (v[0], v[1]) for n, v in _run(_PARALLEL_SCRIPT, agents, seconds).items()}


def _run(script: str, agents: list[int], seconds: float, size: int = SIZE) -> dict:
    exe = python()
    args = json.dumps([agents, seconds, size, DENSITY, OBS_RADIUS])
    try:
        done = subprocess.run([str(exe), "-c", script, args], capture_output=True, text=True,
                              timeout=60 + 4 * seconds * len(agents), stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        raise Unavailable("POGEMA did not finish in time") from None
    if done.returncode != 0:
        tail = done.stderr.strip().splitlines()[-1:] or ["no output"]
        raise Unavailable(f"POGEMA exited {done.returncode}: {tail[0]}")
    return {int(n): v for n, v in json.loads(done.stdout.strip().splitlines()[-1]).items()}
