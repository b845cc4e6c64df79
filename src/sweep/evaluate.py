"""The paper's evaluation protocol (Sec. IV-B, Table III).

``episodes`` deterministic episodes, one per vehicle of a HoverVecEnv, starts uniform in the training
start box drawn from ``eval.seed`` (the same starts for every agent and seed), the training episode length
(T = 500 steps), under the condition(s) ``eval.condition`` names (``flight_conditions``):

* ``fixed`` (the paper's): constant wind ``wind_speed`` along ``direction`` with Dryden gusts of sigma
  ``eval.gust`` (0: none), the vehicle ``eval.mass`` / ``eval.rotor_efficiency``;
* ``current``: the training schedules' condition at the policy's last training step (during training: the one in
  force; at the end: the last segment's);
* ``all``: every distinct condition the training schedules reach in ``train.total_timesteps``, in order of first
  appearance (``c0``, ``c1``, ...): each scored (``<prefix>/c<k>/<field>``), the prefix's fields their mean.

Every flight is scored on the same T states, the positions after each control step (``scored_positions``):
the start (t = 0) is left out, since the protocol sets it, not the policy; a flight that crashed keeps
its exit position for the rest of the episode, so a crash weighs as what it is (being outside the box
until the end) instead of shortening the average. Per flight: position MSE per axis (mean of p_i^2 over
the T states), final distance |p_T|, return, success.

Success (the paper defines none): the flight did not leave the bounds and the vehicle stayed within
``success_radius`` of the origin for the whole final ``success_hold_s`` seconds.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from omegaconf import DictConfig
from sweep import config, metrics
from sweep.cadence import Cadence
from sweep.envs import HoverVecEnv, WindSchedule
from sweep.envs.factory import make_env, vehicle_schedule, wind_schedule
from sweep.envs.hover import condition_at
from sweep.envs.vehicle import NOMINAL, VehicleSchedule, VehicleSegment
from sweep.training.hooks import Hook
from sweep.training.records import RolloutRecord


def hover_success(positions: np.ndarray, crashed: bool, radius: float, hold_steps: int) -> bool:
    """positions: (T, 3) of one flight. True if not crashed and the last ``hold_steps`` states are in the ball."""
    if crashed or len(positions) == 0:
        return False
    tail = positions[-max(int(hold_steps), 1):]
    return bool(np.all(np.linalg.norm(tail, axis=1) <= radius))


def fly(policy, env: HoverVecEnv) -> dict[str, np.ndarray]:
    """Fly each vehicle of ``env`` for one episode with ``policy.predict(obs, deterministic=True)``.

    Returns positions (N, T + 1, 3) from the start on, NaN after the end of a flight; the step rewards
    (N, T), 0 after the end; episode lengths, returns and whether each flight crashed."""
    n, steps = env.num_envs, env.episode_steps
    positions = np.full((n, steps + 1, 3), np.nan)
    rewards = np.zeros((n, steps))
    lengths = np.zeros(n, dtype=int)
    crashed = np.zeros(n, dtype=bool)
    alive = np.ones(n, dtype=bool)
    obs = env.reset()
    positions[:, 0] = env.sim.x
    for t in range(1, steps + 1):
        actions, _ = policy.predict(obs, deterministic=True)
        obs, step_rewards, dones, infos = env.step(actions)
        for i in np.flatnonzero(alive):
            final = infos[i]["terminal_observation"] if dones[i] else obs[i]
            positions[i, t] = final[:3]
            rewards[i, t - 1] = step_rewards[i]
            lengths[i] = t
            if dones[i]:
                alive[i] = False
                crashed[i] = infos[i]["crashed"]
        if not alive.any():
            break
    return {"positions": positions, "rewards": rewards, "returns": rewards.sum(axis=1), "lengths": lengths,
            "crashed": crashed}


def scored_positions(positions: np.ndarray) -> np.ndarray:
    """(T + 1, 3) flight (start first, NaN after an early end) -> the T post-step states the metrics score,
    the last position held after an early end."""
    flown = positions[1:].copy()
    ended = np.isnan(flown[:, 0])
    if ended.any():
        last = int(np.argmax(ended)) - 1
        flown[ended] = flown[last] if last >= 0 else positions[0]
    return flown


def flight_metrics(positions: np.ndarray, crashed: bool, radius: float, hold_steps: int) -> dict[str, float]:
    """Per-axis MSE, final distance and success of one flight (see the module docstring)."""
    scored = scored_positions(positions)
    mse = np.mean(scored ** 2, axis=0)
    return {"mse_x": float(mse[0]), "mse_y": float(mse[1]), "mse_z": float(mse[2]),
            "final_distance": float(np.linalg.norm(scored[-1])),
            "success": float(hover_success(scored, crashed, radius, hold_steps))}


@dataclass(frozen=True)
class FlightCondition:
    """What an evaluation flies under: a constant mean wind (world frame, m/s), its gusts, and a vehicle."""
    name: str
    wind: tuple[float, float, float]
    vehicle: VehicleSegment = NOMINAL
    segment: int = -1   # the training clock's segment it was in force at (-1: fixed)
    gust: float = 0.0   # Dryden sigma (sweep.envs.gusts; 0: none)
    gust_altitude: float = 2.0


def flight_conditions(eval_cfg: DictConfig, wind_cfg: DictConfig | None = None, vehicle_cfg: DictConfig | None = None,
                      timesteps: int = 0, total_timesteps: int = 0) -> list[FlightCondition]:
    """The conditions ``eval.condition`` names (module docstring) for a policy trained ``timesteps`` steps of a
    run of ``total_timesteps`` under the ``wind`` / ``vehicle`` configs (None: a constant still wind / nominal)."""
    mode = eval_cfg.get("condition", "fixed")
    wind_s = wind_schedule(wind_cfg) if wind_cfg is not None else WindSchedule()
    altitude = wind_s.gust_altitude
    if mode == "fixed":
        wind = WindSchedule.constant(eval_cfg.wind_speed, list(eval_cfg.direction)).velocity_at(0)
        vehicle = VehicleSegment.of(eval_cfg)   # runs stored before eval.mass: RotorPy's vehicle
        return [FlightCondition("fixed", tuple(float(c) for c in wind), vehicle, gust=float(eval_cfg.get("gust", 0.0)),
                                gust_altitude=altitude)]
    vehicle_s = vehicle_schedule(vehicle_cfg) if vehicle_cfg is not None else VehicleSchedule()
    if mode == "current":
        c = condition_at(wind_s, vehicle_s, max(int(timesteps) - 1, 0))
        return [FlightCondition("current", c.wind, VehicleSegment(c.mass, c.rotor_efficiency), c.segment, c.gust,
                                altitude)]
    starts = sorted({0} | {k * s for s in (wind_s.segment_steps, vehicle_s.segment_steps)
                           for k in range(1, -(-int(total_timesteps) // s))})
    seen: dict[tuple, FlightCondition] = {}
    for g in starts:
        c = condition_at(wind_s, vehicle_s, g)
        key = (c.wind, c.gust, c.mass, c.rotor_efficiency)
        if key not in seen:
            seen[key] = FlightCondition(f"c{len(seen)}", c.wind, VehicleSegment(c.mass, c.rotor_efficiency), c.segment,
                                        c.gust, altitude)
    return list(seen.values())


def evaluate(policy, eval_cfg: DictConfig, env_cfg: DictConfig, conditions: list[FlightCondition] | None = None
             ) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Run the protocol of ``eval_cfg`` on the task of ``env_cfg`` under ``conditions`` (None: ``eval_cfg``'s
    fixed one); returns (one value per ``sweep.metrics.EVAL_FIELDS`` name, their mean over the conditions, and
    with several conditions also ``c<k>/<field>`` per condition; trajectories for the run's artifact: the first
    condition's flights, the others' under ``c<k>_<name>``)."""
    conditions = conditions or flight_conditions(eval_cfg)
    scored = [fly_protocol(policy, eval_cfg, env_cfg, c) for c in conditions]
    fields = [f.name for f in metrics.EVAL_FIELDS]
    values = {f: float(np.mean([v[f] for v, _ in scored])) for f in fields}
    trajectories = dict(scored[0][1])
    if len(conditions) > 1:
        for c, (v, t) in zip(conditions, scored):
            values.update({f"{c.name}/{f}": v[f] for f in fields})
            if c is not conditions[0]:
                trajectories.update({f"{c.name}_{k}": a for k, a in t.items()})
    return values, trajectories


