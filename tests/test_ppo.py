"""examples/ppo.py learns: PPO with parameter sharing through SuperSuit's vector env, trained on a small world
for a fixed, seeded budget, flies its drones to a mean team return clearly above uniformly random actions'
on the same seeded evaluation episodes. JAX, Flax and Optax come with the `train` extra (tests/run.sh installs
it): the test fails rather than skips where it is missing. Behaviour only: the budget is drone steps, not
seconds."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from dronesim import SOURCE_ROOT, child_env

pytestmark = pytest.mark.slow

BUDGET = 40_000  # drone steps: 39 updates of 16 drones x 64 steps (about 30 s of CPU on this project's machines)


def test_ppo_beats_random_actions() -> None:
    done = subprocess.run([sys.executable, str(SOURCE_ROOT / "examples" / "ppo.py"), "--seed", "1",
                           "--total-timesteps", str(BUDGET)], cwd=SOURCE_ROOT, env=child_env(), capture_output=True,
                          text=True, timeout=1200)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["episodes"] == 24 and result["drones"] == 4
    # a team of 4: +1 a drone that arrives, -1 one that dies; random actions lose most of the team
    assert result["random"] < -2.0, result
    assert result["trained"] > 0.5 and result["trained"] > result["random"] + 3.0, result
