"""The best policies seen while training, kept to be evaluated at the end (``eval.policy``).

The paper evaluates "the policy that produced the highest reward" (Sec. IV-B); on this task one PPO update
can move eval success from 80% to 50%, so the final policy is a different reading. Two best policies are
kept, each as a copy of the learner's parameters, its score and the timestep it was taken at:

* ``reward``: the highest ``rollout/ep_rew_mean`` (SB3's mean return of the last 100 finished episodes),
  read at every rollout end, the paper's reading;
* ``eval``: the highest in-training ``eval/return`` (only when ``eval.every_timesteps`` > 0), read from the
  ``evaluation`` hook (``PeriodicEvaluation``, which this hook requires before it) at the rollout end it evaluated.

A tie keeps the earlier policy. The state (parameters included) is checkpointed, so a resumed run keeps them.
"""
from __future__ import annotations

import numpy as np

from sweep.config import HookSettings
from sweep.training.hooks import Hook
from sweep.training.records import RolloutRecord


class BestPolicies(Hook):
    Settings = HookSettings
    requires = ("evaluation",)

    def __init__(self) -> None:
        self.kept: dict[str, dict] = {}   # reading -> {"score", "step", "params"}

    def setup(self, learner, training) -> None:
        self.evaluation = training.hooks["evaluation"]

    def state_dict(self) -> dict:
        return {"kept": {k: {**v, "params": {n: a.copy() for n, a in v["params"].items()}} for k, v in self.kept.items()}}

    def load_state_dict(self, state: dict) -> None:
        self.kept = dict(state["kept"])

    def offer(self, learner, reading: str, score: float, step: int) -> None:
        """Keep the learner's current parameters if ``score`` beats the best of ``reading`` so far."""
        if not np.isfinite(score) or (reading in self.kept and score <= self.kept[reading]["score"]):
            return
        self.kept[reading] = {"score": float(score), "step": int(step), "params": learner.parameter_arrays()}

    def after_rollout(self, learner, rollout: RolloutRecord) -> dict:
        if rollout.mean_recent_return is not None:
            self.offer(learner, "reward", rollout.mean_recent_return, rollout.timesteps)
        latest = self.evaluation.latest
        if latest is not None and latest[0] == rollout.timesteps:   # evaluated at this rollout end
            self.offer(learner, "eval", latest[1]["return"], rollout.timesteps)
        return {}
