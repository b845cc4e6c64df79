"""Where the anchor task's seeds end: per row, each seed's last evaluation's mean final distance to the target (m) and
crash share, and how many seeds end within 0.1, 0.2 and 0.3 m without a crash. The last evaluation is the one logged
last: at the end of a run two are logged at the last step (the periodic one, then the end's), and this takes the end's.
With FROM (a step), a last column: each seed's mean final distance over its periodic evaluations from that step on
(where a seed holds late in training, not at one evaluation).

    MLFLOW_TRACKING_URI=sqlite:////work/studies/anchor/mlflow.db python docs/anchor_task/distance.py 0-15 [KEY,...] [FROM]
"""
from __future__ import annotations

import sys

import numpy as np
from mlflow.tracking import MlflowClient

from sweep.report import load
from sweep.report.reliability import seed_list


def late_mean(client: MlflowClient, run_id: str, start: int) -> str:
    """The mean of the run's periodic ``eval/final_distance`` values from step ``start`` on (the end's second value at
    the last step left out), to 2 decimals; "–" for a run that ended before it."""
    history = sorted(client.get_metric_history(run_id, "eval/final_distance"), key=lambda m: (m.step, m.timestamp))
    values = {m.step: m.value for m in reversed(history) if m.step >= start}   # per step, the first logged
    return f"{np.mean(list(values.values())):.2f}" if values else "–"


def main(seeds: list[int], by: list[str], start: int | None = None) -> str:
    client = MlflowClient(load.tracking_uri())
    exp_id, _ = load.pick_experiment(client, "anchor-task")
    runs = load.read_runs(client, exp_id, by=by).runs
    runs = runs[runs["seed"].astype(int).isin(seeds)]
    late = [] if start is None else [f"mean final distance from {start // 1000}k, per seed"]
    lines = ["| " + " | ".join(["row", "seeds", "final distance, median (range)", "within 0.1 / 0.2 / 0.3 m",
                                "crashed at the last evaluation", *late]) + " |", "|---" * (5 + len(late)) + "|"]
    for key, group in runs.groupby(by or (lambda _: "")):
        last = {}
        for metric in ("eval/final_distance", "eval/crash_rate"):
            last[metric] = np.array([max(client.get_metric_history(r, metric), key=lambda m: (m.step, m.timestamp)).value
                                     for r in group["run_id"]])
        d, crashed = last["eval/final_distance"], last["eval/crash_rate"] > 0
        within = " / ".join(str(int(((d <= r) & ~crashed).sum())) for r in (0.1, 0.2, 0.3))
        name = ", ".join(f"{k.split('.')[-1]}={v}" for k, v in zip(by, key if isinstance(key, tuple) else (key,)))
        per_seed = "" if start is None else " " + ", ".join(
            late_mean(client, r, start) for r in group.sort_values("seed")["run_id"]) + " |"
        lines.append(f"| {name or 'preset'} | {len(d)} | {np.median(d):.2f} ({d.min():.2f}–{d.max():.2f}) | {within} | "
                     f"{int(crashed.sum())} |{per_seed}")
    return "\n".join(lines)


if __name__ == "__main__":
    print(main(seed_list(sys.argv[1]), [k for k in (sys.argv[2] if len(sys.argv) > 2 else "").split(",") if k],
               int(sys.argv[3]) if len(sys.argv) > 3 else None))
