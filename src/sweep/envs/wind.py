"""Wind schedule (paper Sec. IV-A): the wind changes every ``segment_steps`` timesteps.

The paper lists 3.0, 2.0, 2.5, 1.5, 2.5 m/s, each held for 2M timesteps, over 20M timesteps. Five
segments cover only 10M steps, so we read the list as repeating (20M steps see it twice; ``after_list=repeat``).
The other reading (``after_list=hold``) holds the last speed once the list is used up; the paper's PPO crash is
reported "after 10 million timesteps", where the two readings part. The wind is indexed by the **global**
timestep of the run (``sweep.envs.schedule``). Wind is a world-frame air velocity, segment k's speed along
the unit vector ``direction`` (one for every segment) or ``directions[k]`` (one per segment: ``wind=flip``,
``wind=rotate``); it acts on the vehicle only through RotorPy's aerodynamic drag. ``gusts`` (one per speed) adds
Dryden turbulence of that intensity (RotorPy's ``sig_wind``, the same on each axis; ``sweep.envs.gusts``) on top
of segment k's mean wind, each vehicle its own gusts.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from sweep.envs.schedule import segment_index


def _unit(d: Sequence[float]) -> np.ndarray:
    d = np.asarray(d, dtype=np.float64)
    norm = float(np.linalg.norm(d))
    return d / norm if norm > 0 else np.zeros(3)


@dataclass
class WindSchedule:
    speeds: Sequence[float] = (0.0,)
    segment_steps: int = 2_000_000
    direction: Sequence[float] = (1.0, 0.0, 0.0)
    name: str = "custom"
    after_list: str = "repeat"     # repeat | hold: what follows the last speed of the list
    directions: Sequence[Sequence[float]] | None = None  # one per speed (None: ``direction`` for all)
    gusts: Sequence[float] | None = None  # Dryden sigma per speed (RotorPy's sig_wind; None: no turbulence)
    gust_altitude: float = 2.0            # m: the Dryden model's scale lengths
    _vectors: np.ndarray = field(init=False, repr=False)  # (segments, 3) wind velocity of each segment

    def __post_init__(self) -> None:
        self.speeds = [float(s) for s in self.speeds]
        dirs = [self.direction] * len(self.speeds) if self.directions is None else list(self.directions)
        if len(dirs) != len(self.speeds):
            raise ValueError(f"wind: {len(dirs)} directions for {len(self.speeds)} speeds")
        self._vectors = np.array([s * _unit(d) for s, d in zip(self.speeds, dirs)]).reshape(len(self.speeds), 3)
        self.gusts = [0.0] * len(self.speeds) if self.gusts is None else [float(g) for g in self.gusts]
        if len(self.gusts) != len(self.speeds) or any(not g >= 0 for g in self.gusts):
            raise ValueError(f"wind: gusts {self.gusts} must be {len(self.speeds)} numbers >= 0, one per speed")

    @property
    def varies(self) -> bool:
        """More than one distinct wind (vector and gust intensity) in the list."""
        return len(np.unique(np.column_stack([self._vectors, self.gusts]), axis=0)) > 1

    @property
    def turbulent(self) -> bool:
        """Some segment has gusts."""
        return any(g > 0 for g in self.gusts)

    def gust_at(self, global_step: int) -> float:
        """The Dryden sigma in force at ``global_step`` (0: calm)."""
        return self.gusts[self.index(global_step)]

    def gust_sigmas(self, global_steps: np.ndarray) -> np.ndarray:
        """``gust_at`` for many global timesteps at once: (T,) -> (T,)."""
        return np.asarray(self.gusts, dtype=np.float64)[self.index(np.asarray(global_steps))]

    def index(self, global_step):
        """Index of the segment in force at ``global_step`` (an int or an array of them)."""
        return segment_index(global_step, self.segment_steps, len(self.speeds), self.after_list)

    def speed_at(self, global_step: int) -> float:
        """Wind speed (m/s) in force at global timestep ``global_step``."""
        return self.speeds[self.index(global_step)]

    def velocity_at(self, global_step: int) -> np.ndarray:
        """World-frame wind velocity (m/s), shape (3,)."""
        return self._vectors[self.index(global_step)].copy()

    def velocities(self, global_steps: np.ndarray) -> np.ndarray:
        """``velocity_at`` for many global timesteps at once: (T,) -> (T, 3)."""
        return self._vectors[self.index(np.asarray(global_steps))]

    @classmethod
    def constant(cls, speed: float, direction: Sequence[float] = (1.0, 0.0, 0.0)) -> "WindSchedule":
        return cls(speeds=[speed], segment_steps=1 << 62, direction=direction, name=f"constant{speed:g}")

    @classmethod
    def steady(cls, velocity: Sequence[float], gust: float = 0.0, gust_altitude: float = 2.0) -> "WindSchedule":
        """A constant mean wind of exactly this world-frame velocity (m/s), with Dryden gusts of sigma ``gust``."""
        v = np.asarray(velocity, dtype=np.float64).reshape(3)
        speed = float(np.linalg.norm(v))
        wind = cls(speeds=[speed], segment_steps=1 << 62, direction=v if v.any() else (1.0, 0.0, 0.0),
                   name=f"constant{speed:g}", gusts=[gust], gust_altitude=gust_altitude)
        wind._vectors = v.reshape(1, 3).copy()
        return wind
