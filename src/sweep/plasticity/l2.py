"""L2 regularization for PPO (paper Sec. III-E), coupled as in Dohare et al. 2024.

``coupled``: Adam(weight_decay=coef) adds coef*theta to the gradient, i.e. the gradient of an explicit
penalty (coef/2)*||theta||^2 on the loss, before Adam's normalisation. ``decoupled``: AdamW (weight
decay applied outside Adam's moments). ``params`` chooses the penalized networks (policy = actor MLP +
action head, value = critic MLP + value head, log_std = the Gaussian's log std) and ``biases`` whether
bias vectors are included; everything else sits in a second param group with weight_decay 0.
Adam's eps and betas are copied from SB3's optimizer, so the only difference from plain PPO is L2.
"""
from __future__ import annotations

import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import ActorCriticPolicy

GROUPS = {
    "policy": ("mlp_extractor.policy_net.", "action_net."),
    "value": ("mlp_extractor.value_net.", "value_net."),
    "log_std": ("log_std",),
}


def penalized(name: str, params: list[str], biases: bool) -> bool:
    if not biases and name.endswith("bias"):
        return False
    return any(name.startswith(prefix) for group in params for prefix in GROUPS[group])


def l2_optimizer(policy: ActorCriticPolicy, coef: float, mode: str = "coupled",
                 params: tuple[str, ...] = ("policy", "value"), biases: bool = True) -> torch.optim.Optimizer:
    """A copy of ``policy.optimizer`` (same lr, betas, eps) with weight decay on the chosen parameters."""
    old = policy.optimizer.param_groups[0]
    decay, rest = [], []
    for name, p in policy.named_parameters():
        (decay if penalized(name, list(params), biases) else rest).append(p)
    cls = torch.optim.Adam if mode == "coupled" else torch.optim.AdamW
    groups = [{"params": decay, "weight_decay": coef}, {"params": rest, "weight_decay": 0.0}]
    return cls(groups, lr=old["lr"], betas=old["betas"], eps=old["eps"])


class L2Regularization(BaseCallback):
    """Switches the learner's L2 on when training starts (SB3: ``l2_optimizer``; JAX: the same decay in
    its optax chain, ``sweep.agents.jax_ppo``)."""

    def __init__(self, coef: float = 1e-3, mode: str = "coupled", params=("policy", "value"), biases: bool = True):
        super().__init__()
        self.coef, self.mode, self.params, self.biases = float(coef), mode, tuple(params), bool(biases)

    def _init_callback(self) -> None:
        self.model.use_l2(self.coef, self.mode, self.params, self.biases)

    def _on_step(self) -> bool:
        return True
