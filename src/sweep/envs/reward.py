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

Beyond the paper (each off by default, so the reward is Eqs. 3-4 exactly): the cost form of "Learning to Fly in
Seconds" (Eschmann et al. 2024; ../shared/NOTES.md), ``R = 2 - 0.5 (5 ||p||^2 + 5 (1 - q_w^2) + 0.01 ||v||^2 +
0.01 ||a - a_hover||^2)``, is written in the same terms:

    R = alive_bonus - (w_p ||p||^k + w_v ||v||^k + w_a ||a - a_ref||^k + w_q (1 - q_w^2))

with ``power`` k (1: Eqs. 3-4's norms; 2: quadratic costs), ``w_q`` the attitude cost (``1 - q_w^2`` is the squared
sine of half the angle of the vehicle's whole rotation, yaw included: 0 level and unyawed, 1 at any 180 deg rotation)
and ``action_reference`` a_ref (zero: ``||a||``, the paper's and RotorPy's; hover: the command of the nominal
vehicle's hover speed, ``HoverVecEnv``'s ``hover_action``). The anchor's weights: ``power=2 w_p=2.5 w_q=2.5
w_v=0.005 w_a=0.005 action_reference=hover alive_bonus=2 crash_reward=null`` (conf/experiment/anchor_task.yaml keeps
them with power 1, docs/anchor_task.md).

The anchor also raises its weights as training goes on: every ``every`` env steps it multiplies each weight by its
``factor``, up to its ``limit``, and re-computes the rewards already in the replay buffer. ``RewardCurriculum``
is that schedule (``env.reward_curriculum``, training only; stage k's weight is min(w_0 factor^k, limit)).

``step_reward`` is the rule for one vehicle, compiled with numba so the env's step kernel and
``HoverReward`` (the NumPy-facing form) share one formula; it reads the constants as ``RewardWeights``
(``HoverReward.weights``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
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
    squared: bool         # power 2: squared norms
    w_q: float            # attitude cost weight on 1 - q_w^2
    a_ref: float          # the action the effort term is measured from (each of the 4 commands)


@numba.njit(cache=True)
def step_reward(p, v, a, q_w, crashed, weights):
    """One vehicle's reward: Eqs. 3-4 (or their squared form), the attitude cost on ``q_w`` (the quaternion's scalar
    part) and ``alive_bonus``; ``crash_reward`` on a crash step."""
    if crashed and weights.replace_crash:
        return weights.crash_reward
    if not weights.squared and weights.a_ref == 0.0:   # Eqs. 3-4, in the arithmetic they always had (``a`` in its
        dist = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])   # own dtype), so that runs stay bit for bit
        speed = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        effort = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2] + a[3] * a[3])
        cost = weights.w_p * dist + weights.w_v * speed + weights.w_a * effort
    else:
        e0, e1, e2, e3 = a[0] - weights.a_ref, a[1] - weights.a_ref, a[2] - weights.a_ref, a[3] - weights.a_ref
        dist2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
        speed2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
        effort2 = e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3
        if weights.squared:
            cost = weights.w_p * dist2 + weights.w_v * speed2 + weights.w_a * effort2
        else:
            cost = (weights.w_p * math.sqrt(dist2) + weights.w_v * math.sqrt(speed2)
                    + weights.w_a * math.sqrt(effort2))
    if weights.w_q != 0.0:   # skipped when off, so that Eqs. 3-4 stay bit for bit what they were
        cost += weights.w_q * (1.0 - q_w * q_w)
    return weights.alive_bonus - cost


@numba.njit(cache=True)
def _batch_reward(p, v, a, q_w, crashed, weights, out):
    for i in range(p.shape[0]):
        out[i] = step_reward(p[i], v[i], a[i], q_w[i], crashed[i], weights)


