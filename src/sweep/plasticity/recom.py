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

SB3 resets the optimizer's LR from ``model.lr_schedule`` at every ``train()``; RECOM therefore
replaces that schedule with ``AdaptiveLR``, whose value it sets, so the new LR is what the next
update uses and what ``train/learning_rate`` reports.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sweep.cadence import Cadence


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


@dataclass
class AdaptiveLR:
    """A learning-rate 'schedule' for SB3 whose value RECOM sets (ignores training progress)."""

    value: float

    def __call__(self, progress_remaining: float) -> float:
        return self.value


class Recom(BaseCallback):
    def __init__(self, interval: int = 40960, window: int = 10, gain: float = 5e-6,
                 lr_min: float = 1e-5, lr_max: float = 1e-3, previous: str = "last_update",
                 gradient: str = "absolute", reward: str = "return") -> None:
        super().__init__()
        self.reward = reward
        self.interval, self.window, self.gain = int(interval), int(window), float(gain)
        self.lr_min, self.lr_max, self.previous, self.gradient = float(lr_min), float(lr_max), previous, gradient
        self.episodes: deque[tuple[float, float]] = deque(maxlen=self.window + 1)
        self.last_loss: float | None = None
        self.cost_prev: float | None = None
        self.cadence = Cadence(self.interval)   # an LR update every `interval` timesteps
        self.schedule: AdaptiveLR | None = None

    # -- state (for checkpoints) --
    def state_dict(self) -> dict:
        return {"episodes": list(self.episodes), "last_loss": self.last_loss, "cost_prev": self.cost_prev,
                "next_update": self.cadence.next_at, "lr": self.schedule.value if self.schedule else None}

    def load_state_dict(self, state: dict) -> None:
        self.episodes.clear()
        self.episodes.extend(tuple(e) for e in state["episodes"])
        self.last_loss, self.cost_prev, self.cadence.next_at = state["last_loss"], state["cost_prev"], state["next_update"]
        self.schedule.value = state["lr"]  # called after _init_callback (see sweep.checkpoint)

    # -- SB3 hooks --
    def _init_callback(self) -> None:
        self.schedule = AdaptiveLR(float(self.model.lr_schedule(1.0)))
        self.model.lr_schedule = self.schedule

    def _on_rollout_start(self) -> None:
        """After a train(): remember the mean total loss of that update (SB3 logged its parts)."""
        logged = self.model.logger.name_to_value
        if "train/value_loss" in logged:
            self.last_loss = float(logged["train/policy_gradient_loss"]
                                   + self.model.vf_coef * logged["train/value_loss"]
                                   + self.model.ent_coef * logged["train/entropy_loss"])

    def _on_step(self) -> bool:
        if self.last_loss is None:
            return True
        for info in self.locals["infos"]:
            if "episode" in info:
                r = float(info["episode"]["r"])
                self.episodes.append((r / max(int(info["episode"]["l"]), 1) if self.reward == "per_step" else r,
                                      self.last_loss))
        return True

    def _on_rollout_end(self) -> None:
        if self.cadence.due(self.num_timesteps):
            self.update()

    def update(self) -> None:
        episodes = np.array(self.episodes, dtype=np.float64).reshape(-1, 2)
        current = episodes[-self.window:]
        if len(current) == 0:
            return
        cost = retrospective_cost(current[:, 0], current[:, 1])
        if self.previous == "shifted":
            prev = episodes[:-1][-self.window:]
            cost_prev = retrospective_cost(prev[:, 0], prev[:, 1]) if len(prev) else None
        else:
            cost_prev = self.cost_prev
        lr = self.schedule.value
        if cost_prev is not None:
            gradient = cost_gradient(cost, cost_prev, self.gradient)
            lr, at_bound = recom_lr(lr, gradient, self.gain, self.lr_min, self.lr_max)
            self.schedule.value = lr
            self.logger.record("recom/cost_prev", cost_prev)
            self.logger.record("recom/cost_gradient", gradient)
            self.logger.record("recom/at_bound", float(at_bound))
        self.cost_prev = cost
        self.logger.record("recom/cost", cost)
        self.logger.record("recom/learning_rate", lr)
