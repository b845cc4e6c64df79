"""Checkpoint and resume of one run.

A checkpoint is taken right after a PPO update (at the start of the next rollout), every
``train.checkpoint_every`` timesteps and when training ends. It holds the policy and optimizer, SB3's
loop state (timesteps, last observations, episode-info buffer, the not-yet-dumped logger values),
every stateful callback (RECOM's episodes, cost and LR), the env (vehicles, clocks, start RNG) and the
global RNGs (torch, numpy, python), so the continued run is the run that would have happened.
Written atomically: to ``checkpoint.pt.tmp``, then renamed over ``checkpoint.pt``.

Where: ``<train.checkpoint_dir>/<job key>/``, the job key being a hash of the resolved config and the
tracking store, so re-running the same command finds its own checkpoint; ``job.json`` beside it
records the MLflow run id and whether training/evaluation completed.
"""
from __future__ import annotations

import hashlib
import json
import os
import random
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig
from stable_baselines3.common.callbacks import BaseCallback

from sweep.config import settings
from sweep.status import read_json, update_json


def job_key(cfg: DictConfig, uri: str) -> str:
    """Stable id of a job: its resolved settings (``config.settings``) without ``resume``, and the tracking store."""
    container = settings(cfg)
    container.pop("resume", None)
    container.get("train", {}).pop("progress_every_s", None)
    text = json.dumps({"config": container, "uri": uri}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class JobRecord:
    """``job.json``: MLflow run id and status of a job's checkpoint directory."""

    def __init__(self, directory: Path) -> None:
        self.dir = Path(directory)
        self.path = self.dir / "job.json"
        self.checkpoint = self.dir / "checkpoint.pt"

    def read(self) -> dict[str, Any]:
        return read_json(self.path)

    def write(self, **fields: Any) -> None:
        update_json(self.path, **fields)


def _stateful(callbacks: list[BaseCallback]) -> list[BaseCallback]:
    return [cb for cb in callbacks if hasattr(cb, "state_dict") and hasattr(cb, "load_state_dict")]


class Checkpointer(BaseCallback):
    """Saves every ``every`` timesteps after an update; restores a checkpoint when learning starts."""

    def __init__(self, path: Path, every: int, callbacks: list[BaseCallback], resume: dict | None = None,
                 before_save=None) -> None:
        super().__init__()
        self.path, self.every = Path(path), int(every)
        self.before_save = before_save  # e.g. flush buffered metrics, so the store covers what the checkpoint does
        self.others = _stateful(callbacks)
        self.resume = resume
        self.last_saved = resume["num_timesteps"] if resume else 0

    # -- restoring: loop state before learn(), the rest once every callback has initialised --
    @staticmethod
    def prepare_model(model, state: dict) -> None:
        """Set SB3's loop state so ``learn(reset_num_timesteps=False)`` continues without an env reset."""
        model.num_timesteps = state["num_timesteps"]
        model._n_updates = state["n_updates"]
        model._last_obs = state["last_obs"]
        model._last_episode_starts = state["last_episode_starts"]
        model.load_learner_state(state["learner"], optimizer=False)
        model.ep_info_buffer = deque(state["ep_info_buffer"], maxlen=model._stats_window_size)
        model.ep_success_buffer = deque(state["ep_success_buffer"], maxlen=model._stats_window_size)

    def _init_callback(self) -> None:
        if self.resume is None:
            return
        state = self.resume
        self.model.load_learner_state(state["learner"])  # after the remedies set up the optimizer
        for cb, cb_state in zip(self.others, state["callbacks"]):
            cb.load_state_dict(cb_state)
        self.training_env.set_state(state["env"])
        self.model.logger.name_to_value.update(state["logger_values"])
        self.model.logger.name_to_count.update(state["logger_counts"])
        torch.set_rng_state(state["rng"]["torch"])
        np.random.set_state(state["rng"]["numpy"])
        random.setstate(state["rng"]["python"])

    # -- saving --
    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        if self.num_timesteps - self.last_saved >= self.every:
            self.save()

    def save(self) -> None:
        if self.before_save is not None:
            self.before_save()
        model = self.model
        state = {
            "num_timesteps": model.num_timesteps,
            "n_updates": model._n_updates,
            "learner": model.learner_state(),
            "last_obs": model._last_obs,
            "last_episode_starts": model._last_episode_starts,
            "ep_info_buffer": list(model.ep_info_buffer),
            "ep_success_buffer": list(model.ep_success_buffer),
            "logger_values": dict(model.logger.name_to_value),
            "logger_counts": dict(model.logger.name_to_count),
            "callbacks": [cb.state_dict() for cb in self.others],
            "env": self.training_env.get_state(),
            "rng": {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()},
        }
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".pt.tmp")
        torch.save(state, tmp)
        os.replace(tmp, self.path)
        self.last_saved = model.num_timesteps


def load_checkpoint(path: Path) -> dict | None:
    return torch.load(path, weights_only=False) if Path(path).exists() else None
