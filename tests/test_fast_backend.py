"""FastBackend (vectorised RotorPy model, fixed RK4) against RotorPy itself.

References:
* ``RotorPyRK4Backend``: RotorPy's own state derivative ``Multirotor._s_dot_fn`` with the same fixed RK4
  step. Same maths and integrator, so only floating-point round-off may differ. Measured: <= 4e-13 m,
  3e-13 m/s, 1e-13 rad/s, 3e-14 (quaternion), 0 rad/s (rotors) after 500 steps, even for sequences that
  flip the vehicle. Tolerances are 1e-6 (x, v, w, rotors), 1e-8 (q): a million times the round-off,
  far below what any wrong or missing term produces (e.g. dropping rotor drag at 1 m/s moves x by
  > 1e-3 m within 1 s).
* ``RotorPyBackend``: RotorPy's ``Multirotor.step`` (solve_ivp RK45, rtol 1e-3, atol 1e-6). Its
  adaptive error dominates. Measured after 100 steps (1 s), sequences below: 2e-8 m, 7e-8 m/s,
  1e-8 (q), 4e-7 rad/s, 2e-5 rad/s (rotors at ~1800 rad/s); with 10x more action noise: 7e-6 m,
  2e-5 m/s, 3e-6, 1.4e-5 rad/s, 9e-4 rad/s. Tolerances 1e-3 m, 1e-3 m/s, 1e-4 (q), 1e-3 rad/s,
  0.05 rad/s (rotors, 3e-5 relative): the brief's 1e-3 m, the others matched to it (a position error
  of 1e-3 m over 1 s means ~1e-3 m/s), ~50x the worst gap seen, so solve_ivp's step choice cannot flake.
"""
from __future__ import annotations

import copy

import numpy as np
import pytest

from conftest import CONF, backend, compose_cfg
from sweep.envs.backends.fast import FastBackend
from sweep.envs.backends.rotorpy_backend import RotorPyBackend, RotorPyRK4Backend
from sweep.envs.hover import HoverVecEnv, rotor_speed_to_action
from sweep.envs.vehicle import GRAVITY, crazyflie_params, hover_rotor_speed
from sweep.envs.wind import WindSchedule

DT = 0.01
KEYS = ("x", "v", "q", "w", "rotor_speeds")
TOL_RK4 = {"x": 1e-6, "v": 1e-6, "q": 1e-8, "w": 1e-6, "rotor_speeds": 1e-6}
TOL_IVP = {"x": 1e-3, "v": 1e-3, "q": 1e-4, "w": 1e-3, "rotor_speeds": 5e-2}


def _scenario(n: int, steps: int, seed: int, noise: tuple[float, float]):
    """Random constant winds (|w| <= 3 m/s, random direction), starts in +-2 m, rotors at hover, and
    commanded speeds hover * (1 + collective bias, std 1 %) + white noise per rotor (std drawn in
    ``noise`` x hover). Open loop, so any differential bias would tumble the vehicle: keep it common."""
    p = crazyflie_params(0.05)
    hs = hover_rotor_speed(p)
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    wind = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.0, 3.0, size=(n, 1))
    sigma = rng.uniform(*noise, size=(n, 1, 1)) * hs
    cmds = hs * (1.0 + rng.normal(scale=0.01, size=(n, 1, 1))) + rng.normal(size=(n, steps, 4)) * sigma
    start = {"x": rng.uniform(-2, 2, size=(n, 3)), "v": np.zeros((n, 3)),
             "q": np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), "w": np.zeros((n, 3)),
             "rotor_speeds": np.full((n, 4), hs)}
    return p, wind, cmds, start


def _run_pair(fast, ref, wind, cmds, start):
    for b in (fast, ref):
        b.set_state(start)
    for t in range(cmds.shape[1]):
        fast.step(cmds[:, t], wind)
        ref.step(cmds[:, t], wind)
    return {k: np.abs(getattr(fast, k) - getattr(ref, k)).max() for k in KEYS}, ref


