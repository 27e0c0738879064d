"""Baselines on brl's simulator: modular pipeline (mp), conditional imitation learning (il), deep RL (dqn)."""
