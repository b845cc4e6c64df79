"""RECOM, the retrospective cost mechanism (paper Sec. III-D, Eqs. 5-8).

    C_ret  = 1/T * sum_{last T episodes} (-R[t] + L[t])        (5)
    C_prev = the same cost one step back                        (6)
    G_cost = C_ret - C_prev                                     (7)
    lr    <- clip(lr - R_gain * G_cost, lr_min, lr_max)         (8, clipping ours)

``gradient`` chooses how Eq. 7 is read: ``absolute`` (default, the paper as printed) or ``relative``,
G_cost = (C_ret - C_prev) / |C_prev|, the change as a fraction of the previous cost. With returns and
losses in the hundreds, ``absolute`` x R_gain = 5e-6 moves the LR by ~1e-3 per update and pins it to a
bound (docs/calibration.md measures it); ``relative`` makes the step independent of the cost's scale
(R_gain is then the LR change for a 100% cost change). ``recom/at_bound`` logs 1 when Eq. 8 clipped.

R[t] is, with ``reward=return`` (default), the return of a finished episode (about -400 to -900 here); with
``reward=per_step``, that episode's mean reward per step (about -1 to -2): Eq. 5 says "the mean of rewards
and losses received by the last T episode", and both are natural readings. Under ``per_step`` the loss term
weighs as much as the reward. L[t] is the training loss paired with the episode: the mean total PPO
loss (pg + vf_coef*value + ent_coef*entropy, averaged over all minibatches and epochs) of the last
update *before* the episode ended. Episodes that end before the first update have no loss and are
not used. The update runs every ``interval`` timesteps, at the end of the rollout that reaches it.

C_prev has two readings, both available (``previous``):
  * ``last_update`` (default): the C_ret computed at the previous RECOM update; the first update
    only records C_ret (G = 0, LR unchanged).
  * ``shifted``: Eq. 6 read literally, the mean over the window ending one episode earlier
    (indices N-T .. N-1).

A hook: at set-up it takes over the learning rate (``Learner.set_learning_rate``: the rate in force, from then
on changed only by RECOM), so the new LR is what the next update uses and what ``train/learning_rate`` reports.
The loss of each update comes from its ``UpdateRecord`` (``mean_loss``), the episodes from each ``RolloutRecord``.
"""
from __future__ import annotations

import math

from collections import deque
from dataclasses import dataclass

import numpy as np

from sweep.cadence import Cadence
from sweep.config import (MISSING, ConfigError, HookSettings, algorithm_of, choice, non_negative, positive,
                          positive_int)
from sweep.training.hooks import Hook
from sweep.training.records import RolloutRecord, UpdateRecord


def retrospective_cost(returns: np.ndarray, losses: np.ndarray) -> float:
    """Eq. 5: mean of (-R + L) over the given episodes."""
    return float(np.mean(-np.asarray(returns, dtype=np.float64) + np.asarray(losses, dtype=np.float64)))


def cost_gradient(cost: float, cost_prev: float, reading: str = "absolute") -> float:
    """Eq. 7: C_ret - C_prev (``absolute``), or that change over |C_prev| (``relative``)."""
    change = cost - cost_prev
    return change if reading == "absolute" else change / max(abs(cost_prev), 1e-12)


def recom_lr(lr: float, gradient: float, gain: float, lr_min: float, lr_max: float) -> tuple[float, bool]:
    """Eq. 8 with clipping: returns (new learning rate, whether it was clipped to a bound)."""
    unclipped = lr - gain * gradient
    new = float(np.clip(unclipped, lr_min, lr_max))
    return new, new != unclipped


RecomPrevious = choice("RecomPrevious", "last_update", "shifted")
RecomGradient = choice("RecomGradient", "absolute", "relative")
RecomReward = choice("RecomReward", "return", "per_step")


@dataclass
class RecomSettings(HookSettings):   # conf/remedy/recom.yaml
    interval: int = positive_int(" (timesteps)")
    window: int = positive_int(" (episodes)")
    gain: float = non_negative()
    lr_min: float = positive()
    lr_max: float = positive()
    previous: RecomPrevious = MISSING
    gradient: RecomGradient = MISSING
    reward: RecomReward = MISSING


