"""RECOM reproduction: Hydra sweeps of PPO variants on RotorPy Crazyflie hover under changing wind."""
from sweep import portable as _portable

# Before torch, XLA, numba and NumPy compute anything: the process's float mode (train.portable, sweep/portable.py).
_portable.activate(_portable.requested())
