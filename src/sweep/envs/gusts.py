"""Dryden turbulence on top of the mean wind: RotorPy 3.0's ``DrydenGust`` (``rotorpy/wind/dryden_utils.py``,
after goromal/wind-dynamics), one independent gust process per vehicle and world axis.

Per axis RotorPy filters white noise through the Dryden shaping filter

    H(s) = alpha (1 + b s) / (1 + c s)^2,   b = 2 sqrt(3) L / V,  c = 2 L / V,  alpha = sigma sqrt(2 L / (pi V)),

with V = 1 m/s and the scale lengths of the low-altitude model from the altitude h (in feet):
L_z = h, L_x = L_y = h / (0.177 + 0.000823 h)^1.2 (2 m: L_z = 2.0 m, L_x = L_y = 15.4 m). It discretises H by
Tustin's rule at the step dt and drives it with one draw of uniform(-1, 1) per step, *not* scaled by dt, so the
realised spread is far below ``sigma`` (its ``sig_wind``) and depends on dt: ``realised_std`` computes it (at
100 Hz and 2 m, sigma = 1 gives 0.0326 m/s on each axis). The filter here runs with sigma = 1 and
its output is scaled by the segment's sigma, so a schedule can turn the gusts up and down without restarting
the process (RotorPy's output for a constant sigma, to rounding: tests/test_gusts.py); a change of sigma scales the
gust at once (0 -> 100: a step of a few m/s). The gusts do not depend on the vehicle's state, and a process runs
over the whole run's clock, across episodes. RotorPy starts its filter at rest, and its x/y time constant 2 L / V
is 31 s, longer than an episode: a process started at rest would fly an evaluation (a fresh env) under less than
half the spread of training. So every process starts *settled*: ``settle`` runs it ``SETTLE_S`` = 150 s on draws
of its own generator (the variance is within 0.05% of the stationary one after 120 s).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

GUST_STREAM = 0x67757374  # the gusts' draws: their own stream of the env's seed, so the starts' draws do not move
SETTLE_S = 150.0          # s of draws a new gust process runs before its first step (``settle``)


def scale_lengths(altitude: float) -> np.ndarray:
    """Dryden scale lengths (m) of the x, y, z axes at ``altitude`` (m), as RotorPy's ``DrydenWind`` computes them."""
    lz_ft = 3.281 * altitude
    lx_ft = lz_ft / ((0.177 + 0.000823 * lz_ft) ** 1.2)
    return np.array([lx_ft, lx_ft, lz_ft]) / 3.281


def dryden_coefficients(dt: float, altitude: float = 2.0) -> np.ndarray:
    """(3, 6): per axis RotorPy's ``GustModelBase.run`` coefficients C1..C6 at step ``dt`` for sigma = 1."""
    coef = np.empty((3, 6))
    for axis, length in enumerate(scale_lengths(altitude)):
        v = 1.0
        b, c = 2 * np.sqrt(3) * length / v, 2 * length / v
        alpha = np.sqrt(2 * length / np.pi / v)
        beta, delta, gamma = alpha * b, 2 * c, c * c
        coef[axis] = (1.0 + 2 * delta / dt + 4 * gamma / dt / dt, 2.0 - 8 * gamma / dt / dt,
                      1.0 - 2 * delta / dt + 4 * gamma / dt / dt, alpha + 2 * beta / dt, 2 * alpha, alpha - 2 * beta / dt)
    return coef


class GustFilters(NamedTuple):
    """The gust processes of N vehicles: ``state`` (N, 3, 4) holds each axis's last two inputs and outputs
    (u_k-1, u_k-2, y_k-1, y_k-2) at sigma = 1; ``coef`` (3, 6) the filter (``dryden_coefficients``)."""
    state: np.ndarray
    coef: np.ndarray


@numba.njit(cache=True)
def add_gusts(filters, draws, sigma, wind):
    """One step of every vehicle's gust filter on ``draws`` (N, 3) of uniform(-1, 1); ``wind`` (N, 3), the mean
    wind, gets ``sigma`` times the gust added in place (RotorPy: y_k = (C4 u_k + C5 u_k-1 + C6 u_k-2 - C2 y_k-1
    - C3 y_k-2) / C1)."""
    state, coef = filters.state, filters.coef
    for i in range(state.shape[0]):
        for a in range(3):
            s, c, u = state[i, a], coef[a], draws[i, a]
            y = (c[3] * u + c[4] * s[0] + c[5] * s[1] - c[1] * s[2] - c[2] * s[3]) / c[0]
            s[1], s[0], s[3], s[2] = s[0], u, s[2], y
            wind[i, a] += sigma * y


def new_gusts(n: int, dt: float, altitude: float = 2.0) -> GustFilters:
    """N gust processes at rest (as RotorPy starts its filter; ``settle`` them before use)."""
    if dt > 0.05:
        raise ValueError(f"gusts: step dt={dt:g} s; RotorPy's Dryden filter sub-steps above 0.05 s, which is not "
                         "reproduced here: use env.sim_rate >= 20")
    return GustFilters(state=np.zeros((n, 3, 4)), coef=dryden_coefficients(dt, altitude))


@numba.njit(cache=True)
def _run(filters, draws):
    scratch = np.zeros((filters.state.shape[0], 3))
    for k in range(draws.shape[0]):
        add_gusts(filters, draws[k], 1.0, scratch)


def settle(filters: GustFilters, rng: np.random.Generator, dt: float, seconds: float = SETTLE_S) -> None:
    """Start the processes afresh and run them ``seconds`` on draws of ``rng``, into their stationary spread."""
    filters.state[...] = 0.0
    n = filters.state.shape[0]
    for _ in range(int(math.ceil(seconds / dt / 1000))):   # 1000 steps at a time: bounded memory for many vehicles
        _run(filters, rng.uniform(-1.0, 1.0, (1000, n, 3)))


def gust_rng(seed: int | None) -> np.random.Generator:
    """The generator of a run's gust draws (the env's seed, its own stream)."""
    return np.random.default_rng(None if seed is None else [int(seed), GUST_STREAM])


def realised_std(dt: float, altitude: float = 2.0, seconds: float = 600.0) -> np.ndarray:
    """(3,) stationary standard deviation (m/s) of each axis's gust at sigma = 1: sqrt(Var(u) sum_k h_k^2) over
    the filter's impulse response h (Var of uniform(-1, 1) = 1/3), summed over ``seconds``."""
    steps = int(math.ceil(seconds / dt))
    filters = new_gusts(1, dt, altitude)
    draws = np.zeros((steps, 1, 3))
    draws[0] = 1.0
    response = np.zeros((steps, 3))
    out = np.zeros((1, 3))
    for k in range(steps):
        out[:] = 0.0
        add_gusts(filters, draws[k], 1.0, out)
        response[k] = out[0]
    return np.sqrt((response ** 2).sum(axis=0) / 3.0)
