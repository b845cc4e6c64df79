"""SB3 PPO from ``cfg.agent`` (paper Sec. III-E: SB3 defaults, 64x64 tanh, Adam, batch 64).

Remedies (L2, RECOM, later ones) are SB3 callbacks built from every ``agent.<name>`` entry that has a
``_target_`` and ``enabled: true`` (settings in conf/remedy/); this module does not know which exist.
"""
from __future__ import annotations

from typing import Any

import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}


def build_ppo(agent: DictConfig, env: VecEnv, seed: int) -> PPO:
    policy = agent.policy
    arch = list(policy.net_arch)
    policy_kwargs: dict[str, Any] = {
        "net_arch": {"pi": arch, "vf": arch},
        "activation_fn": ACTIVATIONS[policy.activation],
        "optimizer_class": torch.optim.Adam,
        "optimizer_kwargs": {"eps": float(policy.adam_eps)},
    }
    ppo_kwargs = OmegaConf.to_container(agent.ppo, resolve=True)
    return PPO("MlpPolicy", env, policy_kwargs=policy_kwargs, seed=seed, device="cpu", verbose=0, **ppo_kwargs)


def build_remedies(agent: DictConfig) -> list[BaseCallback]:
    """Instantiate every enabled ``agent.<key>`` that has a ``_target_`` (in config order)."""
    remedies = []
    for spec in agent.values():
        if isinstance(spec, DictConfig) and "_target_" in spec and spec.get("enabled", True):
            kwargs = {k: v for k, v in spec.items() if k != "enabled"}
            remedies.append(instantiate(OmegaConf.create(kwargs)))
    return remedies
