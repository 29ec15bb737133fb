"""The D* autopilot as an expert policy: (observation, action) pairs for imitation learning."""

from dronesim.pettingzoo import expert_policy, parallel_env

env = parallel_env(num_drones=8, seed=1, max_cycles=100)
expert = expert_policy(env)  # one D* planner per drone, giving way to each other as in a game
observations, infos = env.reset()
demonstrations, arrived = [], 0
while env.agents:
    actions = expert()
    demonstrations += [(observations[agent], action) for agent, action in actions.items()]
    observations, rewards, terminations, truncations, infos = env.step(actions)
    arrived += sum(reward > 0 for reward in rewards.values())
print(f"{len(demonstrations)} demonstrations; {arrived} of {len(env.possible_agents)} drones reached their targets")
env.close()
