"""Hover reward, paper Eqs. (3)-(4) with the weights of Table I, and the reward of a crash.

    R_total = R_dis + R_vel + R_action = -w_p ||p|| - w_v ||v|| - w_a ||a||        (Eqs. 3-4)

``p`` and ``v`` are the world-frame position (target = origin) and velocity after the step, ``a``
the policy's action in [-1, 1]^4 (as RotorPy's ``hover_reward`` uses it).

The paper does not say what leaving the safe region costs. RotorPy's gym ``QuadrotorEnv`` (before
3.0), which the paper's setup comes from, *replaces* the reward of the step that leaves the region
(|p_i| > 4 m, |v_i| > 100 m/s, |w_i| > 100 rad/s) with -500; ``crash_reward`` does the same (default
-500.0; ``None`` keeps Eq. 3-4's reward on that step). Without it every term is negative and leaving
the box early *raises* the return (docs/calibration.md measures it). ``alive_bonus`` (not in the
paper, default 0) is added to every step that does not crash.

``step_reward`` is the rule for one vehicle, compiled with numba so the env's step kernel and
``HoverReward`` (the NumPy-facing form) share one formula; it reads the constants as ``RewardWeights``
(``HoverReward.weights``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np


class RewardWeights(NamedTuple):
    """``HoverReward``'s constants as the compiled ``step_reward`` reads them."""
    w_p: float
    w_v: float
    w_a: float
    alive_bonus: float
    replace_crash: bool   # a crash step gets crash_reward instead of Eqs. 3-4
    crash_reward: float   # 0.0 when not replace_crash


@numba.njit(cache=True)
def step_reward(p, v, a, crashed, weights):
    """One vehicle's reward: Eqs. 3-4 plus ``alive_bonus``, or ``crash_reward`` on a crash step."""
    if crashed and weights.replace_crash:
        return weights.crash_reward
    dist = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    speed = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    effort = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2] + a[3] * a[3])
    return weights.alive_bonus - (weights.w_p * dist + weights.w_v * speed + weights.w_a * effort)


@numba.njit(cache=True)
def _batch_reward(p, v, a, crashed, weights, out):
    for i in range(p.shape[0]):
        out[i] = step_reward(p[i], v[i], a[i], crashed[i], weights)


@dataclass(frozen=True)
class HoverReward:
    w_p: float = 1.0
    w_v: float = 0.5
    w_a: float = 1e-5
    alive_bonus: float = 0.0
    crash_reward: float | None = -500.0

    @property
    def weights(self) -> RewardWeights:
        """The constants ``step_reward`` takes after (p, v, a, crashed)."""
        replace = self.crash_reward is not None
        return RewardWeights(w_p=float(self.w_p), w_v=float(self.w_v), w_a=float(self.w_a),
                             alive_bonus=float(self.alive_bonus), replace_crash=replace,
                             crash_reward=float(self.crash_reward) if replace else 0.0)

    def __call__(self, position: np.ndarray, velocity: np.ndarray, action: np.ndarray,
                 crashed: np.ndarray | None = None) -> np.ndarray:
        """Batched reward: inputs (N, 3), (N, 3), (N, 4) and optional crash flags (N,) -> (N,)."""
        p = np.ascontiguousarray(np.atleast_2d(position), dtype=np.float64)
        v = np.ascontiguousarray(np.atleast_2d(velocity), dtype=np.float64)
        a = np.ascontiguousarray(np.atleast_2d(action), dtype=np.float64)
        crashed = np.zeros(len(p), dtype=np.bool_) if crashed is None else np.asarray(crashed, dtype=np.bool_)
        out = np.empty(len(p))
        _batch_reward(p, v, a, crashed, self.weights, out)
        return out
