"""The hover task on RotorPy's physics: reward, wind schedule, hover, terminations and truncations."""
from __future__ import annotations

import numpy as np
import pytest

from sweep.envs import HoverVecEnv, WindSchedule
from sweep.envs.hover import action_to_rotor_speed, rotor_speed_to_action
from sweep.envs.reward import HoverReward
from sweep.envs.vehicle import crazyflie_params, hover_rotor_speed


def hover_action(env: HoverVecEnv) -> np.ndarray:
    a = rotor_speed_to_action(env.hover_speed, env.speed_min, env.speed_max)
    return np.full((env.num_envs, 4), a, dtype=np.float32)


def test_reward_matches_paper_formula_by_hand():
    r = HoverReward(w_p=1.0, w_v=0.5, w_a=1e-5)
    p = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]])       # |p| = 5, 0
    v = np.array([[0.0, 0.0, 2.0], [1.0, 2.0, 2.0]])       # |v| = 2, 3
    a = np.array([[1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.0]])  # |a| = 2, 0
    np.testing.assert_allclose(r(p, v, a), [-(5 + 0.5 * 2 + 1e-5 * 2), -(0.5 * 3)])


def test_reward_weights_are_table_one_and_a_crash_gets_rotorpys_minus_500():
    assert HoverReward() == HoverReward(w_p=1.0, w_v=0.5, w_a=1e-5, alive_bonus=0.0, crash_reward=-500.0)
    p, v, a = np.ones((2, 3)), np.zeros((2, 3)), np.zeros((2, 4))
    np.testing.assert_allclose(HoverReward()(p, v, a, crashed=np.array([True, False])), [-500.0, -np.sqrt(3)])
    np.testing.assert_allclose(HoverReward(crash_reward=None)(p, v, a, crashed=np.array([True, False])),
                               [-np.sqrt(3), -np.sqrt(3)])


def test_crash_step_reward_is_replaced_and_alive_bonus_added_to_the_others():
    env = HoverVecEnv(n_envs=2, wind=WindSchedule(speeds=[0.0]), seed=0,
                      reward=HoverReward(alive_bonus=2.0, crash_reward=-123.0))
    env.reset()
    actions = hover_action(env)
    actions[0] = 1.0  # vehicle 0 climbs out of the box
    for _ in range(500):
        obs, rewards, dones, infos = env.step(actions)
        if dones[0]:
            break
    assert dones[0] and infos[0]["crashed"] and not dones[1]
    plain = HoverReward(crash_reward=None)(obs[1:, :3], obs[1:, 3:6], actions[1:])
    np.testing.assert_allclose(rewards, [-123.0, plain[0] + 2.0], rtol=1e-5)


@pytest.mark.parametrize("crash_reward", [-500.0, None])
def test_episode_return_is_the_sum_of_its_step_rewards(crash_reward):
    env = HoverVecEnv(n_envs=3, wind=WindSchedule(speeds=[2.0]), seed=4, reward=HoverReward(crash_reward=crash_reward))
    env.reset()
    rng = np.random.default_rng(0)
    sums, finished = np.zeros(3), []
    for _ in range(700):
        actions = np.clip(hover_action(env) + rng.normal(scale=0.3, size=(3, 4)), -1, 1).astype(np.float32)
        _, rewards, dones, infos = env.step(actions)
        sums += rewards
        for i in np.flatnonzero(dones):
            finished.append((infos[i]["episode"]["r"], sums[i], infos[i]["crashed"]))
            sums[i] = 0.0
    assert len(finished) >= 3 and any(c for *_, c in finished)  # crashes included
    for logged, summed, _ in finished:
        assert logged == pytest.approx(summed, rel=1e-6, abs=1e-4)


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


def test_action_to_rotor_speed_is_linear_onto_the_rotor_range_and_inverted_by_rotor_speed_to_action():
    p = crazyflie_params(0.05)
    lo, hi = float(p["rotor_speed_min"]), float(p["rotor_speed_max"])
    a = np.linspace(-1.0, 1.0, 101)
    speeds = action_to_rotor_speed.py_func(a, lo, hi)
    assert (speeds[0], speeds[50], speeds[-1]) == (lo, (lo + hi) / 2, hi)
    np.testing.assert_allclose(np.diff(speeds), (hi - lo) / 100, rtol=1e-9)
    np.testing.assert_allclose(rotor_speed_to_action(speeds, lo, hi), a, atol=1e-12)
    # the compiled rule (the rollout's, on the policy's float32 actions) is the env's NumPy rule bit for bit
    a32 = np.random.default_rng(0).uniform(-1.0, 1.0, 1000).astype(np.float32)
    compiled = np.array([action_to_rotor_speed(x, lo, hi) for x in a32])
    np.testing.assert_array_equal(compiled, action_to_rotor_speed.py_func(a32.astype(np.float64), lo, hi))


from conftest import backend as backend_class  # noqa: E402

BACKENDS = ["rotorpy", "fast"]


@pytest.mark.parametrize("backend", BACKENDS)
def test_hover_action_without_wind_stays_near_start_for_one_second(backend):
    env = HoverVecEnv(n_envs=3, backend=backend_class(backend), wind=WindSchedule(speeds=[0.0]), seed=3)
    obs = env.reset()
    start = obs[:, :3].copy()
    for _ in range(100):
        obs, _, dones, _ = env.step(hover_action(env))
        assert not dones.any()
    assert np.abs(obs[:, :3] - start).max() < 0.01


