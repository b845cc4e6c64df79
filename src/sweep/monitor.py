"""Hooks that watch a run without changing it: a progress line, the NaN guard, the condition in force."""
from __future__ import annotations

import logging
import math
import time

from dataclasses import dataclass

import numpy as np

from sweep.config import HookSettings, positive
from sweep.training.hooks import Hook
from sweep.training.records import RolloutRecord, UpdateRecord

log = logging.getLogger("sweep")


def _duration(seconds: float) -> str:
    seconds = int(max(seconds, 0))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else f"{m}m{s:02d}s"


class ProgressLine(Hook):
    """At the first rollout end ``every_s`` seconds after the last line, and at the end:
    ``[label] 40,960/20,000,000 ts (0.2%) | 1,510 ts/s | ETA 3h40m``."""

    @dataclass
    class Settings(HookSettings):
        every_s: float = positive(" (s)")

    def __init__(self, every_s: float = 30.0) -> None:
        self.every_s = float(every_s)

    def setup(self, learner, training) -> None:
        self.label, self.total = training.label, int(training.total_timesteps)
        self.t0 = self.last = time.time()
        self.start_steps = learner.num_timesteps

    def after_rollout(self, learner, rollout: RolloutRecord) -> dict:
        now = time.time()
        if now - self.last >= self.every_s:
            self.last = now
            self.print_line(rollout.timesteps, now)
        return {}

    def at_end(self, learner, update) -> dict:
        self.print_line(learner.num_timesteps, time.time())
        return {}

    def print_line(self, done: int, now: float) -> None:
        rate = (done - self.start_steps) / max(now - self.t0, 1e-9)
        eta = (self.total - done) / rate if rate > 0 else float("inf")
        log.info("[%s] %s/%s ts (%.1f%%) | %s ts/s | ETA %s", self.label, f"{done:,}", f"{self.total:,}",
                 100.0 * done / self.total, f"{rate:,.0f}", _duration(eta) if eta != float("inf") else "?")


class NonFiniteError(FloatingPointError):
    """The training loss or the network's parameters became NaN/inf."""


class NonFiniteGuard(Hook):
    """After every update: stop the run if its loss (``train/loss``) or any parameter is not finite."""

    Settings = HookSettings   # none of its own

    def after_update(self, learner, update: UpdateRecord) -> dict:
        if not math.isfinite(update.loss):
            raise NonFiniteError(f"train/loss={update.loss} after the update at {update.timesteps} timesteps")
        for name, p in learner.parameter_arrays().items():
            if not np.isfinite(p).all():
                raise NonFiniteError(f"parameter {name} is not finite after the update at {update.timesteps} timesteps")
        return {}

    def at_end(self, learner, update: UpdateRecord | None) -> dict:
        return self.after_update(learner, update) if update is not None else {}


class EnvMonitor(Hook):
    """Logs the condition in force at each rollout end (``Condition.metrics``: ``env/segment``, ``env/wind_speed``,
    ``env/wind_x|y|z``, ``env/mass_factor``, ``env/rotor_efficiency_1..4``) and, under a reward curriculum
    (``env.reward_curriculum``), its stage and the weights in force (``env/reward_stage``, ``env/reward_w_p|v|a|q``)."""

    Settings = HookSettings

    def after_rollout(self, learner, rollout: RolloutRecord) -> dict:
        out = rollout.condition.metrics()
        env = getattr(learner, "env", None)
        if getattr(env, "reward_curriculum", None) is not None and env.reward_curriculum.every is not None:
            reward = env.stage_reward()
            out.update({"env/reward_stage": float(env.reward_stage),
                        **{f"env/reward_{w}": float(getattr(reward, w)) for w in ("w_p", "w_v", "w_a", "w_q")}})
        return out