@dataclass(frozen=True)
class HoverReward:
    w_p: float = 1.0
    w_v: float = 0.5
    w_a: float = 1e-5
    alive_bonus: float = 0.0
    crash_reward: float | None = -500.0
    power: int = 1                  # 1: norms (Eqs. 3-4) | 2: squared norms
    w_q: float = 0.0                # attitude cost on 1 - q_w^2
    action_reference: str = "zero"  # zero: ||a|| | hover: ||a - hover_action||

    def __post_init__(self) -> None:
        if self.power not in (1, 2):
            raise ValueError(f"power={self.power!r}: must be 1 (norms) or 2 (squared norms)")
        if self.action_reference not in ("zero", "hover"):
            raise ValueError(f"action_reference={self.action_reference!r}: must be zero or hover")

    def weights(self, hover_action: float = 0.0) -> RewardWeights:
        """The constants ``step_reward`` takes after (p, v, a, q_w, crashed); ``hover_action`` is a_ref when
        ``action_reference`` is hover."""
        replace = self.crash_reward is not None
        return RewardWeights(w_p=float(self.w_p), w_v=float(self.w_v), w_a=float(self.w_a),
                             alive_bonus=float(self.alive_bonus), replace_crash=replace,
                             crash_reward=float(self.crash_reward) if replace else 0.0, squared=self.power == 2,
                             w_q=float(self.w_q),
                             a_ref=float(hover_action) if self.action_reference == "hover" else 0.0)

    def __call__(self, position: np.ndarray, velocity: np.ndarray, action: np.ndarray,
                 crashed: np.ndarray | None = None, q_w: np.ndarray | None = None,
                 hover_action: float = 0.0) -> np.ndarray:
        """Batched reward: inputs (N, 3), (N, 3), (N, 4), optional crash flags (N,) and the quaternions' scalar parts
        (N,) (None: level, q_w = 1) -> (N,)."""
        p = np.ascontiguousarray(np.atleast_2d(position), dtype=np.float64)
        v = np.ascontiguousarray(np.atleast_2d(velocity), dtype=np.float64)
        a = np.ascontiguousarray(np.atleast_2d(action), dtype=np.float64)
        crashed = np.zeros(len(p), dtype=np.bool_) if crashed is None else np.asarray(crashed, dtype=np.bool_)
        q_w = np.ones(len(p)) if q_w is None else np.ascontiguousarray(q_w, dtype=np.float64).reshape(len(p))
        out = np.empty(len(p))
        _batch_reward(p, v, a, q_w, crashed, self.weights(hover_action), out)
        return out


CURRICULUM_WEIGHTS = ("w_p", "w_v", "w_a", "w_q")


@dataclass(frozen=True)
class RewardCurriculum:
    """The anchor's reward-weight curriculum: at every ``every`` env steps of the run's clock (summed over vehicles)
    a stage begins, and stage k's weight is ``min(w_0 * factor**k, limit)`` for each weight named in ``factor`` (a
    weight not named keeps its value; a limit of None: no limit). ``every`` None: no curriculum (stage 0 always)."""
    every: int | None = None
    factor: dict = field(default_factory=dict)
    limit: dict = field(default_factory=dict)
    recompute_replay: bool = True   # an off-policy learner re-computes its replay's rewards at each new stage

    def __post_init__(self) -> None:
        for name in (*self.factor, *self.limit):
            if name not in CURRICULUM_WEIGHTS:
                raise ValueError(f"{name!r}: the curriculum raises {', '.join(CURRICULUM_WEIGHTS)}")

    def stage(self, global_step: int) -> int:
        """The stage in force at ``global_step``: ``global_step // every`` (0 without a curriculum)."""
        return 0 if self.every is None else int(global_step) // int(self.every)

    def next_change(self, global_step: int) -> int | None:
        """The global step at which the next stage begins (None: no curriculum)."""
        return None if self.every is None else (self.stage(global_step) + 1) * int(self.every)

    def reward_at(self, reward: HoverReward, stage: int) -> HoverReward:
        """``reward`` with stage ``stage``'s weights."""
        if stage == 0:
            return reward
        weights = {}
        for name, factor in self.factor.items():
            base, limit = getattr(reward, name), self.limit.get(name)
            try:
                value = base * float(factor) ** stage
            except OverflowError:   # factor**stage past the float range: capped long before (config refuses no cap)
                value = math.inf if base else 0.0
            weights[name] = value if limit is None else min(value, float(limit))
        return replace(reward, **weights)
