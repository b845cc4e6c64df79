"""The learner (``agent.learner``: ``sb3`` = SB3's PPO, SAC or TD3, the reference; ``jax`` = the compiled
equivalent), built from the ``agent`` config group (the agent's remedies are hooks: ``sweep.training.hooks``).

The algorithm is the agent's block of hyperparameters (``agent.ppo``, ``agent.sac`` or ``agent.td3``). Every learner
is an SB3 algorithm and implements one contract, ``sweep.agents.learner.Learner``, which is all that the training
loop, the hooks and checkpoints use.
"""
from __future__ import annotations

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from sweep.agents.schedules import LRSchedule
from sweep.config import algorithm_of


def build_learner(agent: DictConfig, env: VecEnv, seed: int, total_timesteps: int | None = None) -> BaseAlgorithm:
    """The agent's algorithm with its hyperparameters (``agent.ppo|sac|td3``) and ``agent.policy`` networks on the
    learner ``agent.learner`` names among ``agent.learners`` (conf/learner/*.yaml: the ``_target_`` of its
    ``from_config``). ``total_timesteps`` (the run's ``train.total_timesteps``) places ``lr_decay_timesteps`` in it."""
    from_config = instantiate(agent.learners[agent.learner])
    algorithm = algorithm_of(agent)
    hyper = OmegaConf.to_container(agent[algorithm], resolve=True)
    kind, floor = hyper.pop("lr_schedule", "constant"), hyper.pop("lr_floor", 0.0)
    decay = hyper.pop("lr_decay_timesteps", None)
    if kind != "constant":
        if decay is not None and total_timesteps is None:
            raise ValueError(f"agent.{algorithm}.lr_decay_timesteps needs the run's total_timesteps")
        until = 1.0 if decay is None else min(decay / total_timesteps, 1.0)
        hyper["learning_rate"] = LRSchedule(kind, float(hyper["learning_rate"]), float(floor), until)
    p = agent.policy
    return from_config(env, hyper, list(p.net_arch), p.activation, p.adam_eps, seed, layer_norm=bool(p.layer_norm))


__all__ = ["build_learner"]
