"""resume=<job dir>, resume=<MLflow run id>, resume=never and a bad resume value, on real short runs.

A run is cut short in-process: EnvMonitor's end-of-rollout hook raises once 1,536 timesteps are reached, so the
run ends FAILED with its last checkpoint at 1,024 and its metrics up to 1,024 in the store, and the config is
the same one the uninterrupted reference runs (the cut is a monkeypatch, not a config key).
"""
from __future__ import annotations

import contextlib
import logging
import types
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from conftest import compose_cfg, new_store
from sweep.checkpoint import load_checkpoint
from sweep.monitor import EnvMonitor
from sweep.run import run, run_job
from sweep.status import read_status
from sweep.tracking import ensure_store
from sweep.training.hooks import Hook, Hooks

# RECOM + L2 with a short interval: the learning rate moves during the run, so RECOM's state, the optimizer, the
# env and the RNGs must all come back for the continued history to equal the uninterrupted one.
RUN = ["agent=recom_l2", "seed=5", "train.total_timesteps=2048", "agent.ppo.n_steps=512", "agent.ppo.n_epochs=2",
       "agent.recom.interval=512", "agent.recom.window=2", "train.checkpoint_every=512", "eval.episodes=2",
       "env.episode_seconds=1.0", "train.progress_every_s=1000", "plasticity.probe.steps=50"]
CUT, KEPT = 1536, 1024
KEYS = ("rollout/ep_rew_mean", "train/loss", "train/learning_rate", "recom/cost", "plasticity/dormant_ratio",
        "time/total_timesteps", "eval/return", "eval/success_rate")


def histories(uri: str, run_id: str) -> dict[str, list[tuple[int, float]]]:
    client = MlflowClient(uri)
    return {k: [(m.step, m.value) for m in sorted(client.get_metric_history(run_id, k), key=lambda m: m.step)]
            for k in KEYS}


def all_runs(uri: str):
    client = MlflowClient(uri)
    return client.search_runs([e.experiment_id for e in client.search_experiments()])