def fly_protocol(policy, eval_cfg: DictConfig, env_cfg: DictConfig, condition: FlightCondition
                 ) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """The protocol under one condition: (the EVAL_FIELDS values, the flights)."""
    ev = eval_cfg
    wind = WindSchedule.steady(condition.wind, condition.gust, condition.gust_altitude)
    env = make_env(env_cfg, ev.episodes, wind, ev.seed, vehicle=VehicleSchedule(segments=[condition.vehicle]))
    flights = fly(policy, env)
    hold_steps = int(round(ev.success_hold_s * env_cfg.sim_rate))
    per_flight = [flight_metrics(pos, bool(crash), ev.success_radius, hold_steps)
                  for pos, crash in zip(flights["positions"], flights["crashed"])]
    mean = {key: float(np.mean([f[key] for f in per_flight])) for key in per_flight[0]}
    values = {"success_rate": mean["success"], "mse_x": mean["mse_x"], "mse_y": mean["mse_y"], "mse_z": mean["mse_z"],
              "final_distance": mean["final_distance"], "return": float(flights["returns"].mean()),
              "crash_rate": float(flights["crashed"].mean())}
    trajectories = {**flights, "success": np.array([f["success"] > 0 for f in per_flight]),
                    "mse": np.array([[f["mse_x"], f["mse_y"], f["mse_z"]] for f in per_flight]),
                    "dt": np.array(env.dt), "wind": wind.velocity_at(0), "gust": np.array(condition.gust), "mass": np.array(condition.vehicle.mass),
                    "rotor_efficiency": np.array(condition.vehicle.rotor_efficiency)}
    return {f.name: values[f.name] for f in metrics.EVAL_FIELDS}, trajectories


