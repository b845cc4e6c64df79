"""The hover task (paper Sec. III-A..C) on a simulator backend, its wind and vehicle schedules, and its Gymnasium
registration (``gymnasium.make("sweep.envs:CrazyflieHover-v0", ...)``, ``sweep.envs.gym``)."""
from sweep.envs import gym as _gym  # noqa: F401  registers CrazyflieHover-v0
from sweep.envs.hover import HoverVecEnv
from sweep.envs.vehicle import VehicleSchedule, VehicleSegment
from sweep.envs.wind import WindSchedule

__all__ = ["HoverVecEnv", "VehicleSchedule", "VehicleSegment", "WindSchedule"]
