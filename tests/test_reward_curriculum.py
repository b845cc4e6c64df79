"""The reward-weight curriculum of "Learning to Fly in Seconds" (``env.reward_curriculum``): stage k's weights, the env
changing them on the global clock in its own step and in both compiled collects, ``rewards_of`` scoring stored
transitions as the env scores them, the replay re-scored at each new stage on SB3's and the JAX TD3 alike (and kept
through a checkpoint), and the block switched off moving no job key."""
from __future__ import annotations

import numpy as np
import pytest
from omegaconf import open_dict
from stable_baselines3.common.utils import configure_logger

from conftest import compose_cfg
from test_anchor_task import replay_compiled_collect
from sweep.agents import build_learner
from sweep.checkpoint import job_key
from sweep.config import ConfigError, one_line, validate
from sweep.envs.factory import make_env, wind_schedule
from sweep.envs.reward import HoverReward, RewardCurriculum
from sweep.monitor import EnvMonitor
from sweep.training.records import RolloutRecord

ANCHOR = ["experiment=anchor_task"]
CURRICULUM = RewardCurriculum(every=100, factor={"w_p": 1.2, "w_v": 1.4, "w_a": 1.4, "w_q": 1.0},
                              limit={"w_p": 3.0, "w_v": None, "w_a": 0.05, "w_q": None})


def test_stage_k_multiplies_each_weight_by_its_factor_to_the_k_up_to_its_limit():
    base = HoverReward(w_p=2.5, w_v=0.005, w_a=0.005, w_q=2.5)
    assert CURRICULUM.reward_at(base, 0) is base
    assert [CURRICULUM.stage(g) for g in (0, 99, 100, 250)] == [0, 0, 1, 2]
    assert CURRICULUM.next_change(0) == 100 and CURRICULUM.next_change(100) == 200
    one, two = CURRICULUM.reward_at(base, 1), CURRICULUM.reward_at(base, 2)
    assert one.w_p == pytest.approx(3.0) and two.w_p == 3.0                    # 2.5 x 1.44 = 3.6, capped at 3
    assert two.w_v == pytest.approx(0.005 * 1.96) and two.w_q == 2.5          # no limit; factor 1: held
    assert CURRICULUM.reward_at(base, 20).w_a == 0.05
    assert (one.power, one.alive_bonus, one.crash_reward) == (base.power, base.alive_bonus, base.crash_reward)
    assert RewardCurriculum().stage(10 ** 9) == 0 and RewardCurriculum().next_change(5) is None
    with pytest.raises(ValueError, match="'w_x'"):
        RewardCurriculum(every=1, factor={"w_x": 2.0})
    assert CURRICULUM.reward_at(base, 10 ** 6).w_p == 3.0   # far past the float range of 1.2**k: the limit
    assert RewardCurriculum(every=1, factor={"w_q": 2.0}).reward_at(HoverReward(), 10 ** 6).w_q == 0.0


@pytest.mark.parametrize("observation,crash_reward", [("quaternion", "null"), ("euler", "null"),
                                                      ("quaternion", "-500"), ("euler", "-500")])
def test_the_env_raises_its_weights_on_the_global_clock_and_rewards_of_scores_as_it_does(observation, crash_reward):
    """Every step's reward is ``rewards_of`` on the state it returns (tilted starts; crashes beyond the radius, which
    a crash_reward of -500 scores as such), before and after the stages change; after a change the weights are the
    new stage's."""
    cfg = compose_cfg(ANCHOR + [f"env.observation={observation}", "env.reward.power=2", "env.reward_scale=0.5",
                                f"env.reward.crash_reward={crash_reward}", "env.observation_scale.velocity=0.3",
                                "env.observation_scale.body_rate=0.7",
                                "env.reward_curriculum.every=64", "env.reward_curriculum.limit.w_p=1000"])
    validate(cfg)
    env = make_env(cfg.env, 8, wind_schedule(cfg.wind), 3, learning=True)
    env.reset()
    rng = np.random.default_rng(2)
    crashes = 0
    for step in range(40):   # 320 env steps: stages 0..4
        actions = np.clip(env.hover_action + rng.normal(0, 0.5, (8, 4)), -1, 1).astype(np.float32)
        obs, rewards, dones, infos = env.step(actions)
        assert env.reward_stage == (step * 8) // 64   # the stage of the step's first env step, as the step flew
        state = np.array([infos[i]["terminal_observation"] if dones[i] else obs[i] for i in range(8)])
        np.testing.assert_allclose(env.rewards_of(state, actions), rewards, rtol=2e-5, atol=2e-5)
        crashes += sum(info.get("crashed", False) for info in infos)
        if crash_reward == "-500":
            assert (rewards[[info.get("crashed", False) for info in infos]] == -250).all()   # x reward_scale
    assert crashes > 0
    assert env.stage_reward().w_p == pytest.approx(2.5 * 1.2 ** 4) and env.stage_reward().w_q == 2.5
    evaluation = make_env(cfg.env, 8, wind_schedule(cfg.wind), 3)   # evaluations keep the base weights
    evaluation.global_step = 10 ** 6
    evaluation.sync_condition()
    assert evaluation.reward_stage == 0 and evaluation.stage_reward().w_p == 2.5


@pytest.mark.parametrize("algorithm", ["ppo", "td3"])
def test_the_compiled_collects_change_the_weights_at_the_step_the_env_does(algorithm):
    """The JAX learners' collects stop at a stage's start and fly on with its weights: their transitions are
    ``HoverVecEnv.step``'s for the same actions, across 4 stages (every 125 env steps on 2 vehicles: a stage begins
    inside a vector step, which flies the stage of its first env step)."""
    model, _ = replay_compiled_collect(algorithm, [
        "env.reward_curriculum.every=125", "env.reward_curriculum.factor.w_p=3", "env.reward_curriculum.limit.w_p=1000",
        "env.reward_curriculum.recompute_replay=false"], learning_starts=600)   # each reward as the collect wrote it
    assert model.env.reward_stage == 4


