"""Fault injection for tests, attached through the public remedy mechanism (``+agent.fault=...``)."""
from __future__ import annotations

import torch
from stable_baselines3.common.callbacks import BaseCallback


class Fault(BaseCallback):
    """In the run with ``seed``, after ``at_step`` timesteps: raise (kind=raise) or poison a weight (kind=nan)."""

    def __init__(self, seed: int, at_step: int, kind: str = "raise") -> None:
        super().__init__()
        self.seed, self.at_step, self.kind = seed, at_step, kind

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        if self.model.seed != self.seed or self.num_timesteps < self.at_step:
            return
        if self.kind == "raise":
            raise RuntimeError(f"injected failure at {self.num_timesteps}")
        with torch.no_grad():
            self.model.policy.mlp_extractor.value_net[0].weight[0, 0] = float("nan")
