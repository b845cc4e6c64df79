"""The hover task as one Gymnasium environment, with its conditions as keyword arguments, for a learner outside this
harness: ``gymnasium.make("sweep.envs:CrazyflieHover-v0", wind_speeds=[3.0, 3.0], wind_directions=[[1, 0, 0],
[-1, 0, 0]], vehicle_segments=[{"mass": 1.0}, {"mass": 1.3}])``.

It is ``HoverVecEnv`` with one vehicle (the same physics, reward, termination and schedules the studies use),
with Gymnasium's API: ``reset(seed=...)`` -> (obs, info), ``step`` -> (obs, reward, terminated, truncated, info),
``truncated`` at the time limit. The schedules' clock is this env's step count: it runs on across episodes (the
condition changes every ``segment_steps`` steps of the env's life, as in a run) and ``reset`` does not rewind it.
``info`` carries ``crashed`` and the ``condition`` in force (``sweep.training.records.Condition``).
"""
from __future__ import annotations

from typing import Any, Sequence

import gymnasium
import numpy as np
from hydra.utils import get_class

from sweep.envs.hover import HoverVecEnv
from sweep.envs.reward import HoverReward
from sweep.envs.vehicle import VehicleSchedule, VehicleSegment
from sweep.envs.wind import WindSchedule

ENV_ID = "CrazyflieHover-v0"
BACKENDS = {"fast": "sweep.envs.backends.fast.FastBackend", "rotorpy": "sweep.envs.backends.rotorpy_backend.RotorPyBackend"}


class CrazyflieHoverEnv(gymnasium.Env):
    metadata = {"render_modes": []}

    def __init__(self, wind_speeds: Sequence[float] = (0.0,), wind_direction: Sequence[float] = (1.0, 0.0, 0.0),
                 wind_directions: Sequence[Sequence[float]] | None = None, wind_gusts: Sequence[float] | None = None,
                 gust_altitude: float = 2.0,
                 vehicle_segments: Sequence[dict[str, Any]] = ({"mass": 1.0},), segment_steps: int = 2_000_000,
                 vehicle_segment_steps: int | None = None, after_list: str = "repeat", backend: str = "fast",
                 reward: dict[str, float] | None = None, **task: Any) -> None:
        """``wind_*`` as ``conf/wind/`` (speeds, one direction or one per speed), ``wind_gusts`` Dryden
        sigmas, one per speed (RotorPy's ``sig_wind``; None: none) at ``gust_altitude`` m, ``vehicle_segments``
        as ``conf/vehicle/`` (each ``{"mass": f, "rotor_efficiency": [e1, e2, e3, e4]}``, both optional),
        ``segment_steps`` the wind's (and, unless ``vehicle_segment_steps``, the vehicle's) segment length in
        env steps, ``reward`` the ``env.reward`` weights, ``task`` other ``HoverVecEnv`` arguments
        (``episode_seconds``, ``start_bound``, ``observation``, ...)."""
        if backend not in BACKENDS:
            raise ValueError(f"backend={backend!r}: must be one of {'|'.join(BACKENDS)}")
        wind = WindSchedule(speeds=list(wind_speeds), segment_steps=segment_steps, direction=list(wind_direction),
                            directions=None if wind_directions is None else [list(d) for d in wind_directions],
                            gusts=None if wind_gusts is None else list(wind_gusts), gust_altitude=gust_altitude,
                            after_list=after_list, name="gym")
        segments = [VehicleSegment.of(s) for s in vehicle_segments]
        vehicle = VehicleSchedule(segments, segment_steps=vehicle_segment_steps or segment_steps, after_list=after_list,
                                  name="gym")
        self._vec = HoverVecEnv(n_envs=1, backend=get_class(BACKENDS[backend]), wind=wind, vehicle=vehicle,
                                reward=HoverReward(**(reward or {})), **task)
        self.observation_space = self._vec.observation_space
        self.action_space = self._vec.action_space

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._vec.seed(seed)
        obs = self._vec.reset()[0]
        return obs, {"condition": self._vec.condition()}

    def step(self, action):
        obs, reward, done, infos = self._vec.step(np.asarray(action, dtype=np.float32)[None])
        info = {"condition": self._vec.condition()}
        terminated = truncated = False
        if done[0]:
            obs = infos[0]["terminal_observation"][None]
            truncated = bool(infos[0]["TimeLimit.truncated"])
            terminated = not truncated
            info.update(crashed=infos[0]["crashed"], episode=infos[0]["episode"])
        return obs[0], float(reward[0]), terminated, truncated, info


gymnasium.register(id=ENV_ID, entry_point=CrazyflieHoverEnv, disable_env_checker=False)
