"""dronesim.pettingzoo with the tools RL researchers train with: SuperSuit's `black_death_v3` and vector
environments (deaths, the episode's end, auto-reset, on both backends), worlds one cell high (POGEMA's five
actions, PettingZoo's `max_cycles_test` on maps) and what docs/rl.md promises of starts, parked drones,
unreachable targets and the AEC form's done agents.

SuperSuit comes with the `rl` extra (tests/run.sh installs it): imported plainly, so these fail rather than
skip where the extra is missing."""

from __future__ import annotations

import types

import numpy as np
import pytest
import supersuit as ss
from pettingzoo.test import max_cycles_test, parallel_api_test

import dronesim.pettingzoo as dz
from dronesim.rl import FLAT_ACTIONS, ConfigError, Layout, clear_cells
from world.grid import World
from world.movingai import generate, write_map

pytestmark = pytest.mark.filterwarnings("error")


# --------------------------------------------------------------------------- SuperSuit's vector environments


def vector(n: int, backend: str, copies: int):
    """Our env of `n` drones through black_death_v3, pettingzoo_env_to_vec_env_v1 and concat_vec_envs_v1 (as
    PettingZoo's training tutorials and CleanRL's PPO use them): episodes short enough to end in the test."""
    env = dz.parallel_env(num_drones=n, size=(12, 12, 3), max_cycles=6, seed=5, backend=backend)
    env = ss.pettingzoo_env_to_vec_env_v1(ss.black_death_v3(env))
    return ss.concat_vec_envs_v1(env, copies, num_cpus=0, base_class="gymnasium")


def play(venv, steps: int, seed: int = 0) -> list[tuple]:
    """Every array the vector env returns over `steps` random steps (the first: reset's observations)."""
    rng = np.random.default_rng(seed)
    out: list[tuple] = [(venv.reset(seed=3)[0],)]
    for _ in range(steps):
        obs, rew, term, trunc, _ = venv.step(rng.integers(0, 7, venv.num_envs))
        out.append((obs, rew, term, trunc))
    return out


def check_black_death(run: list[tuple], n: int, copies: int) -> None:
    """Dead drones stay present with a zero observation and zero reward until their episode ends; the end is
    every agent done at once (one step after the last one ended, as black_death_v3 decides it); the vector
    env then resets that copy (auto-reset: full observations again)."""
    zero = [(obs == 0).all(axis=1) for obs, *_ in run]
    deaths = resets = 0
    for t in range(1, len(run)):
        obs, rew, term, trunc = run[t]
        assert obs.shape == (n * copies, run[0][0].shape[1]) and rew.shape == (n * copies,)
        for c in range(copies):
            part = slice(c * n, (c + 1) * n)
            done = term[part] | trunc[part]
            assert done.all() or not done.any(), "black_death ends an episode for every agent at once"
            if done.any():
                resets += 1
                assert not zero[t][part].any(), "the copy was reset: every agent observes again"
                continue
            was_zero = zero[t - 1][part]
            assert (rew[part][was_zero] == 0).all(), "a dead drone gets zero reward"
            assert zero[t][part][was_zero].all(), "a dead drone's observation stays zero to the episode's end"
            deaths += int(np.count_nonzero(rew[part] < 0))
    assert deaths > 0 and resets >= copies, (deaths, resets)


@pytest.mark.parametrize("n", [8, 64])
def test_black_death_vector_env_local(n: int) -> None:
    venv = vector(n, "local", copies=2)
    try:
        check_black_death(play(venv, 16), n, 2)
    finally:
        venv.close()


@pytest.mark.integration
@pytest.mark.parametrize("n", [8, 64])
def test_black_death_vector_env_zenoh_is_the_local_one(n: int) -> None:
    """The zenoh backend through SuperSuit: the same arrays as the local backend's, step by step, across an
    auto-reset."""
    local, remote = vector(n, "local", copies=1), vector(n, "zenoh", copies=1)
    try:
        a, b = play(local, 9), play(remote, 9)
    finally:
        local.close()
        remote.close()
    check_black_death(b, n, 1)
    for t, (x, y) in enumerate(zip(a, b)):
        for u, v in zip(x, y):
            assert np.array_equal(u, v), f"the backends differ at step {t}"


def test_a_step_after_the_end_with_no_action_is_empty_and_with_actions_refused() -> None:
    """PettingZoo's convention (its aec_to_parallel): nothing to step, nothing returned; black_death_v3 reads
    the end of the episode from it."""
    env = dz.parallel_env(num_drones=2, size=(6, 6, 2), max_cycles=2)
    env.reset(seed=1)
    while env.agents:
        env.step({a: 0 for a in env.agents})
    assert env.step({}) == ({}, {}, {}, {}, {})
    with pytest.raises(ConfigError, match="after the end"):
        env.step({"drone_1": 0})


# --------------------------------------------------------------------------- worlds one cell high


@pytest.fixture(scope="module")
def map_path(tmp_path_factory: pytest.TempPathFactory):
    path = tmp_path_factory.mktemp("maps") / "random-32-32-10.map"
    path.write_text(write_map(generate("random-32-32-10", 3)), encoding="utf-8")
    return path


