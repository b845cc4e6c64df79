"""Learning-rate schedules (``agent.ppo.lr_schedule``): a control, not a remedy.

A remedy that keeps the policy learning must beat plain annealing; these give PPO the same LR path without
any plasticity mechanism. With p = SB3's ``progress_remaining`` (1 at the start of training, 0 at the end),
lr_0 = ``agent.ppo.learning_rate`` and u = ``until``, the share of training by whose end the decay is done
(``agent.ppo.lr_decay_timesteps`` / ``train.total_timesteps``; 1 = the whole run), r = max((p - (1 - u)) / u, 0)
the share of the decay still ahead (r = p for u = 1):

    constant   lr(p) = lr_0
    linear     lr(p) = floor + (lr_0 - floor) * r
    cosine     lr(p) = floor + (lr_0 - floor) * (1 + cos(pi * (1 - r))) / 2

so lr = floor from the timestep the decay ends to the end of the run.

p is clamped to [0, 1]: SB3's last rollout may end past ``total_timesteps`` (p < 0), which would otherwise
extrapolate below the floor. A resumed run continues the same curve (SB3 counts progress over the whole ``train.total_timesteps``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class LRSchedule:
    kind: str
    initial: float
    floor: float = 0.0
    until: float = 1.0

    def __call__(self, progress_remaining: float) -> float:
        if self.kind == "constant":
            return self.initial
        progress_remaining = min(max(progress_remaining, 0.0), 1.0)  # SB3's last rollout may overshoot the total
        # the share of the decay still ahead: progress_remaining itself when the decay spans the run (until = 1)
        remaining = max((progress_remaining - (1.0 - self.until)) / self.until, 0.0)
        shape = remaining if self.kind == "linear" else 0.5 * (1.0 + math.cos(math.pi * (1.0 - remaining)))
        return self.floor + (self.initial - self.floor) * shape