@contextlib.contextmanager
def cut_at(step: int):
    """Runs inside raise at the first rollout end at or past ``step`` (as a crash mid-run would)."""
    original = EnvMonitor.after_rollout

    def cut(self, learner, rollout):
        if rollout.timesteps >= step:
            raise RuntimeError(f"cut at {rollout.timesteps}")
        return original(self, learner, rollout)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(EnvMonitor, "after_rollout", cut)
        yield


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Metric histories of the same run, uninterrupted, in its own store and checkpoint root."""
    tmp = tmp_path_factory.mktemp("reference")
    uri = new_store(tmp / "ref.db")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MLFLOW_TRACKING_URI", uri)
        mp.setenv("SWEEP_CHECKPOINT_DIR", str(tmp / "checkpoints"))
        mp.chdir(tmp)  # module-scoped: before the autouse fixture that runs each test in its temp dir
        run_id = run(compose_cfg(RUN), tmp / "job")
    ref = histories(uri, run_id)
    assert [s for s, _ in ref["time/total_timesteps"]] == [512, 1024, 1536, 2048]
    assert len({v for _, v in ref["train/learning_rate"]}) > 1, "RECOM never moved the LR: the test would be weak"
    return ref


@pytest.fixture
def interrupted(store, tmp_path, checkpoint_dir):
    """(job output dir, MLflow run id, checkpoint dir) of the run cut at 1,536 timesteps."""
    out = tmp_path / "first"
    with cut_at(CUT), pytest.raises(RuntimeError, match=f"cut at {CUT}"):
        run(compose_cfg(RUN), out)
    (r,) = all_runs(store)
    assert r.info.status == "FAILED" and r.data.tags["failure_reason"] == f"RuntimeError: cut at {CUT}"
    status = read_status(out)
    assert status["run_id"] == r.info.run_id
    ckpt = Path(status["checkpoint_dir"])
    assert load_checkpoint(ckpt / "checkpoint.pt")["num_timesteps"] == KEPT
    assert [s for s, _ in histories(store, r.info.run_id)["time/total_timesteps"]] == [512, KEPT]
    return out, r.info.run_id, ckpt


@pytest.mark.parametrize("form", ["job_dir", "checkpoint_dir", "run_id"])
def test_resume_names_the_run_to_continue(form, store, tmp_path, interrupted, reference, caplog):
    """The continued run is the interrupted MLflow run, FINISHED, with the histories of the uninterrupted run
    (none of its steps logged twice or missing). The continuation runs with another checkpoint root, so its own
    job key finds nothing: only the run named by ``resume`` can be continued (were the value ignored, a new run
    would start and the run-id and single-run checks fail; were a state not restored, the histories differ)."""
    out, run_id, ckpt = interrupted
    value = {"job_dir": out, "checkpoint_dir": ckpt, "run_id": run_id}[form]
    cfg = compose_cfg([*RUN, f"resume={value}", f"train.checkpoint_dir={tmp_path / 'elsewhere'}"])
    with caplog.at_level(logging.INFO, logger="sweep"):
        assert run(cfg, tmp_path / "second") == run_id
    assert f"(resumed at {KEPT:,} timesteps)" in caplog.text
    (r,) = all_runs(store)
    assert r.info.run_id == run_id and r.info.status == "FINISHED"
    assert histories(store, run_id) == reference
    assert not (tmp_path / "elsewhere").exists()  # the checkpoints went on in the resumed run's own directory
    assert load_checkpoint(ckpt / "checkpoint.pt")["num_timesteps"] == 2048


def test_resume_never_starts_a_new_mlflow_run(store, tmp_path, interrupted, reference, caplog):
    """With the interrupted run's checkpoint right there (``auto`` would continue it), ``never`` trains from
    scratch into a new MLflow run; the interrupted run is left as it was."""
    out, run_id, ckpt = interrupted
    with caplog.at_level(logging.INFO, logger="sweep"):
        new_id = run(compose_cfg([*RUN, "resume=never"]), tmp_path / "again")
    assert new_id != run_id and "resumed at" not in caplog.text
    runs = {r.info.run_id: r for r in all_runs(store)}
    assert set(runs) == {run_id, new_id}
    assert runs[run_id].info.status == "FAILED" and runs[new_id].info.status == "FINISHED"
    assert [s for s, _ in histories(store, run_id)["time/total_timesteps"]] == [512, KEPT]
    assert histories(store, new_id) == reference  # from step 512 on: trained from the start, not continued
    assert read_status(tmp_path / "again")["checkpoint_dir"] == str(ckpt)  # the same job: its checkpoint replaced


@pytest.mark.parametrize("value", ["missing_dir", "dir_without_job", "unknown_run_id"])
def test_a_bad_resume_value_is_one_config_error_line(value, store, tmp_path, monkeypatch, capsys):
    """Not a job dir, not a checkpoint dir, not a run of this store: the job stops before anything is tracked,
    exit code 2, one line on stderr naming the value and what is allowed, status INVALID."""
    bad = {"missing_dir": str(tmp_path / "no" / "such" / "job"), "dir_without_job": str(tmp_path),
           "unknown_run_id": "0123456789abcdef0123456789abcdef"}[value]
    ensure_store(store, "recom-hover")  # as `python -m sweep` does before its job (MLflow logs its creation)
    capsys.readouterr()
    out = tmp_path / "job"
    monkeypatch.setattr("sweep.run.tempfile", types.SimpleNamespace(mkdtemp=lambda: str(out)))  # run_job's job dir
    with pytest.raises(SystemExit) as exit_:
        run_job(compose_cfg(["train.total_timesteps=512", "agent.ppo.n_steps=512", f"resume={bad}"]))
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(
        f"sweep: invalid config: resume={bad!r}: must be auto, never, a job output dir or an MLflow run id of this "
        "store with a checkpoint ("), err
    assert all_runs(store) == []
    assert read_status(out)["status"] == "INVALID"


class Counter(Hook):
    """A stateful hook: counts rollouts and logs the count."""

    def __init__(self) -> None:
        self.rollouts = 0

    def after_rollout(self, learner, rollout) -> dict:
        self.rollouts += 1
        return {}

    def state_dict(self) -> dict:
        return {"rollouts": self.rollouts}

    def load_state_dict(self, state: dict) -> None:
        self.rollouts = state["rollouts"]


def test_a_hook_inserted_in_the_middle_resumes_a_checkpoint_taken_before(store, tmp_path, interrupted, reference,
                                                                          monkeypatch, caplog):
    """Hook state is saved by name: a stateful hook inserted before RECOM after the checkpoint was taken starts
    afresh (a warning says so), and every other hook gets its own state back, so the continued run's histories
    are the uninterrupted run's. (Restored by position, RECOM would receive the diagnostics' state, and the run
    would fail or its history differ.)"""
    import sweep.run as run_module

    out, run_id, ckpt = interrupted
    build = run_module.build_hooks
    inserted = Counter()

    def with_counter(cfg):
        hooks = list(build(cfg))
        return Hooks(hooks[:1] + [inserted] + hooks[1:])   # after L2, before RECOM and the diagnostics
    monkeypatch.setattr(run_module, "build_hooks", with_counter)
    with caplog.at_level(logging.INFO, logger="sweep"):
        assert run(compose_cfg([*RUN, f"resume={out}"]), tmp_path / "second") == run_id
    assert "hook 'Counter' has no state in the checkpoint; it starts afresh" in caplog.text
    assert [h.name for h in with_counter(compose_cfg(RUN))][:3] == ["l2", "Counter", "recom"]
    assert inserted.rollouts == 2   # the two rollouts after 1,024 (it started afresh)
    assert histories(store, run_id) == reference
