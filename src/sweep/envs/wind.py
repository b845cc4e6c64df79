"""Wind schedule of the paper (Sec. IV-A): the wind speed changes every ``segment_steps`` timesteps.

The paper lists 3.0, 2.0, 2.5, 1.5, 2.5 m/s, each held for 2M timesteps, over 20M timesteps. Five
segments cover only 10M steps, so we read the list as repeating (20M steps see it twice; ``after_list=repeat``).
The other reading (``after_list=hold``) holds the last speed once the list is used up; the paper's PPO crash is
reported "after 10 million timesteps", where the two readings part. The speed
is indexed by the **global** timestep of the run (vector-env steps x n_envs), so it does not depend on
how many parallel environments collect the data. Wind is a world-frame air velocity along the unit
vector ``direction``; it acts on the vehicle only through RotorPy's aerodynamic drag.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np


@dataclass
class WindSchedule:
    speeds: Sequence[float] = (0.0,)
    segment_steps: int = 2_000_000
    direction: Sequence[float] = (1.0, 0.0, 0.0)
    name: str = "custom"
    after_list: str = "repeat"     # repeat | hold: what follows the last speed of the list
    _unit: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.speeds = [float(s) for s in self.speeds]
        d = np.asarray(self.direction, dtype=np.float64)
        norm = float(np.linalg.norm(d))
        self._unit = d / norm if norm > 0 else np.zeros(3)

    def speed_at(self, global_step: int) -> float:
        """Wind speed (m/s) in force at global timestep ``global_step``."""
        segment, n = int(global_step) // int(self.segment_steps), len(self.speeds)
        return self.speeds[segment % n if self.after_list == "repeat" else min(segment, n - 1)]

    def _index(self, global_steps: np.ndarray) -> np.ndarray:
        segment = np.asarray(global_steps, dtype=np.int64) // int(self.segment_steps)
        n = len(self.speeds)
        return segment % n if self.after_list == "repeat" else np.minimum(segment, n - 1)

    def velocity_at(self, global_step: int) -> np.ndarray:
        """World-frame wind velocity (m/s), shape (3,)."""
        return self.speed_at(global_step) * self._unit

    def velocities(self, global_steps: np.ndarray) -> np.ndarray:
        """``velocity_at`` for many global timesteps at once: (T,) -> (T, 3)."""
        speeds = np.asarray(self.speeds)[self._index(global_steps)]
        return speeds[:, None] * self._unit

    @classmethod
    def constant(cls, speed: float, direction: Sequence[float] = (1.0, 0.0, 0.0)) -> "WindSchedule":
        return cls(speeds=[speed], segment_steps=1 << 62, direction=direction, name=f"constant{speed:g}")
