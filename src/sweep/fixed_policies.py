"""What the task's reward pays fixed, non-learning policies: does crashing pay?

    python -m sweep.fixed_policies [key=value ...]      # any config override, e.g. env.reward.crash_reward=null

Flies fixed (non-learning) policies with the evaluation protocol (``eval.episodes`` starts from
``eval.seed``, constant wind ``eval.wind_speed``) and prints, per policy, the mean undiscounted return,
the mean discounted return (gamma = ``agent.ppo.gamma``, what PPO maximises), the mean episode length
and the crash rate:

* ``hover in place``: every rotor at the hover speed (holds the start position without wind),
* ``motors off``: action -1 (falls out of the box in about 0.9 s),
* ``full throttle``: action +1 (climbs out of the box),
* ``RotorPy SE3 controller``: RotorPy's geometric PD controller (``SE3Control``, its Crazyflie gains)
  flying to the origin: what a classical controller without integral action achieves (success rate and
  final distance are printed too), a yardstick for the learned policies and the success criterion.

A learner can only be expected to hover when hovering in place beats leaving the box.
"""
from __future__ import annotations

import sys

import numpy as np
from omegaconf import DictConfig

from sweep.envs import HoverVecEnv, WindSchedule
from sweep.evaluate import make_env


def _constant(value: float):
    return lambda env: np.full((env.num_envs, 4), value, dtype=np.float32)


def hover_in_place(env: HoverVecEnv) -> np.ndarray:
    return _constant(2.0 * (env.hover_speed - env.speed_min) / (env.speed_max - env.speed_min) - 1.0)(env)


def se3_controller(env: HoverVecEnv):
    """RotorPy's SE3Control steering every vehicle to the origin (level, yaw 0); actions in [-1, 1]."""
    from rotorpy.controllers.quadrotor_control import SE3Control

    control = SE3Control(env.params)
    zero = np.zeros(3)
    target = {"x": zero, "x_dot": zero, "x_ddot": zero, "x_dddot": zero, "x_ddddot": zero, "yaw": 0.0,
              "yaw_dot": 0.0, "yaw_ddot": 0.0}

    def act(env: HoverVecEnv) -> np.ndarray:
        s = env.sim
        speeds = np.stack([control.update(0.0, {"x": s.x[i], "v": s.v[i], "q": s.q[i], "w": s.w[i]}, target)
                           ["cmd_motor_speeds"] for i in range(env.num_envs)])
        return (2.0 * (speeds - env.speed_min) / (env.speed_max - env.speed_min) - 1.0).astype(np.float32)
    return act


POLICIES = {"hover in place": lambda env: hover_in_place, "motors off": lambda env: _constant(-1.0),
            "full throttle": lambda env: _constant(1.0), "RotorPy SE3 controller": se3_controller}


def fly_fixed(env: HoverVecEnv, policy, gamma: float, radius: float, hold_steps: int) -> dict[str, float]:
    """One episode per vehicle of ``env`` under ``policy(env) -> actions``."""
    from sweep.evaluate import hover_success

    n = env.num_envs
    ret, disc, length = np.zeros(n), np.zeros(n), np.zeros(n, dtype=int)
    crashed, alive = np.zeros(n, dtype=bool), np.ones(n, dtype=bool)
    positions = np.full((n, env.episode_steps, 3), np.nan)
    env.reset()
    for t in range(env.episode_steps):
        _, rewards, dones, infos = env.step(policy(env))
        for i in np.flatnonzero(alive):
            positions[i, t] = infos[i]["terminal_observation"][:3] if dones[i] else env.sim.x[i]
            if dones[i]:
                crashed[i] = infos[i]["crashed"]
        ret[alive] += rewards[alive]
        disc[alive] += gamma ** t * rewards[alive]
        length[alive] += 1
        alive &= ~dones
        if not alive.any():
            break
    success = [hover_success(positions[i, :length[i]], crashed[i], radius, hold_steps) for i in range(n)]
    final = [np.linalg.norm(positions[i, length[i] - 1]) for i in range(n)]
    return {"return": float(ret.mean()), "discounted_return": float(disc.mean()),
            "episode_length": float(length.mean()), "crash_rate": float(crashed.mean()),
            "success_rate": float(np.mean(success)), "final_distance": float(np.median(final))}


def table(cfg: DictConfig) -> list[dict]:
    ev = cfg.eval
    hold = int(round(ev.success_hold_s * cfg.env.sim_rate))
    rows = []
    for name, make in POLICIES.items():
        env = make_env(cfg.env, ev.episodes, WindSchedule.constant(ev.wind_speed, list(ev.direction)), ev.seed)
        rows.append({"policy": name, **fly_fixed(env, make(env), cfg.agent.ppo.gamma, ev.success_radius, hold)})
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| policy | return | discounted return | episode length (steps) | crash rate | success rate | "
             "median final distance (m) |", "|---|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['policy']} | {r['return']:.1f} | {r['discounted_return']:.1f} | {r['episode_length']:.0f} | "
              f"{r['crash_rate']:.2f} | {r['success_rate']:.2f} | {r['final_distance']:.2f} |" for r in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from hydra import compose, initialize_config_dir

    from sweep.config import ConfigError, validate
    from sweep.tracking import PROJECT_ROOT

    overrides = list(sys.argv[1:] if argv is None else argv)
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    try:
        validate(cfg)
    except ConfigError as err:
        print(f"sweep.fixed_policies: invalid config: {err}", file=sys.stderr)
        return 2
    r = cfg.env.reward
    print(f"reward: w_p={r.w_p} w_v={r.w_v} w_a={r.w_a} alive_bonus={r.alive_bonus} crash_reward={r.crash_reward}; "
          f"time_limit={cfg.env.time_limit}; {cfg.eval.episodes} starts (seed {cfg.eval.seed}), "
          f"wind {cfg.eval.wind_speed} m/s; gamma={cfg.agent.ppo.gamma}")
    print(markdown(table(cfg)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
