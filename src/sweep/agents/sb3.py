"""``SB3PPO``: Stable-Baselines3's PPO, unchanged, plus the few methods the project asks of a learner.

The reference learner (``agent.learner=sb3``): SB3 PPO with ``MlpPolicy`` as the paper used it
(Sec. III-E: SB3 defaults, 64x64 tanh, Adam, batch 64). The added methods (``use_l2``,
``parameter_arrays``, ``hidden_activations``, ``loss_grad_norm``, ``learner_state``) are what
remedies, diagnostics and checkpoints call, on this learner and on ``JaxPPO`` alike.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecEnv

from sweep.plasticity.l2 import l2_optimizer

ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}


class SB3PPO(PPO):
    @classmethod
    def from_config(cls, env: VecEnv, ppo: dict, net_arch: list[int], activation: str, adam_eps: float,
                    seed: int) -> "SB3PPO":
        policy_kwargs = {"net_arch": {"pi": list(net_arch), "vf": list(net_arch)},
                         "activation_fn": ACTIVATIONS[activation],
                         "optimizer_class": torch.optim.Adam, "optimizer_kwargs": {"eps": float(adam_eps)}}
        return cls("MlpPolicy", env, policy_kwargs=policy_kwargs, seed=seed, device="cpu", verbose=0, **ppo)

    def use_l2(self, coef: float, mode: str = "coupled", params=("policy", "value"), biases: bool = True) -> None:
        self.policy.optimizer = l2_optimizer(self.policy, coef, mode, tuple(params), biases)
        names = {id(p): n for n, p in self.policy.named_parameters()}
        self.l2_decayed = sorted(names[id(p)] for p in self.policy.optimizer.param_groups[0]["params"])

    def parameter_arrays(self) -> dict[str, np.ndarray]:
        return {k: v.detach().numpy().copy() for k, v in self.policy.state_dict().items()}

    def hidden_activations(self, obs: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Hidden-layer activations of the policy and of the value network on ``obs``."""
        policy = self.policy
        with torch.no_grad():
            features = policy.extract_features(torch.as_tensor(obs, dtype=torch.float32), policy.pi_features_extractor)
            return (_activations(policy.mlp_extractor.policy_net, features),
                    _activations(policy.mlp_extractor.value_net, features))

    def loss_grad_norm(self, obs, actions, advantages, returns) -> float:
        """Norm of the PPO loss gradient at the current parameters (ratio 1, so no clipping), as SB3 computes it."""
        t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
        obs, actions, advantages, returns = t(obs), t(actions), t(advantages).flatten(), t(returns).flatten()
        values, log_prob, entropy = self.policy.evaluate_actions(obs, actions)
        if self.normalize_advantage and len(advantages) > 1:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        ratio = torch.exp(log_prob - log_prob.detach())
        loss = (-(advantages * ratio).mean() + self.vf_coef * F.mse_loss(returns, values.flatten())
                - self.ent_coef * (entropy.mean() if entropy is not None else -log_prob.mean()))
        grads = torch.autograd.grad(loss, [p for p in self.policy.parameters() if p.requires_grad], allow_unused=True)
        return float(torch.sqrt(sum((g ** 2).sum() for g in grads if g is not None)))

    def learner_state(self) -> dict[str, Any]:
        return {"policy": self.policy.state_dict(), "optimizer": self.policy.optimizer.state_dict()}

    def load_learner_state(self, state: dict[str, Any], optimizer: bool = True) -> None:
        self.policy.load_state_dict(state["policy"])
        if optimizer:
            self.policy.optimizer.load_state_dict(state["optimizer"])


def _activations(mlp: torch.nn.Sequential, x: torch.Tensor) -> list[np.ndarray]:
    """Outputs of every activation module of an SB3 MLP (Linear, act, Linear, act, ...)."""
    out = []
    for module in mlp:
        x = module(x)
        if not isinstance(module, torch.nn.Linear):
            out.append(x.numpy())
    return out
