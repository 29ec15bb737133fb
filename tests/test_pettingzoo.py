"""dronesim.pettingzoo: PettingZoo's own conformance tests, then the rules, the observations and bad input.

PettingZoo and gymnasium come with the `rl` extra (tests/run.sh installs it): these tests import them
plainly, so they fail rather than skip where the extra is missing."""

from __future__ import annotations

import functools
import subprocess
import sys
import types

import numpy as np
import pytest
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test, render_test, seed_test

import dronesim.pettingzoo as dz
from coordinator.effects import Publish, Refusal
from coordinator.fleet import ALIVE
from dronesim import SOURCE_ROOT, child_env
from dronesim.rl import ACTIONS, ON_TARGET, Board, ConfigError, Episode, Eyes, LocalTurns, Seen, turn_messages
from dronesim.rl_few import FewEpisode
from schema import Done, Intent, Over, Phase, Status, UsageError
from schema.tuning import EPISODE_FEW_DRONES
from world.grid import World

pytestmark = pytest.mark.filterwarnings("error")  # PettingZoo's tests warn about what they do not fail on


# --------------------------------------------------------------------------- PettingZoo's own tests


@pytest.mark.parametrize("on_target", ["finish", "stay", "new"])
def test_parallel_api(on_target: str) -> None:
    parallel_api_test(dz.parallel_env(on_target=on_target, num_drones=6), num_cycles=300)


def test_aec_api() -> None:
    api_test(dz.env(), num_cycles=300)


@pytest.mark.parametrize("on_target", ["finish", "new"])
def test_seed(on_target: str) -> None:
    seed_test(functools.partial(dz.env, on_target=on_target), num_cycles=200)


def test_max_cycles() -> None:
    max_cycles_test(dz)


def test_render(capsys: pytest.CaptureFixture[str]) -> None:
    render_test(lambda render_mode=None: dz.env(render_mode=render_mode))
    assert "z = 0" in capsys.readouterr().out  # "human" prints the ansi drawing


# --------------------------------------------------------------------------- rules


def corridor(length: int) -> World:
    """A world one cell wide and high: a drone can only go along x."""
    return World.from_grid(np.zeros((length, 1, 1), bool))


def towards(obs: np.ndarray) -> int:
    """The action that brings a drone one cell closer to its target along x (the corridor's only axis)."""
    dx = int(obs[-3])
    return 0 if dx == 0 else (1 if dx > 0 else 2)


def test_arrival_finishes_the_agent_and_its_drone_stays_parked() -> None:
    env = dz.parallel_env(world=corridor(8), num_drones=1, seed=3, max_cycles=50, step_cost=0.25)
    obs, infos = env.reset()
    start, target = infos["drone_1"]["cell"], infos["drone_1"]["target"]
    assert start != target and obs["drone_1"][-3] == target[0] - start[0]
    distance = abs(target[0] - start[0])
    for k in range(distance):
        obs, rewards, terms, truncs, infos = env.step({"drone_1": towards(obs["drone_1"])})
        last = k == distance - 1
        assert rewards["drone_1"] == pytest.approx((1.0 if last else 0.0) - 0.25)
        assert terms["drone_1"] is last and truncs["drone_1"] is False
    assert infos["drone_1"] == {"cell": target, "target": target, "note": "reached", "state": "alive", "cause": "none"}
    assert env.agents == []
    assert env.step({}) == ({}, {}, {}, {}, {})  # nothing to step (PettingZoo's convention)
    with pytest.raises(ConfigError, match="after the end"):
        env.step({"drone_1": 0})


def test_stay_rewards_each_arrival_and_truncates_at_max_cycles() -> None:
    env = dz.parallel_env(world=corridor(8), num_drones=1, seed=3, max_cycles=30, on_target="stay")
    obs, infos = env.reset()
    arrivals = 0
    for t in range(1, 31):
        dx = int(obs["drone_1"][-3])
        action = towards(obs["drone_1"]) if dx else (1 if infos["drone_1"]["cell"][0] < 7 else 2)  # off, back
        obs, rewards, terms, truncs, infos = env.step({"drone_1": action})
        arrivals += rewards["drone_1"] == 1.0
        assert terms["drone_1"] is False
        assert truncs["drone_1"] is (t == 30)
    assert arrivals >= 5  # on, off, on, ...: every return counts
    assert env.agents == []


def test_new_targets_are_drawn_on_arrival() -> None:
    env = dz.parallel_env(world=corridor(12), num_drones=1, seed=5, max_cycles=100, on_target="new")
    obs, infos = env.reset()
    seen = [infos["drone_1"]["target"]]
    for _ in range(100):
        obs, rewards, terms, truncs, infos = env.step({"drone_1": towards(obs["drone_1"])})
        if rewards["drone_1"] == 1.0:
            assert infos["drone_1"]["target"] != infos["drone_1"]["cell"]  # the next one, at once
            seen.append(infos["drone_1"]["target"])
        if not env.agents:
            break
    assert len(seen) >= 5 and all(a != b for a, b in zip(seen, seen[1:]))


