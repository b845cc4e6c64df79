"""The learner (``agent.learner``: ``sb3`` = SB3 PPO, the reference; ``jax`` = the compiled equivalent), built
from the ``agent`` config group (the agent's remedies are hooks: ``sweep.training.hooks.remedy_hooks``).

Both learners are SB3 ``OnPolicyAlgorithm``s and implement one contract, ``sweep.agents.learner.Learner``, which
is all that the training loop, the hooks and checkpoints use.
"""
from __future__ import annotations

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.base_class import BaseAlgorithm
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


__all__ = ["build_learner"]
