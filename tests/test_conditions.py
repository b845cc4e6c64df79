"""Changes of condition (issue 33): the vehicle schedule's mass and rotor efficiencies in the fast backend against
RotorPy's own model, the wind's direction per segment, and the env switching both at the right global step.

Reference: ``RotorPyRK4Backend`` (RotorPy's ``Multirotor._s_dot_fn`` under one RK4 step) with the params scaled
and its body wrench minus the thrust each rotor does not make (``ConditionedMultirotor``). Tolerances as
tests/test_fast_backend.py (1e-6 m etc., a million times the round-off seen there).
"""
from __future__ import annotations

import numpy as np
import pytest
from rotorpy.vehicles.multirotor import Multirotor

from test_fast_backend import DT, KEYS, TOL_RK4, _check, _scenario
from sweep.envs.backends.fast import FastBackend
from sweep.envs.backends.rotorpy_backend import ConditionedMultirotor, RotorPyRK4Backend
from sweep.envs.hover import HoverVecEnv, rotor_speed_to_action, segment_count
from sweep.envs.vehicle import GRAVITY, NOMINAL, VehicleSchedule, VehicleSegment, crazyflie_params, hover_rotor_speed
from sweep.envs.wind import WindSchedule

SEGMENTS = {"payload 1.3": VehicleSegment(1.3), "payload 1.5": VehicleSegment(1.5),
            "motor 0.7": VehicleSegment(1.0, (0.7, 1.0, 1.0, 1.0)),
            "both": VehicleSegment(1.2, (1.0, 0.8, 1.0, 0.9))}


@pytest.mark.parametrize("vehicle", [pytest.param(v, id=k) for k, v in SEGMENTS.items()])
def test_fast_backend_matches_rotorpy_under_each_vehicle_change(vehicle):
    """16 random open-loop sequences of 300 steps: nominal for 100 steps, then the changed vehicle (both backends
    switched at the same step), commands at the changed vehicle's hover speed."""
    n, steps = 16, 300
    p, wind, cmds, start = _scenario(n, steps, seed=4, noise=(0.0005, 0.002))
    fast, ref = FastBackend(n, p, DT), RotorPyRK4Backend(n, p, DT)
    for b in (fast, ref):
        b.set_state(start)
    for t in range(steps):
        if t == 100:
            fast.set_vehicle(vehicle)
            ref.set_vehicle(vehicle)
        fast.step(cmds[:, t] * np.sqrt(vehicle.mass if t >= 100 else 1.0), wind)
        ref.step(cmds[:, t] * np.sqrt(vehicle.mass if t >= 100 else 1.0), wind)
    _check({k: np.abs(getattr(fast, k) - getattr(ref, k)).max() for k in KEYS}, TOL_RK4, ref)
    nominal = FastBackend(n, p, DT)  # the change acts: the same commands on the nominal vehicle end elsewhere
    nominal.set_state(start)
    for t in range(steps):
        nominal.step(cmds[:, t] * np.sqrt(vehicle.mass if t >= 100 else 1.0), wind)
    assert np.abs(nominal.x - fast.x).max() > 1e-2


def test_a_rotors_efficiency_is_its_thrust_share_in_rotorpys_derivative():
    """At rest, level, rotors at the nominal hover speed, no wind: with rotor 1 at eta the vertical acceleration
    drops by (1 - eta) k_eta w^2 / m and the body gets that thrust's moment r_1 x (0, 0, -dT); the fast backend's
    derivative says the same."""
    p = crazyflie_params(0.05)
    w = hover_rotor_speed(p)
    state = {"x": np.zeros(3), "v": np.zeros(3), "q": np.array([0.0, 0.0, 0.0, 1.0]), "w": np.zeros(3),
             "wind": np.zeros(3), "rotor_speeds": np.full(4, w)}
    s = Multirotor._pack_state(state)
    eta = (0.7, 1.0, 1.0, 1.0)
    nominal = ConditionedMultirotor(p)._s_dot_fn(0.0, s, np.full(4, w))
    degraded = ConditionedMultirotor(p, eta)._s_dot_fn(0.0, s, np.full(4, w))
    lost = 0.3 * p["k_eta"] * w ** 2
    assert abs(nominal[5]) < 1e-9   # hovering
    assert degraded[5] == pytest.approx(-lost / p["mass"], rel=1e-9)
    r = np.array(p["rotor_pos"]["r1"])
    inertia = np.diag([p["Ixx"], p["Iyy"], p["Izz"]])
    np.testing.assert_allclose(degraded[10:13], np.linalg.solve(inertia, np.cross(r, [0.0, 0.0, -lost])), rtol=1e-9)


