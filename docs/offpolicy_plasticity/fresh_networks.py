"""The off-policy pilot's segment-length measure: how soon does a fresh TD3 network learn under the change?

Every run's first segment and every later segment of a fresh twin (agent ``<name>_fresh``) start from freshly drawn
networks; the continual agent's later segments start from the network that learned the condition before. For each
segment, the timesteps from its start to its first evaluation (a) at >= 50% success (stats.segment_evaluations'
``hover_after``) and (b) whose flights end on average within NEAR m of the target (eval/final_distance), then how
many segments get there by each 100k steps (counting the evaluation that lands just after each mark). Run from the
repo root against the study's store:

    MLFLOW_TRACKING_URI=sqlite:////work/studies/offpolicy/mlflow.db .venv/bin/python \
        docs/offpolicy_plasticity/fresh_networks.py [EXPERIMENT] [NEAR]
"""
from __future__ import annotations

import sys

import numpy as np
import pandas as pd

from sweep.metrics import EVAL_DISTANCE
from sweep.report import load, stats


def near_after(histories: pd.DataFrame, runs: pd.DataFrame, near: float) -> pd.DataFrame:
    """Per run and segment (its evaluations at steps in (k S, (k+1) S], S = wind.segment_steps): the timesteps from
    the segment's start to its first evaluation with a mean final distance <= ``near`` (NaN if none)."""
    rows = []
    far = histories[histories["key"] == EVAL_DISTANCE]
    for run in runs.itertuples():
        h = far[far["run_id"] == run.run_id].drop_duplicates("step", keep="first").sort_values("step")
        k = np.ceil(h["step"].to_numpy(dtype=float) / run.segment_steps).astype(int) - 1
        for segment in np.unique(k[k >= 0]):
            at = h["step"].to_numpy()[(k == segment) & (h["value"].to_numpy() <= near)]
            rows.append({"run_id": run.run_id, "segment": int(segment),
                         "near_after": float(at[0] - segment * run.segment_steps) if len(at) else np.nan})
    return pd.DataFrame(rows, columns=["run_id", "segment", "near_after"])


def main(experiment: str = "offpolicy-plasticity", near: float = 0.3) -> None:
    client = load.client_for(load.tracking_uri())
    exp_id, _ = load.pick_experiment(client, experiment)
    runs = load.load_runs(client, exp_id)[0]
    histories = load.load_histories(client, runs)
    ev = stats.segment_evaluations(histories, runs).merge(near_after(histories, runs, near), how="left",
                                                          on=["run_id", "segment"])
    ev = ev.merge(runs[["run_id", "agent", "wind"]], on="run_id")   # wind: the arm, e.g. flip, none+payload
    length = int(runs["segment_steps"].max())
    marks = range(100_000, length + 1, 100_000)
    logged = histories.loc[histories["key"] == EVAL_DISTANCE, "step"].drop_duplicates().sort_values()
    slack = float(np.median(np.diff(logged))) / 2 if len(logged) > 1 else 0.0   # evaluations land just after a mark
    by = ", ".join(f"{m // 1000}k" for m in marks)
    print(f"| change | networks | segments | first hover (≥ 50% at the success radius) by {by} "
          f"| first mean final distance ≤ {near} m by the same | median steps to hover / near |")
    print("|---|---|---|---|---|---|")
    for wind, w in ev.groupby("wind"):
        twin = w["agent"].str.endswith("_fresh")
        fresh, later = w[(w["segment"] == 0) & ~twin | (w["segment"] > 0) & twin], w[(w["segment"] > 0) & ~twin]
        for name, part in (("fresh (every segment 0, the twins' later ones)", fresh),
                           ("continual, after a change", later)):
            counts = [" / ".join(str(int((part[c] <= m + slack).sum())) for m in marks)
                      for c in ("hover_after", "near_after")]
            print(f"| {wind} | {name} | {len(part)} | {counts[0]} | {counts[1]} | "
                  f"{part['hover_after'].median() / 1e3:.0f}k / {part['near_after'].median() / 1e3:.0f}k |")


if __name__ == "__main__":
    main(*(sys.argv[1:2]), *(float(x) for x in sys.argv[2:3]))
