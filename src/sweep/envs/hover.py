"""Crazyflie hover task (paper Sec. III-B/C) as an SB3 ``VecEnv`` of N vehicles on one backend.

* Episode: ``episode_seconds`` at ``sim_rate`` Hz (paper: 5 s at 100 Hz = 500 steps, counted in
  integer steps, so an episode never runs one step long).
* Start: position uniform in +-``start_bound`` m per axis, at rest, level, rotors at hover speed (the paper's).
  ``start`` widens it: ``tilt_deg`` (a rotation by an angle uniform in [0, tilt_deg] about a horizontal axis of
  uniform direction), ``velocity`` (m/s) and ``body_rate`` (rad/s) (each component uniform in +-that). Each is drawn
  only when non-zero, after the position, so the paper's starts keep their random numbers. ``curriculum``
  (training only): the position box grows linearly from +-``start_bound_from`` at global step 0 to +-``start_bound``
  at ``steps`` (``start_bound_at``); on the global clock, so a resumed run continues it.
* Observation (13-D, RotorPy's layout): position, velocity, attitude quaternion (i, j, k, w), body
  rates; or, with ``observation="euler"``, 12-D with roll/pitch/yaw as in the paper's state list.
  ``observation_scale`` multiplies the velocity (m/s) and body-rate (rad/s) entries (default 1: RotorPy's
  raw state); positions stay in metres. ``observe`` appends (both off in the paper): ``rotor_speeds``, the 4 rotor
  speeds the policy's commands reach through the motor lag, as the action that commands them (in [-1, 1],
  ``rotor_speed_to_action``); ``action_history`` k, the last k actions the env applied (clipped), most recent first,
  4 per action (at a start: the hover action, the command of the rotors' start speed). ``critic_rotor_speeds`` and
  ``critic_condition`` append columns for the critic only (an asymmetric actor-critic: the actor reads the leading
  ``actor_columns``): the rotor speeds as above, and the condition the last vector step flew in (the segment's mean
  wind in m/s, the mass factor, the 4 rotor efficiencies; 8 columns; at a run's first start, the first step's), so an
  observation after a segment boundary shows the new condition one step later, the same in every collect.
  Layout: state | rotor speeds | history || critic's rotor speeds | condition.
* ``reward_scale``: the learner is given the reward times this factor; the episode returns in ``infos``
  (``rollout/ep_rew_mean``, RECOM's R, the evaluation) stay in the task's units.
* Action: 4 motor speeds in [-1, 1], mapped linearly to [rotor_speed_min, rotor_speed_max] as in
  RotorPy's ``cmd_motor_speeds`` mode (``action_to_rotor_speed``; its inverse ``rotor_speed_to_action``).
* Reward: ``HoverReward`` (Eqs. 3-4; the step that leaves the bounds gets ``crash_reward``, -500 as in
  RotorPy's gym env), its weights at the ``reward_curriculum``'s stage of the global step (``sync_condition``
  sets them; ``rewards_of`` scores stored transitions with the weights in force). Termination: out of bounds
  (|p_i| > world_bound, |v_i| > 100, |w_i| > 100), or farther than
  ``terminate_radius`` m from the target (None: no such bound; "Learning to Fly in Seconds" ends at 0.6 m), a crash
  like leaving the bounds.
  ``time_limit="truncate"`` (default) reports the time limit as a truncation, per env with that env's
  own terminal observation, so SB3 bootstraps each env from its own last state; ``"terminate"`` ends
  it as a termination (no bootstrap), as RotorPy's gym env before 3.0 did.
* Conditions: the wind (world-frame air velocity, ``WindSchedule``) and the vehicle (mass factor, rotor
  efficiencies, ``VehicleSchedule``) in force at the global timestep (steps x N); neither is observed.
  ``sync_condition`` brings the wind array and the backend's vehicle to the current step's segments; a change
  of either schedule's segment rebuilds them (the wind's direction, not only its speed). Under a turbulent wind
  (``WindSchedule.gusts``) each vehicle also gets its own Dryden gust each step (``sweep.envs.gusts``), scaled by
  the segment's sigma, its draws from the env's seed on their own stream.
"""
from __future__ import annotations