def test_a_flat_world_has_pogemas_five_actions(map_path) -> None:
    env = dz.parallel_env(world=str(map_path), num_drones=16, max_cycles=40)
    assert env.action_space("drone_1").n == FLAT_ACTIONS == 5
    env.reset(seed=1)
    with pytest.raises(ConfigError, match=r"outside Discrete\(5\): 0 hover, 1 \+x, 2 -x, 3 \+y, 4 -y"):
        env.step({"drone_1": 5})
    _, _, _, _, infos = env.step({"drone_1": 3})  # +y on a floor: its start is clear, it survives
    assert infos["drone_1"]["state"] == "alive"
    assert dz.parallel_env(num_drones=2).action_space("drone_1").n == 7  # a world of several floors: all seven
    parallel_api_test(env, num_cycles=40)


def test_max_cycles_on_a_map(map_path) -> None:
    mod = types.SimpleNamespace(parallel_env=lambda **kw: dz.parallel_env(world=str(map_path), num_drones=8, **kw),
                                env=lambda **kw: dz.env(world=str(map_path), num_drones=8, **kw))
    max_cycles_test(mod)


def test_starts_are_clear_for_the_actions_of_the_world(map_path) -> None:
    world = World.load(map_path)
    clear = clear_cells(world.grid)
    assert clear.sum() > 100  # a floor's clear cells: its 4 neighbours free (±z does not exist there)
    config = dz.parallel_env(world=world, num_drones=30).config
    layout = Layout.draw(config, 4)
    assert layout.clear.all() and clear[tuple(layout.starts.T)].all()
    # a crowded world: every clear cell is a start, the others are free cells (and say so)
    grid = np.zeros((4, 4, 1), bool)
    crowded = dz.parallel_env(world=World.from_grid(grid), num_drones=8).config
    layout = Layout.draw(crowded, 1)
    assert layout.clear.sum() == 4 and len({tuple(c) for c in layout.starts.tolist()}) == 8


# --------------------------------------------------------------------------- what docs/rl.md promises


def corridor(length: int) -> World:
    return World.from_grid(np.zeros((length, 1, 1), bool))


def test_an_unreachable_target_is_noted_at_reset() -> None:
    grid = np.zeros((7, 1, 1), bool)
    grid[2] = True  # two pockets: 0..1 and 3..6
    for few in (99, 0):
        env = dz.parallel_env(world=World.from_grid(grid), num_drones=3, seed=0, max_cycles=5)
        env.few_drones = few
        for seed in range(20):
            _, infos = env.reset(seed=seed)
            layout = env.episode.layout
            notes = [infos[f"drone_{i + 1}"]["note"] for i in range(3)]
            assert notes == ["none" if ok else "unreachable" for ok in layout.reachable.tolist()]
            _, _, _, _, after = env.step({})
            assert [after[a]["note"] for a in after] == [n if n == "unreachable" else after[a]["note"]
                                                         for a, n in zip(after, notes)]
            if not layout.reachable.all():
                break
        else:
            pytest.fail("no seed gave an unreachable target")


@pytest.mark.parametrize("few", [99, 0])
def test_a_drone_flying_into_a_parked_drone_dies_with_it(few: int) -> None:
    """docs/rl.md: a finished drone stays parked on its target; one that flies into it dies with it (a vertex
    conflict), and the parked drone is gone from state() and from the others' observations."""
    env = dz.parallel_env(world=corridor(8), num_drones=2, seed=0, max_cycles=30)
    env.few_drones = few
    for seed in range(50):
        obs, infos = env.reset(seed=seed)
        a, b = sorted(env.agents, key=lambda d: infos[d]["cell"][0])
        ta, tb = infos[a]["target"][0], infos[b]["target"][0]
        # b parks first on a target between a and it, then a flies at it
        if infos[a]["cell"][0] < tb < infos[b]["cell"][0] and ta > tb:
            break
    else:
        pytest.fail("no seed gave the layout")
    while b in env.agents:
        obs, _, terms, _, infos = env.step({b: 2})  # towards -x, onto its target
    assert terms[b] and infos[b]["note"] == "reached"
    while a in env.agents:
        obs, rewards, terms, _, infos = env.step({a: 1})
    assert infos[a]["state"] == "dead" and infos[a]["cause"] == "vertex" and rewards[a] == -1.0
    assert (env.state() == 2).sum() == 0  # both gone


def test_aec_step_with_an_action_for_a_done_agent_is_a_clear_error() -> None:
    env = dz.env(num_drones=3, size=(6, 6, 2), max_cycles=1)
    env.reset(seed=2)
    for _ in env.possible_agents:
        env.step(0)
    agent = env.agent_selection
    assert env.truncations[agent] or env.terminations[agent]
    with pytest.raises(ConfigError, match=f"{agent} is (truncated|terminated): its last step takes None"):
        env.step(0)
    while env.agents:  # nothing broke: the done agents leave with None, as PettingZoo's API says
        env.step(None)
    env.reset(seed=3)
    assert env.agents == env.possible_agents
