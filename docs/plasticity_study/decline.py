"""Does an agent re-learn less late in the run than early? The test of "a schedule that freezes learning late".

The earlier conclusion (docs/remedies_study.md: a small late step size keeps the hover) predicts that under a change
the network must re-learn, an LR decay re-learns well while its step size is large and badly once it is small. Per
run, from the report's segment_runs.csv (every run's per-segment eval-success AUC):

    early = the mean AUC over segments 1-2 (3M-9M: the 8M decay's LR still above its floor for most of it),
    late  = the mean AUC over segments 3-5 (9M-18M: the 8M decay at its floor, the linear one below half its LR),
    decline = early - late (percentage points; > 0: re-learns less late).

Per change and agent: the mean decline (95% Student-t CI) and its difference to PPO's decline (constant LR;
95% percentile bootstrap, sweep.report.stats). Over every seed, and over the seeds that learned segment 0 (an
evaluation at >= 50% in it; reset_all's later segments are fresh networks, so all its seeds). Defined on 12-05,
after main-flip's 8 seeds of every agent had been seen in the report (not computed on them), before the extra
seeds and the payload change. Only runs evaluated under the condition being learned (eval.condition=current).
Run from the repo root on a report folder (run.sh report writes docs/plasticity_study/main):

    .venv/bin/python docs/plasticity_study/decline.py docs/plasticity_study/main
"""
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from sweep.report import stats
from sweep.report.tables import interval, plus_minus

EARLY, LATE = (1, 2), (3, 4, 5)


def declines(per_segment: pd.DataFrame) -> pd.DataFrame:
    """Per run (segment_runs.csv rows evaluated under eval.condition=current, with every segment of EARLY and
    LATE): early, late and decline (fractions), and whether it learned segment 0."""
    current = per_segment[per_segment["eval_condition"] == "current"]
    rows = []
    # by seed, not run id alone: a store re-made from the archive gives its runs new ids, and the bootstrap's
    # resampling follows the row order
    for (wind, agent, condition, _, run_id), run in current.groupby(["wind", "agent", "condition", "seed", "run_id"]):
        auc = run.set_index("segment")["auc"]
        if not set(EARLY + LATE) <= set(auc.index):
            continue
        early, late = auc.loc[list(EARLY)].mean(), auc.loc[list(LATE)].mean()
        learned = bool(run.loc[run["segment"] == 0, "hover_after"].notna().any())
        rows.append({"wind": wind, "agent": agent, "condition": condition, "run_id": run_id, "early": early,
                     "late": late, "decline": early - late, "learned_first": learned or agent == "reset_all"})
    return pd.DataFrame(rows)


def table(runs: pd.DataFrame) -> str:
    """Markdown: per change and condition (sorted by the mean decline), the seeds, the mean early and late AUC (%),
    the mean decline ± 95% t CI and its difference to PPO's [95% bootstrap CI] (points)."""
    lines = ["| Change | Agent | Seeds | Early (%) | Late (%) | Decline (pp) | Decline − PPO's (pp) [95% CI] |",
             "|---|---|---|---|---|---|---|"]
    for wind, change in runs.groupby("wind"):
        ppo = change.loc[change["agent"] == "ppo", "decline"]
        for condition in change.groupby("condition")["decline"].mean().sort_values().index:
            mine = change[change["condition"] == condition]
            mean, half, n = stats.mean_t_ci(100 * mine["decline"])
            versus = (stats.mean_diff_ci(100 * mine["decline"], 100 * ppo) if (mine["agent"] != "ppo").all()
                      else (np.nan,) * 3)
            lines.append(f"| {wind} | {condition} | {n} | {100 * mine['early'].mean():.0f} | "
                         f"{100 * mine['late'].mean():.0f} | {plus_minus(mean, half, 0)} | {interval(*versus, 0)} |")
    return "\n".join(lines)


def main(report: str = "") -> None:
    if not report:
        sys.exit("usage: decline.py REPORT_FOLDER (with segment_runs.csv: python -m sweep.report --out ...)")
    runs = declines(pd.read_csv(Path(report) / "segment_runs.csv"))
    print("Every seed:\n\n" + table(runs))
    print("\nThe seeds that learned segment 0 (reset_all: every seed):\n\n" + table(runs[runs["learned_first"]]))


if __name__ == "__main__":
    main(*sys.argv[1:])
