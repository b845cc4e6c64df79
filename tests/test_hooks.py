"""The training loop's records and hooks (sweep.training): what each update returns on both learners, the hook
list built from config and its errors, and a researcher's own diagnostic added with one class and one YAML."""
from __future__ import annotations


import numpy as np
import pytest
from mlflow.tracking import MlflowClient
from stable_baselines3.common.logger import KVWriter, Logger

from conftest import TINY, compose_cfg, train_with
from sweep.agents import build_learner
from sweep.envs import HoverVecEnv, WindSchedule
from sweep.run import run
from sweep.config import ConfigError
from sweep.training.hooks import Hook, Hooks, build_hooks
from sweep.training.records import RolloutRecord, UpdateRecord

LEARNERS = ["sb3", "jax"]


class Recorder(Hook):
    """Keeps every record it is shown."""

    def __init__(self) -> None:
        self.rollouts: list[RolloutRecord] = []
        self.updates: list[UpdateRecord] = []
        self.ends: list = []

    def after_rollout(self, learner, rollout):
        self.rollouts.append(rollout)
        return {}

    def after_update(self, learner, update):
        self.updates.append(update)
        return {}

    def at_end(self, learner, update):
        self.ends.append(update)
        return {}


class Lines(KVWriter):
    """An SB3 logger output that keeps each dumped line (step -> values)."""

    def __init__(self) -> None:
        self.lines: dict[int, dict] = {}

    def write(self, key_values, key_excluded, step=0):
        self.lines[step] = dict(key_values)

    def close(self):
        pass


@pytest.mark.parametrize("name", LEARNERS)
def test_each_update_returns_its_record_and_the_loop_logs_it_as_sb3_does(name):
    """4 rollouts of 2 x 128 steps: 3 updates reach after_update (the last goes to at_end), each record's
    train/* values are the ones logged with the next rollout's line; the rollout records carry the episodes
    that ended (short episodes: 0.5 s), SB3's ep_rew_mean and the condition; RECOM's loss is the record's."""
    cfg = compose_cfg([f"agent.learner={name}", "agent.ppo.n_steps=128", "agent.ppo.n_epochs=2"])
    env = HoverVecEnv(n_envs=2, seed=0, episode_seconds=0.5, wind=WindSchedule(speeds=[1.0, 2.0], segment_steps=512))
    model = build_learner(cfg.agent, env, seed=0)
    recorder, lines = Recorder(), Lines()
    train_with(model, [recorder], 1024, logger=Logger(None, [lines]))
    assert [r.timesteps for r in recorder.rollouts] == [256, 512, 768, 1024]
    assert [u.index for u in recorder.updates] == [1, 2, 3] and recorder.ends[0].index == 4
    for update in recorder.updates:
        assert update.epochs == 2 and update.n_updates == 2 * update.index and update.learning_rate == 3e-4
        assert update.mean_loss == pytest.approx(update.policy_gradient_loss + 0.5 * update.value_loss)
        logged = lines.lines[update.timesteps + 256]
        assert {k: v for k, v in logged.items() if k.startswith("train/")} == update.metrics()
    assert set(recorder.updates[0].metrics()) == {
        "train/entropy_loss", "train/policy_gradient_loss", "train/value_loss", "train/approx_kl",
        "train/clip_fraction", "train/loss", "train/explained_variance", "train/std", "train/n_updates",
        "train/clip_range", "train/learning_rate"}
    episodes = [ep for r in recorder.rollouts for ep in r.episodes]
    assert len(episodes) >= 8 and all(ep.length <= 50 for ep in episodes)
    assert sum(ep.length for ep in episodes) <= 1024
    last = recorder.rollouts[-1]
    assert last.mean_recent_return == pytest.approx(np.mean([ep.ret for ep in episodes]))
    assert lines.lines[1024]["rollout/ep_rew_mean"] == pytest.approx(last.mean_recent_return)
    assert [(r.condition.segment, r.condition.wind_speed) for r in recorder.rollouts] == \
           [(0, 1.0), (1, 2.0), (1, 2.0), (2, 1.0)]


def test_a_hook_without_the_one_it_requires_is_one_config_error(store, tmp_path):
    """best_policies reads the evaluation hook: dropping the evaluation is an error before anything is tracked."""
    with pytest.raises(ConfigError, match=r"^hooks: hook 'best_policies' \(BestPolicies\) requires hook 'evaluation' "
                                          r"before it; the hooks are, in order: non_finite_guard, diagnostics, "):
        run(compose_cfg([*TINY, "~hooks.evaluation"]), tmp_path / "job")
    assert MlflowClient(store).search_experiments() == [] or not MlflowClient(store).search_runs(
        [e.experiment_id for e in MlflowClient(store).search_experiments()])


@pytest.mark.parametrize("override, message", [
    ("+hooks.probe.stepz=3", r"^hooks\.probe\.stepz: not a config key \(allowed under hooks\.probe: _target_, enabled, "),
    ("+hooks.odd._target_=collections.OrderedDict", r"^hooks\.odd: collections\.OrderedDict declares no settings schema"),
    # a class whose schema lets through what its __init__ refuses: the cause, whole, on the one line
    ("+hooks.odd._target_=faults.Unbuildable +hooks.odd.x=1", r"^hooks: Error in call to target 'faults\.Unbuildable':"
                                                              r" TypeError\(.*unexpected keyword argument 'x'.*\)"),
])
def test_a_hook_that_cannot_be_built_is_one_config_error(override, message, tmp_path):
    with pytest.raises(ConfigError, match=message) as err:
        run(compose_cfg([*TINY, *override.split()]), tmp_path / "job")
    assert "\n" not in str(err.value)


def test_hooks_need_distinct_names_and_the_checkpointer_acts_last():
    hooks = build_hooks(compose_cfg(["agent=recom_l2"]))
    names = [h.name for h in hooks]
    assert names[:2] == ["l2", "recom"] and names[-1] == "checkpointer" and "progress" in names
    with pytest.raises(ValueError, match="distinct"):
        Hooks([Recorder(), Recorder()])
