"""The game as a PettingZoo environment (``pip install 'dronesim[rl]'``): `parallel_env(**config)` and its
AEC form `env(**config)`, as PettingZoo's own environments expose them (an example: docs/rl.md).

Agents are the drones (``drone_1`` flies D01); actions `Discrete(7)` (0 hover, 1 +x, 2 -x, 3 +y, 4 -y, 5 +z,
6 -z; on a world one cell high, POGEMA's five: `Discrete(5)`, no ±z); observations a `Box` of int32: the
cells around the drone (`dronesim.rl.Seen` codes) then the offset to its target. The rules, the
configuration and the backends are in dronesim/rl.py and docs/rl.md.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec_wrapper
from pettingzoo.utils.wrappers import OrderEnforcingWrapper

from dronesim.rl import (
    RENDER_MODES,
    Config,
    ConfigError,
    Episode,
    Expert,
    Eyes,
    Layout,
    LocalTurns,
    Seen,
    Terrain,
    Turns,
    checked_actions,
    int_in,
)
from dronesim.rl_few import FEW_MAX, FewEpisode
from entities.autopilots import COOPERATIVE
from schema.tuning import EPISODE_FEW_DRONES

__all__ = ["DroneParallelEnv", "Expert", "env", "expert_policy", "parallel_env"]


class DroneParallelEnv(ParallelEnv):
    """The drones of one game as PettingZoo agents; see the module's docstring and docs/rl.md."""

    metadata = {"render_modes": list(RENDER_MODES), "name": "dronesim_v0", "is_parallelizable": True}

    def __init__(self, **config: object) -> None:
        self.config = cfg = Config.of(**config)
        self.render_mode = cfg.render_mode
        #: Steps before truncation; read at each reset (PettingZoo's tests set it).
        self.max_cycles = cfg.max_cycles
        self.possible_agents = [f"drone_{i}" for i in range(1, cfg.num_drones + 1)]
        self._row = {a: i for i, a in enumerate(self.possible_agents)}
        self.agents: list[str] = []
        self._obs_bounds = Eyes.bounds_for(cfg.size, cfg.obs_radius)  # (a given world's size is the size)
        #: The space of `state()`: the whole world as observation codes.
        self.state_space = spaces.Box(0, max(Seen), shape=cfg.size, dtype=np.int8)
        # Action spaces are seeded from the configuration's seed, so sampled actions are reproducible too.
        self._action_spaces = {a: spaces.Discrete(cfg.actions, seed=cfg.seed + i)
                               for i, a in enumerate(self.possible_agents)}
        self._observation_spaces: dict[str, spaces.Box] = {}
        self._episodes = np.random.default_rng(cfg.seed)  # seeds of the episodes reset() without a seed starts
        self._seeded = False
        self._turns: Turns | None = None
        self._eyes: Eyes | None = None
        self._terrain: Terrain | None = None
        self.episode: Episode | FewEpisode | None = None
        #: Episodes of up to this many drones are played drone by drone (`FewEpisode`: the same steps, fewer
        #: array operations) on the local backend; 0: always by `Episode` and the engine.
        self.few_drones = min(EPISODE_FEW_DRONES, FEW_MAX) if cfg.backend == "local" else 0
        #: The zenoh backend sends a step's MOVES with its DONE (the coordinator holds them); False: once the
        #: drones' phase is announced, a second round trip a step (`dronesim bench rl --ahead-gain`).
        self.moves_ahead = True

    # ------------------------------------------------------------------ spaces

    def observation_space(self, agent: str) -> spaces.Box:
        space = self._observation_spaces.get(agent)
        if space is None:
            self.action_space(agent)  # (an unknown agent's error)
            space = self._observation_spaces[agent] = spaces.Box(*self._obs_bounds, dtype=np.int32)
        return space

    def action_space(self, agent: str) -> spaces.Discrete:
        space = self._action_spaces.get(agent)
        if space is None:
            raise ConfigError(f"unknown agent {agent!r}: this environment's agents are drone_1 .. "
                              f"drone_{len(self.possible_agents)}")
        return space

    # ------------------------------------------------------------------ episodes

    def _backend(self) -> Turns:
        if self._turns is None and self.config.backend == "zenoh":
            from dronesim.rl_zenoh import ZenohTurns

            self._turns = ZenohTurns(connect=self.config.connect, deadline=self.config.deadline,
                                     moves_ahead=self.moves_ahead)
        elif self._turns is None:
            self._turns = LocalTurns()
        return self._turns

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        max_cycles = int_in(self.max_cycles, "max_cycles", 1)
        if seed is not None:
            episode_seed = int_in(seed, "seed", 0)
            self._episodes = np.random.default_rng(episode_seed)
        elif not self._seeded:
            episode_seed = self.config.seed
        else:
            episode_seed = int(self._episodes.integers(2**31))
        self._seeded = True
        self.episode, self.agents = None, []  # (a layout that cannot be drawn leaves no episode to step on)
        layout = Layout.draw(self.config, episode_seed, self._terrain)
        self._terrain = layout.terrain  # (the next episode's, if it has the same world: a given one)
        turns = self._backend()
        if self.config.num_drones <= self.few_drones and isinstance(turns, LocalTurns):
            self.episode = FewEpisode(self.config, layout, max_cycles, turns, self._eyes)
        else:
            self.episode = Episode(self.config, layout, turns, max_cycles, self._eyes)
        self._eyes = self.episode.eyes
        self.agents = self.possible_agents[:]
        rows = range(len(self.agents))  # (every row: no episode selects by them)
        observations = dict(zip(self.agents, self.episode.observe(rows)))
        infos = dict(zip(self.agents, self.episode.infos(rows)))
        if self.render_mode == "human":
            self.render()
        return observations, infos

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        episode = self.episode
        if episode is None:
            raise ConfigError("step() before reset()")
        if not episode.left:  # (`episode.ended`, without its property's call)
            if isinstance(actions, Mapping) and not actions:  # (PettingZoo's convention: nothing to step)
                return {}, {}, {}, {}, {}
            raise ConfigError("step() after the end of the episode: call reset()")
        if type(actions) is not dict and not isinstance(actions, Mapping):
            raise ConfigError(f"actions must be a dict of agent -> action, got {type(actions).__name__}")
        row = self._row
        try:
            rows = list(map(row.__getitem__, actions))
        except (KeyError, TypeError):
            bad = [a for a in actions if a not in row] if isinstance(actions, dict) else actions
            raise ConfigError(f"actions must map agents to actions; unknown agents: {bad!r}") from None
        done, seen, rewards, terminated, truncated, infos = episode.act(rows, list(actions.values()))
        names = self.possible_agents if len(done) == episode.n else [self.possible_agents[i] for i in done]
        self.agents = [a for a, end, cut in zip(names, terminated, truncated) if not (end or cut)] \
            if True in terminated or True in truncated else names[:]
        if self.render_mode == "human":
            self.render()
        return (dict(zip(names, seen)), dict(zip(names, rewards)), dict(zip(names, terminated)),
                dict(zip(names, truncated)), dict(zip(names, infos)))

    # ------------------------------------------------------------------ the rest

    def render(self) -> str | np.ndarray | None:
        if self.render_mode is None:
            logging.getLogger("dronesim.rl").warning("render() without a render_mode: nothing to render")
            return None
        if self.episode is None:
            raise ConfigError("render() before reset()")
        if self.render_mode != "human":
            return self.episode.rgb() if self.render_mode == "rgb_array" else self.episode.ansi()
        print(self.episode.ansi(), flush=True)
        return None

    def state(self) -> np.ndarray:
        """The whole world as the observations' codes (nx, ny, nz) int8: buildings and alive drones."""
        if self.episode is None:
            raise ConfigError("state() before reset()")
        return self.episode.state_grid()

    def close(self) -> None:
        self.episode = None
        if self._turns is not None:
            self._turns.close()
            self._turns = None

    def __str__(self) -> str:
        return "dronesim_v0"