def test_a_payload_needs_the_hover_speed_of_its_mass():
    """x1.3: the Crazyflie hovers at sqrt(1.3) x 1789 = ~2039 rad/s (thrust-to-weight 1.95 -> 1.50); at the nominal
    hover speed it sinks at 0.3 / 1.3 g (to 1e-3: within the step, the rotors' drag on the descent already acts)."""
    p = crazyflie_params(0.05)
    heavy = VehicleSegment(1.3)
    hs = hover_rotor_speed(p)
    assert hs == pytest.approx(1789, abs=1) and hs * np.sqrt(1.3) == pytest.approx(2039, abs=1)
    assert 4 * p["k_eta"] * p["rotor_speed_max"] ** 2 / (1.3 * p["mass"] * GRAVITY) == pytest.approx(1.50, abs=0.01)
    for speed, accel in ((hs * np.sqrt(1.3), 0.0), (hs, -0.3 / 1.3 * GRAVITY)):
        b = FastBackend(1, p, DT)
        b.set_vehicle(heavy)
        b.rotor_speeds[:] = speed
        b.step(np.full((1, 4), speed), np.zeros((1, 3)))
        assert b.v[0, 2] / DT == pytest.approx(accel, abs=1e-6, rel=1e-3)


def test_the_nominal_vehicle_is_rotorpys_bit_for_bit():
    """set_vehicle(NOMINAL) changes nothing (every run before conf/vehicle/ stays the same)."""
    n, steps = 4, 50
    p, wind, cmds, start = _scenario(n, steps, seed=1, noise=(0.0005, 0.002))
    a, b = FastBackend(n, p, DT), FastBackend(n, p, DT)
    b.set_vehicle(NOMINAL)
    for x in (a, b):
        x.set_state(start)
        for t in range(steps):
            x.step(cmds[:, t], wind)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.q, b.q)


def test_a_vehicle_segment_checks_its_values():
    """The Python API (and the Gymnasium env) get the config's rules: 4 efficiencies in (0, 1], a mass factor > 0."""
    for bad in (dict(rotor_efficiency=(1.0, 1.0, 1.0)), dict(rotor_efficiency=(1.2, 1.0, 1.0, 1.0)), dict(mass=0.0)):
        with pytest.raises(ValueError, match="must be"):
            VehicleSegment(**bad)


def test_wind_directions_per_segment():
    flip = WindSchedule([3.0, 3.0], segment_steps=10, directions=[[1, 0, 0], [-2, 0, 0]])
    np.testing.assert_array_equal(flip.velocity_at(9), [3.0, 0.0, 0.0])
    np.testing.assert_array_equal(flip.velocity_at(10), [-3.0, 0.0, 0.0])
    np.testing.assert_array_equal(flip.velocities(np.array([0, 10, 20])), [[3, 0, 0], [-3, 0, 0], [3, 0, 0]])
    assert flip.varies and not WindSchedule([2.0, 2.0]).varies
    paper = WindSchedule([3.0, 2.0], direction=(1.0, 1.0, 0.0))   # one direction for all: as before
    np.testing.assert_array_equal(paper.velocity_at(0), 3.0 * np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0))
    np.testing.assert_array_equal(WindSchedule.steady([0.3, -1.7, 0.2]).velocity_at(5), [0.3, -1.7, 0.2])


def test_the_env_rebuilds_the_wind_when_only_the_direction_changes():
    """The trap of a wind rebuilt on a change of speed only: a flip at the same speed must reach the vehicles."""
    env = HoverVecEnv(n_envs=2, seed=0, wind=WindSchedule([3.0, 3.0], segment_steps=4, directions=[[1, 0, 0], [-1, 0, 0]]))
    env.reset()
    seen = []
    for _ in range(4):
        env.step(np.zeros((2, 4)))
        seen.append(env._wind_array[0, 0])
    assert seen == [3.0, 3.0, -3.0, -3.0]
    assert env.condition().wind == (3.0, 0.0, 0.0) and env.condition().segment == 2


