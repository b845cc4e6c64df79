"""Periodic reset (Nikishin et al. 2022, "The primacy bias in deep reinforcement learning"): every N env steps the
networks are drawn afresh and their optimizers start afresh; the replay buffer (and everything else) is kept.

Nikishin et al. rebuild SAC whole (actor, critics, temperature, their optimizers) every 200k steps on DMC, and the last
layers only on Atari (SPR). At the first round end at or past each multiple of ``every_steps`` on the run's clock
(``after_update``, so the next round's gradient steps start from the fresh networks):

    layers=all:   theta <- a fresh draw of the init of every trained network (``networks.fresh_parameters``: SAC/TD3
                  torch's uniform, PPO orthogonal; SAC's log entropy coefficient 0, i.e. alpha 1; PPO's log_std 0),
                  the target networks <- copies of them (``reset_targets``), every optimizer <- its initial state;
    layers=heads: only each network's output layer(s) (the actor's mean and log-std heads, each critic's Q head;
                  PPO's action and value heads) drawn afresh, Adam's moments of exactly those entries zeroed (step count
                  kept), the target networks' heads copied from them.

Logs ``remedy/periodic_reset/resets`` (how many so far). State: that count and the next reset's timestep.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sweep.agents.learner import Learner
from sweep.agents.networks import fresh_parameters
from sweep.cadence import Cadence
from sweep.config import MISSING, HookSettings, choice, positive_int
from sweep.training.hooks import Hook
from sweep.training.records import UpdateRecord

ResetLayers = choice("ResetLayers", "all", "heads")


class PeriodicReset(Hook):
    @dataclass
    class Settings(HookSettings):   # conf/remedy/periodic_reset.yaml
        every_steps: int = positive_int(" (env steps)")
        layers: ResetLayers = MISSING

    def __init__(self, every_steps: int = 200_000, layers: str = "all") -> None:
        self.every, self.layers = int(every_steps), layers
        self.cadence = Cadence(self.every)
        self.resets = 0

    def after_update(self, learner: Learner, update: UpdateRecord) -> dict[str, float]:
        if not self.cadence.due(update.timesteps):
            return {}
        self.reset(learner)
        self.resets += 1
        return {"remedy/periodic_reset/resets": float(self.resets)}

    def reset(self, learner: Learner) -> None:
        theta = learner.parameter_arrays()
        fresh = fresh_parameters({k: v.shape for k, v in theta.items()}, learner.networks, learner.rng)
        if self.layers == "all":
            learner.write_parameters(fresh)
            learner.reset_targets()
            learner.reset_optimizer_state()
            return
        heads = [f"{layer}.{kind}" for net in learner.networks for layer in (net.head, *net.extra_heads)
                 for kind in ("weight", "bias")]
        learner.write_parameters({k: fresh[k] for k in heads})
        learner.reset_optimizer({k: np.ones(theta[k].shape, bool) for k in heads})
        learner.reset_targets(heads)   # the target heads follow (the rest of each target network keeps averaging)

    def state_dict(self) -> dict:
        return {"resets": self.resets, "next_at": self.cadence.next_at}

    def load_state_dict(self, state: dict) -> None:
        self.resets, self.cadence.next_at = state["resets"], state["next_at"]