class Recom(Hook):
    Settings = RecomSettings

    @classmethod
    def check_config(cls, where: str, settings: dict, cfg: dict) -> None:
        if settings["lr_min"] > settings["lr_max"]:
            raise ConfigError(f"{where}.lr_min={settings['lr_min']!r} > {where}.lr_max={settings['lr_max']!r}: "
                              "must be lr_min <= lr_max")
        algorithm = algorithm_of(cfg["agent"])
        schedule = cfg["agent"][algorithm]["lr_schedule"]
        if schedule != "constant":
            raise ConfigError(f"agent.{algorithm}.lr_schedule={schedule!r}: must be constant with {where}.enabled=True "
                              "(RECOM sets the learning rate itself)")

    def __init__(self, interval: int = 40960, window: int = 10, gain: float = 5e-6,
                 lr_min: float = 1e-5, lr_max: float = 1e-3, previous: str = "last_update",
                 gradient: str = "absolute", reward: str = "return") -> None:
        self.reward = reward
        self.interval, self.window, self.gain = int(interval), int(window), float(gain)
        self.lr_min, self.lr_max, self.previous, self.gradient = float(lr_min), float(lr_max), previous, gradient
        self.episodes: deque[tuple[float, float]] = deque(maxlen=self.window + 1)
        self.last_loss: float | None = None
        self.cost_prev: float | None = None
        self.cadence = Cadence(self.interval)   # an LR update every `interval` timesteps
        self.lr: float | None = None

    # -- state (for checkpoints) --
    def state_dict(self) -> dict:
        return {"episodes": list(self.episodes), "last_loss": self.last_loss, "cost_prev": self.cost_prev,
                "next_update": self.cadence.next_at, "lr": self.lr}

    def load_state_dict(self, state: dict) -> None:
        self.episodes.clear()
        self.episodes.extend(tuple(e) for e in state["episodes"])
        self.last_loss, self.cost_prev, self.cadence.next_at = state["last_loss"], state["cost_prev"], state["next_update"]
        self.lr = self.learner.set_learning_rate(state["lr"])

    # -- the loop's moments --
    def setup(self, learner, training) -> None:
        """The learning rate in force becomes RECOM's to set (the learner's schedule no longer moves it)."""
        self.learner = learner
        self.lr = learner.set_learning_rate()

    def after_update(self, learner, update: UpdateRecord) -> dict[str, float]:
        """L[t] of the episodes that end from now on: the update's mean total loss (PPO) or mean critic loss (SAC,
        TD3; none before learning starts)."""
        if not math.isnan(update.mean_loss):
            self.last_loss = update.mean_loss
        return {}

    def after_rollout(self, learner, rollout: RolloutRecord) -> dict[str, float]:
        if self.last_loss is not None:
            for ep in rollout.episodes:
                self.episodes.append((ep.ret / max(ep.length, 1) if self.reward == "per_step" else ep.ret, self.last_loss))
        return self.update() if self.cadence.due(rollout.timesteps) else {}

    def update(self) -> dict[str, float]:
        """Eqs. 5-8 on the episodes kept; sets the learner's learning rate."""
        episodes = np.array(self.episodes, dtype=np.float64).reshape(-1, 2)
        current = episodes[-self.window:]
        if len(current) == 0:
            return {}
        cost = retrospective_cost(current[:, 0], current[:, 1])
        if self.previous == "shifted":
            prev = episodes[:-1][-self.window:]
            cost_prev = retrospective_cost(prev[:, 0], prev[:, 1]) if len(prev) else None
        else:
            cost_prev = self.cost_prev
        out = {}
        if cost_prev is not None:
            gradient = cost_gradient(cost, cost_prev, self.gradient)
            lr, at_bound = recom_lr(self.lr, gradient, self.gain, self.lr_min, self.lr_max)
            self.lr = self.learner.set_learning_rate(lr)
            out = {"recom/cost_prev": cost_prev, "recom/cost_gradient": gradient, "recom/at_bound": float(at_bound)}
        self.cost_prev = cost
        return {**out, "recom/cost": cost, "recom/learning_rate": self.lr}
