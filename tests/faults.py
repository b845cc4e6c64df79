"""Fault injection for tests, attached as a hook through the agent config (``+agent.fault._target_=faults.Fault``)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sweep.config import HookSettings, at_least, choice, positive_int
from sweep.training.hooks import Hook


Kind = choice("Kind", "raise", "nan")


class Fault(Hook):
    """In the run with ``seed``, at the first rollout end after ``at_step`` timesteps: raise (kind=raise) or
    poison a weight (kind=nan)."""

    @dataclass
    class Settings(HookSettings):
        seed: int = at_least(0)
        at_step: int = positive_int(" (timesteps)")
        kind: Kind = "raise"

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


class Unbuildable(Hook):
    """A schema that lets through an argument its class does not take (to see the whole error of a failed build)."""

    @dataclass
    class Settings(HookSettings):
        x: int = 0

    def __init__(self) -> None:
        pass
