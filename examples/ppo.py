"""PPO with parameter sharing on the drones, in the CleanRL style: one file, every step in sight
(pip install 'dronesim[rl,train]': JAX on the CPU, Flax and Optax; docs/rl.md says why JAX).

One policy acts for every drone: SuperSuit's `black_death_v3` keeps dead drones present (zero observation,
zero reward) and `pettingzoo_env_to_vec_env_v1` + `concat_vec_envs_v1` make each drone of each game one
environment of a gymnasium vector environment, which resets a game when it ends. PPO as CleanRL writes it
(Schulman et al. 2017; Huang et al., "The 37 implementation details of PPO"): rollouts of `--num-steps`,
GAE, clipped policy and value losses, an entropy bonus, advantage normalisation, global gradient clipping,
Adam with a linearly annealed learning rate. The update is one jitted JAX function.

    python examples/ppo.py                                  # train, then evaluate against random actions
    python examples/ppo.py --total-timesteps 200000 --num-drones 8

The last line printed is a JSON object: the mean team return (the sum of every drone's rewards in an
episode) of the trained policy and of uniformly random actions over the same seeded evaluation episodes.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
import supersuit as ss

from dronesim.pettingzoo import parallel_env
from dronesim.rl import Seen


@dataclass(frozen=True, slots=True, kw_only=True)
class Args:
    seed: int = 1
    num_drones: int = 4
    size: tuple[int, int, int] = (8, 8, 2)
    obs_radius: int = 1
    max_cycles: int = 32
    num_games: int = 4  # games side by side (concat_vec_envs_v1): num_games * num_drones environments
    total_timesteps: int = 120_000  # drone steps
    num_steps: int = 64  # rollout length
    learning_rate: float = 2.5e-3
    anneal_lr: bool = True
    gamma: float = 0.97
    gae_lambda: float = 0.95
    num_minibatches: int = 4
    update_epochs: int = 4
    clip_coef: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    eval_episodes: int = 24

    def env_config(self) -> dict:
        return dict(num_drones=self.num_drones, size=self.size, obs_radius=self.obs_radius,
                    max_cycles=self.max_cycles)


def make_envs(args: Args):
    """The vector environment: every drone of every game one environment (parameter sharing)."""
    env = ss.black_death_v3(parallel_env(seed=args.seed, **args.env_config()))
    return ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(env), args.num_games, num_cpus=0,
                                 base_class="gymnasium")


class Agent(nn.Module):
    """Actor and critic over one drone's observation: each sensed cell one-hot (`Seen`'s codes), the offset to
    the target as its sign and its size scaled down."""

    actions: int

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        cells, offset = obs[:, :-3], obs[:, -3:].astype(jnp.float32)
        x = jnp.concatenate([jax.nn.one_hot(cells, len(Seen)).reshape(len(obs), -1),
                             jnp.sign(offset), offset / 8.0], axis=1)
        init = nn.initializers.orthogonal

        def trunk(h: jax.Array) -> jax.Array:
            for _ in range(2):
                h = jnp.tanh(nn.Dense(64, kernel_init=init(np.sqrt(2)))(h))
            return h

        logits = nn.Dense(self.actions, kernel_init=init(0.01))(trunk(x))
        value = nn.Dense(1, kernel_init=init(1.0))(trunk(x))
        return logits, value[:, 0]


def train(args: Args, log: Callable[[str], None] = print):
    """PPO for `args.total_timesteps` drone steps: the trained parameters and the network."""
    envs = make_envs(args)
    n_envs = envs.num_envs
    actions = int(envs.action_space.n)  # (SuperSuit's vector env: one environment's space)
    agent = Agent(actions)
    key = jax.random.PRNGKey(args.seed)
    key, init_key = jax.random.split(key)
    obs, _ = envs.reset(seed=args.seed)
    params = jax.jit(agent.init)(init_key, jnp.asarray(obs))  # (jitted: one compilation, not one per operation)
    batch = n_envs * args.num_steps
    minibatch = batch // args.num_minibatches
    updates = args.total_timesteps // batch
    schedule = (lambda k: args.learning_rate * (1.0 - (k // (args.num_minibatches * args.update_epochs)) / updates)) \
        if args.anneal_lr else args.learning_rate
    tx = optax.chain(optax.clip_by_global_norm(args.max_grad_norm), optax.adam(schedule, eps=1e-5))
    opt_state = tx.init(params)

    value_of = jax.jit(lambda params, obs: agent.apply(params, obs)[1])

    @jax.jit
    def act(params, obs, key):
        logits, value = agent.apply(params, obs)
        action = jax.random.categorical(key, logits)
        logprob = jax.nn.log_softmax(logits)[jnp.arange(len(action)), action]
        return action, logprob, value

    def loss_fn(params, obs, action, old_logprob, advantage, ret, old_value):
        logits, value = agent.apply(params, obs)
        logp_all = jax.nn.log_softmax(logits)
        logprob = logp_all[jnp.arange(len(action)), action]
        ratio = jnp.exp(logprob - old_logprob)
        adv = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
        pg = jnp.maximum(-adv * ratio, -adv * jnp.clip(ratio, 1 - args.clip_coef, 1 + args.clip_coef)).mean()
        clipped = old_value + jnp.clip(value - old_value, -args.clip_coef, args.clip_coef)
        v = 0.5 * jnp.maximum((value - ret) ** 2, (clipped - ret) ** 2).mean()
        entropy = -(jnp.exp(logp_all) * logp_all).sum(axis=1).mean()
        return pg - args.ent_coef * entropy + args.vf_coef * v

    @partial(jax.jit, donate_argnums=(1,))
    def update(params, opt_state, data, key):
        def epoch(carry, key):
            params, opt_state = carry
            order = jax.random.permutation(key, batch).reshape(args.num_minibatches, minibatch)

            def step(carry, idx):
                params, opt_state = carry
                grads = jax.grad(loss_fn)(params, *(d[idx] for d in data))
                changes, opt_state = tx.update(grads, opt_state)
                return (optax.apply_updates(params, changes), opt_state), None

            return jax.lax.scan(step, (params, opt_state), order)[0], None

        return jax.lax.scan(epoch, (params, opt_state), jax.random.split(key, args.update_epochs))[0]

    buf_obs = np.zeros((args.num_steps, n_envs, obs.shape[1]), np.int32)
    buf = {k: np.zeros((args.num_steps, n_envs), np.float32) for k in ("logprob", "reward", "done", "value")}
    buf_action = np.zeros((args.num_steps, n_envs), np.int32)
    done = np.zeros(n_envs, np.float32)
    started = time.monotonic()
    for u in range(1, updates + 1):
        key, *keys = jax.random.split(key, args.num_steps + 1)
        for t in range(args.num_steps):
            action, logprob, value = act(params, jnp.asarray(obs), keys[t])
            buf_obs[t], buf["done"][t] = obs, done
            buf_action[t], buf["logprob"][t], buf["value"][t] = action, logprob, value
            obs, reward, term, trunc, _ = envs.step(np.asarray(action))
            buf["reward"][t] = reward
            done = np.logical_or(term, trunc).astype(np.float32)
        # GAE(lambda), bootstrapped from the value of the last observation
        next_value, next_done = np.asarray(value_of(params, jnp.asarray(obs))), done
        advantage = np.zeros_like(buf["reward"])
        running = np.zeros(n_envs, np.float32)
        for t in reversed(range(args.num_steps)):
            if t < args.num_steps - 1:
                next_value, next_done = buf["value"][t + 1], buf["done"][t + 1]
            delta = buf["reward"][t] + args.gamma * next_value * (1 - next_done) - buf["value"][t]
            running = delta + args.gamma * args.gae_lambda * (1 - next_done) * running
            advantage[t] = running
        returns = advantage + buf["value"]
        data = tuple(jnp.asarray(a.reshape(batch, *a.shape[2:])) for a in
                     (buf_obs, buf_action, buf["logprob"], advantage, returns, buf["value"]))
        key, sub = jax.random.split(key)
        params, opt_state = update(params, opt_state, data, sub)
        if u % 10 == 0 or u == updates:
            log(f"update {u}/{updates}: mean reward per drone step {buf['reward'].mean():+.4f}, "
                f"{u * batch / (time.monotonic() - started):.0f} drone steps/s")
    envs.close()
    return agent, params


def team_returns(args: Args, choose: Callable[[np.ndarray, np.random.Generator], np.ndarray]) -> list[float]:
    """The team return (every drone's rewards summed) of `args.eval_episodes` seeded episodes, each drone's
    action from `choose(observations, rng)` (rows: the acting drones)."""
    env = parallel_env(**args.env_config())
    rng = np.random.default_rng(10_000 + args.seed)
    out = []
    for episode in range(args.eval_episodes):
        obs, _ = env.reset(seed=10_000 + episode)  # seeds no training episode used first
        total = 0.0
        while env.agents:
            agents = env.agents
            chosen = choose(np.stack([obs[a] for a in agents]), rng)
            obs, rewards, *_ = env.step(dict(zip(agents, chosen.tolist())))
            total += sum(rewards.values())
        out.append(total)
    env.close()
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    for field, default in Args.__dataclass_fields__.items():
        value = default.default
        if isinstance(value, tuple):
            parser.add_argument(f"--{field.replace('_', '-')}", type=lambda s: tuple(map(int, s.split(","))),
                                default=value)
        elif not isinstance(value, bool):
            parser.add_argument(f"--{field.replace('_', '-')}", type=type(value), default=value)
    args = Args(**vars(parser.parse_args(argv)))
    agent, params = train(args)
    policy = jax.jit(lambda obs: jnp.argmax(agent.apply(params, obs)[0], axis=1))
    trained = team_returns(args, lambda obs, rng: np.asarray(policy(jnp.asarray(obs))))
    actions = args.env_config() and parallel_env(**args.env_config()).config.actions
    random = team_returns(args, lambda obs, rng: rng.integers(0, actions, len(obs)))
    result = {"trained": float(np.mean(trained)), "random": float(np.mean(random)),
              "episodes": args.eval_episodes, "drones": args.num_drones}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
