"""The reward form and the termination radius of "Learning to Fly in Seconds" (``env.reward.power``, ``w_q``,
``action_reference``; ``env.terminate_radius``) and its preset ``experiment=anchor_task``: the preset's reward is the
anchor's formula, the radius ends training episodes only, the compiled collects step the same task as
``HoverVecEnv.step``, both learners train on it, and the options switched off leave job keys where they were."""
from __future__ import annotations

import math

import numpy as np
import pytest
from omegaconf import open_dict
from stable_baselines3.common.utils import configure_logger

from conftest import compose_cfg
from sweep.agents import build_learner
from sweep.checkpoint import job_key
from sweep.config import ConfigError, one_line, validate
from sweep.envs.factory import make_env, wind_schedule
from sweep.envs.reward import HoverReward

ANCHOR = ["experiment=anchor_task"]


def anchor_formula(p, v, a, q_w, hover):
    """The anchor's reward as its paper writes it (../shared/NOTES.md): 2 - 0.5 (Cp|p|^2 + 5(1 - q_w^2) + Cv|v|^2 +
    Ca|a - hover|^2), Cp 5, Cv = Ca = 0.01 (the curriculum's start)."""
    return 2 - 0.5 * (5 * (p ** 2).sum(1) + 5 * (1 - q_w ** 2) + 0.01 * (v ** 2).sum(1)
                      + 0.01 * ((a - hover) ** 2).sum(1))


def test_the_presets_weights_squared_are_the_anchors_formula():
    """The preset's weights with the anchor's squared costs (env.reward.power=2; the preset's own power is 1,
    measured in docs/anchor_task.md) give the anchor's reward."""
    assert compose_cfg(ANCHOR).env.reward.power == 1
    reward = HoverReward(**compose_cfg(ANCHOR + ["env.reward.power=2"]).env.reward)
    rng = np.random.default_rng(0)
    p, v, a = rng.normal(size=(50, 3)), rng.normal(size=(50, 3)), rng.uniform(-1, 1, (50, 4))
    q_w, hover = rng.uniform(-1, 1, 50), -0.27
    np.testing.assert_allclose(reward(p, v, a, q_w=q_w, hover_action=hover), anchor_formula(p, v, a, q_w, hover),
                               rtol=1e-12)
    crashed = np.zeros(50, bool)
    crashed[:5] = True   # crash_reward null: a crash step keeps the formula (the anchor has no crash penalty)
    np.testing.assert_allclose(reward(p, v, a, crashed=crashed, q_w=q_w, hover_action=hover),
                               anchor_formula(p, v, a, q_w, hover), rtol=1e-12)


def test_the_papers_reward_ignores_the_attitude_and_each_option_changes_only_its_term():
    p, v, a = np.array([[3.0, 4.0, 0.0]]), np.array([[0.0, 0.0, 2.0]]), np.array([[1.0, 1.0, 1.0, 1.0]])
    paper = HoverReward()(p, v, a)
    assert HoverReward()(p, v, a, q_w=np.array([0.3])) == paper
    np.testing.assert_allclose(HoverReward(power=2)(p, v, a), -(25 + 0.5 * 4 + 1e-5 * 4))
    np.testing.assert_allclose(HoverReward(w_q=2.0)(p, v, a, q_w=np.array([0.6])), paper - 2.0 * (1 - 0.36))
    np.testing.assert_allclose(HoverReward(action_reference="hover")(p, v, a, hover_action=0.5),
                               -(5 + 0.5 * 2 + 1e-5 * 1.0))
    with pytest.raises(ValueError, match="power=3"):
        HoverReward(power=3)


def test_the_radius_ends_a_training_episode_as_a_crash_and_evaluations_keep_the_world_bound():
    cfg = compose_cfg(ANCHOR + ["env.start.tilt_deg=0", "env.start.velocity=0", "env.start.body_rate=0"])
    trained = make_env(cfg.env, 8, wind_schedule(cfg.wind), 0, learning=True)
    evaluated = make_env(cfg.env, 8, wind_schedule(cfg.wind), 0)
    assert trained.terminate_radius == 0.6 and evaluated.terminate_radius == math.inf
    for env in (trained, evaluated):
        env.reset()
        env.sim.x[:4] = [[0.5, 0.0, 0.0], [0.0, 0.0, -0.59], [0.4, 0.4, 0.3], [0.0, 0.7, 0.0]]   # |p| < .6, > .6
    actions = np.full((8, 4), trained.hover_action, np.float32)
    _, _, dones, infos = trained.step(actions)
    assert dones.tolist()[:4] == [False, False, True, True] and not dones[4:].any()   # +-0.2 m starts stay inside
    assert infos[2]["crashed"] and infos[3]["crashed"] and not infos[2]["TimeLimit.truncated"]
    _, _, dones, _ = evaluated.step(actions)
    assert not dones.any()


def test_the_env_rewards_each_step_with_its_attitude_and_the_hover_command():
    """HoverVecEnv.step's reward under the preset's weights squared is the formula on the state it returns: its
    attitude's q_w (observation column 9) and the nominal hover command, for tilted and yawed starts."""
    cfg = compose_cfg(ANCHOR + ["env.reward.power=2"])
    env = make_env(cfg.env, 16, wind_schedule(cfg.wind), 3, learning=True)
    obs = env.reset()
    assert (np.abs(obs[:, 9]) < 0.99).any()   # the starts are tilted up to 90 deg
    rng = np.random.default_rng(1)
    for _ in range(20):
        actions = np.clip(env.hover_action + rng.normal(0, 0.3, (16, 4)), -1, 1).astype(np.float32)
        obs, rewards, dones, infos = env.step(actions)
        state = np.array([infos[i]["terminal_observation"] if dones[i] else obs[i] for i in range(16)])
        expected = anchor_formula(state[:, :3].astype(float), state[:, 3:6].astype(float), actions.astype(float),
                                  state[:, 9].astype(float), env.hover_action)
        np.testing.assert_allclose(rewards, expected, rtol=1e-5, atol=1e-5)


