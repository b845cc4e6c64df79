"""Shrink-and-perturb (Ash & Adams 2020, "On warm-starting neural network training").

Every K updates, every weight and bias of the chosen networks becomes

    theta <- lambda * theta + sigma * eps,    eps ~ the parameter's own init distribution

(a fresh orthogonal draw with the layer's gain for weights, 0 for biases: ``sweep.agents.networks``),
drawn from the learner's generator. lambda < 1 shrinks the weights back toward the origin, where
gradients are informative again; the noise restores the symmetry-breaking of a fresh init. Adam's state
is left as it is. Logs ``remedy/shrink_perturb/weight_norm_before`` and ``_after``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List

import numpy as np

from sweep.agents.learner import Learner
from sweep.agents.networks import fresh_parameters
from sweep.config import MISSING, HookSettings, non_negative, unit_interval
from sweep.plasticity.l2 import ParamGroup, params_key, penalized
from sweep.plasticity.remedy import Remedy, every_updates_key


@dataclass
class ShrinkPerturbSettings(HookSettings):   # conf/remedy/shrink_perturb.yaml
    every_updates: int = every_updates_key()
    shrink: float = unit_interval()
    perturb: float = non_negative()
    params: List[ParamGroup] = params_key()
    biases: bool = MISSING


class ShrinkPerturb(Remedy):
    Settings = ShrinkPerturbSettings
    name = "shrink_perturb"

    def __init__(self, every_updates: int = 200, shrink: float = 0.8, perturb: float = 0.2,
                 params=("policy", "value"), biases: bool = True) -> None:
        super().__init__(every_updates)
        self.shrink, self.perturb = float(shrink), float(perturb)
        self.params, self.biases = tuple(params), bool(biases)

    def act(self, learner: Learner, observations: np.ndarray | None) -> dict[str, float]:
        theta = learner.parameter_arrays()
        eps = fresh_parameters({k: v.shape for k, v in theta.items()}, learner.networks, learner.rng)
        names = [k for k in theta if penalized(k, list(self.params), self.biases, learner.groups)]
        new = {k: (self.shrink * theta[k] + self.perturb * eps[k]).astype(np.float32) for k in names}
        learner.write_parameters(new)
        norm = lambda d: float(np.sqrt(sum(float((d[k].astype(np.float64) ** 2).sum()) for k in names)))  # noqa: E731
        return {"weight_norm_before": norm(theta), "weight_norm_after": norm(new)}
