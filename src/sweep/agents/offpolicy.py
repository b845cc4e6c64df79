"""The steps of SB3's ``OffPolicyAlgorithm.learn`` one at a time, returning records: what the off-policy learners add.

SB3's off-policy ``learn()`` alternates ``collect_rollouts`` (``train_freq`` steps per env into the replay buffer)
and ``train(gradient_steps)`` once ``num_timesteps > learning_starts``, and logs every few episodes. The project's
loop (``sweep.training.loop``) drives the same alternation one turn at a time:

* ``collect()``: one SB3 ``collect_rollouts`` of ``train_freq`` steps per env -> ``RolloutRecord``;
* ``update()``: SB3's ``train(gradient_steps, batch_size)`` on the replay buffer, when SB3's ``learn`` would.

Hooks and log lines come once per **round** of ``round_steps`` env steps (all envs), not per turn: a turn of SAC's
default is one env step. The collect that completes a round returns ``ends_round=True`` with every episode the round
finished; the update after it returns an ``OffPolicyUpdate`` of all the round's gradient steps (the losses' means over
them). So a hook's ``every_updates`` and the diagnostics' ``every_rollouts`` count rounds, and a remedy acts between
the gradient steps of one round and the next. Inside a round the order of env steps and gradient steps is SB3's.

Under a reward curriculum (``env.reward_curriculum``) ``collect()`` ends by re-scoring the replay buffer when a new
stage has begun (``rescore_replay``), as the anchor does, so both learners (they fill the same SB3 buffer) do it alike
and the round's hooks and updates see one stage's rewards.

Only this module and the learner modules touch SB3's loop fields (``replay_buffer``, ``ep_info_buffer``,
``lr_schedule``, ``_last_obs``, ``action_noise``).
"""
from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.logger import Logger

from sweep.agents.onpolicy import ConstantLR, _Episodes
from sweep.training.records import Episode, OffPolicyUpdate, RolloutRecord, Samples