def replay_compiled_collect(algorithm: str, overrides: list[str], learning_starts: int = 100):
    """A JAX learner's first compiled collect (PPO: one rollout of 256 vector steps; TD3: turns until 256 rows) on the
    anchor's task (2 vehicles, 0.6 s episodes), each transition checked against ``HoverVecEnv.step`` flown with its
    actions from the same seed: observation and reward equal. Returns (the learner, the crashes flown)."""
    steps = ["agent.ppo.n_steps=256", "agent.ppo.batch_size=64"] if algorithm == "ppo" else \
        [f"agent.td3.learning_starts={learning_starts}", "agent.td3.batch_size=32", "agent.td3.round_steps=256"]
    cfg = compose_cfg(ANCHOR + [f"agent={algorithm}", "agent.learner=jax", "agent.policy.net_arch=[16,16]",
                                "env.episode_seconds=0.6", "env.n_envs=2", *steps, *overrides])
    validate(cfg)

    def env():
        return make_env(cfg.env, 2, wind_schedule(cfg.wind), 5, learning=True)
    model = build_learner(cfg.agent, env(), 5, 10_000)
    model.set_logger(configure_logger(0, None, "", False))
    model.begin(512)
    model.collect()
    while algorithm == "td3" and model.replay_buffer.pos < 256:   # a TD3 collect is one turn (train_freq steps)
        model.collect()
    if algorithm == "ppo":
        buf, n = model.rollout_buffer, 256
        observations, actions, rewards = buf.observations, np.clip(buf.actions, -1, 1), buf.rewards
    else:
        buf = model.replay_buffer
        n = buf.pos
        observations, actions, rewards = buf.observations, buf.actions, buf.rewards
    replay = env()
    obs = replay.reset()
    crashes = 0
    for t in range(n):
        np.testing.assert_array_equal(observations[t], obs)
        obs, step_rewards, dones, infos = replay.step(actions[t])
        done_rewards = step_rewards if algorithm == "td3" else \
            np.where([infos[i].get("TimeLimit.truncated", False) for i in range(2)], rewards[t], step_rewards)
        np.testing.assert_array_equal(rewards[t], done_rewards)   # PPO adds the time limit's bootstrap to its reward
        crashes += sum(infos[i].get("crashed", False) for i in range(2))
    assert n >= 256
    return model, crashes


@pytest.mark.parametrize("algorithm", ["ppo", "td3"])
def test_the_compiled_collects_step_the_anchor_task_as_the_env_does(algorithm):
    """The JAX learners' numba collects (PPO's rollout, TD3's replay collect) write the transitions HoverVecEnv.step
    gives for the same actions under the anchor's reward, radius, starts and observation."""
    _, crashes = replay_compiled_collect(algorithm, [])
    assert crashes > 0


@pytest.mark.parametrize("learner", ["sb3", "jax"])
def test_td3_trains_on_the_anchor_task_on_both_learners(learner):
    cfg = compose_cfg(ANCHOR + [f"agent.learner={learner}", "agent.policy.net_arch=[8,8]",
                                "agent.td3.learning_starts=64",
                                "agent.td3.batch_size=32", "agent.td3.round_steps=128", "agent.td3.train_freq=2"])
    validate(cfg)
    env = make_env(cfg.env, 1, wind_schedule(cfg.wind), 0, learning=True)
    model = build_learner(cfg.agent, env, 0, 1000)
    model.set_logger(configure_logger(0, None, "", False))
    before = {k: v.copy() for k, v in model.parameter_arrays().items()}
    total = model.begin(512)
    while model.num_timesteps < total:
        model.collect()
        model.update()
    assert env.observation_space.shape == (13 + 4 * 32 + 4,)
    assert any(not np.array_equal(before[k], v) for k, v in model.parameter_arrays().items())


def test_the_options_switched_off_move_no_job_key_and_bad_values_are_one_line():
    base = compose_cfg([])
    before = compose_cfg([])   # the config as it was before the options existed
    with open_dict(before):
        for block, name in (("reward", "power"), ("reward", "w_q"), ("reward", "action_reference"),
                            (None, "terminate_radius")):
            del (before.env[block] if block else before.env)[name]
    assert "power" not in before.env.reward and "terminate_radius" not in before.env
    assert job_key(base, "sqlite:///x.db") == job_key(before, "sqlite:///x.db")
    for override in ("env.reward.power=2", "env.reward.w_q=1", "env.reward.action_reference=hover",
                     "env.terminate_radius=0.6"):
        assert job_key(compose_cfg([override]), "sqlite:///x.db") != job_key(base, "sqlite:///x.db")
    for override, message in [("env.reward.power=3", "env.reward.power=3: must be 1 (norms"),
                              ("env.terminate_radius=0", "env.terminate_radius=0"),
                              ("env.reward.w_q=-1", "env.reward.w_q=-1"),
                              ("env.terminate_radius=3",
                               "env.terminate_radius=3: must be > 3.46 m, the farthest start")]:
        with pytest.raises(ConfigError) as error:
            validate(compose_cfg([override]))
        assert one_line(error.value).startswith(message)