@pytest.mark.parametrize("few_drones", [99, 0])
def test_a_new_target_is_a_free_cell_of_its_own_pocket_and_hovering_earns_nothing(few_drones: int) -> None:
    """Lifelong, a drone whose pocket of free cells is small (here two: its start and its target) gets the pocket's
    other cell on arrival, whatever the number of targets elsewhere in the world; hovering there earns nothing (it
    once got its own cell back as its 'new' target and +1 a step for staying on it)."""
    env = dz.parallel_env(num_drones=6, size=(5, 5, 2), on_target="new", max_cycles=30)
    env.few_drones = few_drones
    obs, infos = env.reset(seed=5)
    start, first = infos["drone_1"]["cell"], infos["drone_1"]["target"]
    delta = tuple(b - a for a, b in zip(start, first))  # (the pocket is two cells side by side)
    obs, rewards, _, _, infos = env.step({"drone_1": ACTIONS.index(delta)})
    assert rewards["drone_1"] == 1.0 and infos["drone_1"]["cell"] == first
    assert infos["drone_1"]["target"] == start  # the pocket's other cell
    for _ in range(3):
        obs, rewards, _, _, infos = env.step({"drone_1": 0})
        assert rewards["drone_1"] == 0.0 and infos["drone_1"]["cell"] == first


def test_death_by_leaving_the_world() -> None:
    env = dz.parallel_env(world=corridor(6), num_drones=1, seed=1, reward_death=-5.0)
    _, infos = env.reset()
    x = infos["drone_1"]["cell"][0]
    obs = None
    for _ in range(x + 1):  # towards -x until it leaves
        obs, rewards, terms, _, infos = env.step({"drone_1": 2})
    assert rewards["drone_1"] == -5.0 and terms["drone_1"] is True
    assert infos["drone_1"]["state"] == "dead" and infos["drone_1"]["cause"] == "outside"
    assert infos["drone_1"]["cell"] == (-1, 0, 0)
    assert obs is not None and obs["drone_1"] in env.observation_space("drone_1")


def test_collisions_kill_both_drones() -> None:
    # two drones in a corridor of 4: whatever their starts, driving them at each other makes them meet
    env = dz.parallel_env(world=corridor(4), num_drones=2, seed=2, max_cycles=10)
    _, infos = env.reset()
    (a, b) = sorted(env.agents, key=lambda d: infos[d]["cell"][0])
    for _ in range(4):
        if not env.agents:
            break
        _, rewards, terms, _, infos = env.step({a: 1, b: 2})
    assert terms == {a: True, b: True}
    assert {infos[a]["cause"], infos[b]["cause"]} <= {"vertex", "swap"}


def test_movingai_map_is_a_world(tmp_path) -> None:
    from world.movingai import generate, write_map

    path = tmp_path / "warehouse-32-32.map"
    path.write_text(write_map(generate("warehouse-32-32", 1)), encoding="utf-8")
    env = dz.parallel_env(world=str(path), num_drones=12, max_cycles=30)
    env.reset(seed=2)
    assert env.state().shape == (32, 32, 1)
    assert env.observation_space("drone_1").high[-1] == 1  # one floor: no offset along z beyond the world's
    parallel_api_test(env, num_cycles=30)


@pytest.mark.parametrize("form", ["arrays", "cells"])
def test_observation_cells(form: str) -> None:
    grid = np.zeros((5, 5, 3), bool)
    grid[3, 2, 1] = True  # a building at +x of the centre
    eyes = Eyes(World.from_grid(grid), 1)

    def see(pos: list, drones: list) -> np.ndarray:
        targets = [(0, 0, 0)] * len(pos)
        if form == "cells":
            return np.asarray(eyes.see_few(pos, np.array(targets, np.intp), drones))[0]
        return eyes.see(*(np.array(c, np.int32).reshape(-1, 3) for c in (pos, targets, drones)))[0]

    obs = see([(2, 2, 1)], [(2, 2, 1), (2, 3, 1)])  # the second drone at +y of the first

    def at(dx: int, dy: int, dz_: int) -> int:
        return int(obs[((dx + 1) * 3 + (dy + 1)) * 3 + (dz_ + 1)])

    assert at(0, 0, 0) == Seen.FREE
    assert at(1, 0, 0) == Seen.BUILDING
    assert at(0, 1, 0) == Seen.DRONE
    assert at(-1, 0, 0) == Seen.FREE and at(0, 0, 1) == Seen.FREE
    assert at(1, 1, 0) == Seen.UNKNOWN and at(1, 1, 1) == Seen.UNKNOWN  # beyond radius 1
    assert obs[-3:].tolist() == [-2, -2, -1]  # the offset to the target
    top = see([(2, 2, 2)], [(2, 2, 2)])
    assert top[((1) * 3 + 1) * 3 + 2] == Seen.OUTSIDE  # above the top floor
    assert top.dtype == dz.parallel_env(world=World.from_grid(grid), obs_radius=1).observation_space("drone_1").dtype


