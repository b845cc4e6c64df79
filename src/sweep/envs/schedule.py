"""Segments on the run's global clock: what ``conf/wind/`` and ``conf/vehicle/`` schedules share.

A schedule holds a list of segments, each in force for ``segment_steps`` global timesteps (vector-env steps x
n_envs, so the schedule does not depend on how many vehicles collect the data). After the list: ``repeat``
starts it again, ``hold`` keeps the last segment.
"""
from __future__ import annotations

import numpy as np


def segment_index(global_steps, segment_steps: int, n_segments: int, after_list: str):
    """Index into the segment list in force at ``global_steps`` (an int or an array of them)."""
    period = np.asarray(global_steps, dtype=np.int64) // int(segment_steps)
    index = period % n_segments if after_list == "repeat" else np.minimum(period, n_segments - 1)
    return int(index) if np.ndim(index) == 0 else index


def next_boundary(global_step: int, segment_steps: int) -> int:
    """The first global step of the next segment period after ``global_step``."""
    return (int(global_step) // int(segment_steps) + 1) * int(segment_steps)
