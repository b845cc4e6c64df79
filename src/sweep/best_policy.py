"""The best policies seen while training, kept to be evaluated at the end (``eval.policy``).

The paper evaluates "the policy that produced the highest reward" (Sec. IV-B); on this task one PPO update
can move eval success from 80% to 50%, so the final policy is a different reading. Two best policies are
kept, each as a copy of the learner's parameters, its score and the timestep it was taken at:

* ``reward``: the highest ``rollout/ep_rew_mean`` (SB3's mean return of the last 100 finished episodes),
  read at every rollout end, the paper's reading;
* ``eval``: the highest in-training ``eval/return`` (only when ``eval.every_timesteps`` > 0; this callback
  must come after ``PeriodicEvaluation``, which records it at the same rollout end).

A tie keeps the earlier policy. The state (parameters included) is checkpointed, so a resumed run keeps them.
"""
from __future__ import annotations

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sweep.metrics import eval_key


class BestPolicies(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.kept: dict[str, dict] = {}   # reading -> {"score", "step", "params"}

    def state_dict(self) -> dict:
        return {"kept": {k: {**v, "params": {n: a.copy() for n, a in v["params"].items()}} for k, v in self.kept.items()}}

    def load_state_dict(self, state: dict) -> None:
        self.kept = dict(state["kept"])

    def _on_step(self) -> bool:
        return True

    def offer(self, reading: str, score: float) -> None:
        """Keep the learner's current parameters if ``score`` beats the best of ``reading`` so far."""
        if not np.isfinite(score) or (reading in self.kept and score <= self.kept[reading]["score"]):
            return
        self.kept[reading] = {"score": float(score), "step": int(self.num_timesteps),
                              "params": self.model.parameter_arrays()}

    def _on_rollout_end(self) -> None:
        episodes = self.model.ep_info_buffer
        if episodes:
            self.offer("reward", float(np.mean([ep["r"] for ep in episodes])))
        eval_return = self.model.logger.name_to_value.get(eval_key("final", "return"))
        if eval_return is not None:   # PeriodicEvaluation evaluated at this rollout end
            self.offer("eval", float(eval_return))