def seen(world: World, radius: int, cell: tuple, target: tuple, drones: set) -> list[int]:
    """An observation cell by cell, from its definition (dronesim.rl.Seen): the reference of `Eyes`."""
    out = []
    span = range(-radius, radius + 1)
    for dx in span:
        for dy in span:
            for dz_ in span:
                c = (cell[0] + dx, cell[1] + dy, cell[2] + dz_)
                if dx * dx + dy * dy + dz_ * dz_ > radius * radius:
                    out.append(Seen.UNKNOWN)
                elif (dx, dy, dz_) == (0, 0, 0):
                    out.append(Seen.FREE)
                elif not world.contains(c):
                    out.append(Seen.OUTSIDE)
                else:
                    out.append(Seen.DRONE if c in drones else Seen.BUILDING if world.is_building(c) else Seen.FREE)
    return out + [t - c for t, c in zip(target, cell)]


@pytest.mark.parametrize(("n", "on_target"), [(1, "finish"), (3, "finish"), (12, "stay"), (40, "new")])
def test_observations_are_the_world_and_the_alive_drones_around(n: int, on_target: str) -> None:
    """Every observation of random episodes (deaths included: a dead drone is not seen, and its cell, in a
    building or outside the world, is seen as such afterwards) against `seen`."""
    env = dz.parallel_env(num_drones=n, size=(7, 7, 3), on_target=on_target, max_cycles=25, obs_radius=2)
    rng = np.random.default_rng(n)
    deaths = 0
    for seed in range(4):
        obs, infos = env.reset(seed=seed)
        world = env.episode.world
        while True:
            episode = env.episode
            drones = set(map(tuple, episode.pos[episode.state == ALIVE].tolist()))
            for a, o in obs.items():
                assert o.tolist() == seen(world, 2, infos[a]["cell"], infos[a]["target"], drones), a
            if not env.agents:
                break
            obs, _, _, _, infos = env.step({a: int(rng.integers(7)) for a in env.agents})
            deaths += sum(i["state"] == "dead" for i in infos.values())
    assert deaths > 0


def test_same_seed_same_episode_and_reset_seed_matches_config_seed() -> None:
    runs = []
    for env in (dz.parallel_env(num_drones=12, seed=9, on_target="new"),
                dz.parallel_env(num_drones=12, seed=0, on_target="new")):
        obs, _ = env.reset(seed=9) if len(runs) else env.reset()
        rng = np.random.default_rng(1)
        trace = [obs]
        while env.agents:
            trace.append(env.step({a: int(rng.integers(7)) for a in env.agents}))
        runs.append(trace)
    assert len(runs[0]) == len(runs[1])
    for x, y in zip(*runs):
        assert repr(x) == repr(y)


def test_a_new_world_is_seen_after_reset() -> None:
    """An episode of another world does not see through the previous episode's eyes (its buildings)."""
    again, fresh = dz.parallel_env(num_drones=4, size=(10, 10, 4)), dz.parallel_env(num_drones=4, size=(10, 10, 4))
    again.reset(seed=1)
    obs, _ = again.reset(seed=2)
    assert repr(obs) == repr(fresh.reset(seed=2)[0])


def test_render_modes() -> None:
    env = dz.parallel_env(num_drones=3, render_mode="rgb_array")
    env.reset()
    image = env.render()
    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
    assert len(np.unique(image.reshape(-1, 3), axis=0)) >= 5  # free, building, grid, targets, drones
    env = dz.parallel_env(num_drones=3, render_mode="ansi")
    env.reset()
    text = env.render()
    assert "D01" in text and "TGT" in text and "BLK" in text


@pytest.mark.parametrize("n", [4, 120])
def test_state_is_the_world_with_its_drones(n: int) -> None:
    env = dz.parallel_env(num_drones=n, size=(24, 24, 8))
    _, infos = env.reset()
    state = env.state()
    assert state.shape == tuple(env.config.size) and state in env.state_space
    for info in infos.values():
        assert state[info["cell"]] == Seen.DRONE
    assert np.count_nonzero(state == Seen.DRONE) == n


