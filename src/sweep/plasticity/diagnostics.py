"""``PlasticityDiagnostics``: network statistics a plasticity study tracks, logged under ``plasticity/``.

Computed at the end of every ``every_rollouts``-th rollout on the ``batch_size`` most recent
observations of that rollout:

  plasticity/dormant_ratio           tau-dormant share over the policy network's hidden layers (paper Figs. 4-5)
  plasticity/dormant_ratio_layer{i}  per hidden layer of the policy network
  plasticity/value_dormant_ratio     the same over the value network's hidden layers
  plasticity/saturated_ratio         share of policy activations with |h| > saturation (tanh saturation)
  plasticity/srank                   effective rank of the policy's last hidden features (Kumar et al. 2021)
  plasticity/weight_norm             L2 norm of all policy+value parameters
  plasticity/grad_norm               norm of the PPO loss gradient on that batch (before SB3's clipping)
"""
from __future__ import annotations

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sweep.plasticity.batch import recent_rollout
from sweep.plasticity.dormant import dormant_ratio, saturated_ratio, srank


class PlasticityDiagnostics(BaseCallback):
    """Reads the networks through the learner (``hidden_activations``, ``parameter_arrays``,
    ``loss_grad_norm``), so the statistics are the same code for every learner."""

    def __init__(self, every_rollouts: int = 1, tau: float = 0.025, batch_size: int = 1024,
                 saturation: float = 0.99, srank_delta: float = 0.01) -> None:
        super().__init__()
        self.every, self.tau, self.batch_size = int(every_rollouts), float(tau), int(batch_size)
        self.saturation, self.srank_delta = float(saturation), float(srank_delta)
        self.rollouts = 0

    def state_dict(self) -> dict:
        return {"rollouts": self.rollouts}

    def load_state_dict(self, state: dict) -> None:
        self.rollouts = state["rollouts"]

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self.rollouts += 1
        if (self.rollouts - 1) % self.every == 0:
            for key, value in self.measure().items():
                self.logger.record(f"plasticity/{key}", value)

    def measure(self) -> dict[str, float]:
        model = self.model
        obs, actions, advantages, returns = recent_rollout(model.rollout_buffer, self.batch_size)
        activations = model.hidden_activations(obs)
        pi_layers = [h.post for h in activations["policy"]]
        vf_layers = [h.post for h in activations["value"]]
        stats: dict[str, float] = {}
        stats["dormant_ratio"], per_layer = dormant_ratio(pi_layers, self.tau)
        for i, r in enumerate(per_layer):
            stats[f"dormant_ratio_layer{i}"] = r
        stats["value_dormant_ratio"], _ = dormant_ratio(vf_layers, self.tau)
        stats["saturated_ratio"] = saturated_ratio(pi_layers, self.saturation)
        stats["srank"] = float(srank(pi_layers[-1], self.srank_delta))
        stats["weight_norm"] = float(np.sqrt(sum(float((p.astype(np.float64) ** 2).sum())
                                                 for p in model.parameter_arrays().values())))
        stats["grad_norm"] = model.loss_grad_norm(obs, actions, advantages, returns)
        return stats
