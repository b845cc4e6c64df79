"""The hover task (paper Sec. III-A..C) on a simulator backend, and the wind schedule."""
from sweep.envs.hover import HoverVecEnv
from sweep.envs.wind import WindSchedule

__all__ = ["HoverVecEnv", "WindSchedule"]
