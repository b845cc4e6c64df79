"""The env's observation, start and curriculum options (``env.observe``, ``env.start``, ``env.curriculum``): the
layout, the draws, the clock they run on, their checkpoint, the compiled collects against ``HoverVecEnv.step``, every
learner on the wider observation, and their config (one-line errors, job keys that stay put when they are off)."""
from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3.common.utils import configure_logger

from conftest import compose_cfg
from sweep.agents import build_learner
from sweep.checkpoint import job_key
from sweep.config import ConfigError, one_line, validate
from sweep.envs import HoverVecEnv, WindSchedule
from sweep.envs.factory import make_env, vehicle_schedule, wind_schedule
from sweep.envs.hover import observation_dim, rotor_speed_to_action

OBSERVE = dict(rotor_speeds=True, action_history=3)
START = dict(tilt_deg=60.0, velocity=1.0, body_rate=2.0)


def test_the_observation_is_the_state_then_rotor_speeds_then_the_last_actions_most_recent_first():
    env = HoverVecEnv(n_envs=2, seed=1, observe=OBSERVE)
    assert env.observation_space.shape == (13 + 4 + 12,) == (observation_dim("quaternion", True, 3),)
    obs = env.reset()
    hover = rotor_speed_to_action(env.hover_speed, env.speed_min, env.speed_max)
    np.testing.assert_allclose(obs[:, 13:], np.float32(hover), rtol=0, atol=0)   # at rest: rotors and history at hover
    actions = [np.array([[0.1, 0.2, 0.3, 0.4], [-1, -1, -1, -1]], np.float32), np.full((2, 4), 0.5, np.float32),
               np.full((2, 4), 2.0, np.float32)]
    for t, a in enumerate(actions):
        obs, _, dones, _ = env.step(a)
        assert not dones.any()
        np.testing.assert_array_equal(obs[:, 13:17], rotor_speed_to_action(env.sim.rotor_speeds, env.speed_min,
                                                                            env.speed_max).astype(np.float32))
        expected = [np.clip(actions[t - j], -1, 1) if t - j >= 0 else np.full((2, 4), hover, np.float32)
                    for j in range(3)]
        np.testing.assert_array_equal(obs[:, 17:], np.concatenate(expected, axis=1).astype(np.float32))
    assert not np.allclose(obs[:, 13:17], hover)   # the rotors follow the commands through their lag
    euler = HoverVecEnv(n_envs=1, observation="euler", observe=dict(action_history=2))
    assert euler.reset().shape == (1, 12 + 8)


def test_the_critics_columns_come_last_and_follow_the_condition():
    from sweep.envs.vehicle import VehicleSchedule, VehicleSegment
    env = HoverVecEnv(n_envs=2, seed=1, observe=dict(action_history=1, critic_rotor_speeds=True, critic_condition=True),
                      wind=WindSchedule([3.0, 1.0], segment_steps=20, direction=[0.0, 1.0, 0.0]),
                      vehicle=VehicleSchedule([VehicleSegment(1.0), VehicleSegment(1.5, (0.7, 1.0, 1.0, 1.0))],
                                              segment_steps=30))
    assert env.observation_space.shape == (13 + 4 + 4 + 8,) and env.actor_columns == 17
    obs = env.reset()
    np.testing.assert_array_equal(obs[:, 21:], np.float32([[0, 3, 0, 1, 1, 1, 1, 1]] * 2))
    rows = []
    for _ in range(20):   # 40 global steps: the wind changes at 20, the vehicle at 30
        obs, _, _, _ = env.step(np.full((2, 4), 0.43, np.float32))
        np.testing.assert_array_equal(obs[:, 17:21], rotor_speed_to_action(env.sim.rotor_speeds, env.speed_min,
                                                                            env.speed_max).astype(np.float32))
        rows.append(obs[0, 21:])
    assert rows[0].tolist() == [0, 3, 0, 1, 1, 1, 1, 1]          # the condition the step flew in
    assert rows[10].tolist() == [0, 1, 0, 1, 1, 1, 1, 1]          # global steps 20-21: the second wind
    assert rows[15].tolist() == pytest.approx([0, 1, 0, 1.5, 0.7, 1, 1, 1])   # 30-31: the second vehicle


