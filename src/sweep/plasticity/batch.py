"""The most recent samples of a rollout buffer, whichever learner filled it (both use SB3's RolloutBuffer)."""
from __future__ import annotations

import numpy as np
from stable_baselines3.common.buffers import RolloutBuffer


def recent_rollout(buf: RolloutBuffer, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(observations, actions, advantages, returns) of the ``n`` most recent steps of the rollout."""
    if buf.generator_ready:  # SB3 already flattened it for an update (env-major order)
        flat = lambda a: a  # noqa: E731
    else:  # (steps, envs, ...) -> (steps*envs, ...), most recent steps last
        flat = lambda a: a.reshape(-1, *a.shape[2:])  # noqa: E731
    total = buf.buffer_size * buf.n_envs
    idx = slice(max(0, total - n), total)
    return (flat(buf.observations)[idx].copy(), flat(buf.actions)[idx].copy(), flat(buf.advantages)[idx].ravel().copy(),
            flat(buf.returns)[idx].ravel().copy())
