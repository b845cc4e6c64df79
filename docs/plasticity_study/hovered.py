"""How many seeds hover in each segment: the per-segment count behind the AUC means.

Per change, agent and segment, from the report's segment_runs.csv: the seeds with an evaluation at >= 50% success
within the segment (the report's "hover", column hover_after set), over every seed and over the seeds that learned
segment 0 (the report's own flag, relearning_runs.csv's learned_first). A mean AUC mixes how many seeds hover with
how well; outcomes on the hover task are bimodal per seed, so the count says which. Added on 12-06 after the payload
change's tables were read (a reading, not a test). Only runs evaluated under the condition being learned
(eval.condition=current). Run from the repo root on a report folder (run.sh report writes it next to decline.md):

    .venv/bin/python docs/plasticity_study/hovered.py docs/plasticity_study/payload
"""
import sys
from pathlib import Path

import pandas as pd

from sweep.report.tables import markdown


def counts(per_segment: pd.DataFrame, learned: set[str] | None = None) -> pd.DataFrame:
    """Rows (wind, condition, seeds) with one "k/n" column per segment: k seeds hovered there, of n; with
    ``learned``, over those run ids only."""
    current = per_segment[per_segment["eval_condition"] == "current"].copy()
    current["hovered"] = current["hover_after"].notna()
    if learned is not None:
        current = current[current["run_id"].isin(learned)]
    rows = []
    for (wind, condition), runs in current.groupby(["wind", "condition"]):
        per = runs.groupby("segment")["hovered"].agg(["sum", "size"])
        rows.append({"Change": wind, "Agent": condition, "Seeds": runs["run_id"].nunique(),
                     **{str(seg): f"{int(k)}/{int(n)}" for seg, (k, n) in per.iterrows()}})
    return pd.DataFrame(rows).sort_values(["Change", "Agent"])


def main(folder: Path) -> None:
    per_segment = pd.read_csv(folder / "segment_runs.csv")
    per_run = pd.read_csv(folder / "relearning_runs.csv")   # the report's own "learned segment 0" per run
    learned = set(per_run.loc[per_run["learned_first"] == 1.0, "run_id"])
    print("Seeds with an evaluation at >= 50% success in each segment (k of n; docs/plasticity_study/hovered.py).\n")
    print("Every seed:\n")
    print(markdown(counts(per_segment)))
    print("\nThe seeds that learned segment 0:\n")
    print(markdown(counts(per_segment, learned)))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
