"""Real runs into a real temporary MLflow store: tags, metric histories, artifacts, failure status."""
from __future__ import annotations

import sqlite3
import time
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from conftest import TINY, compose_cfg
from sweep.run import run
from sweep.tracking import MlflowWriter, TrackedRun, ensure_store, flatten, tracking_uri, use_write_ahead_log


def all_runs(uri: str):
    client = MlflowClient(uri)
    return client, client.search_runs([e.experiment_id for e in client.search_experiments()])


def test_tracking_uri_is_absolute(monkeypatch, tmp_path):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    assert tracking_uri(None).startswith("sqlite:////") and tracking_uri(None).endswith("/mlflow.db")
    monkeypatch.chdir(tmp_path)
    assert tracking_uri("sqlite:///rel.db") == f"sqlite:///{tmp_path / 'rel.db'}"


def test_flatten_config():
    assert flatten({"a": {"b": 1, "c": [1, 2]}, "d": None}) == {"a.b": "1", "a.c": "[1, 2]", "d": "None"}


def test_single_tiny_run_writes_one_tracked_run(store, tmp_path):
    cfg = compose_cfg(["agent=ppo", "seed=3", "wind=paper", *TINY])
    run_id = run(cfg, tmp_path / "job")
    client, runs = all_runs(store)
    assert [r.info.run_id for r in runs] == [run_id]
    r = runs[0]
    assert r.info.status == "FINISHED"
    assert {k: r.data.tags[k] for k in ("agent", "wind", "seed", "sweep")} == \
           {"agent": "ppo", "wind": "paper", "seed": "3", "sweep": "single"}
    assert r.data.params["train.total_timesteps"] == "1024" and r.data.params["wind.speeds"] == "[3.0, 2.0, 2.5, 1.5, 2.5]"
    rewards = client.get_metric_history(run_id, "rollout/ep_rew_mean")
    assert [m.step for m in rewards] == [512, 1024]
    for key in ("train/loss", "train/learning_rate", "plasticity/dormant_ratio", "env/wind_speed",
                "eval/success_rate", "eval/mse_x", "eval/mse_y", "eval/mse_z"):
        assert client.get_metric_history(run_id, key), key
    artifacts = {a.path for a in client.list_artifacts(run_id)}
    assert {"config.yaml", "model.zip", "eval_trajectories.npz"} <= artifacts


def test_periodic_evaluation_is_logged_during_training(store, tmp_path):
    cfg = compose_cfg(["train.total_timesteps=1536", "agent.ppo.n_steps=512", "eval.episodes=2",
                       "eval.every_timesteps=1024", "env.episode_seconds=1.0"])
    run_id = run(cfg, tmp_path / "job")
    steps = [m.step for m in MlflowClient(store).get_metric_history(run_id, "eval/success_rate")]
    assert steps == [1024, 1536]  # during training, then the final evaluation


def test_failing_run_ends_failed_with_reason(store, tmp_path):
    cfg = compose_cfg(TINY)
    with pytest.raises(RuntimeError):
        with TrackedRun(cfg.tracking, {}, {"agent": "ppo"}) as tracked:
            MlflowWriter(tracked, flush_every_s=0).write({"rollout/ep_rew_mean": -3.0, "note": "text"}, {}, step=7)
            raise RuntimeError("boom")
    client, (r,) = all_runs(store)
    assert r.info.status == "FAILED" and r.data.tags["failure_reason"] == "RuntimeError: boom"
    assert [(m.step, m.value) for m in client.get_metric_history(r.info.run_id, "rollout/ep_rew_mean")] == [(7, -3.0)]


def test_writer_buffers_dumps_until_flush_and_drops_replayed_steps(store):
    with TrackedRun(compose_cfg(TINY).tracking, {}, {"agent": "ppo"}) as tracked:
        writer = MlflowWriter(tracked, after_step=4, flush_every_s=3600)
        for step in (4, 5, 6):  # step 4 was logged before a resume: dropped
            writer.write({"rollout/ep_rew_mean": float(-step), "time/iterations": 1}, {}, step=step)
        history = lambda: [(m.step, m.value) for m in tracked.client.get_metric_history(tracked.run_id,  # noqa: E731
                                                                                        "rollout/ep_rew_mean")]
        assert history() == []
        writer.flush()
        assert history() == [(5, -5.0), (6, -6.0)]
        assert tracked.client.get_metric_history(tracked.run_id, "time/iterations") == []


def test_a_reader_of_the_sqlite_store_does_not_block_a_jobs_write(store):
    """A study job died on "database is locked" while a sqlite3 shell read its store: WAL mode lets both run."""
    exp_id = ensure_store(store, "reader")
    use_write_ahead_log(store)  # as the sweep's callback does before its jobs start
    client = MlflowClient(store)
    run_id = client.create_run(exp_id).info.run_id
    reader = sqlite3.connect(store[len("sqlite:///"):], isolation_level=None)
    try:
        assert reader.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        reader.execute("BEGIN")
        reader.execute("SELECT count(*) FROM metrics").fetchone()  # the reader now holds its read transaction
        start = time.monotonic()
        client.log_metric(run_id, "rollout/ep_rew_mean", -1.0, step=0)  # rollback-journal mode: fails after ~20 s
        assert time.monotonic() - start < 5
    finally:
        reader.close()
    assert [m.value for m in client.get_metric_history(run_id, "rollout/ep_rew_mean")] == [-1.0]