def test_a_reset_on_a_segment_boundary_shows_the_condition_the_last_step_flew_in():
    """Episodes of 10 steps on 2 vehicles end at global step 20, where the wind changes: the terminal and the new
    start's observations both show the wind of the step just flown; the next step's, the new wind."""
    env = HoverVecEnv(n_envs=2, seed=1, episode_seconds=0.1, observe=dict(critic_condition=True),
                      wind=WindSchedule([3.0, 1.0], segment_steps=20))
    env.reset()
    hover = np.full((2, 4), rotor_speed_to_action(env.hover_speed, env.speed_min, env.speed_max), np.float32)
    for _ in range(10):
        obs, _, dones, infos = env.step(hover)
    assert dones.all() and env.global_step == 20
    assert [i["terminal_observation"][13] for i in infos] == [3.0, 3.0] and obs[:, 13].tolist() == [3.0, 3.0]
    obs, _, _, _ = env.step(hover)
    assert obs[:, 13].tolist() == [1.0, 1.0]


def test_the_paper_start_keeps_its_draws_and_the_wider_start_stays_in_its_bounds():
    paper, wide = HoverVecEnv(n_envs=64, seed=4), HoverVecEnv(n_envs=64, seed=4, start=START)
    paper.reset(), wide.reset()
    np.testing.assert_array_equal(paper.sim.x, wide.sim.x)   # the position first: the same numbers
    assert np.all(paper.sim.q == (0, 0, 0, 1)) and not paper.sim.v.any() and not paper.sim.w.any()
    q = wide.sim.q
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    assert np.all(q[:, 2] == 0)   # about a horizontal axis: no yaw component
    tilt = np.degrees(2 * np.arccos(q[:, 3]))
    assert tilt.max() <= 60.0 + 1e-9 and tilt.max() > 45 and tilt.min() < 15
    assert np.abs(wide.sim.v).max() <= 1.0 and np.abs(wide.sim.v).max() > 0.8
    assert np.abs(wide.sim.w).max() <= 2.0 and np.abs(wide.sim.w).max() > 1.6


def test_the_curriculum_and_the_wide_starts_are_for_training_only():
    env = HoverVecEnv(n_envs=256, seed=0, curriculum=dict(start_bound_from=0.2, steps=1000))
    assert [env.start_bound_at(g) for g in (0, 500, 1000, 5000)] == pytest.approx([0.2, 1.1, 2.0, 2.0])
    env.reset()
    assert np.abs(env.sim.x).max() <= 0.2
    env.global_step = 500
    env.reset()
    assert 0.9 < np.abs(env.sim.x).max() <= 1.1
    cfg = compose_cfg(["env.curriculum.start_bound_from=0.5", "env.curriculum.steps=100", "env.start.tilt_deg=60"])
    trained = make_env(cfg.env, 64, wind_schedule(cfg.wind), 0, learning=True)
    evaluated = make_env(cfg.env, 64, wind_schedule(cfg.wind), 0)
    trained.reset(), evaluated.reset()
    assert np.abs(trained.sim.x).max() <= 0.5 and np.abs(evaluated.sim.x).max() > 1.5
    assert (trained.sim.q[:, 3] < 0.99).any() and np.all(evaluated.sim.q == (0, 0, 0, 1))   # scored from the paper's


def test_a_restored_env_continues_the_action_history_and_the_curriculum():
    kwargs = dict(n_envs=3, seed=2, observe=OBSERVE, start=START, curriculum=dict(start_bound_from=0.1, steps=300),
                  episode_seconds=0.5)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (400, 3, 4)).astype(np.float32)
    env = HoverVecEnv(**kwargs)
    env.reset()
    for a in actions[:150]:
        env.step(a)
    state = env.get_state()
    copy = HoverVecEnv(**kwargs)
    copy.set_state(state)
    for a in actions[150:]:
        o1, r1, d1, _ = env.step(a)
        o2, r2, d2, _ = copy.step(a)
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)