def _check(diff, tol, ref):
    bad = {k: f"{diff[k]:.3e} > {tol[k]:.0e}" for k in KEYS if not diff[k] <= tol[k]}
    assert not bad, bad
    assert np.all(np.isfinite(ref.x))


def test_matches_rotorpy_derivative_rk4_hover_noise():
    """32 sequences of 500 steps, hover +- 0.05..0.2 % white noise (the sane regime)."""
    n, steps = 32, 500
    p, wind, cmds, start = _scenario(n, steps, seed=0, noise=(0.0005, 0.002))
    diff, ref = _run_pair(FastBackend(n, p, DT), RotorPyRK4Backend(n, p, DT), wind, cmds, start)
    _check(diff, TOL_RK4, ref)
    # a sane regime: upright, slow rotation (open loop, so the wind still blows them up to ~25 m away)
    assert np.all(1.0 - 2.0 * (ref.q[:, 0] ** 2 + ref.q[:, 1] ** 2) > 0.0)
    assert np.abs(ref.w).max() < 2.0
    assert np.abs(ref.x - start["x"]).max() > 0.1  # and moved: wind, drag and noise are exercised


def test_matches_rotorpy_derivative_rk4_aggressive():
    """6 sequences, noise 3..5 % of hover: vehicles tumble (large rates, inverted); still round-off only."""
    n, steps = 6, 500
    p, wind, cmds, start = _scenario(n, steps, seed=1, noise=(0.03, 0.05))
    diff, ref = _run_pair(FastBackend(n, p, DT), RotorPyRK4Backend(n, p, DT), wind, cmds, start)
    _check(diff, TOL_RK4, ref)
    assert np.abs(ref.w).max() > 5.0


def test_all_aero_terms_against_rk4():
    """k_h, k_flap and parasitic drag are zero for the Crazyflie: switch them on to test those terms too,
    with a non-diagonal inertia and a commanded speed outside [min, max] (clipped as in RotorPy)."""
    p, wind, cmds, start = _scenario(8, 200, seed=2, noise=(0.0005, 0.002))
    p = copy.deepcopy(p)
    p.update({"k_h": 1e-3, "k_flap": 1e-9, "c_Dx": 2e-3, "c_Dy": 1.5e-3, "c_Dz": 2.5e-3,
              "Ixy": 1e-7, "Ixz": -2e-7, "Iyz": 5e-8, "rotor_speed_min": 200})
    cmds[0, :20, 0] = 3000.0  # above rotor_speed_max
    cmds[1, :20, 1] = 0.0  # below rotor_speed_min
    diff, ref = _run_pair(FastBackend(8, p, DT), RotorPyRK4Backend(8, p, DT),
                          wind, cmds, start)
    _check(diff, TOL_RK4, ref)
    # the extra terms matter: the Crazyflie model without them is far off
    base = crazyflie_params(0.05)
    plain = FastBackend(8, base, DT)
    plain.set_state(start)
    for t in range(cmds.shape[1]):
        plain.step(cmds[:, t], wind)
    assert np.abs(plain.x - ref.x).max() > 1e-3


def test_matches_rotorpy_solve_ivp_after_1s():
    """32 sequences of 100 steps (1 s) against Multirotor.step (solve_ivp RK45)."""
    n, steps = 32, 100
    p, wind, cmds, start = _scenario(n, steps, seed=3, noise=(0.0005, 0.002))
    diff, ref = _run_pair(FastBackend(n, p, DT), RotorPyBackend(n, p, DT), wind, cmds, start)
    _check(diff, TOL_IVP, ref)


