"""The steps of SB3's ``OnPolicyAlgorithm.learn`` one at a time, returning records: what both learners add to SB3.

SB3's ``learn()`` runs collect -> log -> ``train()`` in a closed loop and reports through its logger. The
project's loop (``sweep.training.loop``) needs each step on its own and its results as values, so both learners
(``SB3PPO``, ``JaxPPO``; both are SB3 ``OnPolicyAlgorithm``s) get these methods of the ``Learner`` contract:

* ``begin(timesteps, reset)``: ``learn()``'s set-up (``_setup_learn``); returns the timestep to train to;
* ``collect()``: one rollout (SB3's ``collect_rollouts``) -> ``RolloutRecord`` (episodes it finished, the
  condition at its end);
* ``update()``: one PPO update -> ``UpdateRecord`` (the learner's ``_train_record``);
* ``log_rollout(iteration)``: SB3's own log line of the rollout (``rollout/*``, ``time/*``), then the dump;
* ``recent_samples(n)``, ``set_learning_rate(value)``, ``training_state()`` / ``load_training_state()``.

Only this module and the two learner modules touch SB3's loop fields (``ep_info_buffer``, ``rollout_buffer``,
``lr_schedule``, ``_last_obs``).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback

from sweep.agents.networks import GROUPS
from sweep.training.records import Episode, RolloutRecord, Samples, UpdateRecord


@dataclass
class ConstantLR:
    """A learning-rate 'schedule' that ignores training progress (``set_learning_rate``)."""

    value: float

    def __call__(self, progress_remaining: float) -> float:
        return self.value


class _Episodes(BaseCallback):
    """Collects the episodes a rollout finishes from the infos SB3's ``collect_rollouts`` passes each step."""

    def __init__(self) -> None:
        super().__init__()
        self.episodes: list[Episode] = []

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            if "episode" in info:
                self.episodes.append(Episode(float(info["episode"]["r"]), int(info["episode"]["l"]),
                                             bool(info.get("crashed", False))))
        return True


def recent_rollout(buf: RolloutBuffer, n: int) -> Samples:
    """The ``n`` most recent steps of the rollout buffer. Before an update they are the last ``n`` in time; after
    SB3's ``train()`` has flattened the buffer (env-major, ``generator_ready``) they are the last ``n`` of that
    order (with one env the same)."""
    if buf.generator_ready:
        flat = lambda a: a  # noqa: E731
    else:  # (steps, envs, ...) -> (steps*envs, ...), most recent steps last
        flat = lambda a: a.reshape(-1, *a.shape[2:])  # noqa: E731
    total = buf.buffer_size * buf.n_envs
    idx = slice(max(0, total - n), total)
    return Samples(flat(buf.observations)[idx].copy(), flat(buf.actions)[idx].copy(),
                   flat(buf.advantages)[idx].ravel().copy(), flat(buf.returns)[idx].ravel().copy())


class StepwiseLearning:
    """Mixin for an SB3 ``OnPolicyAlgorithm`` (see the module docstring). A learner implements ``_train_record()``:
    one update, returned as an ``UpdateRecord``."""

    _rollouts = 0
    _updates = 0
    groups = GROUPS   # remedies' parameter groups (``Learner.groups``)
    algorithm = "ppo"

    def begin(self, timesteps: int, reset: bool = True) -> int:
        """``learn()``'s set-up for ``timesteps`` more steps (``reset``: from 0, env reset); returns the total."""
        total, _ = self._setup_learn(timesteps, None, reset_num_timesteps=reset, progress_bar=False)
        return total

    def collect(self) -> RolloutRecord:
        """One rollout of ``n_steps`` per env into the rollout buffer."""
        episodes = _Episodes()
        episodes.init_callback(self)
        if not self.collect_rollouts(self.env, episodes, self.rollout_buffer, n_rollout_steps=self.n_steps):
            raise RuntimeError("the rollout stopped early")
        self._rollouts += 1
        self._update_current_progress_remaining(self.num_timesteps, self._total_timesteps)
        recent = [ep["r"] for ep in self.ep_info_buffer]
        return RolloutRecord(index=self._rollouts, timesteps=int(self.num_timesteps), episodes=tuple(episodes.episodes),
                             mean_recent_return=float(np.mean(recent)) if recent else None,
                             condition=self.env.condition())

    def log_rollout(self, iteration: int) -> None:
        """SB3's log line of the rollout (``rollout/ep_rew_mean``, ``time/fps``, ...), written with what the loop
        recorded before, at ``num_timesteps``."""
        self.dump_logs(iteration)

    def update(self) -> UpdateRecord:
        """One PPO update on the rollout just collected."""
        self._updates += 1
        return self._train_record()

    def target_arrays(self) -> dict[str, np.ndarray]:
        """PPO has no target networks."""
        return {}

    def reset_targets(self, names=None) -> None:
        """PPO has no target networks."""

    def recent_samples(self, n: int) -> Samples:
        """The ``n`` most recent steps of the rollout buffer (``recent_rollout``)."""
        return recent_rollout(self.rollout_buffer, n)

    def set_learning_rate(self, value: float | None = None) -> float:
        """From now on every update uses ``value`` (None: the rate in force now); returns it."""
        if value is None:
            value = float(self.lr_schedule(self._current_progress_remaining))
        self.lr_schedule = ConstantLR(float(value))
        return float(value)

    def training_state(self) -> dict[str, Any]:
        """SB3's loop state (timesteps, last observations, episode buffers) and ``learner_state()``."""
        return {"num_timesteps": self.num_timesteps, "n_updates": self._n_updates, "rollouts": self._rollouts,
                "updates": self._updates, "last_obs": self._last_obs, "last_episode_starts": self._last_episode_starts,
                "ep_info_buffer": list(self.ep_info_buffer), "ep_success_buffer": list(self.ep_success_buffer),
                "learner": self.learner_state()}

    def load_training_state(self, state: dict[str, Any]) -> None:
        """The loop state of ``training_state`` (before ``begin(..., reset=False)``); the learner's own
        (parameters, optimizer) is loaded by ``load_learner_state(state["learner"])`` once the hooks are set up."""
        self.num_timesteps, self._n_updates = state["num_timesteps"], state["n_updates"]
        self._rollouts, self._updates = state["rollouts"], state["updates"]
        self._last_obs, self._last_episode_starts = state["last_obs"], state["last_episode_starts"]
        self.ep_info_buffer = deque(state["ep_info_buffer"], maxlen=self._stats_window_size)
        self.ep_success_buffer = deque(state["ep_success_buffer"], maxlen=self._stats_window_size)


__all__ = ["ConstantLR", "StepwiseLearning", "recent_rollout"]