@pytest.mark.parametrize("algorithm,critic", [("sac", False), ("td3", False), ("td3", True)])
def test_the_compiled_off_policy_collect_is_the_env_stepped_with_its_actions(algorithm, critic):
    """The JAX SAC/TD3 collect (numba) writes the transitions ``HoverVecEnv.step`` gives for the same actions: with the
    rotor speeds and the action history observed, wide starts and the curriculum, across crashes and time limits."""
    overrides = [f"agent={algorithm}", "agent.learner=jax", "agent.policy.net_arch=[16,16]",
                 f"agent.{algorithm}.learning_starts=100", f"agent.{algorithm}.batch_size=32",
                 f"agent.{algorithm}.round_steps=256", "env.episode_seconds=0.6", "env.n_envs=2",
                 "env.observe.rotor_speeds=true", "env.observe.action_history=3", "env.start.tilt_deg=80",
                 "env.start.velocity=1", "env.curriculum.start_bound_from=0.5", "env.curriculum.steps=600"]
    if critic:   # an asymmetric actor-critic under a wind and a vehicle that change
        overrides = [o for o in overrides if "rotor_speeds" not in o] + [
            "env.observe.critic_rotor_speeds=true", "env.observe.critic_condition=true", "wind=paper",
            "wind.segment_steps=300", "vehicle=payload", "vehicle.segment_steps=400"]
    cfg = compose_cfg(overrides)
    validate(cfg)

    def env():
        return make_env(cfg.env, 2, wind_schedule(cfg.wind), 7, learning=True, vehicle=vehicle_schedule(cfg.vehicle))
    model = build_learner(cfg.agent, env(), 7, 10_000)
    model.set_logger(configure_logger(0, None, "", False))
    total = model.begin(1024)
    while model.num_timesteps < total:
        model.collect()
        model.update()
    buf, steps = model.replay_buffer, model.replay_buffer.pos
    replay = env()
    obs = replay.reset()
    ends = 0
    for t in range(steps):
        np.testing.assert_array_equal(buf.observations[t], obs)
        obs, rewards, dones, infos = replay.step(buf.actions[t])
        next_obs = np.array([infos[i].get("terminal_observation", obs[i]) for i in range(2)])
        np.testing.assert_array_equal(buf.next_observations[t], next_obs)
        np.testing.assert_array_equal(buf.rewards[t], rewards)
        np.testing.assert_array_equal(buf.dones[t], dones)
        ends += dones.sum()
    assert ends > 10 and steps == 512


def trained_on(agent: str, learner: str, *options: str):
    """(learner of 8 x 8 units trained 256 steps on the hover env with ``options``, its env)."""
    steps = ["agent.ppo.n_steps=128", "agent.ppo.batch_size=64"] if agent == "ppo" else \
        [f"agent.{agent}.learning_starts=64", f"agent.{agent}.batch_size=32", f"agent.{agent}.round_steps=128"]
    cfg = compose_cfg([f"agent={agent}", f"agent.learner={learner}", "agent.policy.net_arch=[8,8]", *steps, *options])
    validate(cfg)
    env = make_env(cfg.env, 1, wind_schedule(cfg.wind), 0, learning=True)
    model = build_learner(cfg.agent, env, 0, 1000)
    model.set_logger(configure_logger(0, None, "", False))
    total = model.begin(256)
    while model.num_timesteps < total:
        model.collect()
        model.update()
    return model, env


@pytest.mark.parametrize("agent,learner", [(a, i) for a in ("ppo", "sac", "td3") for i in ("sb3", "jax")])
def test_every_learner_reads_the_wider_observation(agent, learner):
    model, env = trained_on(agent, learner, "env.observe.rotor_speeds=true", "env.observe.action_history=8")
    first = [v for k, v in model.parameter_arrays().items() if v.ndim == 2]
    assert 13 + 4 + 32 in {a.shape[1] for a in first}   # the contract lays weights out (out, in) on both
    assert model.predict(env.reset(), deterministic=True)[0].shape == (1, 4)


