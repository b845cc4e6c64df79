"""agent=reset_all (Juliani & Ash 2024's reference): at each change of condition a fresh network and a fresh Adam,
on both learners; a run logs each reset and resumes exactly across one."""
from __future__ import annotations

import numpy as np
import pytest
from mlflow.tracking import MlflowClient

from conftest import compose_cfg, train_with
from sweep.agents import build_learner
from sweep.agents.networks import fresh_parameters
from sweep.envs import HoverVecEnv, WindSchedule
from sweep.plasticity.reset_all import ResetAll
from sweep.run import run
from sweep.training.records import Condition
from test_resume import cut_at

LEARNERS = ["sb3", "jax"]


def trained(name: str, seed: int = 0):
    cfg = compose_cfg([f"agent.learner={name}", "agent=reset_all", "agent.ppo.n_steps=256"])
    model = build_learner(cfg.agent, HoverVecEnv(n_envs=2, seed=seed, wind=WindSchedule([2.0])), seed)
    train_with(model, [], 1024)   # Adam's moments and step count are non-zero
    return model


@pytest.mark.parametrize("name", LEARNERS)
def test_a_reset_draws_a_fresh_init_from_the_learner_generator_and_restarts_adam(name):
    """After at_change: every weight equals fresh_parameters drawn from the learner's generator as it was; Adam's
    moments are zero; and the next update equals the update of a new learner given those weights (so Adam's step
    count restarted too: its bias correction is the first step's)."""
    model = trained(name)
    assert any(np.abs(m).sum() > 0 for m, _ in model.optimizer_moments().values())
    before = model.parameter_arrays()
    generator = np.random.Generator(np.random.PCG64())
    generator.bit_generator.state = model.rng.bit_generator.state
    logged = ResetAll().at_change(model, Condition(1, (2.0, 0.0, 0.0)))
    assert logged == {"remedy/reset_all/resets": 1.0}
    expected = fresh_parameters({k: v.shape for k, v in before.items()}, model.networks, generator)
    after = model.parameter_arrays()
    assert all(np.array_equal(after[k], expected[k]) for k in expected)
    assert not all(np.array_equal(after[k], before[k]) for k in before)
    assert all(not m.any() and not v.any() for m, v in model.optimizer_moments().values())
    twin = trained(name, seed=1)   # another learner: its own weights and an Adam that has stepped
    twin.write_parameters(after)
    twin.reset_optimizer_state()
    new = build_learner(compose_cfg([f"agent.learner={name}", "agent.ppo.n_steps=256"]).agent,
                        HoverVecEnv(n_envs=2, seed=1, wind=WindSchedule([2.0])), 1)
    new.write_parameters(after)
    for learner in (model, new):
        learner.rollout_buffer = twin.rollout_buffer   # the same rollout for both
        np.random.seed(5)
        learner.update()
    a, b = model.parameter_arrays(), new.parameter_arrays()
    assert all(np.array_equal(a[k], b[k]) for k in a), [k for k in a if not np.array_equal(a[k], b[k])]


RUN = ["agent=reset_all", "seed=3", "train.total_timesteps=2048", "agent.ppo.n_steps=512", "agent.ppo.n_epochs=2",
       "wind.segment_steps=768", "train.checkpoint_every=512", "eval.episodes=2", "env.episode_seconds=1.0",
       "train.progress_every_s=1000", "plasticity.probe.steps=20"]


@pytest.mark.parametrize("name", LEARNERS)
def test_a_run_resets_at_each_change_and_resumes_exactly_across_one(name, store, tmp_path):
    """Segments of 768 steps, rollouts of 512: the condition changes at the rollout ends 1,024 and 1,536, and the
    run logs a reset at each. Cut at 1,536 (before that change's reset) and resumed from the checkpoint at 1,024
    (after the first reset), the run's histories equal the uninterrupted run's."""
    overrides = [f"agent.learner={name}", *RUN]
    client = MlflowClient(store)
    whole = run(compose_cfg(overrides), tmp_path / "whole")
    resets = [(m.step, m.value) for m in client.get_metric_history(whole, "remedy/reset_all/resets")]
    assert sorted(resets) == [(1024, 1.0), (1536, 2.0)]
    keys = ["rollout/ep_rew_mean", "train/loss", "plasticity/weight_norm", "remedy/reset_all/resets",
            "plasticity/probe_loss", "eval/return"]
    history = lambda run_id: {k: sorted((m.step, m.value) for m in client.get_metric_history(run_id, k))  # noqa: E731
                              for k in keys}
    cut = tmp_path / "cut"
    with cut_at(1536), pytest.raises(RuntimeError):
        run(compose_cfg([*overrides, "tracking.experiment=cut", "resume=never"]), cut)
    resumed = run(compose_cfg([*overrides, "tracking.experiment=cut", f"resume={cut}"]), tmp_path / "again")
    assert history(resumed) == history(whole)


@pytest.mark.parametrize("total,segment", [(2000, 1000), (2048, 1024)])
def test_a_change_met_by_the_last_rollout_is_not_acted_on(total, segment, store, tmp_path):
    """Rollouts of 512: the condition changes at the rollout ends 1,024 and 2,048, the second at or past the end of
    training (2,000 steps in segments of 1,000; exactly at it, 2,048 in segments of 1,024). The run resets at the
    first only: at the second no training would follow, and the final policy (the one evaluated and kept) would be
    a fresh draw."""
    overrides = ["agent.learner=sb3", *RUN, f"train.total_timesteps={total}", f"wind.segment_steps={segment}"]
    client = MlflowClient(store)
    run_id = run(compose_cfg(overrides), tmp_path / "run")
    resets = [(m.step, m.value) for m in client.get_metric_history(run_id, "remedy/reset_all/resets")]
    assert resets == [(1024, 1.0)]
    segments = sorted((m.step, m.value) for m in client.get_metric_history(run_id, "env/segment"))
    assert segments[-1] == (2048, 2.0)   # the run did meet the second change