def run_td3(learner: str, recompute: bool = True, checkpoint_at: int | None = None):
    """TD3 on the anchor's task with stages every 256 env steps, 1024 steps; (model, env, state at checkpoint_at)."""
    cfg = compose_cfg(ANCHOR + [f"agent.learner={learner}", "agent.policy.net_arch=[8,8]", "env.n_envs=2",
                                "agent.td3.learning_starts=64", "agent.td3.batch_size=32",
                                "agent.td3.round_steps=128", "agent.td3.train_freq=2",
                                "env.reward_curriculum.every=256", "env.reward_curriculum.factor.w_p=2",
                                "env.reward_curriculum.limit.w_p=1000",
                                f"env.reward_curriculum.recompute_replay={str(recompute).lower()}"])
    validate(cfg)
    env = make_env(cfg.env, 2, wind_schedule(cfg.wind), 0, learning=True)
    model = build_learner(cfg.agent, env, 0, 1000)
    model.set_logger(configure_logger(0, None, "", False))
    total, state = model.begin(1024), None
    while model.num_timesteps < total:
        model.collect()
        model.update()
        if checkpoint_at is not None and state is None and model.num_timesteps >= checkpoint_at:
            state = model.training_state()
    return model, env, state


def stored(model):
    buf = model.replay_buffer
    size = buf.buffer_size if buf.full else buf.pos
    return (buf.next_observations[:size].reshape(-1, buf.next_observations.shape[-1]),
            buf.actions[:size].reshape(-1, 4), buf.rewards[:size].ravel())


@pytest.mark.parametrize("learner", ["sb3", "jax"])
def test_each_new_stage_re_scores_the_replay_on_both_learners(learner):
    """After the last stage change every reward in the buffer is the new weights' (``rewards_of``), those collected
    under stage 0 included; with ``recompute_replay: false`` they keep the weights they were collected with."""
    model, env, _ = run_td3(learner)
    next_obs, actions, rewards = stored(model)
    assert env.reward_stage == 3 and model._replay_stage == 3 and len(rewards) == 1024
    # the re-scored rows exactly; those collected since (stage 3's own) as the env gave them, to float32 rounding
    np.testing.assert_allclose(rewards, env.rewards_of(next_obs, actions), rtol=2e-5, atol=2e-5)
    kept, kept_env, _ = run_td3(learner, recompute=False)
    next_obs, actions, rewards = stored(kept)
    first = slice(0, 256)   # stage 0's transitions keep stage 0's rewards: not the stage-3 scores
    assert not np.allclose(rewards[first], kept_env.rewards_of(next_obs[first], actions[first]), rtol=1e-3)
    last = slice(1024 - 64, 1024)   # the last stage's own transitions, as the env gave them
    np.testing.assert_allclose(rewards[last], kept_env.rewards_of(next_obs[last], actions[last]), rtol=2e-5,
                               atol=2e-5)


def test_a_checkpoint_keeps_the_stage_its_replay_was_scored_at_and_the_weights_in_force_are_logged():
    model, env, state = run_td3("jax", checkpoint_at=600)
    record = RolloutRecord(index=1, timesteps=model.num_timesteps, episodes=(), mean_recent_return=None,
                           condition=env.condition())
    logged = EnvMonitor().after_rollout(model, record)
    assert logged["env/reward_stage"] == 3 and logged["env/reward_w_p"] == pytest.approx(2.5 * 8)
    assert logged["env/reward_w_q"] == 2.5 and "env/wind_speed" in logged
    assert state["replay_stage"] == 2
    restored, _, _ = run_td3("jax")
    restored.load_training_state(state)
    assert restored._replay_stage == 2
    del state["replay_stage"]   # a checkpoint from before the curriculum: stage 0
    restored.load_training_state(state)
    assert restored._replay_stage == 0


def test_the_block_switched_off_moves_no_job_key_and_bad_values_are_one_line():
    base = compose_cfg([])
    before = compose_cfg([])   # the config as it was before the block existed
    with open_dict(before):
        del before.env["reward_curriculum"]
    assert job_key(base, "sqlite:///x.db") == job_key(before, "sqlite:///x.db")
    assert job_key(compose_cfg(["env.reward_curriculum.every=100000"]), "sqlite:///x.db") != \
        job_key(base, "sqlite:///x.db")
    for override, message in [
            ("env.reward_curriculum.every=0",
             "env.reward_curriculum.every=0: must be an integer > 0 (env steps) or null"),
            ("env.reward_curriculum.factor.w_p=0", "env.reward_curriculum.factor.w_p=0: must be a number > 0"),
            ("env.reward_curriculum.limit.w_p=0.5",
             "env.reward_curriculum.limit.w_p=0.5: must be >= env.reward.w_p=1 (the curriculum raises"),
            ("env.reward_curriculum.limit.w_v=null",
             "env.reward_curriculum.limit.w_v=null: must be a number with env.reward_curriculum.factor.w_v=1.4 > 1"),
            ("eval.policy=both", "eval.policy=both: must be final under env.reward_curriculum.every=100")]:
        overrides = [override] + ([] if "every" in override else ["env.reward_curriculum.every=100"])
        overrides += [] if "eval.policy" in override else ["eval.policy=final"]
        with pytest.raises(ConfigError) as error:
            validate(compose_cfg(overrides))
        assert one_line(error.value).startswith(message), one_line(error.value)
