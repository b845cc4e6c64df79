"""Fault injection for tests, attached as a hook through the agent config (``+agent.fault._target_=faults.Fault``)."""
from __future__ import annotations

import numpy as np

from sweep.training.hooks import Hook


class Fault(Hook):
    """In the run with ``seed``, at the first rollout end after ``at_step`` timesteps: raise (kind=raise) or
    poison a weight (kind=nan)."""

    def __init__(self, seed: int, at_step: int, kind: str = "raise") -> None:
        self.seed, self.at_step, self.kind = seed, at_step, kind

    def after_rollout(self, learner, rollout) -> dict:
        if learner.seed != self.seed or rollout.timesteps < self.at_step:
            return {}
        if self.kind == "raise":
            raise RuntimeError(f"injected failure at {rollout.timesteps}")
        name = "mlp_extractor.value_net.0.weight"
        weight = learner.parameter_arrays()[name]
        weight[0, 0] = np.nan
        learner.write_parameters({name: weight})
        return {}
