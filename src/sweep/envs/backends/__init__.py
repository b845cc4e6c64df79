"""Simulator backends: batched vehicle state in, batched vehicle state out.

Every backend exposes the same small interface (``Backend``) so the hover task does not care which
integrator moves the vehicles. ``make_backend(name, ...)`` picks one by the config key ``env.backend``.
"""
from __future__ import annotations

from sweep.envs.backends.base import Backend

BACKENDS = {
    "rotorpy": "sweep.envs.backends.rotorpy_backend:RotorPyBackend",
    "rotorpy_rk4": "sweep.envs.backends.rotorpy_backend:RotorPyRK4Backend",
    "fast": "sweep.envs.backends.fast:FastBackend",
}


def make_backend(name: str, n: int, params: dict, dt: float) -> Backend:
    import importlib

    if name not in BACKENDS:
        raise ValueError(f"env.backend={name!r} is unknown; allowed: {sorted(BACKENDS)}")
    module, cls = BACKENDS[name].split(":")
    return getattr(importlib.import_module(module), cls)(n=n, params=params, dt=dt)


__all__ = ["Backend", "BACKENDS", "make_backend"]