@pytest.mark.parametrize("layer_norm", [False, True])
@pytest.mark.parametrize("agent,learner", [(a, i) for a in ("ppo", "sac", "td3") for i in ("sb3", "jax")])
def test_an_asymmetric_actor_reads_its_columns_the_critic_all_and_the_saved_zip_is_sb3s(agent, learner, layer_norm,
                                                                                       tmp_path):
    """env.observe.critic_*: the actor's first layer takes the leading actor_columns, the critics' all; the diagnostics
    and the probe run; the saved model loads with SB3's own class and acts the same."""
    from stable_baselines3 import PPO, SAC, TD3
    from sweep.plasticity.probe import probe_fit
    model, _ = trained_on(agent, learner, f"agent.policy.layer_norm={layer_norm}", "env.observe.action_history=2",
                          "env.observe.critic_rotor_speeds=true", "env.observe.critic_condition=true")
    actor, critic = 13 + 8, 13 + 8 + 4 + 8
    arrays = model.parameter_arrays()
    first = {net.name: arrays[f"{net.hidden[0]}.weight"].shape[1] for net in model.networks}
    assert first == ({"policy": actor, "value": critic} if agent == "ppo" else
                     {"actor": actor, "critic_0": critic + 4, "critic_1": critic + 4})
    obs = np.random.default_rng(0).normal(size=(64, critic)).astype(np.float32)
    hidden = model.hidden_activations(obs)
    assert all(h.pre.shape == (64, 8) for layers in hidden.values() for h in layers)
    assert np.isfinite(probe_fit(model, obs, steps=5, batch_size=16)).all()
    model.save(tmp_path / "model.zip")
    loaded = {"ppo": PPO, "sac": SAC, "td3": TD3}[agent].load(tmp_path / "model.zip", device="cpu")
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0],
                               atol=1e-5)
    changed = obs.copy()
    changed[:, actor:] += 5.0   # what only the critic sees does not move the actor
    np.testing.assert_array_equal(model.predict(changed, deterministic=True)[0], model.predict(obs, deterministic=True)[0])


@pytest.mark.parametrize("override,message", [
    ("env.observe.critic_rotor_speeds=true,env.observe.rotor_speeds=true",
     "env.observe.critic_rotor_speeds=true: must be false with env.observe.rotor_speeds=true"),
    ("env.curriculum.start_bound_from=3", "env.curriculum.start_bound_from=3: must be <= env.start_bound=2"),
    ("env.observe.action_history=-1", "env.observe.action_history=-1: must be an integer >= 0"),
    ("env.observe.rotor_speeds=maybe", "env.observe.rotor_speeds"),
    ("env.start.tilt_deg=200", "env.start.tilt_deg=200: must be a number in [0, 180] (degrees)"),
    ("env.start.velocity=-1", "env.start.velocity=-1: must be a number in [0, 100) (m/s"),
    ("env.start.body_rate=100", "env.start.body_rate=100: must be a number in [0, 100) (rad/s"),
    ("env.curriculum.start_bound_from=-0.5", "env.curriculum.start_bound_from=-0.5: must be a number >= 0 (m) or null"),
    ("env.curriculum.steps=0", "env.curriculum.steps=0: must be an integer > 0"),
])
def test_a_bad_option_is_one_line(override, message):
    with pytest.raises(ConfigError) as err:
        validate(compose_cfg(override.split(",")))
    assert message in one_line(err.value) and "\n" not in one_line(err.value)


def test_the_options_enter_the_job_key_only_when_on():
    key = lambda *o: job_key(compose_cfg(list(o)), "sqlite:///x.db")  # noqa: E731
    base = key()
    assert key("env.curriculum.steps=5") == base == key("env.start.tilt_deg=0", "env.observe.action_history=0")
    on = ["env.observe.rotor_speeds=true", "env.observe.action_history=8", "env.observe.critic_rotor_speeds=true",
          "env.observe.critic_condition=true", "env.start.tilt_deg=30",
          "env.start.velocity=0.5", "env.curriculum.start_bound_from=0.2"]
    assert len({base, *(key(o) for o in on)}) == len(on) + 1
