"""python -m sweep.report on one small real store (built once per module by a real Hydra multirun)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mlflow.tracking import MlflowClient

from sweep.report.__main__ import main

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = "report-test"
SWEEP = ["-m", "agent=ppo,recom_l2", "seed=0,1", "wind=paper", "train.total_timesteps=1024", "agent.ppo.n_steps=512",
         "wind.segment_steps=512", "++agent.recom.interval=512", "eval.episodes=2", "tracking.log_model=false",
         "train.progress_every_s=1000", f"tracking.experiment={EXPERIMENT}", "hydra.launcher.n_jobs=2"]
FIGURES = ["reward_paper", "dormant_paper", "learning_rate_paper", "eval_flights_3d", "eval_position_axes"]
TABLES = ["table3.md", "table3.tex", "table3.csv", "summary.md", "summary.csv"]


def env_with(uri: str) -> dict:
    return {**os.environ, "MLFLOW_TRACKING_URI": uri, "HYDRA_FULL_ERROR": "0"}


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> str:
    tmp = tmp_path_factory.mktemp("store")
    uri = f"sqlite:///{tmp / 'mlflow.db'}"
    proc = subprocess.run([sys.executable, "-m", "sweep", *SWEEP, f"hydra.sweep.dir={tmp / 'sweep'}"], cwd=ROOT,
                          env=env_with(uri), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return uri


@pytest.fixture(scope="module")
def report(store, tmp_path_factory):
    """(output dir, stdout) of one report run, in-process."""
    out = tmp_path_factory.mktemp("report")
    mp = pytest.MonkeyPatch()
    mp.setenv("MLFLOW_TRACKING_URI", store)
    try:
        import contextlib
        import io

        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            code = main(["--experiment", EXPERIMENT, "--out", str(out)])
    finally:
        mp.undo()
    assert code == 0, buf.getvalue()
    return out, buf.getvalue()


def test_report_writes_every_file_and_says_what_is_missing(report):
    out, stdout = report
    for stem in FIGURES:
        for ext in ("png", "pdf"):
            assert (out / f"{stem}.{ext}").stat().st_size > 1000, f"{stem}.{ext}"
    for name in TABLES:
        assert (out / name).stat().st_size > 0, name
    assert stdout.strip().splitlines()[-1] == str(out.resolve())
    assert "missing: agent=l2 wind=paper" in stdout and "missing: agent=ppo wind=none" in stdout


def test_table3_equals_a_hand_aggregation_of_the_mlflow_values(store, report):
    out, _ = report
    client = MlflowClient(store)
    exp = client.get_experiment_by_name(EXPERIMENT)
    runs = client.search_runs([exp.experiment_id])
    hand = pd.DataFrame([{"agent": r.data.tags["agent"], "wind": r.data.tags["wind"],
                          **{k: r.data.metrics[f"eval/{k}"] for k in ("success_rate", "mse_x", "mse_y", "mse_z")}}
                         for r in runs]).groupby(["agent", "wind"])
    table = pd.read_csv(out / "table3.csv").set_index(["agent", "wind"])
    assert sorted(table.index) == [("ppo", "paper"), ("recom_l2", "paper")]
    means, counts = hand.mean(), hand.size()
    for idx in table.index:
        assert table.loc[idx, "n_seeds"] == counts[idx] == 2
        assert table.loc[idx, "success_rate_mean"] == pytest.approx(100 * means.loc[idx, "success_rate"])
        for axis in "xyz":
            assert table.loc[idx, f"mse_{axis}_mean"] == pytest.approx(means.loc[idx, f"mse_{axis}"])
        assert np.isfinite(table.loc[idx, "mse_x_ci95"])  # two seeds: a Student-t interval exists
    markdown = (out / "table3.md").read_text()
    assert f"{means.loc[('ppo', 'paper'), 'mse_x']:.2f}" in markdown


def test_summary_has_one_row_per_condition_and_compares_with_ppo(report):
    out, _ = report
    summary = pd.read_csv(out / "summary.csv").set_index("agent")
    assert list(summary.index) == ["ppo", "recom_l2"] and (summary["n_seeds"] == 2).all()
    assert np.isnan(summary.loc["ppo", "p_improve_over_ppo"])
    assert 0.0 <= summary.loc["recom_l2", "p_improve_over_ppo"] <= 1.0
    for agent in summary.index:
        row = summary.loc[agent]
        assert row["iqm_ci_low"] <= row["iqm_final_reward"] <= row["iqm_ci_high"]
        assert row["collapse"] >= 0 and 0 <= row["final_dormant_ratio"] <= 1


def test_empty_store_is_one_error_line_and_exit_1(tmp_path):
    uri = f"sqlite:///{tmp_path / 'empty.db'}"
    MlflowClient(uri).search_experiments()  # creates the schema: a store without runs
    proc = subprocess.run([sys.executable, "-m", "sweep.report", "--out", str(tmp_path / "out")], cwd=tmp_path,
                          env=env_with(uri), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sweep.report: ") and "no runs" in lines[0], proc.stderr
    assert not (tmp_path / "out").exists()


def test_unknown_experiment_is_one_error_line_and_exit_1(store, monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", store)
    assert main(["--experiment", "no-such-experiment", "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sweep.report: unknown experiment 'no-such-experiment'")
    assert EXPERIMENT in err[0]
