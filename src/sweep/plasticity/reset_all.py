"""Reset-all: a fresh network at every change of condition, the reference a continual network is compared to.

Juliani & Ash 2024 ("A study of plasticity loss in on-policy deep RL") run PPO with a ``reset-all`` condition:
when the task changes, the policy and value networks are re-initialised and the optimizer starts afresh. What a
continually trained network learns on a new condition, set against what this agent learns on it, measures
plasticity directly: worse than reset-all is plasticity lost; better is transfer.

At the first rollout end under a new condition (``at_change``), before the update on that rollout:

    theta <- a fresh draw of the learner's own init (``networks.fresh_parameters``: orthogonal, SB3's gains,
             zero biases, LayerNorm 1/0, log_std 0), from the learner's generator ``learner.rng``
    Adam   <- its initial state (moments zero, step count zero: ``reset_optimizer_state``)

The rollout collected before the reset is still learned from (by the new network: the update's importance
ratio then starts far from 1 and is clipped, as in any PPO update on data from another policy). Logs
``remedy/reset_all/resets`` (how many so far). State: that count; the generator is the learner's (checkpointed).
"""
from __future__ import annotations

from sweep.agents.learner import Learner
from sweep.agents.networks import fresh_parameters
from sweep.config import HookSettings
from sweep.training.hooks import Hook
from sweep.training.records import Condition


class ResetAll(Hook):
    Settings = HookSettings   # no settings of its own
    def __init__(self) -> None:
        self.resets = 0

    def at_change(self, learner: Learner, condition: Condition) -> dict[str, float]:
        shapes = {name: value.shape for name, value in learner.parameter_arrays().items()}
        learner.write_parameters(fresh_parameters(shapes, learner.networks, learner.rng))
        learner.reset_targets()   # off-policy: the target networks copy the fresh ones (PPO has none)
        learner.reset_optimizer_state()
        self.resets += 1
        return {"remedy/reset_all/resets": float(self.resets)}

    def state_dict(self) -> dict:
        return {"resets": self.resets}

    def load_state_dict(self, state: dict) -> None:
        self.resets = state["resets"]
