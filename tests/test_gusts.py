"""Dryden turbulence (sweep.envs.gusts) against RotorPy 3.0's own DrydenGust, and its way through the env, the
checkpoint, the evaluation, the config and the Gymnasium env."""
from __future__ import annotations

import numpy as np
import pytest
from rotorpy.wind.dryden_winds import DrydenGust

from sweep.envs.gusts import add_gusts, new_gusts, realised_std, scale_lengths
from sweep.envs.hover import HoverVecEnv, rotor_speed_to_action
from sweep.envs.wind import WindSchedule


@pytest.mark.parametrize("dt,altitude,sigma", [(0.01, 2.0, 1.0), (0.002, 5.0, 30.0)])
def test_the_gusts_are_rotorpys_dryden_gusts(dt, altitude, sigma):
    """Fed RotorPy's own uniform draws (its global NumPy RNG, one per axis per step), the filter gives RotorPy's
    DrydenGust wind, its mean wind plus the gusts, over 3000 steps."""
    mean = np.array([3.0, -1.0, 0.5])
    np.random.seed(11)
    rotorpy = DrydenGust(dt=dt, avg_wind=mean, sig_wind=np.full(3, sigma), altitude=altitude)
    want = np.array([rotorpy.update(0.0, None) for _ in range(3000)])
    np.random.seed(11)
    draws = np.random.uniform(-1.0, 1.0, (3000, 3))
    filters, got = new_gusts(1, dt, altitude), np.empty((3000, 3))
    for k in range(3000):
        wind = mean[None].copy()
        add_gusts(filters, draws[k][None], sigma, wind)
        got[k] = wind[0]
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    assert np.abs(got - mean).max() > 0.01 * sigma   # not a zero filter


def test_the_realised_spread_is_far_below_sigma():
    """RotorPy's sig_wind is not the spread: at 100 Hz and 2 m the stationary std is 0.0326 m/s per unit sigma
    (the impulse-response sum), which 256 vehicles' draws reproduce within 5% after 150 s (the x and y filters'
    time constant 2 L / V is 31 s)."""
    np.testing.assert_allclose(scale_lengths(2.0), [15.41, 15.41, 2.0], atol=0.01)
    std = realised_std(0.01, 2.0)
    np.testing.assert_allclose(std, 0.0326, atol=0.0005)
    filters, rng = new_gusts(256, 0.01), np.random.default_rng(0)
    samples = np.zeros((20000, 256, 3))
    for k in range(20000):
        add_gusts(filters, rng.uniform(-1.0, 1.0, (256, 3)), 1.0, samples[k])
    np.testing.assert_allclose(samples[15000:].std(axis=(0, 1)), std, rtol=0.05)
    np.testing.assert_allclose(realised_std(0.002, 2.0), std / np.sqrt(5), rtol=0.01)   # draws not scaled by dt: std ~ sqrt(dt)


def test_a_new_env_flies_settled_gusts_from_its_first_step():
    """An evaluation's env is new: its gusts must have training's spread at once, not start at rest (the x/y filters'
    time constant, 31 s, is longer than an episode). 2000 vehicles' first-step gusts have the stationary std."""
    env = HoverVecEnv(n_envs=2000, seed=3, wind=WindSchedule.steady([0.0, 0.0, 0.0], gust=1.0))
    env.reset()
    env.step(np.zeros((2000, 4)))
    np.testing.assert_allclose(env._wind_now.std(axis=0), realised_std(0.01), rtol=0.06)
    again = HoverVecEnv(n_envs=2000, seed=3, wind=WindSchedule.steady([0.0, 0.0, 0.0], gust=1.0))
    again.reset()
    again.step(np.zeros((2000, 4)))
    np.testing.assert_array_equal(again._wind_now, env._wind_now)   # the same seed, the same gusts


