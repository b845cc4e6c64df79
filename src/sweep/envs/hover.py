"""Crazyflie hover task (paper Sec. III-B/C) as an SB3 ``VecEnv`` of N vehicles on one backend.

* Episode: ``episode_seconds`` at ``sim_rate`` Hz (paper: 5 s at 100 Hz = 500 steps, counted in
  integer steps, so an episode never runs one step long).
* Start: position uniform in +-``start_bound`` m per axis, at rest, level, rotors at hover speed.
* Observation (13-D, RotorPy's layout): position, velocity, attitude quaternion (i, j, k, w), body
  rates; or, with ``observation="euler"``, 12-D with roll/pitch/yaw as in the paper's state list.
* Action: 4 motor speeds in [-1, 1], mapped linearly to [rotor_speed_min, rotor_speed_max] as in
  RotorPy's ``cmd_motor_speeds`` mode.
* Reward: ``HoverReward`` (Eqs. 3-4). Termination: out of bounds (|p_i| > world_bound, |v_i| > 100,
  |w_i| > 100). The time limit is a truncation, reported per env with that env's own terminal
  observation, so SB3 bootstraps each env from its own last state.
* Wind: world-frame air velocity from ``WindSchedule`` at the global timestep (steps x N); not observed.
"""
from __future__ import annotations

import time
from typing import Any, Sequence

import numpy as np
from gymnasium import spaces
from scipy.spatial.transform import Rotation
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from sweep.envs.backends import make_backend
from sweep.envs.reward import HoverReward
from sweep.envs.vehicle import crazyflie_params, hover_rotor_speed
from sweep.envs.wind import WindSchedule

OBSERVATIONS = ("quaternion", "euler")


