"""Run-time callbacks that are not remedies: a progress line and environment statistics."""
from __future__ import annotations

import logging
import math
import time

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

log = logging.getLogger("sweep")


def _duration(seconds: float) -> str:
    seconds = int(max(seconds, 0))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else f"{m}m{s:02d}s"


class ProgressLine(BaseCallback):
    """Every ``every_s`` seconds: ``[label] 40,960/20,000,000 ts (0.2%) | 1,510 ts/s | ETA 3h40m``."""

    def __init__(self, label: str, total_timesteps: int, every_s: float = 30.0) -> None:
        super().__init__()
        self.label, self.total, self.every_s = label, int(total_timesteps), float(every_s)

    def _on_training_start(self) -> None:
        self.t0 = self.last = time.time()
        self.start_steps = self.num_timesteps

    def _on_step(self) -> bool:
        now = time.time()
        if now - self.last >= self.every_s:
            self.last = now
            self.print_line(now)
        return True

    def _on_training_end(self) -> None:
        self.print_line(time.time())

    def print_line(self, now: float) -> None:
        done = self.num_timesteps
        rate = (done - self.start_steps) / max(now - self.t0, 1e-9)
        eta = (self.total - done) / rate if rate > 0 else float("inf")
        log.info("[%s] %s/%s ts (%.1f%%) | %s ts/s | ETA %s", self.label, f"{done:,}", f"{self.total:,}",
                 100.0 * done / self.total, f"{rate:,.0f}", _duration(eta) if eta != float("inf") else "?")


class NonFiniteError(FloatingPointError):
    """The training loss or the network's parameters became NaN/inf."""


class NonFiniteGuard(BaseCallback):
    """After every update: stop the run if ``train/loss`` or any parameter is not finite."""

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self._on_rollout_start()

    def _on_rollout_start(self) -> None:
        loss = self.model.logger.name_to_value.get("train/loss")
        if loss is not None and not math.isfinite(loss):
            raise NonFiniteError(f"train/loss={loss} after the update at {self.num_timesteps} timesteps")
        for name, p in self.model.parameter_arrays().items():
            if not np.isfinite(p).all():
                raise NonFiniteError(f"parameter {name} is not finite after the update at {self.num_timesteps} timesteps")


class EnvMonitor(BaseCallback):
    """Logs the wind speed in force (``env/wind_speed``) and the throughput (``time/fps`` is SB3's)."""

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        env = self.training_env
        self.logger.record("env/wind_speed", float(env.wind.speed_at(env.global_step)))