def test_the_env_flies_the_vehicle_of_the_segment_and_restores_it():
    """The backend's vehicle follows the schedule on the global clock, and set_state (resume) restores it."""
    schedule = VehicleSchedule([VehicleSegment(1.0), VehicleSegment(1.5, (0.7, 1.0, 1.0, 1.0))], segment_steps=6)
    env = HoverVecEnv(n_envs=2, seed=0, vehicle=schedule)
    env.reset()
    hover = rotor_speed_to_action(env.hover_speed, env.speed_min, env.speed_max)
    masses = []
    for _ in range(5):
        env.step(np.full((2, 4), hover))
        masses.append(env.sim.physics.mass / crazyflie_params()["mass"])
    assert masses == pytest.approx([1.0, 1.0, 1.0, 1.5, 1.5])
    c = env.condition()
    assert (c.mass, c.rotor_efficiency, c.segment) == (1.5, (0.7, 1.0, 1.0, 1.0), 1)
    state = env.get_state()
    other = HoverVecEnv(n_envs=2, seed=1, vehicle=schedule)
    other.set_state(state)
    assert other.sim.physics.mass == env.sim.physics.mass
    np.testing.assert_array_equal(other.sim.physics.thrust_coef, env.sim.physics.thrust_coef)
    for e in (env, other):
        e.step(np.full((2, 4), hover))
    np.testing.assert_array_equal(other.sim.x, env.sim.x)


def test_segments_count_both_clocks():
    wind, nominal = WindSchedule([3.0, 2.0], segment_steps=10), VehicleSchedule()
    assert [segment_count(wind, nominal, g) for g in (0, 9, 10, 35)] == [0, 0, 1, 3]
    payload = VehicleSchedule([VehicleSegment(1.0), VehicleSegment(1.3)], segment_steps=15)
    # boundaries at 10, 15, 20, 30 (wind and vehicle both at 30), 40, 45
    assert [segment_count(wind, payload, g) for g in (0, 10, 15, 20, 29, 30, 45)] == [0, 1, 2, 3, 3, 4, 6]


def test_eval_condition_fixed_current_and_all():
    """``fixed`` flies eval.*; ``current`` the schedules' condition at the policy's last step; ``all`` every distinct
    condition the run reaches, in order of appearance (flip x payload, both 2M: 4 segments in 8M, 3 distinct)."""
    from conftest import compose_cfg
    from sweep.evaluate import flight_conditions

    cfg = compose_cfg(["wind=flip", "vehicle=payload", "train.total_timesteps=8000000", "eval.mass=1.2"])
    (fixed,) = flight_conditions(cfg.eval, cfg.wind, cfg.vehicle, 8_000_000, 8_000_000)
    assert fixed.wind == (3.0, 0.0, 0.0) and fixed.vehicle == VehicleSegment(1.2) and fixed.segment == -1
    cfg.eval.condition = "current"
    (now,) = flight_conditions(cfg.eval, cfg.wind, cfg.vehicle, 3_000_000, 8_000_000)
    assert (now.wind, now.vehicle.mass, now.segment) == ((-3.0, 0.0, 0.0), 1.3, 1)
    (end,) = flight_conditions(cfg.eval, cfg.wind, cfg.vehicle, 8_000_000, 8_000_000)   # the last segment's, not the next
    assert (end.wind, end.vehicle.mass, end.segment) == ((-3.0, 0.0, 0.0), 1.5, 3)
    cfg.eval.condition = "all"
    every = flight_conditions(cfg.eval, cfg.wind, cfg.vehicle, 8_000_000, 8_000_000)
    # segments: (+x, 1.0), (-x, 1.3), (+x, 1.0) again, (-x, 1.5)
    assert [(c.name, c.wind[0], c.vehicle.mass, c.segment) for c in every] == [
        ("c0", 3.0, 1.0, 0), ("c1", -3.0, 1.3, 1), ("c2", -3.0, 1.5, 3)]


def test_evaluate_under_all_conditions_scores_each_and_their_mean():
    from conftest import compose_cfg
    from sweep.evaluate import FlightCondition, evaluate

    class Hover:   # a fixed policy: every rotor at the nominal hover speed
        def predict(self, obs, deterministic=True):
            p = crazyflie_params()
            a = rotor_speed_to_action(hover_rotor_speed(p), p["rotor_speed_min"], p["rotor_speed_max"])
            return np.full((len(obs), 4), a, np.float32), None

    cfg = compose_cfg(["eval.episodes=2"])
    conditions = [FlightCondition("c0", (0.0, 0.0, 0.0)), FlightCondition("c1", (0.0, 0.0, 0.0), VehicleSegment(1.5))]
    values, flights = evaluate(Hover(), cfg.eval, cfg.env, conditions)
    assert values["return"] == pytest.approx((values["c0/return"] + values["c1/return"]) / 2)
    assert values["c1/mse_z"] > values["c0/mse_z"]   # the heavier vehicle sinks at the nominal hover speed
    assert float(flights["c1_mass"]) == 1.5 and float(flights["mass"]) == 1.0
