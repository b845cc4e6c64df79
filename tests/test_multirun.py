"""Real Hydra multiruns through the joblib launcher into one fresh MLflow store."""
from __future__ import annotations

import sqlite3

from mlflow.tracking import MlflowClient

from conftest import TINY, new_store, run_cli

PLASTICITY = ["plasticity/dormant_ratio", "plasticity/dormant_ratio_layer0", "plasticity/dormant_ratio_layer1",
              "plasticity/value_dormant_ratio", "plasticity/saturated_ratio", "plasticity/weight_norm",
              "plasticity/grad_norm", "plasticity/srank"]


def runs_of(uri):
    client = MlflowClient(uri)
    return client, client.search_runs([e.experiment_id for e in client.search_experiments()])


def test_two_job_multirun_writes_two_runs_into_one_fresh_store(tmp_path):
    uri = f"sqlite:///{tmp_path / 'fresh.db'}"  # the store's first creation, not new_store's copy
    proc = run_cli(["-m", "agent=ppo", "seed=0,1", "wind=paper", "wind.segment_steps=512", *TINY,
                    f"hydra.sweep.dir={tmp_path / 'sweep'}", "hydra.launcher.n_jobs=2"], uri, tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    client, runs = runs_of(uri)
    assert sorted(r.data.tags["seed"] for r in runs) == ["0", "1"]
    for r in runs:
        assert r.info.status == "FINISHED" and r.data.tags["agent"] == "ppo"
        assert r.data.tags["sweep"] == str((tmp_path / "sweep").resolve())
        assert len(client.get_metric_history(r.info.run_id, "rollout/ep_rew_mean")) == 2
        winds = [m.value for m in client.get_metric_history(r.info.run_id, "env/wind_speed")]
        assert winds == [2.0, 2.5]  # global steps 512 and 1024 with 512-step segments
    assert "2/2 jobs finished" in proc.stdout
    # the sweep put its SQLite store in WAL mode (a reader no longer blocks the jobs' writes)
    assert sqlite3.connect(tmp_path / "fresh.db").execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    # the start announces the sweep's size and expected time; the end links the runs table of a
    # model-training experiment (MLflow 3 would otherwise open its GenAI overview)
    assert "sweep: 2 jobs, expected wall time ~" in proc.stdout and "agent.learner=jax" in proc.stdout
    exp = client.get_experiment_by_name("recom-hover")
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development"
    assert (f"sweep: then the runs table: http://127.0.0.1:5000/#/experiments/{exp.experiment_id}"
            "?workflowType=machine_learning") in proc.stdout


def test_three_agents_log_every_metric(tmp_path):
    uri = new_store(tmp_path / "x.db")
    proc = run_cli(["-m", "agent=ppo,l2,recom_l2", "seed=0", "wind.segment_steps=512",
                    "train.total_timesteps=2048", "agent.ppo.n_steps=512", "eval.episodes=2",
                    "++agent.recom.interval=512", f"hydra.sweep.dir={tmp_path / 'sweep'}", "hydra.launcher.n_jobs=2"],
                   uri, tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    client, runs = runs_of(uri)
    by_agent = {r.data.tags["agent"]: r for r in runs}
    assert sorted(by_agent) == ["l2", "ppo", "recom_l2"]
    for agent, r in by_agent.items():
        assert r.info.status == "FINISHED"
        for key in PLASTICITY + ["rollout/ep_rew_mean", "train/learning_rate"]:
            assert client.get_metric_history(r.info.run_id, key), (agent, key)
    recom = by_agent["recom_l2"].info.run_id
    assert client.get_metric_history(recom, "recom/cost_gradient")
    lrs = [m.value for m in client.get_metric_history(recom, "train/learning_rate")]
    assert len(set(lrs)) > 1, lrs
    ppo_lrs = {m.value for m in client.get_metric_history(by_agent["ppo"].info.run_id, "train/learning_rate")}
    assert ppo_lrs == {3e-4}
