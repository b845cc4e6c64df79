"""The learner (``agent.learner``: ``sb3`` = SB3 PPO, the reference; ``jax`` = the compiled equivalent) and
the agent's remedies, built from the ``agent`` config group.

Both learners are SB3 ``OnPolicyAlgorithm``s (same ``learn()``, logger and callbacks) and implement one
contract, ``sweep.agents.learner.Learner``, which is all that remedies, diagnostics and checkpoints use.
"""
from __future__ import annotations

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sweep.agents.schedules import LRSchedule


def build_learner(agent: DictConfig, env: VecEnv, seed: int, total_timesteps: int | None = None) -> BaseAlgorithm:
    """PPO with ``agent.ppo`` hyperparameters and ``agent.policy`` networks on the learner ``agent.learner``
    names among ``agent.learners`` (conf/learner/*.yaml: the ``_target_`` of its ``from_config``).
    ``total_timesteps`` (the run's ``train.total_timesteps``) places ``agent.ppo.lr_decay_timesteps`` in it."""
    from_config = instantiate(agent.learners[agent.learner])
    ppo = OmegaConf.to_container(agent.ppo, resolve=True)
    kind, floor = ppo.pop("lr_schedule", "constant"), ppo.pop("lr_floor", 0.0)
    decay = ppo.pop("lr_decay_timesteps", None)
    if kind != "constant":
        if decay is not None and total_timesteps is None:
            raise ValueError("agent.ppo.lr_decay_timesteps needs the run's total_timesteps")
        until = 1.0 if decay is None else min(decay / total_timesteps, 1.0)
        ppo["learning_rate"] = LRSchedule(kind, float(ppo["learning_rate"]), float(floor), until)
    p = agent.policy
    return from_config(env, ppo, list(p.net_arch), p.activation, p.adam_eps, seed, layer_norm=bool(p.layer_norm))


def build_remedies(agent: DictConfig) -> list[BaseCallback]:
    """Instantiate every enabled ``agent.<key>`` that has a ``_target_`` (in config order)."""
    remedies = []
    for spec in agent.values():
        if isinstance(spec, DictConfig) and "_target_" in spec and spec.get("enabled", True):
            kwargs = {k: v for k, v in spec.items() if k != "enabled"}
            remedies.append(instantiate(OmegaConf.create(kwargs)))
    return remedies


__all__ = ["build_learner", "build_remedies"]