@pytest.mark.parametrize("name", sorted(p.stem for p in (CONF / "backend").glob("*.yaml")))
def test_each_configured_backend_builds_and_flies_the_vehicle(name):
    """Each conf/backend/ name (env.backends, built by its _target_) gives a backend of n vehicles stepped by dt: with the rotors stopped a vehicle falls
    freely (z = -g t^2 / 2, v_z = -g t: no rotor force, no drag at zero rotor speed, and RK4 / RK45 are exact
    on a parabola), and under hover commands with wind it flies as RotorPy's own derivative does."""
    n, steps = 3, 30
    p, wind, cmds, start = _scenario(n, steps, seed=4, noise=(0.0005, 0.002))
    b = backend(name)(n=n, params=p, dt=DT)
    assert (b.n, b.dt, b.x.shape, b.q.shape, b.rotor_speeds.shape) == (n, DT, (n, 3), (n, 4), (n, 4))
    b.set_state({**start, "rotor_speeds": np.zeros((n, 4))})
    for _ in range(steps):
        b.step(np.zeros((n, 4)), np.zeros((n, 3)))
    t = steps * DT
    np.testing.assert_allclose(b.x[:, 2] - start["x"][:, 2], -0.5 * GRAVITY * t * t, rtol=1e-9)
    np.testing.assert_allclose(b.v, np.tile([0.0, 0.0, -GRAVITY * t], (n, 1)), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(b.x[:, :2], start["x"][:, :2], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(b.q, start["q"])
    diff, ref = _run_pair(b, RotorPyRK4Backend(n, p, DT), wind, cmds, start)
    _check(diff, TOL_IVP if name == "rotorpy" else TOL_RK4, ref)  # solve_ivp's adaptive error, else round-off
    assert np.abs(ref.x - start["x"]).max() > 1e-3  # the wind moved them: the comparison is not trivial


def test_an_unknown_backend_name_is_a_config_error():
    from sweep.config import ConfigError, validate

    with pytest.raises(ConfigError, match=r"^env\.backend='fastest': must be one of fast\|rotorpy\|rotorpy_rk4"):
        validate(compose_cfg(["env.backend=fastest"]))


def test_hover_env_fast_equals_rotorpy_rk4():
    """Same seeds and actions: identical dones, terminations, truncations, resets; rewards to 1e-5."""
    n, steps = 4, 1100
    # light wind for the first 600 vector steps (uncontrolled vehicles last a whole episode), then 3 m/s
    wind = WindSchedule(speeds=(0.3, 3.0), segment_steps=600 * n, direction=(1.0, 1.0, 0.3))
    envs = [HoverVecEnv(n_envs=n, backend=backend(b), wind=wind, seed=123) for b in ("fast", "rotorpy_rk4")]
    obs = [e.reset() for e in envs]
    np.testing.assert_array_equal(obs[0], obs[1])
    p = crazyflie_params(0.05)
    a_hover = rotor_speed_to_action(hover_rotor_speed(p), p["rotor_speed_min"], p["rotor_speed_max"])
    rng = np.random.default_rng(7)
    n_term = n_trunc = 0
    for t in range(steps):
        act = (a_hover + rng.normal(scale=0.002, size=(n, 4))).astype(np.float32)
        if 600 <= t < 800:
            act[0] = -1.0  # motors off: vehicle 0 falls out of the +-4 m box
        out = [e.step(act) for e in envs]
        (o0, r0, d0, i0), (o1, r1, d1, i1) = out
        np.testing.assert_array_equal(d0, d1, err_msg=f"dones differ at step {t}")
        np.testing.assert_allclose(r0, r1, rtol=1e-5, atol=1e-6, err_msg=f"rewards differ at step {t}")
        np.testing.assert_allclose(o0, o1, rtol=1e-5, atol=1e-5, err_msg=f"obs differ at step {t}")
        for i in np.flatnonzero(d0):
            assert i0[i]["TimeLimit.truncated"] == i1[i]["TimeLimit.truncated"]
            assert i0[i]["episode"]["l"] == i1[i]["episode"]["l"]
            np.testing.assert_allclose(i0[i]["episode"]["r"], i1[i]["episode"]["r"], rtol=1e-5)
            np.testing.assert_allclose(i0[i]["terminal_observation"], i1[i]["terminal_observation"],
                                       rtol=1e-5, atol=1e-5)
            if i0[i]["TimeLimit.truncated"]:
                n_trunc += 1
            else:
                n_term += 1
    assert n_term >= 1, "no out-of-bounds termination happened"
    assert n_trunc >= 1, "no episode boundary (time limit) happened"
