"""Read one experiment of the MLflow store back into pandas (the only module that reads the store).

* ``runs``: one row per FINISHED run: run_id, agent, wind, seed, sweep, the wind schedule and eval params,
  and the final ``eval/*`` metrics.
* ``histories``: long table (run_id, key, step, value) of the metric histories the report plots.
* ``trajectories``: the ``eval_trajectories.npz`` artifact of one run.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
from mlflow.exceptions import MlflowException  # noqa: E402
from mlflow.tracking import MlflowClient  # noqa: E402

EVAL_KEYS = ["eval/success_rate", "eval/mse_x", "eval/mse_y", "eval/mse_z", "eval/final_distance",
             "eval/return", "eval/crash_rate"]
CURVE_KEYS = ["rollout/ep_rew_mean", "plasticity/dormant_ratio", "train/learning_rate"]
PARAM_KEYS = {"wind.segment_steps": "segment_steps", "wind.speeds": "speeds", "train.total_timesteps": "total_timesteps",
              "eval.wind_speed": "eval_wind_speed", "eval.success_radius": "success_radius"}


class ReportError(Exception):
    """A problem the user must fix; reported as one line, exit code 1."""


def tracking_uri() -> str:
    """``$MLFLOW_TRACKING_URI`` if set, else the project's store (resolved exactly as the jobs resolve it)."""
    from sweep.tracking import tracking_uri as resolve  # noqa: PLC0415 - heavy import (SB3), only when needed

    return resolve(None)


def client_for(uri: str) -> MlflowClient:
    if uri.startswith("sqlite:///") and not Path(uri[len("sqlite:///"):]).exists():
        raise ReportError(f"no MLflow store at {uri} (run a sweep first)")
    return MlflowClient(tracking_uri=uri)


def pick_experiment(client: MlflowClient, name: str | None) -> tuple[str, str]:
    """(experiment id, name): the named one, else the experiment whose latest run started last."""
    if name is not None:
        exp = client.get_experiment_by_name(name)
        if exp is None:
            known = ", ".join(sorted(e.name for e in client.search_experiments())) or "none"
            raise ReportError(f"unknown experiment {name!r} (experiments in the store: {known})")
        return exp.experiment_id, exp.name
    latest = []
    for exp in client.search_experiments():
        runs = client.search_runs([exp.experiment_id], max_results=1, order_by=["attributes.start_time DESC"])
        if runs:
            latest.append((runs[0].info.start_time, exp.experiment_id, exp.name))
    if not latest:
        raise ReportError("the MLflow store has no runs (run a sweep first, e.g. python -m sweep -m experiment=demo)")
    _, exp_id, exp_name = max(latest)
    return exp_id, exp_name


def _all_runs(client: MlflowClient, exp_id: str) -> list:
    runs, token = [], None
    while True:
        page = client.search_runs([exp_id], max_results=1000, page_token=token)
        runs.extend(page)
        token = page.token
        if not token:
            return runs


def matches_sweep(tag: str, sweep: str | None) -> bool:
    """``sweep`` is an existing directory (exact match of the resolved path) or a substring of the tag."""
    if sweep is None:
        return True
    if Path(sweep).is_dir():
        return tag == str(Path(sweep).resolve())
    return sweep in tag


def load_runs(client: MlflowClient, exp_id: str, sweep: str | None = None) -> tuple[pd.DataFrame, list[str]]:
    """(finished runs as a DataFrame, notes about runs left out)."""
    rows, notes = [], []
    for run in _all_runs(client, exp_id):
        tags, params, metrics = run.data.tags, run.data.params, run.data.metrics
        if not matches_sweep(tags.get("sweep", ""), sweep):
            continue
        name = tags.get("run_name", run.info.run_id[:8])
        if run.info.status != "FINISHED":
            notes.append(f"left out run {name} ({run.info.status})")
            continue
        row = {"run_id": run.info.run_id, "agent": tags.get("agent", "?"), "wind": tags.get("wind", "?"),
               "seed": int(tags.get("seed", -1)), "sweep": tags.get("sweep", ""), "run_name": name,
               "start_time": run.info.start_time}
        row.update({short: params.get(key) for key, short in PARAM_KEYS.items()})
        row.update({key: metrics.get(key, np.nan) for key in EVAL_KEYS})
        rows.append(row)
    df = pd.DataFrame(rows)
    if df.empty:
        return df, notes
    df["segment_steps"] = pd.to_numeric(df["segment_steps"], errors="coerce")
    df["speeds"] = df["speeds"].map(lambda s: json.loads(s) if isinstance(s, str) else [])
    df = df.sort_values(["agent", "wind", "seed", "start_time"])
    dupes = df.duplicated(["agent", "wind", "seed"], keep="last")
    if dupes.any():
        notes.append(f"{int(dupes.sum())} older duplicate run(s) of the same agent/wind/seed left out "
                     "(use --sweep to pick one sweep)")
        df = df[~dupes]
    return df.reset_index(drop=True), notes


def load_histories(client: MlflowClient, run_ids, keys=CURVE_KEYS) -> pd.DataFrame:
    """Long table: run_id, key, step, value (sorted by step; a repeated step keeps its last value)."""
    frames = []
    for run_id in run_ids:
        for key in keys:
            hist = client.get_metric_history(run_id, key)
            if hist:
                frames.append(pd.DataFrame({"run_id": run_id, "key": key, "step": [m.step for m in hist],
                                            "value": [m.value for m in hist], "ts": [m.timestamp for m in hist]}))
    if not frames:
        return pd.DataFrame(columns=["run_id", "key", "step", "value"])
    df = pd.concat(frames, ignore_index=True).sort_values(["run_id", "key", "step", "ts"])
    return df.drop_duplicates(["run_id", "key", "step"], keep="last").drop(columns="ts").reset_index(drop=True)


def load_trajectories(client: MlflowClient, run_id: str) -> dict[str, np.ndarray] | None:
    """The run's ``eval_trajectories.npz`` as a dict of arrays, or None if the run has none."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            path = client.download_artifacts(run_id, "eval_trajectories.npz", tmp)
        except (MlflowException, OSError):
            return None
        with np.load(path) as npz:
            return {k: npz[k] for k in npz.files}
