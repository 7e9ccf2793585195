"""Reinforcement learning: training stable-baselines3 agents (one seed or several),
their envs and features, frame encoders, hyperparameters (hyperparams/), the RL Zoo
files, run folders and checkpoints, and the shipped agents (agents/).
"""
