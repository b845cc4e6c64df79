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
from sweep.envs.hover import rotor_speed_to_action
from sweep.envs.factory import make_env
from sweep.evaluate import flight_metrics, fly


class FixedPolicy:
    """``predict`` of a non-learning policy, ``act(env) -> actions`` (it may read the vehicles' state)."""

    def __init__(self, env: HoverVecEnv, act) -> None:
        self.env, self.act = env, act

    def predict(self, obs, deterministic: bool = True):
        return self.act(self.env), None


def to_action(env: HoverVecEnv, rotor_speeds) -> np.ndarray:
    """Rotor speeds (rad/s) -> actions in [-1, 1] (the inverse of the env's linear mapping)."""
    return np.asarray(rotor_speed_to_action(np.asarray(rotor_speeds, np.float64), env.speed_min, env.speed_max),
                      dtype=np.float32)


def constant(speed):
    return lambda env: np.broadcast_to(to_action(env, speed(env)), (env.num_envs, 4)).copy()


def se3_controller(env: HoverVecEnv):
    """RotorPy's SE3Control steering every vehicle to the origin (level, yaw 0)."""
    from rotorpy.controllers.quadrotor_control import SE3Control

    control = SE3Control(env.params)
    zero = np.zeros(3)
    target = {"x": zero, "x_dot": zero, "x_ddot": zero, "x_dddot": zero, "x_ddddot": zero, "yaw": 0.0,
              "yaw_dot": 0.0, "yaw_ddot": 0.0}

    def act(env: HoverVecEnv) -> np.ndarray:
        s = env.sim
        return to_action(env, [control.update(0.0, {"x": s.x[i], "v": s.v[i], "q": s.q[i], "w": s.w[i]}, target)
                               ["cmd_motor_speeds"] for i in range(env.num_envs)])
    return act


POLICIES = {"hover in place": lambda env: constant(lambda e: e.hover_speed),
            "motors off": lambda env: constant(lambda e: e.speed_min),
            "full throttle": lambda env: constant(lambda e: e.speed_max),
            "RotorPy SE3 controller": se3_controller}


def table(cfg: DictConfig) -> list[dict]:
    ev = cfg.eval
    hold = int(round(ev.success_hold_s * cfg.env.sim_rate))
    rows = []
    for name, make in POLICIES.items():
        env = make_env(cfg.env, ev.episodes, WindSchedule.constant(ev.wind_speed, list(ev.direction)), ev.seed)
        flights = fly(FixedPolicy(env, make(env)), env)
        scored = [flight_metrics(p, bool(c), ev.success_radius, hold)
                  for p, c in zip(flights["positions"], flights["crashed"])]
        discount = cfg.agent.ppo.gamma ** np.arange(env.episode_steps)
        rows.append({"policy": name, "return": float(flights["returns"].mean()),
                     "discounted_return": float((flights["rewards"] @ discount).mean()),
                     "episode_length": float(flights["lengths"].mean()),
                     "crash_rate": float(flights["crashed"].mean()),
                     "success_rate": float(np.mean([f["success"] for f in scored])),
                     "final_distance": float(np.median([f["final_distance"] for f in scored]))})
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