class HoverVecEnv(VecEnv):
    def __init__(
        self,
        n_envs: int = 1,
        backend: str = "fast",
        wind: WindSchedule | None = None,
        reward: HoverReward | None = None,
        sim_rate: float = 100.0,
        episode_seconds: float = 5.0,
        start_bound: float = 2.0,
        world_bound: float = 4.0,
        motor_time_constant: float | None = 0.05,
        observation: str = "quaternion",
        seed: int | None = None,
    ) -> None:
        if observation not in OBSERVATIONS:
            raise ValueError(f"env.observation={observation!r}; allowed: {list(OBSERVATIONS)}")
        self.params = crazyflie_params(motor_time_constant)
        self.dt = 1.0 / float(sim_rate)
        self.episode_steps = int(round(episode_seconds * sim_rate))
        self.start_bound = float(start_bound)
        self.world_bound = float(world_bound)
        self.observation = observation
        self.wind = wind or WindSchedule()
        self.reward_fn = reward or HoverReward()
        self.sim = make_backend(backend, n_envs, self.params, self.dt)
        self.hover_speed = hover_rotor_speed(self.params)
        self.speed_min = float(self.params["rotor_speed_min"])
        self.speed_max = float(self.params["rotor_speed_max"])

        obs_dim = 13 if observation == "quaternion" else 12
        observation_space = spaces.Box(-np.inf, np.inf, shape=(obs_dim,), dtype=np.float32)
        action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.render_mode = None
        super().__init__(n_envs, observation_space, action_space)

        self.global_step = 0  # env steps of the whole run, summed over the N envs (wind schedule clock)
        self.t_idx = np.zeros(n_envs, dtype=np.int64)
        self.ep_return = np.zeros(n_envs)
        self.ep_start_time = np.full(n_envs, time.time())
        self._actions = np.zeros((n_envs, 4), dtype=np.float32)
        self._rng = np.random.default_rng(seed)
        self._wind_speed: float | None = None
        self._wind_array = np.zeros((n_envs, 3))

    # ---- task pieces -------------------------------------------------------------------------
    def actions_to_rotor_speeds(self, actions: np.ndarray) -> np.ndarray:
        """Actions in [-1, 1] (already clipped) -> commanded rotor speeds, linearly (RotorPy's mapping)."""
        return self.speed_min + (actions.astype(np.float64) + 1.0) * 0.5 * (self.speed_max - self.speed_min)

    def _wind_now(self) -> np.ndarray:
        """(N, 3) wind of the current global step, rebuilt only when the speed changes."""
        speed = self.wind.speed_at(self.global_step)
        if speed != self._wind_speed:
            self._wind_speed = speed
            self._wind_array = np.ascontiguousarray(np.tile(self.wind.velocity_at(self.global_step), (self.num_envs, 1)))
        return self._wind_array

    def _reset_envs(self, idx: np.ndarray) -> None:
        k = len(idx)
        if k == 0:
            return
        self.sim.x[idx] = self._rng.uniform(-self.start_bound, self.start_bound, size=(k, 3))
        self.sim.v[idx] = 0.0
        self.sim.q[idx] = (0.0, 0.0, 0.0, 1.0)
        self.sim.w[idx] = 0.0
        self.sim.rotor_speeds[idx] = self.hover_speed
        self.t_idx[idx] = 0
        self.ep_return[idx] = 0.0
        self.ep_start_time[idx] = time.time()

    def _obs(self) -> np.ndarray:
        s = self.sim
        if self.observation == "quaternion":
            att = s.q
        else:
            att = Rotation.from_quat(s.q).as_euler("xyz")
        return np.concatenate([s.x, s.v, att, s.w], axis=1).astype(np.float32)

    def _out_of_bounds(self) -> np.ndarray:
        s = self.sim
        return (
            np.any(np.abs(s.x) > self.world_bound, axis=1)
            | np.any(np.abs(s.v) > 100.0, axis=1)
            | np.any(np.abs(s.w) > 100.0, axis=1)
        )

    # ---- checkpoints ----------------------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Everything needed to continue exactly where this env is (vehicles, clocks, RNG)."""
        return {"sim": self.sim.get_state(), "global_step": self.global_step, "t_idx": self.t_idx.copy(),
                "ep_return": self.ep_return.copy(), "rng": self._rng.bit_generator.state}

    def set_state(self, state: dict[str, Any]) -> None:
        self.sim.set_state(state["sim"])
        self.global_step = int(state["global_step"])
        self.t_idx[...] = state["t_idx"]
        self.ep_return[...] = state["ep_return"]
        self._rng.bit_generator.state = state["rng"]

    # ---- VecEnv API ---------------------------------------------------------------------------
    def reset(self) -> np.ndarray:
        self._reset_envs(np.arange(self.num_envs))
        return self._obs()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, 4)

    def step_wait(self):
        actions = np.clip(self._actions, -1.0, 1.0)
        self.sim.step(self.actions_to_rotor_speeds(actions), self._wind_now())
        self.global_step += self.num_envs
        self.t_idx += 1

        obs = self._obs()
        terminated = self._out_of_bounds()
        rewards = self.reward_fn(self.sim.x, self.sim.v, actions)
        if self.reward_fn.crash_penalty:
            rewards = rewards - self.reward_fn.crash_penalty * terminated
        rewards = rewards.astype(np.float32)
        self.ep_return += rewards
        truncated = (self.t_idx >= self.episode_steps) & ~terminated
        dones = terminated | truncated

        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        if not dones.any():
            return obs, rewards, dones, infos
        done_idx = np.flatnonzero(dones)
        now = time.time()
        for i in done_idx:
            infos[i]["terminal_observation"] = obs[i].copy()
            infos[i]["TimeLimit.truncated"] = bool(truncated[i])
            infos[i]["episode"] = {"r": float(self.ep_return[i]), "l": int(self.t_idx[i]),
                                   "t": round(now - self.ep_start_time[i], 6)}
        self._reset_envs(done_idx)
        obs[done_idx] = self._obs()[done_idx]
        return obs, rewards, dones, infos

    def close(self) -> None:
        pass

    def seed(self, seed: int | None = None) -> Sequence[None | int]:
        self._rng = np.random.default_rng(seed)
        return [None if seed is None else seed + i for i in range(self.num_envs)]

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        return [getattr(self, method_name)(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def _get_indices(self, indices):
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else indices
