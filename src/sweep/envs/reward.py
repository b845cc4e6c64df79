"""Hover reward, paper Eqs. (3)-(4) with the weights of Table I.

    R_total = R_dis + R_vel + R_action = -w_p ||p|| - w_v ||v|| - w_a ||a||

``p`` and ``v`` are the world-frame position (target = origin) and velocity after the step, ``a``
the policy's action in [-1, 1]^4 (as RotorPy's ``hover_reward`` uses it).

Not in the paper, both 0 by default: ``alive_bonus`` added to every step's reward, and
``crash_penalty`` subtracted on the step that leaves the bounds. With every term negative, a policy
that leaves the box early collects a *higher* return than one that hovers 5 s at 1 m; these two keys
let a study remove that incentive (the README shows it happening).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class HoverReward:
    w_p: float = 1.0
    w_v: float = 0.5
    w_a: float = 1e-5
    alive_bonus: float = 0.0
    crash_penalty: float = 0.0

    def __call__(self, position: np.ndarray, velocity: np.ndarray, action: np.ndarray) -> np.ndarray:
        """Batched reward: inputs (N, 3), (N, 3), (N, 4) -> (N,)."""
        return self.alive_bonus - (
            self.w_p * np.linalg.norm(position, axis=-1)
            + self.w_v * np.linalg.norm(velocity, axis=-1)
            + self.w_a * np.linalg.norm(action, axis=-1)
        )