def test_a_turbulent_env_gives_each_vehicle_its_own_gusts_and_resumes_them():
    wind = WindSchedule([3.0, 3.0], segment_steps=8, gusts=[0.0, 40.0])
    assert wind.turbulent and wind.varies and not WindSchedule([3.0]).turbulent
    env = HoverVecEnv(n_envs=3, seed=5, wind=wind)
    env.reset()
    hover = np.full((3, 4), rotor_speed_to_action(env.hover_speed, env.speed_min, env.speed_max))
    winds = []
    for _ in range(5):
        env.step(hover)
        winds.append(env._wind_now.copy())
    np.testing.assert_array_equal(winds[0], np.tile([3.0, 0.0, 0.0], (3, 1)))   # calm segment: the mean wind
    assert env.condition().gust == 40.0 and env.condition().metrics()["env/gust_sigma"] == 40.0
    assert len({tuple(w) for w in winds[4]}) == 3 and not np.allclose(winds[4], winds[3])  # per vehicle, per step
    state = env.get_state()
    other = HoverVecEnv(n_envs=3, seed=6, wind=wind)
    other.set_state(state)
    for e in (env, other):
        for _ in range(4):
            e.step(hover)
    np.testing.assert_array_equal(other._wind_now, env._wind_now)
    np.testing.assert_array_equal(other.sim.x, env.sim.x)


def test_calm_runs_draw_no_gusts():
    """A wind without gusts leaves the gust stream untouched and steps the mean wind (every run before the gusts)."""
    env = HoverVecEnv(n_envs=2, seed=0, wind=WindSchedule([3.0]))
    env.reset()
    before = env._gust_rng.bit_generator.state
    env.step(np.zeros((2, 4)))
    assert env._gust_rng.bit_generator.state == before
    assert env.condition().metrics()["env/gust_sigma"] == 0.0


def test_evaluations_fly_the_gusts_of_their_condition():
    """``eval.gust`` (fixed) and the schedule's gusts (current, all) reach the evaluation's env; a gust changes the
    flights, and the same eval seed flies the same gusts."""
    from conftest import compose_cfg
    from sweep.evaluate import FlightCondition, flight_conditions, fly_protocol

    cfg = compose_cfg(["wind=gusts", "eval.episodes=3", "eval.gust=20"])
    (fixed,) = flight_conditions(cfg.eval, cfg.wind, cfg.vehicle, 0, 4_000_000)
    assert fixed.gust == 20.0
    cfg.eval.condition = "all"
    assert [(c.name, c.gust) for c in flight_conditions(cfg.eval, cfg.wind, cfg.vehicle, 0, 4_000_000)] == [
        ("c0", 0.0), ("c1", 60.0)]

    class Hover:
        def predict(self, obs, deterministic=True):
            return np.zeros((len(obs), 4), np.float32), None

    calm = fly_protocol(Hover(), cfg.eval, cfg.env, FlightCondition("a", (3.0, 0.0, 0.0)))[1]
    gusty = fly_protocol(Hover(), cfg.eval, cfg.env, FlightCondition("b", (3.0, 0.0, 0.0), gust=200.0))[1]
    again = fly_protocol(Hover(), cfg.eval, cfg.env, FlightCondition("b", (3.0, 0.0, 0.0), gust=200.0))[1]
    assert not np.array_equal(calm["positions"], gusty["positions"])
    np.testing.assert_array_equal(gusty["positions"], again["positions"])
    assert float(gusty["gust"]) == 200.0


@pytest.mark.parametrize("override,message", [
    ("wind.gusts=[1.0]", "wind.gusts: 1 sigmas for 2 speeds"),
    ("wind.gusts=[0.0,-1.0]", "wind.gusts"),
    ("eval.gust=-1", "eval.gust"),
    ("env.sim_rate=10", "env.sim_rate=10 with Dryden gusts"),
])
def test_bad_gusts_are_one_line_config_errors(override, message):
    from conftest import compose_cfg
    from sweep.config import ConfigError, validate

    with pytest.raises(ConfigError, match=message.replace("[", r"\[")):
        validate(compose_cfg(["wind=gusts", override]))


def test_the_gymnasium_env_takes_gusts():
    import gymnasium
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make("sweep.envs:CrazyflieHover-v0", wind_speeds=[3.0], wind_gusts=[30.0])
    check_env(env.unwrapped)
    env.reset(seed=1)
    _, _, _, _, info = env.step(np.zeros(4, np.float32))
    assert info["condition"].gust == 30.0