def expert_policy(env: DroneParallelEnv, autopilot: str = COOPERATIVE):
    """A policy for `env` (a `parallel_env`): called with no argument, the actions of every agent for the
    current step, chosen by one of the project's autopilots per drone (see `dronesim.rl.Expert`)."""
    expert = Expert(autopilot)
    names = env.possible_agents

    def act() -> dict[str, int]:
        if env.episode is None:
            raise ConfigError("the expert acts after reset()")
        return {names[row]: a for row, a in expert.actions(env.episode).items()}

    return act


def parallel_env(**config: object) -> DroneParallelEnv:
    """The game as a PettingZoo ParallelEnv (keywords: see dronesim.rl.Config)."""
    return DroneParallelEnv(**config)


class _ToAEC(parallel_to_aec_wrapper):
    """PettingZoo's `parallel_to_aec_wrapper`, but an action other than None for an agent that is done (its
    turn comes once more, to be removed) raises ConfigError before anything changes, where the wrapper would
    fail a bare assertion after dropping the agent's entry, the environment broken."""

    def step(self, action):
        agent = self.agent_selection
        if self.terminations.get(agent) or self.truncations.get(agent):
            if action is not None:
                why = "terminated" if self.terminations.get(agent) else "truncated"
                raise ConfigError(f"{agent} is {why}: its last step takes None (env.step(None)), not {action!r}")
        else:  # (checked now: the wrapper would keep a bad action and fail at the last agent's step, every time)
            checked_actions([self.env.possible_agents.index(agent)], [action], self.action_space(agent).n)
        super().step(action)


class _Enforcing(OrderEnforcingWrapper):
    """PettingZoo's `OrderEnforcingWrapper`, but `max_cycles` is the parallel environment's (read at each reset),
    set as on `parallel_env` (set on the wrapper, it was its own and changed nothing)."""

    @property
    def max_cycles(self) -> int:
        return self.unwrapped.max_cycles

    @max_cycles.setter
    def max_cycles(self, value: int) -> None:
        self.unwrapped.max_cycles = value


def env(**config: object):
    """The game as a PettingZoo AECEnv (PettingZoo's `parallel_to_aec` of `parallel_env`, with a clear error
    for an action outside the action space or given to an agent that is done, at once)."""
    return _Enforcing(_ToAEC(parallel_env(**config)))