class RoundwiseLearning:
    """Mixin for an SB3 ``OffPolicyAlgorithm`` (see the module docstring). Needs ``round_steps`` (env steps per round)
    and ``_train_stats()``: the SB3 logger values of one ``train()`` call to accumulate."""

    round_steps = 2048
    _rollouts = 0      # rounds completed
    _updates = 0       # rounds' updates completed
    _round_from = 0    # timestep the round began at
    _round_episodes: list[Episode]
    _round_sums: dict[str, float]
    _round_counts: dict[str, int]
    _round_steps_run = 0
    _ends_round = False
    _replay_stage = 0  # the reward curriculum's stage the replay buffer's rewards were computed at

    def begin(self, timesteps: int, reset: bool = True) -> int:
        """``learn()``'s set-up for ``timesteps`` more steps (``reset``: from 0, env reset); returns the total."""
        total, _ = self._setup_learn(timesteps, None, reset_num_timesteps=reset, progress_bar=False)
        self._total = total
        if reset:
            self._round_from, self._ends_round = 0, False
            self._clear_round()
        return total

    def _clear_round(self) -> None:
        self._round_episodes, self._round_sums, self._round_counts, self._round_steps_run = [], {}, {}, 0

    def collect(self) -> RolloutRecord:
        """``train_freq`` steps per env into the replay buffer (SB3's ``collect_rollouts``, its exploration: uniform
        actions before ``learning_starts``, then the policy's, with ``action_noise`` if set)."""
        episodes = _Episodes()
        episodes.init_callback(self)
        out = self.collect_rollouts(self.env, callback=episodes, train_freq=self.train_freq,
                                    replay_buffer=self.replay_buffer, action_noise=self.action_noise,
                                    learning_starts=self.learning_starts, log_interval=None)
        if not out.continue_training:
            raise RuntimeError("the rollout stopped early")
        self.rescore_replay()
        self._round_episodes.extend(episodes.episodes)
        self._ends_round = (self.num_timesteps - self._round_from >= self.round_steps
                            or self.num_timesteps >= self._total)
        if not self._ends_round:   # a turn inside the round: the loop reads only ends_round
            return RolloutRecord(index=self._rollouts, timesteps=int(self.num_timesteps), episodes=(),
                                 mean_recent_return=None, condition=None, ends_round=False)
        self._rollouts += 1
        recent = [ep["r"] for ep in self.ep_info_buffer]
        return RolloutRecord(index=self._rollouts, timesteps=int(self.num_timesteps),
                             episodes=tuple(self._round_episodes),
                             mean_recent_return=float(np.mean(recent)) if recent else None,
                             condition=self.env.condition(), ends_round=True)

    def log_rollout(self, iteration: int) -> None:
        """SB3's off-policy log line (``rollout/ep_rew_mean``, ``time/fps``, ...) at ``num_timesteps``."""
        self.dump_logs()

    @property
    def gradient_steps_per_turn(self) -> int:
        """SB3's ``gradient_steps`` (-1: as many as the turn's env steps, all envs)."""
        return self.gradient_steps if self.gradient_steps >= 0 else self.train_freq.frequency * self.n_envs

    _last_round_steps = 0

    @property
    def minibatches_per_update(self) -> int:
        """Gradient steps of the last round (CBP's maturity clock: 0 before ``learning_starts``, fewer in a round that
        starts learning)."""
        return self._last_round_steps

    def update(self) -> OffPolicyUpdate:
        """SB3's ``train(gradient_steps, batch_size)`` once past ``learning_starts``, as its ``learn()``; the record
        of the round so far (the loop reads it when the round ends)."""
        steps = self.gradient_steps_per_turn
        if self.num_timesteps > self.learning_starts and steps > 0:
            caught = Logger(folder=None, output_formats=[])
            own, self._logger = getattr(self, "_logger", None), caught
            try:
                self.train(gradient_steps=steps, batch_size=self.batch_size)
            finally:
                if own is not None:
                    self._logger = own
            for key, value in self._train_stats(caught.name_to_value).items():
                n = self._train_counts(key, steps)
                self._round_sums[key] = self._round_sums.get(key, 0.0) + float(value) * n
                self._round_counts[key] = self._round_counts.get(key, 0) + n
            self._round_steps_run += steps
        means = {k: self._round_sums[k] / self._round_counts[k] for k in self._round_sums if self._round_counts[k]}
        record = OffPolicyUpdate(index=self._updates + 1, timesteps=int(self.num_timesteps),
                                 learning_rate=float(self.lr_schedule(self._current_progress_remaining)),
                                 gradient_steps=self._round_steps_run, n_updates=int(self._n_updates), **means)
        if self._ends_round:
            self._updates += 1
            self._last_round_steps = self._round_steps_run
            self._round_from = self.num_timesteps
            self._clear_round()
        return record

    def rescore_replay(self, chunk: int = 65536) -> bool:
        """When the env's reward curriculum has moved to a new stage since the buffer was last scored, every stored
        reward re-computed with the new weights (``HoverVecEnv.rewards_of`` on the stored next observations and
        actions, about ``chunk`` transitions at a time); returns whether it did. ``recompute_replay: false`` only
        follows the stage (the buffer keeps each reward as it was given)."""
        env = self.env
        stage = getattr(env, "reward_stage", 0)
        if stage == self._replay_stage:
            return False
        self._replay_stage = stage
        if not env.reward_curriculum.recompute_replay:
            return False
        buf = self.replay_buffer
        size = buf.buffer_size if buf.full else buf.pos
        step = max(1, chunk // buf.n_envs)
        for start in range(0, size, step):
            rows = slice(start, min(size, start + step))
            next_obs, actions = buf.next_observations[rows], buf.actions[rows]
            buf.rewards[rows] = env.rewards_of(next_obs.reshape(-1, next_obs.shape[-1]),
                                               actions.reshape(-1, actions.shape[-1])).reshape(actions.shape[:2])
        return True

    def _train_counts(self, key: str, steps: int) -> int:
        """How many gradient steps the mean SB3 logged for ``key`` covers (TD3's actor loss: the delayed ones)."""
        return steps

    def recent_samples(self, n: int) -> Samples:
        """The ``n`` most recent transitions of the replay buffer, oldest first (env-major within a step)."""
        buf = self.replay_buffer
        size = buf.buffer_size if buf.full else buf.pos
        rows = min(-(-n // buf.n_envs), size)
        idx = (buf.pos - rows + np.arange(rows)) % buf.buffer_size

        def flat(a):
            return a[idx].reshape(-1, *a.shape[2:])[-n:].copy()
        timeouts = flat(buf.timeouts).ravel()
        return Samples(flat(buf.observations), flat(buf.actions), rewards=flat(buf.rewards).ravel(),
                       next_observations=flat(buf.next_observations),
                       dones=flat(buf.dones).ravel() * (1.0 - timeouts))

    def set_learning_rate(self, value: float | None = None) -> float:
        """From now on every gradient step of every optimizer uses ``value`` (None: the rate in force now); returns it.
        SB3 drives the actor's, the critics' and SAC's entropy coefficient's optimizers from one schedule."""
        if value is None:
            value = float(self.lr_schedule(self._current_progress_remaining))
        self.lr_schedule = ConstantLR(float(value))
        return float(value)

    # ---- checkpoints -----------------------------------------------------------------------------------
    def training_state(self) -> dict[str, Any]:
        """SB3's loop state, the replay buffer's filled part, the round so far and ``learner_state()``.

        The buffer's filled part is held as tensors that *share* the buffer's memory (``torch.from_numpy``, no copy):
        ``torch.save`` writes a tensor's bytes as they are, where a NumPy array would pickle through a latin-1 string
        (several copies at ~1.4x its size: a 500k-transition buffer of 145-column observations took a run past 10 GB
        resident). Write the state before training continues."""
        buf = self.replay_buffer
        size = buf.buffer_size if buf.full else buf.pos
        arrays = {k: torch.from_numpy(getattr(buf, k)[:size]) for k in ("observations", "next_observations", "actions",
                                                                         "rewards", "dones", "timeouts")}
        return {"num_timesteps": self.num_timesteps, "n_updates": self._n_updates, "episode_num": self._episode_num,
                "rollouts": self._rollouts, "updates": self._updates, "last_obs": self._last_obs,
                "last_original_obs": self._last_original_obs, "last_episode_starts": self._last_episode_starts,
                "ep_info_buffer": list(self.ep_info_buffer), "ep_success_buffer": list(self.ep_success_buffer),
                "replay": {"arrays": arrays, "pos": buf.pos, "full": buf.full},
                "round": {"from": self._round_from, "episodes": list(self._round_episodes),
                          "sums": dict(self._round_sums), "counts": dict(self._round_counts),
                          "steps": self._round_steps_run, "ends": self._ends_round, "last": self._last_round_steps},
                "replay_stage": self._replay_stage,
                "action_noise": _noise_state(self.action_noise),
                "action_space_rng": self.action_space.np_random.bit_generator.state,   # learning_starts' uniform draws
                "learner": self.learner_state()}

    def load_training_state(self, state: dict[str, Any]) -> None:
        """The loop state of ``training_state`` (before ``begin(..., reset=False)``)."""
        self.num_timesteps, self._n_updates = state["num_timesteps"], state["n_updates"]
        self._episode_num, self._rollouts, self._updates = state["episode_num"], state["rollouts"], state["updates"]
        self._last_obs, self._last_original_obs = state["last_obs"], state["last_original_obs"]
        self._last_episode_starts = state["last_episode_starts"]
        self.ep_info_buffer = deque(state["ep_info_buffer"], maxlen=self._stats_window_size)
        self.ep_success_buffer = deque(state["ep_success_buffer"], maxlen=self._stats_window_size)
        buf, replay = self.replay_buffer, state["replay"]
        for key, value in replay["arrays"].items():
            getattr(buf, key)[:len(value)] = np.asarray(value)   # a tensor (a checkpoint before 2026-12-07: an array)
        buf.pos, buf.full = int(replay["pos"]), bool(replay["full"])
        self._replay_stage = int(state.get("replay_stage", 0))   # checkpoints before the reward curriculum: 0
        r = state["round"]
        self._round_from, self._round_episodes = r["from"], [Episode(*e) for e in r["episodes"]]
        self._round_sums, self._round_counts = dict(r["sums"]), dict(r["counts"])
        self._round_steps_run, self._ends_round, self._last_round_steps = r["steps"], r["ends"], r["last"]
        _load_noise_state(self.action_noise, state["action_noise"])
        self.action_space.np_random.bit_generator.state = state["action_space_rng"]


def _noise_state(noise) -> dict | None:
    """An SB3 action noise's own state (Ornstein-Uhlenbeck's previous value; Gaussian noise has none)."""
    if noise is None:
        return None
    noises = getattr(noise, "noises", [noise])
    return {"prev": [getattr(n, "noise_prev", None) for n in noises]}


def _load_noise_state(noise, state: dict | None) -> None:
    if noise is None or state is None:
        return
    for n, prev in zip(getattr(noise, "noises", [noise]), state["prev"]):
        if prev is not None:
            n.noise_prev = prev


__all__ = ["RoundwiseLearning"]
