"""Checkpoint and resume of one run: where a job's checkpoint lives, and the hook that writes it.

A checkpoint is taken by the ``Checkpointer`` hook right after a PPO update, once the other hooks have acted on
it, every ``train.checkpoint_every`` timesteps and when training ends. It holds ``Training.snapshot()``
(``sweep.training.loop``, which also restores it): the policy and optimizer, the learner's loop state, every hook's
state by name, the loop's pending metrics, the env and the global RNGs, so the continued run is the run that would
have happened. This module imports the loop; the loop imports nothing of it.
Written atomically: to ``checkpoint.pt.tmp``, then renamed over ``checkpoint.pt``.

Where: ``<train.checkpoint_dir>/<job key>/``, the job key being a hash of the resolved config and the
tracking store, so re-running the same command finds its own checkpoint; ``job.json`` beside it
records the MLflow run id and whether training/evaluation completed.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import torch
from omegaconf import DictConfig, OmegaConf

from sweep.config import (ConfigError, HookSettings, drop_as_before, positive_int, remedy_blocks, runs, settings,
                          unrun_remedy_settings)
from sweep.status import read_json, update_json
from sweep.training.hooks import Hook
from sweep.training.loop import SNAPSHOT_FORMAT, Training


def _running(blocks: dict) -> dict:
    """The hook blocks that run (``config.runs``), each without its ``enabled`` flag."""
    return {name: {k: v for k, v in block.items() if k != "enabled"} for name, block in blocks.items() if runs(block)}


def job_key(cfg: DictConfig, uri: str) -> str:
    """Stable id of a job: what it runs, and the tracking store. That is its resolved settings (``config.settings``)
    without ``resume`` and the progress line's period; of the agent's remedy blocks only those enabled (a remedy the
    job does not run, or one added to the code since, does not enter it); its hooks in order with their resolved
    settings (a run with another hook list, or a hook set otherwise, is another job). Settings of a remedy the agent
    does not compose (``config.unrun_remedy_settings``) are not in it either: such jobs are the same job, and a
    sweep that lists it twice runs it once (``JobRecord.hold``). A block added since whose setting means "as before"
    (``config.ENV_AS_BEFORE``: the env's observe, start, curriculum and reward_curriculum switched off; and
    ``config.ENV_KEYS_AS_BEFORE``'s keys at their "as before" values) stays out too."""
    container = settings(cfg)
    drop_as_before(container.get("env", {}))
    agent = container.get("agent", {})
    remedies = remedy_blocks(agent)
    for name in [*remedies, *unrun_remedy_settings(agent)]:
        agent.pop(name)
    agent.update(_running(remedies))
    hooks = _running(OmegaConf.to_container(cfg.get("hooks", OmegaConf.create({})), resolve=True))
    hooks.get("progress", {}).pop("every_s", None)
    for spec in hooks.values():
        if isinstance(spec.get("env_cfg"), dict):   # a hook given the env (the evaluation's)
            drop_as_before(spec["env_cfg"])
    container["hooks"] = [[name, spec] for name, spec in hooks.items()]
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

    @contextmanager
    def hold(self, waiting: Callable[[], None] = lambda: None) -> Iterator[None]:
        """Hold the job for this process: an exclusive lock on ``job.lock`` (``fcntl.flock``, released when the
        process ends, however). Another process holding it runs the same job (a sweep that lists one job twice,
        settings it does not run being all that differ): ``waiting`` is called, and this one waits for it."""
        self.dir.mkdir(parents=True, exist_ok=True)
        with open(self.dir / "job.lock", "w") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                waiting()
                fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)


class Checkpointer(Hook):
    """Saves ``training.snapshot()`` after the first update that passes each ``every`` timesteps, and at the end.
    Runs last (``runs_last``), so the snapshot holds what every other hook did and returned after that update."""

    runs_last = True

    @dataclass
    class Settings(HookSettings):
        every: int = positive_int(" (timesteps)")

    def __init__(self, every: int) -> None:
        self.every = int(every)
        self.last_saved = 0
        self.training: Training | None = None

    def setup(self, learner, training: Training) -> None:
        self.training = training
        self.last_saved = learner.num_timesteps

    def after_update(self, learner, update) -> dict:
        if learner.num_timesteps - self.last_saved >= self.every:
            self.save()
        return {}

    def at_end(self, learner, update) -> dict:
        self.save()
        return {}

    def save(self) -> None:
        if self.training.flush is not None:   # the store covers what the checkpoint does
            self.training.flush()
        path = self.training.checkpoint_path
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".pt.tmp")
        torch.save(self.training.snapshot(), tmp)
        os.replace(tmp, path)
        self.last_saved = self.training.learner.num_timesteps


def load_checkpoint(path: Path) -> dict | None:
    """The checkpoint at ``path`` (None if there is none); one written before format 2 is a ConfigError."""
    if not Path(path).exists():
        return None
    state = torch.load(path, weights_only=False)
    if state.get("format") != SNAPSHOT_FORMAT:
        raise ConfigError(f"resume: {path} was written by an older version of the training loop (checkpoint format "
                          f"{state.get('format', 1)}, this code reads {SNAPSHOT_FORMAT}); run with resume=never, or delete it")
    return state