import math
import time
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np
from gymnasium import spaces
import numba
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from sweep.envs.backends.base import Backend, Vehicles
from sweep.envs.backends.fast import FastBackend, Physics, rotation_matrix
from sweep.envs.gusts import GustFilters, add_gusts, gust_rng, new_gusts, settle
from sweep.envs.reward import HoverReward, RewardCurriculum, RewardWeights, step_reward
from sweep.envs.schedule import next_boundary
from sweep.envs.vehicle import NOMINAL, VehicleSchedule, crazyflie_params, hover_rotor_speed
from sweep.envs.wind import WindSchedule
from sweep.training.records import Condition

SAFE_SPEED, SAFE_RATE = 100.0, 100.0  # m/s, rad/s: RotorPy's safety_exit bounds


@numba.njit(cache=True, inline="always")
def action_to_rotor_speed(action, speed_min, speed_max):
    """Action in [-1, 1] (already clipped) -> commanded rotor speed (rad/s), linearly: RotorPy's
    ``cmd_motor_speeds`` mapping. Compiled for the rollout; ``action_to_rotor_speed.py_func`` is the same
    rule evaluated by NumPy (on float64 arrays, as the env steps)."""
    return speed_min + (action + 1.0) * 0.5 * (speed_max - speed_min)


@numba.njit(cache=True, inline="always")
def rotor_speed_to_action(speed, speed_min, speed_max):
    """Rotor speed (rad/s) -> the action ``action_to_rotor_speed`` maps to it (its inverse); compiled, for a scalar
    (``task_outcome``) or a NumPy array alike."""
    return 2.0 * (speed - speed_min) / (speed_max - speed_min) - 1.0


@numba.njit(cache=True)
def quat_to_euler_xyz(q, out):
    """Roll, pitch, yaw of a scalar-last quaternion: extrinsic x-y-z, i.e. scipy's ``as_euler("xyz")``
    (R = Rz(yaw) Ry(pitch) Rx(roll); roll = atan2(R21, R22), pitch = -asin(R20), yaw = atan2(R10, R00))."""
    r00, _, _, r10, _, _, r20, r21, r22 = rotation_matrix(q[0], q[1], q[2], q[3])
    out[0] = math.atan2(r21, r22)
    out[1] = -math.asin(min(1.0, max(-1.0, r20)))
    out[2] = math.atan2(r10, r00)


class Task(NamedTuple):
    """The task's constants, as ``task_outcome`` reads them."""
    episode_steps: int
    world_bound: float        # m, per axis
    terminate_at_limit: bool  # time_limit="terminate"
    euler: bool               # observation="euler"
    velocity_scale: float     # observation_scale
    body_rate_scale: float
    reward: RewardWeights
    terminate_radius: float   # m from the target (inf: none)
    rotor_speeds: bool        # observe.rotor_speeds
    speed_min: float          # rad/s: the action -1 ...
    speed_max: float          # ... and +1
    critic_rotor_speeds: bool  # observe.critic_rotor_speeds
    critic_condition: bool     # observe.critic_condition


def state_dim(observation: str) -> int:
    """Columns of the vehicle's state in the observation: 13 (quaternion) or 12 (euler)."""
    return 12 if observation == "euler" else 13


CONDITION_COLUMNS = 8   # the critic's condition: mean wind (3), mass factor, 4 rotor efficiencies


def observation_dim(observation: str, rotor_speeds: bool, action_history: int, critic_rotor_speeds: bool = False,
                    critic_condition: bool = False) -> int:
    """Columns of the observation: the state, the 4 rotor speeds, the last ``action_history`` actions (the actor's),
    then the critic's own: the rotor speeds, the condition."""
    return (state_dim(observation) + 4 * int(rotor_speeds) + 4 * int(action_history) + 4 * int(critic_rotor_speeds)
            + CONDITION_COLUMNS * int(critic_condition))