@pytest.mark.parametrize("backend", BACKENDS)
def test_wind_pushes_the_vehicle_downwind(backend):
    env = HoverVecEnv(n_envs=1, backend=backend_class(backend), wind=WindSchedule(speeds=[3.0], direction=[1, 0, 0]), seed=3)
    obs = env.reset()
    x0 = obs[0, 0]
    for _ in range(100):
        obs, *_ = env.step(hover_action(env))
    assert obs[0, 0] - x0 > 0.05


@pytest.mark.parametrize("backend", BACKENDS)
def test_time_limit_is_per_env_truncation_with_own_terminal_observation(backend):
    env = HoverVecEnv(n_envs=3, backend=backend_class(backend), wind=WindSchedule(speeds=[0.0]), seed=1, episode_seconds=0.2)
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
    env = HoverVecEnv(n_envs=2, backend=backend_class(backend), wind=WindSchedule(speeds=[0.0]), seed=0)
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


def test_euler_observation_is_scipys_xyz_angles_of_the_attitude():
    from scipy.spatial.transform import Rotation

    env = HoverVecEnv(n_envs=64, observation="euler", wind=WindSchedule(speeds=[0.0]), seed=0)
    assert env.reset().shape == (64, 12)
    rng = np.random.default_rng(1)
    obs = None
    for _ in range(30):  # random actions tumble the vehicles into varied attitudes
        obs, _, dones, _ = env.step(rng.uniform(-1, 1, size=(64, 4)).astype(np.float32))
    alive = ~dones
    expected = Rotation.from_quat(env.sim.q[alive]).as_euler("xyz")
    assert np.abs(expected).max() > 0.5  # the check covers large angles, not only near-level flight
    np.testing.assert_allclose(obs[alive, 6:9], expected, atol=1e-5)
    np.testing.assert_allclose(obs[alive, 9:12], env.sim.w[alive], rtol=1e-6)


def test_time_limit_terminate_ends_the_episode_as_a_termination_not_a_crash():
    env = HoverVecEnv(n_envs=2, wind=WindSchedule(speeds=[0.0]), seed=1, episode_seconds=0.2, time_limit="terminate")
    env.reset()
    for _ in range(20):
        _, _, dones, infos = env.step(hover_action(env))
    assert dones.all()
    assert all(info["TimeLimit.truncated"] is False and info["crashed"] is False for info in infos)
    assert all(info["episode"]["l"] == 20 for info in infos)


def test_same_seed_same_starts():
    a, b = HoverVecEnv(n_envs=4, seed=7).reset(), HoverVecEnv(n_envs=4, seed=7).reset()
    np.testing.assert_array_equal(a, b)
    assert np.abs(a[:, :3]).max() <= 2.0


def test_observation_scale_multiplies_velocity_and_body_rates_only():
    kwargs = dict(n_envs=3, wind=WindSchedule(speeds=[2.0]), seed=5)
    raw, scaled = HoverVecEnv(**kwargs), HoverVecEnv(**kwargs, observation_scale={"velocity": 0.5, "body_rate": 0.1})
    raw.reset(), scaled.reset()
    rng = np.random.default_rng(0)
    for _ in range(40):
        a = rng.uniform(-1, 1, size=(3, 4)).astype(np.float32)
        o1, r1, *_ = raw.step(a)
        o2, r2, *_ = scaled.step(a)
    np.testing.assert_array_equal(r1, r2)  # the task is the same; only what the policy sees changes
    np.testing.assert_allclose(o2[:, :3], o1[:, :3])
    np.testing.assert_allclose(o2[:, 3:6], 0.5 * o1[:, 3:6], rtol=1e-6)
    np.testing.assert_allclose(o2[:, 6:10], o1[:, 6:10])
    np.testing.assert_allclose(o2[:, 10:13], 0.1 * o1[:, 10:13], rtol=1e-6)
    assert np.abs(o1[:, 10:13]).max() > 1.0


def test_reward_scale_scales_what_the_learner_gets_not_the_logged_return():
    kwargs = dict(n_envs=2, wind=WindSchedule(speeds=[1.0]), seed=2, episode_seconds=0.3)
    plain, scaled = HoverVecEnv(**kwargs), HoverVecEnv(**kwargs, reward_scale=0.01)
    plain.reset(), scaled.reset()
    a = hover_action(plain)
    for _ in range(30):
        _, r1, d1, i1 = plain.step(a)
        _, r2, d2, i2 = scaled.step(a)
        np.testing.assert_allclose(r2, 0.01 * r1, rtol=1e-6)
    assert d1.all() and d2.all()
    assert [i["episode"]["r"] for i in i2] == [i["episode"]["r"] for i in i1]


def test_wind_after_the_list_repeats_or_holds():
    """wind.after_list: the paper's five speeds over 20M steps, read as repeating (default) or holding the last."""
    speeds = [3.0, 2.0, 2.5, 1.5, 2.5]
    repeat = WindSchedule(speeds, 2_000_000, after_list="repeat")
    hold = WindSchedule(speeds, 2_000_000, after_list="hold")
    steps = np.arange(0, 20_000_000, 1_000_000)
    assert [repeat.speed_at(s) for s in steps] == [s for s in speeds for _ in (0, 1)] * 2
    assert [hold.speed_at(s) for s in steps] == [s for s in speeds for _ in (0, 1)] + [2.5] * 10
    for w in (repeat, hold):   # the compiled rollout's vectorised lookup agrees with the scalar one
        np.testing.assert_array_equal(w.velocities(steps)[:, 0], [w.speed_at(s) for s in steps])
