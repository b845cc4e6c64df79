"""The paper's evaluation protocol (Sec. IV-B, Table III).

``episodes`` deterministic episodes, one per vehicle of a HoverVecEnv, starts uniform in the training
start box drawn from ``eval.seed`` (the same starts for every agent and seed), constant wind
``wind_speed`` along ``direction``, the training episode length. Per episode: position MSE per axis
over every state of the flight (start included), final distance, return, and success.

Success (the paper defines none): the flight did not leave the bounds and the vehicle stayed within
``success_radius`` of the origin for the whole final ``success_hold_s`` seconds.
"""
from __future__ import annotations

import numpy as np
from omegaconf import DictConfig
from stable_baselines3.common.callbacks import BaseCallback

from sweep.envs import HoverVecEnv, WindSchedule
from sweep.envs.reward import HoverReward


def hover_success(positions: np.ndarray, crashed: bool, radius: float, hold_steps: int) -> bool:
    """positions: (T, 3) of one flight. True if not crashed and the last ``hold_steps`` states are in the ball."""
    if crashed or len(positions) == 0:
        return False
    tail = positions[-max(int(hold_steps), 1):]
    return bool(np.all(np.linalg.norm(tail, axis=1) <= radius))


def make_env(env_cfg: DictConfig, n_envs: int, wind: WindSchedule, seed: int) -> HoverVecEnv:
    return HoverVecEnv(
        n_envs=n_envs, backend=env_cfg.backend, wind=wind, reward=HoverReward(**env_cfg.reward),
        sim_rate=env_cfg.sim_rate, episode_seconds=env_cfg.episode_seconds, start_bound=env_cfg.start_bound,
        world_bound=env_cfg.world_bound, motor_time_constant=env_cfg.motor_time_constant,
        observation=env_cfg.observation, time_limit=env_cfg.time_limit, seed=seed)


def fly(policy, env: HoverVecEnv) -> dict[str, np.ndarray]:
    """Fly each vehicle of ``env`` for one episode; positions after the end of a flight are NaN."""
    n, steps = env.num_envs, env.episode_steps
    positions = np.full((n, steps + 1, 3), np.nan)
    returns = np.zeros(n)
    crashed = np.zeros(n, dtype=bool)
    alive = np.ones(n, dtype=bool)
    obs = env.reset()
    positions[:, 0] = env.sim.x
    for t in range(1, steps + 1):
        actions, _ = policy.predict(obs, deterministic=True)
        obs, rewards, dones, infos = env.step(actions)
        for i in np.flatnonzero(alive):
            final = infos[i]["terminal_observation"] if dones[i] else obs[i]
            positions[i, t] = final[:3]
            returns[i] += rewards[i]
            if dones[i]:
                alive[i] = False
                crashed[i] = infos[i]["crashed"]
        if not alive.any():
            break
    return {"positions": positions, "returns": returns, "crashed": crashed}


def evaluate(policy, cfg: DictConfig) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Run the protocol; returns (metrics named eval/*, trajectories for the run's artifact)."""
    ev = cfg.eval
    wind = WindSchedule.constant(ev.wind_speed, list(ev.direction))
    env = make_env(cfg.env, ev.episodes, wind, ev.seed)
    flights = fly(policy, env)
    hold_steps = int(round(ev.success_hold_s * cfg.env.sim_rate))
    per_axis, final_dist, success = [], [], []
    for pos, crash in zip(flights["positions"], flights["crashed"]):
        flown = pos[~np.isnan(pos[:, 0])]
        per_axis.append(np.mean(flown ** 2, axis=0))
        final_dist.append(float(np.linalg.norm(flown[-1])))
        success.append(hover_success(flown, bool(crash), ev.success_radius, hold_steps))
    per_axis = np.array(per_axis)
    metrics = {
        "eval/success_rate": float(np.mean(success)),
        "eval/mse_x": float(per_axis[:, 0].mean()),
        "eval/mse_y": float(per_axis[:, 1].mean()),
        "eval/mse_z": float(per_axis[:, 2].mean()),
        "eval/final_distance": float(np.mean(final_dist)),
        "eval/return": float(flights["returns"].mean()),
        "eval/crash_rate": float(flights["crashed"].mean()),
    }
    trajectories = {**flights, "success": np.array(success), "mse": per_axis,
                    "dt": np.array(env.dt), "wind": wind.velocity_at(0)}
    return metrics, trajectories


class PeriodicEvaluation(BaseCallback):
    """Runs the protocol during training every ``every`` timesteps (after the rollout that passes it),
    logging ``eval/*`` at that step. The final evaluation is done by ``run`` at the end."""

    def __init__(self, cfg: DictConfig, every: int) -> None:
        super().__init__()
        self.cfg, self.every, self.next_at = cfg, int(every), int(every)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        if self.num_timesteps < self.next_at:
            return
        while self.next_at <= self.num_timesteps:
            self.next_at += self.every
        metrics, _ = evaluate(self.model, self.cfg)
        for key, value in metrics.items():
            self.logger.record(key, value)

    def state_dict(self) -> dict:
        return {"next_at": self.next_at}

    def load_state_dict(self, state: dict) -> None:
        self.next_at = state["next_at"]