class Outcome(NamedTuple):
    """``task_outcome``'s per-vehicle results of one step, (N,) arrays rewritten in place."""
    rewards: np.ndarray     # float32, in the task's units
    crashed: np.ndarray     # bool: left the bounds
    terminated: np.ndarray  # bool
    truncated: np.ndarray   # bool


class HoverKernel(NamedTuple):
    """What a compiled loop needs to step a ``HoverVecEnv`` itself (``HoverVecEnv.kernel``; the arrays are the
    env's own, so the env sees every step)."""
    vehicles: Vehicles
    physics: Physics
    task: Task
    t_idx: np.ndarray      # (N,) int64: steps of each episode so far
    ep_return: np.ndarray  # (N,) float64: return of each episode so far, task units
    reward_scale: float    # the learner gets the reward times this
    outcome: Outcome
    gust_filters: GustFilters  # the vehicles' gust processes (at rest and unused when the wind has no gusts)
    history: np.ndarray        # (N, k, 4) float32: the last k actions, most recent first (k = observe.action_history)
    vehicle: np.ndarray        # (5,) float64: the vehicle in force, mass factor and rotor efficiencies (critic_condition)


class RolloutWind(NamedTuple):
    """The wind of the next T vector steps (``HoverVecEnv.rollout_wind``): the mean wind (T, 3), the gusts' sigma
    (T,) and their uniform draws (T, N, 3) ((0, N, 3) when the wind has no gusts)."""
    mean: np.ndarray
    gust_sigma: np.ndarray
    gust_draws: np.ndarray


@numba.njit(cache=True, inline="always")
def write_rotor_speeds(row, col, rotor_speeds, task):
    """Columns ``col`` to ``col + 3`` of one observation ``row``: the rotor speeds as the actions that command them."""
    for r in range(4):
        row[col + r] = rotor_speed_to_action(rotor_speeds[r], task.speed_min, task.speed_max)


@numba.njit(cache=True)
def task_outcome(vehicles, actions, t_idx, task, obs, outcome, history, wind, vehicle):
    """After the physics step: advance each episode clock ``t_idx``, push ``actions`` into the action ``history``,
    write the observation ``obs`` and the ``outcome`` (reward, crashed = left the bounds, terminated, truncated) of
    every vehicle (in place). ``wind`` (3,) is the mean wind the step flew in and ``vehicle`` (5,) the vehicle (the
    critic's condition columns)."""
    x, v, q, w = vehicles.x, vehicles.v, vehicles.q, vehicles.w
    rewards, crashed, terminated, truncated = outcome
    world_bound, terminate_at_limit, v_scale, w_scale = (task.world_bound, task.terminate_at_limit,
                                                         task.velocity_scale, task.body_rate_scale)
    episode_steps, euler, weights = task.episode_steps, task.euler, task.reward  # fields read once, not per vehicle
    radius2 = task.terminate_radius * task.terminate_radius
    for i in range(x.shape[0]):
        t_idx[i] += 1
        out = False
        for a in range(3):
            out = out or abs(x[i, a]) > world_bound or abs(v[i, a]) > SAFE_SPEED or abs(w[i, a]) > SAFE_RATE
        out = out or x[i, 0] * x[i, 0] + x[i, 1] * x[i, 1] + x[i, 2] * x[i, 2] > radius2
        rewards[i] = step_reward(x[i], v[i], actions[i], q[i, 3], out, weights)
        at_limit = t_idx[i] >= episode_steps and not out
        crashed[i] = out
        terminated[i] = out or (at_limit and terminate_at_limit)
        truncated[i] = at_limit and not terminate_at_limit
        for a in range(3):
            obs[i, a] = x[i, a]
            obs[i, 3 + a] = v[i, a] * v_scale
        if euler:
            quat_to_euler_xyz(q[i], obs[i, 6:9])
            for a in range(3):
                obs[i, 9 + a] = w[i, a] * w_scale
        else:
            for a in range(4):
                obs[i, 6 + a] = q[i, a]
            for a in range(3):
                obs[i, 10 + a] = w[i, a] * w_scale
        col = 12 if euler else 13
        if task.rotor_speeds:
            write_rotor_speeds(obs[i], col, vehicles.rotor_speeds[i], task)
            col += 4
        k = history.shape[1]
        if k:
            for j in range(k - 1, 0, -1):   # shift: the oldest action drops out, this step's comes first
                history[i, j] = history[i, j - 1]
            history[i, 0] = actions[i]
            for j in range(k):
                for a in range(4):
                    obs[i, col + 4 * j + a] = history[i, j, a]
        col += 4 * k
        if task.critic_rotor_speeds:
            write_rotor_speeds(obs[i], col, vehicles.rotor_speeds[i], task)
            col += 4
        if task.critic_condition:
            for a in range(3):
                obs[i, col + a] = wind[a]
            for a in range(5):
                obs[i, col + 3 + a] = vehicle[a]


