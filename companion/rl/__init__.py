"""Reinforcement-learning baselines: the landing task as a Gymnasium env over the same MAVLink
path, and the paper's PPO baseline (docs/baselines.md)."""