def test_each_agent_flies_its_own_drone() -> None:
    env = dz.parallel_env(num_drones=120, size=(24, 24, 8))  # D100 and on: ids no longer sort as numbers
    _, before = env.reset()
    _, _, _, _, after = env.step({"drone_105": 5})  # +z (a start is clear: it survives)
    moved = {a for a in env.possible_agents if after[a]["cell"] != before[a]["cell"]}
    assert moved == {"drone_105"}
    x, y, z = before["drone_105"]["cell"]
    assert after["drone_105"]["cell"] == (x, y, z + 1)


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(("config", "match"), [
    ({"num_drone": 3}, "unknown configuration key"),
    ({"num_drones": 0}, "num_drones"),
    ({"num_drones": 40, "size": (3, 3, 4)}, "too few"),
    ({"size": (4, 4)}, "size"),
    ({"on_target": "restart"}, "on_target"),
    ({"render_mode": "video"}, "render_mode"),
    ({"backend": "mqtt"}, "backend"),
    ({"obs_radius": -1}, "obs_radius"),
    ({"max_cycles": 0}, "max_cycles"),
    ({"reward_target": float("nan")}, "reward_target"),
    ({"world": "/nonexistent/world.json"}, "cannot read world file"),
    ({"world": corridor(4), "size": (4, 1, 1)}, "not both"),
    ({"connect": "tcp/127.0.0.1:7447"}, "connect"),
])
def test_bad_configuration(config: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        dz.parallel_env(**config)


def test_bad_steps() -> None:
    env = dz.parallel_env(num_drones=2, max_cycles=5)
    with pytest.raises(ConfigError, match="before reset"):
        env.step({})
    env.reset()
    for bad in (7, -1, 1.0, "1", None, True, np.array([1])):
        with pytest.raises(ConfigError, match="outside Discrete"):
            env.step({"drone_1": bad})
    with pytest.raises(ConfigError, match="unknown agents"):
        env.step({"drone_3": 0})
    with pytest.raises(ConfigError, match="must be a dict"):
        env.step([0, 0])
    assert env.episode.cycle == 0  # refused steps play no turn
    env.step({"drone_1": np.int64(0), "drone_2": np.array(0)})  # numpy integers are actions too
    with pytest.raises(ConfigError, match="unknown agent"):
        env.observation_space("drone_9")
    assert env.observation_space("drone_1") is env.observation_space("drone_1")
    assert env.action_space("drone_2") is env.action_space("drone_2")
    assert env.action_space("drone_2").n == len(ACTIONS) == 7  # (a world of several floors)


@pytest.mark.parametrize("action", [99, -1, None, 2.0])
def test_the_aec_form_refuses_an_action_outside_the_space_at_once_and_plays_on(action: object) -> None:
    """AEC: a bad action for a live agent is refused when given (ConfigError), not kept by PettingZoo's converter
    to fail at the last agent's step, and every step after, until a reset."""
    aec = dz.env(num_drones=2, size=(6, 6, 2), seed=1)
    aec.reset(seed=1)
    first = aec.agent_selection
    with pytest.raises(ConfigError, match=f"for {first} is outside Discrete"):
        aec.step(action)
    assert aec.agent_selection == first
    aec.step(0)
    aec.step(0)  # (the last agent's: the turn is played)
    assert aec.unwrapped.episode.cycle == 1


def test_max_cycles_set_on_the_aec_form_is_the_episodes() -> None:
    aec = dz.env(num_drones=2, size=(8, 8, 2), seed=1)
    aec.max_cycles = 3
    aec.reset(seed=1)
    for _ in aec.agent_iter():
        _, _, term, trunc, _ = aec.last()
        aec.step(None if term or trunc else 0)
    assert aec.unwrapped.max_cycles == 3 and aec.unwrapped.episode.cycle == 3


def test_a_reset_that_cannot_draw_its_layout_leaves_no_episode() -> None:
    env = dz.parallel_env(num_drones=8, size=(4, 4, 2))
    env.reset(seed=1)
    with pytest.raises(ConfigError, match="too few for 8 drones"):
        env.reset(seed=7)  # (this seed's world has 14 free cells)
    assert env.agents == []
    with pytest.raises(ConfigError, match="before reset"):
        env.step({"drone_1": 0})


@pytest.mark.parametrize("few_drones", [99, 0])
def test_an_agent_that_is_done_cannot_act(few_drones: int) -> None:
    env = dz.parallel_env(world=corridor(8), num_drones=2, seed=1)
    env.few_drones = few_drones
    for seed in range(20):  # a layout where the lower drone's target is not on its way out (-x)
        _, infos = env.reset(seed=seed)
        low = min(env.agents, key=lambda a: infos[a]["cell"][0])
        if infos[low]["target"][0] > infos[low]["cell"][0]:
            break
    while low in env.agents:  # towards -x until it leaves the world (the other hovers)
        env.step({low: 2})
    assert env.agents and infos[low]["cell"][0] + 1 == env.episode.cycle
    with pytest.raises(ConfigError, match=f"agents that are done: {low}"):
        env.step({a: 0 for a in env.possible_agents})


@pytest.mark.parametrize("few_drones", [99, 0])
def test_an_episode_prepares_no_arbitration(few_drones: int) -> None:
    """An episode's drones are not cooperative: its game never arbitrates, so its start (at every reset) builds
    none of the search's graph of the world (coordinator/lacam.py, `prepare`: some 20 ms on 64x64x16)."""
    env = dz.parallel_env(size=(16, 16, 4), num_drones=3, seed=1)
    env.few_drones = few_drones
    for seed in range(2):
        env.reset(seed=seed)
        env.step({a: 0 for a in env.agents})
        engine = env.episode.engine if few_drones else env._turns.engine
        assert not engine.fleet.cooperating and engine.arbitration._open is None
        assert engine.arbitration.arbiter._graph is None


def test_done_agents_cannot_act() -> None:
    env = dz.parallel_env(world=corridor(6), num_drones=1, seed=1, max_cycles=20)
    _, infos = env.reset()
    for _ in range(infos["drone_1"]["cell"][0] + 1):
        env.step({"drone_1": 2})
    with pytest.raises(ConfigError, match="after the end"):
        env.step({"drone_1": 0})


def test_the_core_needs_no_rl_library() -> None:
    code = ("import sys; sys.modules['pettingzoo'] = None; sys.modules['gymnasium'] = None\n"
            "import dronesim.rl, dronesim.cli, coordinator.engine\n"
            "from dronesim.rl import Config, Layout, LocalTurns, Episode\n"
            "cfg = Config.of(num_drones=2); Episode(cfg, Layout.draw(cfg, 0), LocalTurns(), 5)\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=SOURCE_ROOT, env=child_env(), capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_module_has_pettingzoo_entry_points() -> None:
    assert isinstance(dz, types.ModuleType)
    assert callable(dz.parallel_env) and callable(dz.env)
    aec = dz.env(num_drones=2)
    aec.reset(seed=1)
    assert aec.agent_selection == "drone_1"
    assert aec.unwrapped.metadata["name"] == "dronesim_v0"


# --------------------------------------------------------------------------- the zenoh backend


def greedy(obs: np.ndarray, rng: np.random.Generator, actions: int = 7) -> int:
    """Along the axis of the largest offset to the target, or a random action (of `actions`) one time in three."""
    offset = obs[-3:]
    axis = int(np.argmax(np.abs(offset)))
    if rng.random() < 1 / 3 or offset[axis] == 0:
        return int(rng.integers(actions))
    return 1 + 2 * axis + (offset[axis] < 0)


def trace(env, seed: int, actions_seed: int = 1) -> list:
    """Everything an episode returns, step by step, under a seeded half-greedy policy."""
    rng = np.random.default_rng(actions_seed)
    out = [env.reset(seed=seed)]
    while env.agents:
        obs = out[-1][0]
        out.append(env.step({a: greedy(obs[a], rng) for a in env.agents}))
    return out


class MessageTurns(LocalTurns):
    """The engine of the local backend fed the messages the processes would send (its message path, as the
    coordinator's), where LocalTurns plays its turns from arrays (`Engine.play`)."""

    def play(self, turn, aim_rows, aims, move_rows, moves, notes):
        done, host_moves = turn_messages(turn, aim_rows, aims, move_rows, moves, notes)
        effects = self.engine.receive(done) + (self.engine.receive(host_moves) if host_moves else [])
        assert not [e for e in effects if isinstance(e, Refusal)]
        sent = [e.msg for e in effects if isinstance(e, Publish)]
        status = next(m for m in sent if isinstance(m, Status) and m.turn == turn)
        return Board.of_status(status, len(self.engine.fleet)), next((m for m in sent if isinstance(m, Over)), None)


def test_a_few_drones_are_played_drone_by_drone() -> None:
    few, many = dz.parallel_env(num_drones=3), dz.parallel_env(num_drones=EPISODE_FEW_DRONES + 1, size=(16, 16, 8))
    few.reset()
    many.reset()
    assert isinstance(few.episode, FewEpisode) and isinstance(many.episode, Episode)
    assert dz.parallel_env(num_drones=3, backend="zenoh").few_drones == 0


def random_trace(env, seed: int) -> list:
    """`trace`'s with random actions for a random subset of the agents (the others hover)."""
    rng = np.random.default_rng(seed)
    out = [env.reset(seed=seed)]
    k = env.config.actions  # (5 on a world one cell high)
    while env.agents:
        obs = out[-1][0]
        agents = [a for a in env.agents if rng.random() < 0.9]
        out.append(env.step({a: greedy(obs[a], rng, k) if rng.random() < 0.5 else int(rng.integers(k))
                             for a in agents}))
    return out


@pytest.mark.parametrize("case", range(28))
def test_few_drones_drone_by_drone_are_the_episode_of_the_engine(case: int) -> None:
    """FewEpisode (a few drones, drone by drone) and Episode over the engine (arrays) give the same episodes,
    step by step: random worlds, drone counts, rules and actions (a property test)."""
    rng = np.random.default_rng(case)
    n = int(rng.choice([1, 1, 2, 3, 5, 8, 16, 33, 99]))
    side = int(rng.integers(4, 12))
    size = (side, side, int(rng.integers(1, 5))) if n <= 8 else (10, 10, 3) if n <= 33 else (16, 16, 3)
    config = dict(num_drones=n, size=size,
                  on_target=ON_TARGET[case % 3], max_cycles=int(rng.integers(1, 60)),
                  obs_radius=int(rng.integers(0, 4)), step_cost=float(rng.choice([0.0, 0.1])),
                  reward_death=float(rng.choice([-1.0, -3.0])), seed=case)
    if case // 3 % 2:  # a random flat grid: pockets of a few cells (starts in them too: no cell is clear),
        size = (size[0], size[1] * size[2], 1)  # targets out of reach, nowhere new to go but the same target
        grid = rng.random(size) < 0.35
        config["world"] = World.from_grid(grid if np.count_nonzero(~grid) >= 2 * n else np.zeros(size, bool))
        del config["size"]
    if case >= 24:  # two pockets: a drone in the small one has nowhere new to go but the same target
        grid = np.zeros((7, 1, 1), bool)
        grid[2] = True
        config.update(world=World.from_grid(grid), num_drones=2, on_target="new", max_cycles=40)
        config.pop("size", None)
    few, engine = dz.parallel_env(**config), dz.parallel_env(**config)
    few.few_drones, engine.few_drones = 99, 0
    for seed in (case, case + 100):
        a, b = random_trace(few, seed), random_trace(engine, seed)
        assert isinstance(few.episode, FewEpisode) and isinstance(engine.episode, Episode)
        assert len(a) == len(b)
        for t, (x, y) in enumerate(zip(a, b)):
            assert repr(x) == repr(y), f"the paths differ at step {t}"


@pytest.mark.parametrize(("n", "few_drones", "on_target"),
                         [(1, 99, "finish"), (6, 99, "new"), (6, 0, "stay"), (70, 99, "finish")])
def test_episodes_after_a_reset_are_those_of_a_new_environment(n: int, few_drones: int, on_target: str) -> None:
    """Each reset restarts the last episode's engine (`Engine.restart`, `LocalTurns`) where the world, the drones and
    the turn limit are the same: the episodes one after the other in one environment are those of a new environment
    each, step by step (a given world; and a generated one, a new engine each time)."""
    for world in (World.from_grid(np.random.default_rng(n).random((10, 10, 3)) < 0.2), None):
        config = dict(num_drones=n, on_target=on_target, max_cycles=25, seed=3,
                      **({"world": world} if world is not None else {"size": (10, 10, 3)}))
        env = dz.parallel_env(**config)
        env.few_drones = few_drones
        engines = []
        for seed in range(4):
            fresh = dz.parallel_env(**config)
            fresh.few_drones = few_drones
            a, b = random_trace(env, seed), random_trace(fresh, seed)
            engines.append(env._turns.engine)
            assert repr(a) == repr(b), f"episode {seed} differs"
        assert len({id(e) for e in engines}) == (1 if world is not None else 4)


@pytest.mark.parametrize(("n", "on_target"), [(5, "finish"), (24, "new"), (130, "stay")])
def test_turns_from_arrays_are_the_turns_from_messages(n: int, on_target: str) -> None:
    """Engine.play (the local backend) and the engine's message path give the same episode, deaths and
    arrivals included; with 130 drones the engine's rows (D10 < D100 < D11) are not the agents' order."""
    config = dict(num_drones=n, size=(12, 12, 6), on_target=on_target, max_cycles=30, step_cost=0.01)
    arrays, messages = dz.parallel_env(**config), dz.parallel_env(**config)
    messages._turns = MessageTurns()
    arrays.few_drones = messages.few_drones = 0  # (the engine's turns, both)
    a, b = trace(arrays, seed=2), trace(messages, seed=2)
    assert len(a) == len(b) > 5
    for t, (x, y) in enumerate(zip(a, b)):
        assert repr(x) == repr(y), f"the paths differ at step {t}"
    assert any(r < -0.5 for step in a[1:] for r in step[1].values())  # deaths happened
    engines = arrays._turns.engine, messages._turns.engine
    if engines[0] is not None and engines[1] is not None:  # (an episode that ended stops its game)
        assert engines[0].arbitration.priority.tolist() == engines[1].arbitration.priority.tolist()


def test_a_turn_from_arrays_refuses_bad_input() -> None:
    env = dz.parallel_env(num_drones=3, size=(8, 8, 4))
    env.few_drones = 0
    env.reset(seed=0)
    engine = env._turns.engine
    rows, pos = np.arange(3), engine.fleet.pos.copy()
    none, cells, notes = rows[:0], np.zeros((0, 3), np.int32), np.zeros(3, np.uint8)
    far = pos.copy()
    far[1] += (2, 0, 0)
    with pytest.raises(UsageError, match="more than one cell"):
        engine.play(none, cells, rows, far, notes)
    with pytest.raises(UsageError, match="outside the world"):
        engine.play(rows[:1], np.array([[8, 0, 0]], np.int32), rows, pos, notes)
    assert engine.turn == 1 and (engine.fleet.pos == pos).all()  # nothing changed
    assert engine.play(none, cells, rows, pos, notes) is None and engine.turn == 2
    engine.receive(Done(turn=3, sender="GCS", phase=Phase.GCS, intent=Intent.CONTINUE))
    with pytest.raises(UsageError, match="GCS phase"):  # (its answer sent ahead would be lost)
        engine.play(none, cells, rows, pos, notes)


@pytest.mark.integration
def test_zenoh_parallel_api() -> None:
    env = dz.parallel_env(backend="zenoh", num_drones=6)
    try:
        parallel_api_test(env, num_cycles=40)
    finally:
        env.close()


@pytest.mark.integration
def test_zenoh_seed() -> None:
    seed_test(functools.partial(dz.env, backend="zenoh", num_drones=4, on_target="new"), num_cycles=40)


@pytest.mark.integration
@pytest.mark.parametrize(("on_target", "moves_ahead"), [("finish", True), ("new", True), ("new", False)])
def test_backends_agree_step_by_step(on_target: str, moves_ahead: bool) -> None:
    """(`moves_ahead=False`: each step's MOVES waits for its drones' phase, the benchmark's "off".)"""
    config = dict(num_drones=24, size=(12, 12, 6), on_target=on_target, max_cycles=40, step_cost=0.01)
    local, remote = dz.parallel_env(**config), dz.parallel_env(backend="zenoh", **config)
    remote.moves_ahead = moves_ahead
    try:
        a, b = trace(local, seed=4), trace(remote, seed=4)
    finally:
        remote.close()
    assert len(a) == len(b) > 10
    for t, (x, y) in enumerate(zip(a, b)):
        assert repr(x) == repr(y), f"the backends differ at step {t}"
    assert any(r < -0.5 for step in a[1:] for r in step[1].values())  # deaths happened
    assert any(r > 0.5 for step in a[1:] for r in step[1].values())  # and arrivals


@pytest.mark.integration
def test_zenoh_joins_a_router_and_close_ends_every_process() -> None:
    import zenoh

    from network.transport import router_config, router_locators

    with zenoh.open(router_config()) as router:
        env = dz.parallel_env(backend="zenoh", connect=router_locators(router)[0], num_drones=3, max_cycles=5)
        env.reset(seed=2)
        env.step({a: 0 for a in env.agents})
        procs = list(env._turns._game.procs.values())
        assert all(p.poll() is None for p in procs)
        env.close()
        assert all(p.poll() is not None for p in procs)


@pytest.mark.integration
def test_zenoh_unreachable_router_raises() -> None:
    from dronesim.rl import BackendError

    env = dz.parallel_env(backend="zenoh", connect="tcp/127.0.0.1:1", num_drones=2)
    with pytest.raises(BackendError, match="cannot open a session with the Zenoh router at tcp/127.0.0.1:1"):
        env.reset()
    env.close()


@pytest.mark.integration
@pytest.mark.parametrize("role", ["SRV", "ENV"])
def test_zenoh_process_death_raises(role: str) -> None:
    from dronesim.rl import BackendError

    env = dz.parallel_env(backend="zenoh", num_drones=3, max_cycles=50, deadline=20.0)
    try:
        env.reset(seed=1)
        game = env._turns._game
        game.procs[role].kill()
        game.procs[role].wait()
        with pytest.raises(BackendError, match="coordinator|environment"):
            for _ in range(50):
                env.step({a: 0 for a in env.agents})
    finally:
        env.close()
    assert all(p.poll() is not None for p in game.procs.values())


@pytest.mark.integration
def test_zenoh_coordinator_dead_before_admission_raises_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """The backend's admission is events of its inbox, its processes checked while none comes: a coordinator that
    exits before it admits anyone is said (its exit code), not waited for until the deadline."""
    from dronesim import rl_zenoh
    from dronesim.rl import BackendError

    start = rl_zenoh._Game._start

    def dead_coordinator(self, name: str, argv: list[str]) -> None:
        start(self, name, [sys.executable, "-c", "raise SystemExit(3)"] if name == "SRV" else argv)

    monkeypatch.setattr(rl_zenoh._Game, "_start", dead_coordinator)
    env = dz.parallel_env(backend="zenoh", num_drones=2, deadline=600.0)
    try:
        with pytest.raises(BackendError, match="coordinator process exited with 3"):
            env.reset(seed=1)
    finally:
        env.close()


# --------------------------------------------------------------------------- the expert and the examples


def expert_episode(**config: object) -> tuple[int, int]:
    """The D* expert's episode: how many drones arrived, how many died."""
    env = dz.parallel_env(**config)
    act = dz.expert_policy(env)
    env.reset()
    arrived = died = 0
    while env.agents:
        _, rewards, _, _, infos = env.step(act())
        arrived += sum(r > 0 for r in rewards.values())
        died += sum(info["state"] == "dead" for info in infos.values())
    return arrived, died


def test_dstar_expert_brings_a_swarm_home_without_a_collision() -> None:
    arrived, died = expert_episode(num_drones=32, seed=7, max_cycles=120)
    assert died == 0
    assert arrived >= 30


def test_the_expert_gives_way_as_a_game_does() -> None:
    """The expert's D* drones go through the arbitration games run (the search and PIBT, in the expert's own game
    of the episode): in a crowded flat world every one of them arrives; the former fixed-priority rule, where a
    drone whose move another claims hovers, brought 15 of the 24 home in the same 150 steps."""
    assert expert_episode(num_drones=24, seed=8, max_cycles=150, size=(10, 10, 2)) == (24, 0)


@pytest.mark.parametrize(("example", "expected"), [
    ("random_policy.py", "returns: {'drone_1': "),
    ("dstar_expert.py", "8 of 8 drones reached their targets"),
])
def test_examples_run(example: str, expected: str) -> None:
    done = subprocess.run([sys.executable, str(SOURCE_ROOT / "examples" / example)], cwd=SOURCE_ROOT,
                          env=child_env(), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert expected in done.stdout


@pytest.mark.integration
def test_zenoh_environment_dropped_without_close_leaves_no_process() -> None:
    import gc

    env = dz.parallel_env(backend="zenoh", num_drones=2)
    env.reset(seed=3)
    procs = list(env._turns._game.procs.values())
    del env
    gc.collect()
    assert all(p.poll() is not None for p in procs)


def test_bad_reset() -> None:
    env = dz.parallel_env(num_drones=2)
    for seed, match in ((-1, "seed"), (1.5, "seed"), ("3", "seed")):
        with pytest.raises(ConfigError, match=match):
            env.reset(seed=seed)
    env.max_cycles = 0
    with pytest.raises(ConfigError, match="max_cycles"):
        env.reset()


class _Events:
    """An inbox that hands out `events`, then nothing (waiting out the timeout, as an empty inbox does)."""

    def __init__(self, events: list) -> None:
        self.events = list(events)

    def get(self, timeout: float):
        import time

        if self.events:
            return self.events.pop(0)
        time.sleep(timeout)
        return None


def _game_reading(events: list):
    from dronesim.rl_zenoh import _Game

    game = _Game.__new__(_Game)
    game.inbox, game.procs, game.over, game.vanished, game.deadline = _Events(events), {}, None, None, 5.0
    return game


def test_a_process_leaving_at_the_games_end_is_not_a_failure_when_its_over_follows() -> None:
    """The environment leaves on OVER, and its token's removal may overtake the last STATUS and OVER on the way to the
    backend (seen in CI at a game's last turn): they are read, and the game ends as it should."""
    import time

    from dronesim.rl import BackendError
    from dronesim.rl_zenoh import _Game
    from network.transport import Presence, Received
    from schema import EndReason, Over, Status

    last = Status(turn=40, sender="SRV", game="g", drones=())
    over = Over(turn=40, sender="SRV", game="g", reason=EndReason.TURN_LIMIT, text="the end")
    game = _game_reading([Presence(entity="ENV", session="s", alive=False), Received("k", last), Received("k", over)])
    assert _Game._status(game, 40, time.monotonic() + 5.0) == last
    with pytest.raises(BackendError, match="the game ended before"):
        _Game._status(game, 41, time.monotonic() + 5.0)
    assert game.over == over


def test_a_process_leaving_mid_game_is_reported_within_the_grace() -> None:
    import time

    from dronesim.rl import BackendError
    from dronesim.rl_zenoh import _Game
    from network.transport import Presence

    game = _game_reading([Presence(entity="ENV", session="s", alive=False)])
    with pytest.raises(BackendError, match="the environment left the game"):
        _Game._status(game, 3, time.monotonic() + 5.0)