def segment_count(wind: WindSchedule, vehicle: VehicleSchedule, global_step: int) -> int:
    """Segments passed on the run's clock: the wind's segment periods, plus the vehicle's boundaries that are not
    also the wind's when the vehicle changes (with the same ``segment_steps``, both are ``global_step //
    segment_steps``). With a constant wind it still counts the wind's periods, as every run before the vehicle
    schedule did (the probe and the resets act at each)."""
    g, w = int(global_step), int(wind.segment_steps)
    if not vehicle.varies or vehicle.segment_steps == w:
        return g // w
    v = int(vehicle.segment_steps)
    return g // w + g // v - g // math.lcm(w, v)


def condition_at(wind: WindSchedule, vehicle: VehicleSchedule, global_step: int) -> Condition:
    """The ``Condition`` in force at ``global_step`` under the two schedules."""
    segment = vehicle.at(global_step)
    return Condition(segment=segment_count(wind, vehicle, global_step),
                     wind=tuple(float(c) for c in wind.velocity_at(global_step)),
                     mass=segment.mass, rotor_efficiency=tuple(segment.rotor_efficiency),
                     gust=wind.gust_at(global_step))


class HoverVecEnv(VecEnv):
    def __init__(
        self,
        n_envs: int = 1,
        backend: Callable[..., Backend] = FastBackend,
        wind: WindSchedule | None = None,
        vehicle: VehicleSchedule | None = None,
        reward: HoverReward | None = None,
        sim_rate: float = 100.0,
        episode_seconds: float = 5.0,
        start_bound: float = 2.0,
        world_bound: float = 4.0,
        terminate_radius: float | None = None,
        motor_time_constant: float | None = 0.05,
        observation: str = "quaternion",
        time_limit: str = "truncate",
        observation_scale: dict | None = None,
        reward_scale: float = 1.0,
        observe: dict | None = None,
        start: dict | None = None,
        curriculum: dict | None = None,
        reward_curriculum: RewardCurriculum | None = None,
        seed: int | None = None,
    ) -> None:
        """``observe``: {rotor_speeds: bool, action_history: k, critic_rotor_speeds: bool, critic_condition: bool};
        ``start``: {tilt_deg, velocity, body_rate}; ``curriculum``: {start_bound_from: m or None, steps} (None: the
        paper's, each; see the module docstring); ``reward_curriculum``: the reward's weights by stage (None: fixed)."""
        self.time_limit = time_limit
        scale = {"velocity": 1.0, "body_rate": 1.0, **(observation_scale or {})}
        self.velocity_scale, self.body_rate_scale = float(scale["velocity"]), float(scale["body_rate"])
        self.reward_scale = float(reward_scale)
        self.params = crazyflie_params(motor_time_constant)
        self.dt = 1.0 / float(sim_rate)
        self.episode_steps = int(round(episode_seconds * sim_rate))
        self.start_bound = float(start_bound)
        self.world_bound = float(world_bound)
        self.terminate_radius = math.inf if terminate_radius is None else float(terminate_radius)
        self.observation = observation
        self.wind = wind or WindSchedule()
        self.vehicle = vehicle or VehicleSchedule()
        self.reward_fn = reward or HoverReward()
        self.reward_curriculum = reward_curriculum or RewardCurriculum()
        self.reward_stage = 0   # the curriculum's stage the task's weights are at (sync_condition)
        self.sim = backend(n=n_envs, params=self.params, dt=self.dt)
        self.hover_speed = hover_rotor_speed(self.params)
        self.speed_min = float(self.params["rotor_speed_min"])
        self.speed_max = float(self.params["rotor_speed_max"])

        observe = {"rotor_speeds": False, "action_history": 0, "critic_rotor_speeds": False, "critic_condition": False,
                   **(observe or {})}
        self.observe_rotor_speeds, self.action_history = bool(observe["rotor_speeds"]), int(observe["action_history"])
        self.critic_rotor_speeds, self.critic_condition = (bool(observe["critic_rotor_speeds"]),
                                                           bool(observe["critic_condition"]))
        start = {"tilt_deg": 0.0, "velocity": 0.0, "body_rate": 0.0, **(start or {})}
        self.start_tilt = math.radians(float(start["tilt_deg"]))
        self.start_velocity, self.start_body_rate = float(start["velocity"]), float(start["body_rate"])
        curriculum = {"start_bound_from": None, "steps": 1, **(curriculum or {})}
        self.start_bound_from = curriculum["start_bound_from"]
        self.curriculum_steps = int(curriculum["steps"])
        obs_dim = observation_dim(observation, self.observe_rotor_speeds, self.action_history, self.critic_rotor_speeds,
                                  self.critic_condition)
        self.actor_columns = observation_dim(observation, self.observe_rotor_speeds, self.action_history)
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
        self._segments: tuple[int, int] | None = None  # (wind, vehicle) segment indices the arrays were built for
        self._wind_array = np.zeros((n_envs, 3))  # the mean wind of the current segments
        self._wind_now = np.zeros((n_envs, 3))    # with this step's gusts
        self._gust_sigma = 0.0
        self._gust_filters = new_gusts(n_envs, self.dt, self.wind.gust_altitude) if self.wind.turbulent else \
            GustFilters(state=np.zeros((n_envs, 3, 4)), coef=np.zeros((3, 6)))
        self._gust_rng = gust_rng(seed)
        self._settle_gusts()
        self.hover_action = float(rotor_speed_to_action(self.hover_speed, self.speed_min, self.speed_max))
        self.history = np.full((n_envs, self.action_history, 4), self.hover_action, dtype=np.float32)
        self.vehicle_condition = np.array([NOMINAL.mass, *NOMINAL.rotor_efficiency], dtype=np.float64)
        # outputs of task_outcome, reused every step
        self._obs_buf = np.zeros((n_envs, obs_dim), dtype=np.float32)
        self._rewards = np.zeros(n_envs, dtype=np.float32)
        self._crashed = np.zeros(n_envs, dtype=np.bool_)
        self._terminated = np.zeros(n_envs, dtype=np.bool_)
        self._truncated = np.zeros(n_envs, dtype=np.bool_)
        self._outcome = Outcome(rewards=self._rewards, crashed=self._crashed, terminated=self._terminated,
                                truncated=self._truncated)
        self._task = Task(episode_steps=self.episode_steps, world_bound=self.world_bound,
                          terminate_at_limit=time_limit == "terminate", euler=observation == "euler",
                          velocity_scale=self.velocity_scale, body_rate_scale=self.body_rate_scale,
                          reward=self.reward_fn.weights(self.hover_action), terminate_radius=self.terminate_radius,
                          rotor_speeds=self.observe_rotor_speeds,
                          speed_min=self.speed_min, speed_max=self.speed_max,
                          critic_rotor_speeds=self.critic_rotor_speeds, critic_condition=self.critic_condition)

    @property
    def kernel(self) -> HoverKernel:
        """What a compiled loop needs to step this env itself: the fast backend's state and physics, then
        ``task_outcome``'s inputs and outputs (see ``sweep.agents.rollout``)."""
        s = self.sim
        if not hasattr(s, "physics"):
            raise TypeError(f"a compiled rollout needs env.backend=fast, not {type(s).__name__}")
        return HoverKernel(vehicles=s.vehicles, physics=s.physics, task=self._task, t_idx=self.t_idx,
                           ep_return=self.ep_return, reward_scale=self.reward_scale, outcome=self._outcome,
                           gust_filters=self._gust_filters, history=self.history, vehicle=self.vehicle_condition)

    # ---- task pieces -------------------------------------------------------------------------
    def sync_condition(self) -> None:
        """Bring the (N, 3) wind array and the backend's vehicle to the segments in force at the current global
        step; rebuilt when either schedule's segment index changes (a new direction at the same speed too)."""
        g = self.global_step
        stage = self.reward_curriculum.stage(g)
        if stage != self.reward_stage:
            self.reward_stage = stage
            self._task = self._task._replace(reward=self.stage_reward().weights(self.hover_action))
        segments = (self.wind.index(g), self.vehicle.index(g))
        if segments == self._segments:
            return
        if self._segments is None or segments[1] != self._segments[1]:
            vehicle = self.vehicle.at(g)
            self.vehicle_condition[...] = (vehicle.mass, *vehicle.rotor_efficiency)
            if self._segments is not None or not vehicle.nominal:  # the backend starts nominal
                self.sim.set_vehicle(vehicle)
        self._segments = segments
        self._wind_array = np.ascontiguousarray(np.tile(self.wind.velocity_at(g), (self.num_envs, 1)))
        self._gust_sigma = self.wind.gust_at(g)

    def rollout_wind(self, n_steps: int) -> RolloutWind:
        """The wind of the next ``n_steps`` vector steps from the current global step, for a compiled loop that steps
        the backend itself; the gusts' draws are taken now, the numbers ``step`` would take one step at a time (a
        loop that stops before ``n_steps`` has drawn the rest too: as the learner's action noise, it must then not
        go on stepping this env)."""
        steps = self.global_step + self.num_envs * np.arange(n_steps)
        turbulent = self.wind.turbulent
        return RolloutWind(mean=self.wind.velocities(steps), gust_sigma=self.wind.gust_sigmas(steps),
                           gust_draws=self._gust_draws(n_steps) if turbulent else np.zeros((0, self.num_envs, 3)))

    def _settle_gusts(self) -> None:
        if self.wind.turbulent:
            settle(self._gust_filters, self._gust_rng, self.dt)

    def _gust_draws(self, n_steps: int) -> np.ndarray:
        return self._gust_rng.uniform(-1.0, 1.0, (n_steps, self.num_envs, 3))

    def steps_to_task_change(self) -> int | None:
        """Vector steps from now until the vehicle schedule's next segment boundary or the reward curriculum's next
        stage, whichever comes first (None: neither changes): a compiled loop that steps the backend itself must
        stop there and ``sync_condition``."""
        g = self.global_step
        changes = [] if not self.vehicle.varies else [next_boundary(g, self.vehicle.segment_steps)]
        stage_ends = self.reward_curriculum.next_change(g)
        changes += [] if stage_ends is None else [stage_ends]
        return None if not changes else -(-(min(changes) - g) // self.num_envs)

    def stage_reward(self) -> HoverReward:
        """The reward with the weights of the curriculum's stage in force (``reward_fn`` without a curriculum)."""
        return self.reward_curriculum.reward_at(self.reward_fn, self.reward_stage)

    def rewards_of(self, next_observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The reward (times ``reward_scale``, float32) each transition would get now, with the weights in force,
        from what a replay buffer keeps: its (N, obs_dim) next observations (a terminal one where the episode
        ended) and (N, 4) actions. A crash is read off the next state as ``task_outcome`` decides it; the values
        agree with the env's own to float32 rounding (the env scores the float64 state)."""
        o = np.asarray(next_observations[:, :13], dtype=np.float64)   # the state's columns (12 under euler)
        p, v = o[:, 0:3], o[:, 3:6] / self.velocity_scale
        if self.observation == "euler":
            half = 0.5 * o[:, 6:9]
            c, s = np.cos(half), np.sin(half)   # q_w of R = Rz(yaw) Ry(pitch) Rx(roll) (quat_to_euler_xyz's angles)
            q_w = c[:, 0] * c[:, 1] * c[:, 2] + s[:, 0] * s[:, 1] * s[:, 2]
            w = o[:, 9:12] / self.body_rate_scale
        else:
            q_w, w = o[:, 9], o[:, 10:13] / self.body_rate_scale
        crashed = ((np.abs(p) > self.world_bound).any(1) | (np.abs(v) > SAFE_SPEED).any(1)
                   | (np.abs(w) > SAFE_RATE).any(1) | ((p * p).sum(1) > self.terminate_radius ** 2))
        a = np.clip(np.asarray(actions, dtype=np.float32), -1.0, 1.0)
        rewards = self.stage_reward()(p, v, a, crashed=crashed, q_w=q_w, hover_action=self.hover_action)
        return (rewards.astype(np.float32) * np.float32(self.reward_scale) if self.reward_scale != 1.0
                else rewards.astype(np.float32))

    def start_bound_at(self, global_step: int) -> float:
        """The start box's half-width (m) at ``global_step``: ``start_bound``, or under the curriculum the linear
        ramp from ``start_bound_from`` at 0 to ``start_bound`` at ``curriculum_steps``."""
        if self.start_bound_from is None:
            return self.start_bound
        done = min(1.0, global_step / self.curriculum_steps)
        return float(self.start_bound_from) + done * (self.start_bound - float(self.start_bound_from))

    def _reset_envs(self, idx: np.ndarray) -> None:
        k = len(idx)
        if k == 0:
            return
        bound = self.start_bound_at(self.global_step)
        self.sim.x[idx] = self._rng.uniform(-bound, bound, size=(k, 3))
        self.sim.v[idx] = 0.0
        self.sim.q[idx] = (0.0, 0.0, 0.0, 1.0)
        self.sim.w[idx] = 0.0
        if self.start_tilt > 0:   # about a horizontal axis (cos phi, sin phi, 0) by an angle in [0, tilt]
            phi = self._rng.uniform(0.0, 2.0 * np.pi, size=k)
            half = 0.5 * self._rng.uniform(0.0, self.start_tilt, size=k)
            self.sim.q[idx] = np.stack([np.cos(phi) * np.sin(half), np.sin(phi) * np.sin(half), np.zeros(k),
                                        np.cos(half)], axis=1)
        if self.start_velocity > 0:
            self.sim.v[idx] = self._rng.uniform(-self.start_velocity, self.start_velocity, size=(k, 3))
        if self.start_body_rate > 0:
            self.sim.w[idx] = self._rng.uniform(-self.start_body_rate, self.start_body_rate, size=(k, 3))
        self.sim.rotor_speeds[idx] = self.hover_speed
        self.history[idx] = self.hover_action
        self.t_idx[idx] = 0
        self.ep_return[idx] = 0.0
        self.ep_start_time[idx] = time.time()

    def _obs(self) -> np.ndarray:
        """Observations of the vehicles' current states (after a reset)."""
        s = self.sim
        if self.observation == "quaternion":
            att = s.q
        else:
            att = np.zeros((self.num_envs, 3))
            for i in range(self.num_envs):
                quat_to_euler_xyz(s.q[i], att[i])
        columns = [s.x, s.v * self.velocity_scale, att, s.w * self.body_rate_scale]
        if self.observe_rotor_speeds:
            columns.append(rotor_speed_to_action(s.rotor_speeds, self.speed_min, self.speed_max))
        columns.append(self.history.reshape(self.num_envs, -1))
        if self.critic_rotor_speeds:
            columns.append(rotor_speed_to_action(s.rotor_speeds, self.speed_min, self.speed_max))
        if self.critic_condition:   # at a start as after a step: the condition the last vector step flew in
            flown = max(0, self.global_step - self.num_envs)
            vehicle = self.vehicle.at(flown)
            condition = [*self.wind.velocity_at(flown), vehicle.mass, *vehicle.rotor_efficiency]
            columns.append(np.tile(np.asarray(condition, np.float64), (self.num_envs, 1)))
        return np.concatenate(columns, axis=1).astype(np.float32)

    def condition(self) -> Condition:
        """The condition in force at the current global step (``Condition``: its segment, wind and vehicle)."""
        return condition_at(self.wind, self.vehicle, self.global_step)

    # ---- checkpoints ----------------------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """Everything needed to continue exactly where this env is (vehicles, clocks, RNG)."""
        return {"sim": self.sim.get_state(), "global_step": self.global_step, "t_idx": self.t_idx.copy(),
                "ep_return": self.ep_return.copy(), "rng": self._rng.bit_generator.state,
                "gusts": self._gust_filters.state.copy(), "gust_rng": self._gust_rng.bit_generator.state,
                "history": self.history.copy()}

    def set_state(self, state: dict[str, Any]) -> None:
        self.sim.set_state(state["sim"])
        self.global_step = int(state["global_step"])
        self.t_idx[...] = state["t_idx"]
        self.ep_return[...] = state["ep_return"]
        self._rng.bit_generator.state = state["rng"]
        if "gusts" in state:  # checkpoints before the gusts have none (their winds had none)
            self._gust_filters.state[...] = state["gusts"]
            self._gust_rng.bit_generator.state = state["gust_rng"]
        if "history" in state:  # checkpoints before the action history have none (they observed none)
            self.history[...] = state["history"]
        self._segments = None
        self.sim.set_vehicle(NOMINAL)
        self.sync_condition()

    # ---- VecEnv API ---------------------------------------------------------------------------
    def reset(self) -> np.ndarray:
        self._reset_envs(np.arange(self.num_envs))
        return self._obs()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, 4)

    def step_wait(self):
        actions = np.clip(self._actions, -1.0, 1.0)
        cmd = action_to_rotor_speed.py_func(actions.astype(np.float64), self.speed_min, self.speed_max)
        self.sync_condition()
        wind = self._wind_array
        if self.wind.turbulent:
            wind = self._wind_now
            wind[...] = self._wind_array
            add_gusts(self._gust_filters, self._gust_draws(1)[0], self._gust_sigma, wind)
        self.sim.step(cmd, wind)
        self.global_step += self.num_envs
        task_outcome(self.sim.vehicles, actions, self.t_idx, self._task, self._obs_buf, self._outcome, self.history,
                     self._wind_array[0], self.vehicle_condition)
        obs, rewards = self._obs_buf.copy(), self._rewards.copy()
        self.ep_return += rewards
        dones = self._terminated | self._truncated
        infos = self.end_episodes(obs, dones)
        return obs, rewards * np.float32(self.reward_scale) if self.reward_scale != 1.0 else rewards, dones, infos

    def end_episodes(self, obs: np.ndarray, dones: np.ndarray) -> list[dict[str, Any]]:
        """SB3's infos of one step; every vehicle whose episode ended (``dones``) is reset and its row of
        ``obs`` replaced by its new start, the last observation moving to ``terminal_observation``."""
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        if not dones.any():
            return infos
        done_idx = np.flatnonzero(dones)
        now = time.time()
        for i in done_idx:
            infos[i]["terminal_observation"] = obs[i].copy()
            infos[i]["TimeLimit.truncated"] = bool(self._truncated[i])
            infos[i]["crashed"] = bool(self._crashed[i])
            infos[i]["episode"] = {"r": float(self.ep_return[i]), "l": int(self.t_idx[i]),
                                   "t": round(now - self.ep_start_time[i], 6)}
        self._reset_envs(done_idx)
        obs[done_idx] = self._obs()[done_idx]
        return infos

    def close(self) -> None:
        pass

    def seed(self, seed: int | None = None) -> Sequence[None | int]:
        self._rng = np.random.default_rng(seed)
        self._gust_rng = gust_rng(seed)
        self._settle_gusts()   # the gust processes start afresh with their draws
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
