"""Simulator backends: batched vehicle state in, batched vehicle state out.

Every backend exposes the same small interface (``Backend``) so the hover task does not care which
integrator moves the vehicles. ``env.backend`` names one of ``env.backends`` (conf/backend/*.yaml: its class
by ``_target_``); ``sweep.envs.factory.make_env`` builds it and hands the class to ``HoverVecEnv``.
"""
from __future__ import annotations

from sweep.envs.backends.base import Backend

__all__ = ["Backend"]
