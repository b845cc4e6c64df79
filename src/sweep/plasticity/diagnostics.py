"""``PlasticityDiagnostics``: network statistics a plasticity study tracks, logged under ``plasticity/``.

A hook (conf/hooks/diagnostics.yaml, settings under ``plasticity.*``). Computed at the end of every
``every_rollouts``-th rollout, before the update, on the ``batch_size`` most recent
observations of that rollout:

  plasticity/dormant_ratio           tau-dormant share over the policy network's hidden layers (paper Figs. 4-5)
  plasticity/dormant_ratio_layer{i}  per hidden layer of the policy network
  plasticity/value_dormant_ratio     the same over the value network's hidden layers
  plasticity/dormant_ratio_tau{t}    Sokar's ratio at each further threshold of ``extra_taus`` (0.1: ReDo's authors)
  plasticity/dead_tanh_ratio         units with |h| > saturation on >= dead_fraction of the batch (stuck at +-1)
  plasticity/signed_mean_ratio       units whose signed mean output is ~0: |E h_i| / mean_k E|h_k| <= signed_mean_tau
  plasticity/active_ratio            Plasticine's active share (tanh: 1 - share of |h| > saturation; ReLU: h > 0)
  (each of these four also per hidden layer, ``..._layer{i}``)
  plasticity/saturated_ratio         share of policy activations with |h| > saturation (tanh saturation)
  plasticity/srank                   effective rank of the policy's last hidden features (Kumar et al. 2021)
  plasticity/weight_norm             L2 norm of all policy+value parameters
  plasticity/grad_norm               norm of the PPO loss gradient on that batch (before SB3's clipping)
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List

import numpy as np

from sweep.config import MISSING, Activation, HookSettings, key, positive_int, unit_interval
from sweep.plasticity.dormant import (active_ratio, dead_tanh_mask, dormant_mask, dormant_ratio, pooled,
                                     saturated_ratio, signed_mean_mask, srank)
from sweep.training.hooks import Hook
from sweep.training.records import RolloutRecord


class PlasticityDiagnostics(Hook):
    """Reads the networks through the learner (``recent_samples``, ``hidden_activations``, ``parameter_arrays``,
    ``loss_grad_norm``), so the statistics are the same code for every learner."""

    @dataclass
    class Settings(HookSettings):   # conf/hooks/diagnostics.yaml: the plasticity.* keys
        every_rollouts: int = positive_int()
        tau: float = unit_interval()
        batch_size: int = positive_int()
        saturation: float = unit_interval()
        srank_delta: float = unit_interval()
        extra_taus: List[float] = key(lambda v: all(0 <= t <= 1 for t in v), "a list of numbers in [0, 1]")
        dead_fraction: float = unit_interval()
        signed_mean_tau: float = unit_interval()
        activation: Activation = MISSING

    def __init__(self, every_rollouts: int = 1, tau: float = 0.025, batch_size: int = 1024,
                 saturation: float = 0.99, srank_delta: float = 0.01, extra_taus=(0.1,), dead_fraction: float = 0.99,
                 signed_mean_tau: float = 0.1, activation: str = "tanh") -> None:
        self.every, self.tau, self.batch_size = int(every_rollouts), float(tau), int(batch_size)
        self.saturation, self.srank_delta = float(saturation), float(srank_delta)
        self.extra_taus, self.dead_fraction = tuple(float(t) for t in extra_taus), float(dead_fraction)
        self.signed_mean_tau, self.activation = float(signed_mean_tau), activation
        self.rollouts = 0

    def state_dict(self) -> dict:
        return {"rollouts": self.rollouts}

    def load_state_dict(self, state: dict) -> None:
        self.rollouts = state["rollouts"]

    def after_rollout(self, learner, rollout: RolloutRecord) -> dict[str, float]:
        self.rollouts += 1
        if (self.rollouts - 1) % self.every:
            return {}
        return {f"plasticity/{key}": value for key, value in self.measure(learner).items()}

    def measure(self, model) -> dict[str, float]:
        """The statistics of the learner's networks on its ``batch_size`` most recent observations."""
        samples = model.recent_samples(self.batch_size)
        activations = model.hidden_activations(samples.observations)
        first = {net.role: net.name for net in reversed(model.networks)}   # PPO's policy and value; the actor, critic 0
        pi_layers = [h.post for h in activations[first["policy"]]]
        vf_layers = [h.post for h in activations[first["value"]]]
        stats: dict[str, float] = {}
        stats["dormant_ratio"], per_layer = dormant_ratio(pi_layers, self.tau)
        for i, r in enumerate(per_layer):
            stats[f"dormant_ratio_layer{i}"] = r
        stats["value_dormant_ratio"], _ = dormant_ratio(vf_layers, self.tau)
        readings = {f"dormant_ratio_tau{t:g}": [dormant_mask(h, t) for h in pi_layers] for t in self.extra_taus}
        readings["dead_tanh_ratio"] = [dead_tanh_mask(h, self.saturation, self.dead_fraction) for h in pi_layers]
        readings["signed_mean_ratio"] = [signed_mean_mask(h, self.signed_mean_tau) for h in pi_layers]
        for name, masks in readings.items():
            stats[name], per_layer = pooled(masks)
            stats.update({f"{name}_layer{i}": r for i, r in enumerate(per_layer)})
        stats["active_ratio"], per_layer = active_ratio(pi_layers, self.activation, self.saturation)
        stats.update({f"active_ratio_layer{i}": r for i, r in enumerate(per_layer)})
        stats["saturated_ratio"] = saturated_ratio(pi_layers, self.saturation)
        stats["srank"] = float(srank(pi_layers[-1], self.srank_delta))
        stats["weight_norm"] = float(np.sqrt(sum(float((p.astype(np.float64) ** 2).sum())
                                                 for p in model.parameter_arrays().values())))
        stats["grad_norm"] = model.loss_grad_norm(samples)
        return stats
