"""RECOM reproduction: Hydra sweeps of PPO variants on RotorPy Crazyflie hover under changing wind."""
