"""Do larger weights at the changes go with worse re-learning? A test fixed before the payload change was read.

On the flip change, the report's rank correlation of the weight norm at the changes with the re-learning AUC was
+0.46 within the runs that learned segment 0, driven by the agents at its two ends (shrink-and-perturb: the
smallest weights and the least re-learning; LayerNorm: among the largest and the best). With those left out, the
other learned runs gave -0.45 [-0.69, -0.13]: a reading made after seeing the data (docs/plasticity_study.md,
"Does the probe, or another plasticity reading, predict re-learning?"). Fixed in commit abe3d96 (12-05 22:48),
when 30 of the payload change's 144 runs had FINISHED and their results had not been read beyond the study's
progress listing (which prints each run's per-segment success), the test on the payload change is:

    runs: evaluated under the condition being learned, that learned segment 0 (learned_first = 1), of every agent
          but reset_all (fresh networks), LayerNorm and the combination (LayerNorm + L2 + LR decay by 8M: the same
          normalisation, left out with it) and shrink-and-perturb;
    rho:  Spearman's rank correlation between weight_norm_at_changes (the policy and value networks' weight norm,
          the last value logged at or before each change, averaged over the run's changes) and relearning (the
          mean eval-success AUC over the segments after the first), with its 95% bootstrap CI
          (sweep.report.relearning.spearman_ci);
    confirmed if the CI lies below 0; not confirmed otherwise.

It reads the report's relearning_runs.csv (every run's measures and readings), as sweep.report computes them at
abe3d96 (learned_first, the readings at the changes, spearman_ci's resamples and seed); later edits of this file
change its wording only, but one: the fresh twins (``<agent>_fresh``, issue 56, run after the test was fixed) are
fresh networks at every change as reset_all is, and are left out with it (relearning.fresh_draws). The flip's row is
the reading that suggested the test, not a test. Run from the repo root on a report folder:

    .venv/bin/python docs/plasticity_study/weight_norm.py docs/plasticity_study/main
"""
import sys
from pathlib import Path

import pandas as pd

from sweep.report.relearning import fresh_draws, spearman_ci
from sweep.report.tables import interval, markdown

LEFT_OUT = ("reset_all", "layer_norm", "layer_norm_l2_lr_decay_8m", "shrink_perturb")
READING = "weight_norm_at_changes"


def test(runs: pd.DataFrame) -> pd.DataFrame:
    """Per change (wind): n, rho and its CI over the learned runs of the agents not LEFT_OUT, and the verdict."""
    kept = runs[(runs["learned_first"] == 1.0) & ~runs["agent"].isin(LEFT_OUT) & ~fresh_draws(runs["agent"])]
    rows = []
    for wind, change in kept.groupby("wind"):
        rho, low, high, n = spearman_ci(change[READING], change["relearning"])
        verdict = "confirmed" if high < 0 else "not confirmed"
        rows.append({"Change": wind, "Runs": n, "Agents": change["agent"].nunique(),
                     "ρ [95% CI]": interval(rho, low, high, 2),
                     "Verdict": "post hoc (suggested the test)" if wind == "flip" else verdict})
    return pd.DataFrame(rows)


def main(folder: Path) -> None:
    runs = pd.read_csv(folder / "relearning_runs.csv")
    table = test(runs)
    print("Larger weights at the changes, worse re-learning? Spearman's ρ between the weight norm at the changes and "
          "the re-learning AUC, within the runs that learned segment 0, every agent but " + ", ".join(LEFT_OUT)
          + " and the fresh twins (docs/plasticity_study/weight_norm.py). Confirmed if the 95% CI lies below 0.\n")
    print(markdown(table))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
