"""Random actions for every drone, until the episode ends (pip install 'dronesim[rl]')."""

from dronesim.pettingzoo import parallel_env

env = parallel_env(num_drones=8, seed=1, max_cycles=100, render_mode="ansi")
observations, infos = env.reset()
total = dict.fromkeys(env.agents, 0.0)
while env.agents:
    actions = {agent: env.action_space(agent).sample() for agent in env.agents}
    observations, rewards, terminations, truncations, infos = env.step(actions)
    for agent, reward in rewards.items():
        total[agent] += reward
print(env.render())
print("returns:", total)
env.close()
