"""The training loop, the same for every learner: collect -> hooks -> log -> update -> hooks, once per round.

    for each round, until ``total_timesteps``:
        rollout = learner.collect()                          # RolloutRecord
        log(hooks.after_rollout(rollout) [+ hooks.at_change(condition), when the condition changed and
                                          this is not the run's last rollout]
            + what the previous update's hooks returned)      # SB3's log line, at the timesteps after the rollout
        update = learner.update()                            # UpdateRecord
        pending = update.metrics() + hooks.after_update(update)   # logged with the next rollout's line
    log(hooks.at_end(last update)) at the final timestep

A PPO round is one turn: a rollout and one update. An off-policy round (``sweep.agents.offpolicy``) is many turns of
``train_freq`` env steps and ``gradient_steps`` gradient steps; only its last collect returns ``ends_round`` and gets
the hooks and the log line, with the episodes of the whole round, and the update after it reports the round's
gradient steps.

This is SB3's ``learn()`` order (an update's ``train/*`` appear in the next rollout's log line, and the last
update's never), so the logged histories are those SB3's loop wrote (tests/test_reference_history.py).
``Training`` holds what the loop owns beside the learner: the env, the hooks, the logger it writes to, the
metrics waiting for the next line and the condition of the last rollout; its ``snapshot`` is what a checkpoint holds
(``sweep.checkpoint`` writes it to disk), and ``train(training, resume=snapshot)`` continues it.
"""
from __future__ import annotations

import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from stable_baselines3.common.logger import Logger

from sweep.training.hooks import Hooks, Metrics
from sweep.training.records import Condition, UpdateRecord


@dataclass
class Training:
    learner: Any                          # sweep.agents.learner.Learner
    env: Any                              # the learner's HoverVecEnv
    hooks: Hooks
    total_timesteps: int
    logger: Logger = field(default_factory=lambda: Logger(folder=None, output_formats=[]))  # written to, never read
    label: str = "run"                    # the run's name in progress lines
    checkpoint_path: Path | None = None   # where the checkpointer hook writes
    flush: Callable[[], None] | None = None   # makes the store hold everything logged so far (before a checkpoint)
    pending: Metrics = field(default_factory=dict)   # for the next log line (an update's metrics and its hooks')
    condition: Condition | None = None    # at the last rollout end

    def write(self, metrics: Metrics) -> None:
        for key, value in metrics.items():
            self.logger.record(key, value)

    def state_dict(self) -> dict[str, Any]:
        return {"pending": dict(self.pending), "condition": self.condition}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.pending, self.condition = dict(state["pending"]), state["condition"]

    def snapshot(self) -> dict[str, Any]:
        """Everything the run needs to continue exactly: the learner's loop state and networks, every hook's state
        by name, the loop's own (metrics waiting for the next log line, the last condition), the env and the global
        RNGs. A checkpoint holds it (format ``SNAPSHOT_FORMAT``)."""
        return {"format": SNAPSHOT_FORMAT, "num_timesteps": self.learner.num_timesteps,
                "training": self.learner.training_state(), "hooks": self.hooks.state_dict(),
                "loop": self.state_dict(), "env": self.env.get_state(),
                "rng": {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}}

    def restore(self, state: dict[str, Any]) -> None:
        """Once every hook is set up (L2 has replaced the optimizer): the networks and optimizer, the hooks by name,
        the loop, the env and the global RNGs of a ``snapshot`` (its loop state came before the set-up: ``train``)."""
        self.learner.load_learner_state(state["training"]["learner"])
        self.hooks.load_state_dict(state["hooks"])
        self.load_state_dict(state["loop"])
        self.env.set_state(state["env"])
        torch.set_rng_state(state["rng"]["torch"])
        np.random.set_state(state["rng"]["numpy"])
        random.setstate(state["rng"]["python"])


SNAPSHOT_FORMAT = 3   # 2: hooks by name and the loop's pending metrics (issue 31); 3: the condition's wind vector and
                      # vehicle (issue 33). Older snapshots do not resume


def train(training: Training, resume: dict | None = None) -> UpdateRecord | None:
    """Train ``training.learner`` to ``training.total_timesteps``, continuing the checkpoint ``resume`` if given
    (one taken at the end is only restored); returns the last update's record (None if no update ran)."""
    t, learner = training, training.learner
    learner.set_logger(t.logger)
    if resume is not None:   # the loop state first, so begin(..., reset=False) continues without an env reset
        learner.load_training_state(resume["training"])
    total = learner.begin(t.total_timesteps - learner.num_timesteps, reset=resume is None)
    for hook in t.hooks:
        hook.setup(learner, t)
    if resume is not None:
        t.restore(resume)
    if learner.num_timesteps >= total:   # a checkpoint taken at the end: restored (networks, kept policies), no more
        return None

    update = None
    while learner.num_timesteps < total:
        rollout = learner.collect()
        if not rollout.ends_round:   # an off-policy turn inside a round: its gradient steps, no hooks, no log line
            learner.update()
            continue
        metrics = t.hooks.call("after_rollout", learner, rollout)
        last = learner.num_timesteps >= total   # the run's last rollout: only its own update follows
        if t.condition is not None and rollout.condition != t.condition and not last:
            metrics.update(t.hooks.call("at_change", learner, rollout.condition))
        t.condition = rollout.condition
        t.write({**t.pending, **metrics})
        t.pending = {}
        learner.log_rollout(rollout.index)
        update = learner.update()
        if learner.num_timesteps >= total:
            break
        t.pending = update.metrics()
        t.hooks.call("after_update", learner, update, on_metrics=t.pending.update)
    end = t.hooks.call("at_end", learner, update)
    if end:
        t.write(end)
        t.logger.dump(step=learner.num_timesteps)
    return update


__all__ = ["Training", "train"]