class PeriodicEvaluation(Hook):
    """Runs the protocol during training every ``eval.every_timesteps`` (0: never; after the rollout that passes
    it), logging the current policy's ``eval/*`` at that step (with ``eval.condition=current`` also
    ``eval/segment``, the segment of the condition it flew under) and keeping them as ``latest`` = (timesteps, values)
    for hooks that read them. The final evaluation is done by ``run`` at the end."""

    @dataclass
    class Settings(config.HookSettings):   # the run's own blocks (conf/hooks/evaluation.yaml)
        eval_cfg: config.Eval = field(default_factory=config.Eval)
        env_cfg: config.Env = field(default_factory=config.Env)
        wind_cfg: config.Wind = field(default_factory=config.Wind)
        vehicle_cfg: config.Vehicle = field(default_factory=config.Vehicle)
        total_timesteps: int = config.positive_int()

    def __init__(self, eval_cfg: DictConfig, env_cfg: DictConfig, wind_cfg: DictConfig | None = None,
                 vehicle_cfg: DictConfig | None = None, total_timesteps: int = 0) -> None:
        self.eval_cfg, self.env_cfg = eval_cfg, env_cfg
        self.schedules = (wind_cfg, vehicle_cfg, total_timesteps)
        self.cadence = Cadence(eval_cfg.every_timesteps) if eval_cfg.every_timesteps > 0 else None
        self.latest: tuple[int, dict[str, float]] | None = None

    def after_rollout(self, learner, rollout: RolloutRecord) -> dict[str, float]:
        if self.cadence is None or not self.cadence.due(rollout.timesteps):
            return {}
        wind_cfg, vehicle_cfg, total = self.schedules
        conditions = flight_conditions(self.eval_cfg, wind_cfg, vehicle_cfg, rollout.timesteps, total)
        values, _ = evaluate(learner, self.eval_cfg, self.env_cfg, conditions)
        self.latest = (rollout.timesteps, values)
        flown = {"eval/segment": float(conditions[0].segment)} if self.eval_cfg.condition == "current" else {}
        return {**{metrics.eval_key("final", field): value for field, value in values.items()}, **flown}

    def state_dict(self) -> dict:
        return {"next_at": self.cadence.next_at if self.cadence else None}

    def load_state_dict(self, state: dict) -> None:
        if self.cadence is not None:
            self.cadence.next_at = state["next_at"]
