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
seeds and the payload change. Run from the repo root on a report folder:

    .venv/bin/python docs/plasticity_study/decline.py docs/plasticity_study/main
"""
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from sweep.report import stats

EARLY, LATE = (1, 2), (3, 4, 5)


def declines(per_segment: pd.DataFrame) -> pd.DataFrame:
    """Per run: early, late and decline (fractions), and whether it learned segment 0."""
    rows = []
    for (wind, agent, seed), g in per_segment.groupby(["wind", "agent", "seed"]):
        auc = g.set_index("segment")["auc"]
        if not set(EARLY + LATE) <= set(auc.index):
            continue
        early, late = auc.loc[list(EARLY)].mean(), auc.loc[list(LATE)].mean()
        learned = 0 in auc.index and bool(g.loc[g["segment"] == 0, "hover_after"].notna().any())
        rows.append({"wind": wind, "agent": agent, "seed": seed, "early": early, "late": late,
                     "decline": early - late, "learned_first": learned or agent == "reset_all"})
    return pd.DataFrame(rows)


def table(d: pd.DataFrame) -> str:
    lines = ["| Change | Agent | Seeds | Early (%) | Late (%) | Decline (pp) | Decline − PPO's (pp) [95% CI] |",
             "|---|---|---|---|---|---|---|"]
    for wind, w in d.groupby("wind"):
        ppo = w.loc[w["agent"] == "ppo", "decline"]
        order = w.groupby("agent")["decline"].mean().sort_values().index
        for agent in order:
            g = w[w["agent"] == agent]
            mean, half, n = stats.mean_t_ci(100 * g["decline"])
            diff = stats.mean_diff_ci(g["decline"], ppo) if agent != "ppo" else (np.nan,) * 3
            versus = "–" if not np.isfinite(diff[0]) else "{:+.0f} [{:+.0f}, {:+.0f}]".format(*(100 * x for x in diff))
            lines.append(f"| {wind} | {agent} | {n} | {100 * g['early'].mean():.0f} | {100 * g['late'].mean():.0f} "
                         f"| {mean:+.0f} ± {half:.0f} | {versus} |")
    return "\n".join(lines)


def main(report: str) -> None:
    d = declines(pd.read_csv(Path(report) / "segment_runs.csv"))
    print("Every seed:\n\n" + table(d))
    print("\nThe seeds that learned segment 0 (reset_all: every seed):\n\n" + table(d[d["learned_first"]]))


if __name__ == "__main__":
    main(*sys.argv[1:])
