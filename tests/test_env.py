"""The hover task on RotorPy's physics: reward, wind schedule, hover, terminations and truncations."""
from __future__ import annotations

import numpy as np
import pytest

from sweep.envs import HoverVecEnv, WindSchedule
from sweep.envs.reward import HoverReward
from sweep.envs.vehicle import crazyflie_params, hover_rotor_speed


def hover_action(env: HoverVecEnv) -> np.ndarray:
    a = 2 * (env.hover_speed - env.speed_min) / (env.speed_max - env.speed_min) - 1
    return np.full((env.num_envs, 4), a, dtype=np.float32)


def test_reward_matches_paper_formula_by_hand():
    r = HoverReward(w_p=1.0, w_v=0.5, w_a=1e-5)
    p = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]])       # |p| = 5, 0
    v = np.array([[0.0, 0.0, 2.0], [1.0, 2.0, 2.0]])       # |v| = 2, 3
    a = np.array([[1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.0]])  # |a| = 2, 0
    np.testing.assert_allclose(r(p, v, a), [-(5 + 0.5 * 2 + 1e-5 * 2), -(0.5 * 3)])


def test_reward_weights_are_table_one():
    assert HoverReward() == HoverReward(w_p=1.0, w_v=0.5, w_a=1e-5, alive_bonus=0.0, crash_penalty=0.0)


def test_alive_bonus_and_crash_penalty():
    env = HoverVecEnv(n_envs=2, wind=WindSchedule(speeds=[0.0]), seed=0,
                      reward=HoverReward(alive_bonus=2.0, crash_penalty=100.0))
    env.reset()
    actions = hover_action(env)
    actions[0] = 1.0  # vehicle 0 climbs out of the box
    for _ in range(500):
        obs, rewards, dones, infos = env.step(actions)
        if dones[0]:
            break
    final = np.stack([infos[0]["terminal_observation"], obs[1]])
    plain = HoverReward()(final[:, :3], final[:, 3:6], actions)
    np.testing.assert_allclose(rewards, plain + 2.0 - np.array([100.0, 0.0]), rtol=1e-5)


@pytest.mark.parametrize("step,speed", [(0, 3.0), (1_999_999, 3.0), (2_000_000, 2.0), (4_000_000, 2.5),
                                        (6_000_000, 1.5), (8_000_000, 2.5), (10_000_000, 3.0),
                                        (19_999_999, 2.5)])
def test_paper_wind_schedule(step, speed):
    wind = WindSchedule(speeds=[3.0, 2.0, 2.5, 1.5, 2.5], segment_steps=2_000_000, direction=[2.0, 0.0, 0.0])
    assert wind.speed_at(step) == speed
    np.testing.assert_allclose(wind.velocity_at(step), [speed, 0.0, 0.0])


def test_wind_follows_global_steps_across_envs():
    wind = WindSchedule(speeds=[1.0, 2.0], segment_steps=8)
    env = HoverVecEnv(n_envs=4, wind=wind, seed=0)
    env.reset()
    seen = []
    for _ in range(4):  # global steps 0, 4, 8, 12
        seen.append(wind.speed_at(env.global_step))
        env.step(hover_action(env))
    assert seen == [1.0, 1.0, 2.0, 2.0] and env.global_step == 16


def test_crazyflie_params_from_rotorpy_with_paper_motor_constant():
    p = crazyflie_params(0.05)
    assert p["tau_m"] == 0.05 and p["mass"] == 0.03 and p["Ixx"] == 1.43e-5 and p["rotor_speed_max"] == 2500
    assert hover_rotor_speed(p) == pytest.approx(1788.5, abs=0.5)


BACKENDS = ["rotorpy", "fast"]


@pytest.mark.parametrize("backend", BACKENDS)
def test_hover_action_without_wind_stays_near_start_for_one_second(backend):
    env = HoverVecEnv(n_envs=3, backend=backend, wind=WindSchedule(speeds=[0.0]), seed=3)
    obs = env.reset()
    start = obs[:, :3].copy()
    for _ in range(100):
        obs, _, dones, _ = env.step(hover_action(env))
        assert not dones.any()
    assert np.abs(obs[:, :3] - start).max() < 0.01


@pytest.mark.parametrize("backend", BACKENDS)
def test_wind_pushes_the_vehicle_downwind(backend):
    env = HoverVecEnv(n_envs=1, backend=backend, wind=WindSchedule(speeds=[3.0], direction=[1, 0, 0]), seed=3)
    obs = env.reset()
    x0 = obs[0, 0]
    for _ in range(100):
        obs, *_ = env.step(hover_action(env))
    assert obs[0, 0] - x0 > 0.05


@pytest.mark.parametrize("backend", BACKENDS)
def test_time_limit_is_per_env_truncation_with_own_terminal_observation(backend):
    env = HoverVecEnv(n_envs=3, backend=backend, wind=WindSchedule(speeds=[0.0]), seed=1, episode_seconds=0.2)
    env.reset()
    for step in range(1, 21):
        before = env.sim.x.copy()
        obs, rewards, dones, infos = env.step(hover_action(env))
        if step < 20:
            assert not dones.any()
    assert dones.all()
    terminal = np.stack([info["terminal_observation"] for info in infos])
    assert all(info["TimeLimit.truncated"] for info in infos)
    np.testing.assert_allclose(terminal[:, :3], before, atol=0.01)   # each env's own last state
    assert len({tuple(t[:3]) for t in terminal}) == 3                # not one env's state copied to all
    assert not np.allclose(obs[:, :3], terminal[:, :3])               # obs are the reset starts
    assert all(info["episode"]["l"] == 20 for info in infos)
    np.testing.assert_allclose(rewards, HoverReward()(terminal[:, :3], terminal[:, 3:6], hover_action(env)), rtol=1e-5)


def test_episode_is_exactly_500_steps():
    env = HoverVecEnv(n_envs=1, wind=WindSchedule(speeds=[0.0]), seed=0)
    env.reset()
    for step in range(1, 501):
        _, _, dones, infos = env.step(hover_action(env))
        if dones[0]:
            break
    assert step == 500 and infos[0]["TimeLimit.truncated"]


@pytest.mark.parametrize("backend", BACKENDS)
def test_out_of_bounds_is_termination_not_truncation(backend):
    env = HoverVecEnv(n_envs=2, backend=backend, wind=WindSchedule(speeds=[0.0]), seed=0)
    env.reset()
    actions = hover_action(env)
    actions[0] = 1.0  # full throttle on vehicle 0: climbs out of the +-4 m box
    for _ in range(500):
        _, _, dones, infos = env.step(actions)
        if dones[0]:
            break
    assert dones[0] and not dones[1]
    assert infos[0]["TimeLimit.truncated"] is False
    assert infos[0]["terminal_observation"][2] > 4.0


def test_euler_observation_is_twelve_dimensional():
    env = HoverVecEnv(n_envs=2, observation="euler", seed=0)
    assert env.reset().shape == (2, 12)


def test_same_seed_same_starts():
    a, b = HoverVecEnv(n_envs=4, seed=7).reset(), HoverVecEnv(n_envs=4, seed=7).reset()
    np.testing.assert_array_equal(a, b)
    assert np.abs(a[:, :3]).max() <= 2.0
