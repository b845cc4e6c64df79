"""The report's twin columns (twins.py) on a hand-built store: each agent against its own fresh twin, paired by seed,
beside Δ vs reset_all; segment 0 counted as the same run; the figure twins."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from mlflow.tracking import MlflowClient

from sweep.report import stats
from test_report import SEGMENT_EVALS, log_segment_runs, md_table, run_report, spy_figures

SAME_0 = [0.0, 0.5, 1.0, 1.0]
TWIN_EVALS = {   # agent -> evaluations every 100 steps in three segments of 400 steps (a dict: by seed)
    **SEGMENT_EVALS,   # reset_all 62.5% AUC in every segment; PPO 62.5, 100, 12.5
    "layer_norm": [SAME_0, [0.0, 0.0, 0.5, 1.0], [0.0, 0.0, 0.0, 0.5]],              # AUC 62.5, 37.5, 12.5
    "layer_norm_fresh": {0: [SAME_0, [1.0] * 4, SAME_0],                              # 62.5, 100, 62.5
                         1: [SAME_0, [1.0] * 4, [0.0, 0.0, 0.5, 1.0]]},               # 62.5, 100, 37.5
    "redo": [SAME_0, [1.0] * 4, [1.0] * 4],
    "redo_fresh": {0: [SAME_0, [1.0] * 4, [0.0] * 4],
                   1: [[0.0] * 4, [1.0] * 4, [0.0] * 4]},   # seed 1's segment 0 differs: not the same run
}


def test_paired_difference_is_the_mean_of_per_seed_differences():
    x, y = pd.Series([0.5, 0.25, 1.0], index=[0, 1, 2]), pd.Series([0.0, 0.5, 0.5, 9.0], index=[0, 1, 2, 7])
    d, lo, hi, n = stats.paired_diff_ci(x, y)
    assert (d, n) == (pytest.approx((0.5 - 0.25 + 0.5) / 3), 3)   # seed 7 has no pair
    assert -0.25 <= lo <= d <= hi <= 0.5
    assert stats.paired_diff_ci(x.iloc[:1], y)[1:] == (pytest.approx(np.nan, nan_ok=True),) * 2 + (1,)


def test_each_agent_against_its_own_fresh_twin_on_hand_built_evaluations(tmp_path, monkeypatch):
    """LayerNorm re-learns 37.5 then 12.5% where its twin re-learns 100 and 62.5/37.5% (by seed): Δ -62.5 and
    -37.5 pp per segment, -50 pp on the re-learning AUC, P(> own twin) 0; PPO's twin is reset_all (Δ -6.25 pp);
    ReDo's twin differs from it in segment 0 on seed 1 (1 of 2 pairs the same run)."""
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    log_segment_runs(MlflowClient(uri), "twins", [(a, segs, [], "current") for a, segs in TWIN_EVALS.items()])
    drawn = spy_figures(monkeypatch)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "twins")
    assert code == 0, stdout + stderr
    got = pd.read_csv(tmp_path / "out" / "twins.csv").set_index(["agent", "segment"])
    ln = got.loc["layer_norm"]
    assert list(ln["twin"]) == ["layer_norm_fresh"] * 3
    assert list(ln["auc_vs_twin"]) == pytest.approx([0.0, -0.625, -0.375])
    assert list(ln["auc_vs_twin_low"])[:2] == list(ln["auc_vs_twin_high"])[:2] == pytest.approx([0.0, -0.625])
    assert ln.loc[2, "auc_vs_twin_low"] == pytest.approx(-0.5) and ln.loc[2, "auc_vs_twin_high"] == pytest.approx(-0.25)
    assert ln.loc[0, "same_pairs"] == 2 and got.loc[("redo", 0), "same_pairs"] == 1
    assert list(got.loc["ppo", "twin"]) == ["reset_all"] * 3
    assert list(got.loc["ppo", "auc_vs_twin"]) == pytest.approx([0.0, 0.375, -0.5])
    assert got.loc[("layer_norm_fresh", 1), "auc_mean"] == 1.0 and pd.isna(got.loc[("layer_norm_fresh", 1), "twin"])

    shown = md_table(tmp_path / "out" / "twins.md").set_index("Agent")
    assert set(shown.index) == {"PPO", "layer_norm", "redo"}   # the twins are not agents of their own here
    assert shown.loc["layer_norm", "Twin"] == "layer_norm_fresh"
    assert shown.loc["layer_norm", "Segment 0 the same run (pairs)"] == "2/2"
    assert shown.loc["redo", "Segment 0 the same run (pairs)"] == "1/2"
    assert shown.loc["layer_norm", "Re-learning AUC Δ vs own twin (pp) [95% CI]"] == "-50 [-56, -44]"
    assert shown.loc["layer_norm", "P(> own twin) [95% CI]"] == "0.00 [0.00, 0.00]"
    assert shown.loc["layer_norm", "Δ vs reset_all (pp) [95% CI]"] == "-38 [-38, -38]"   # 25% vs 62.5%
    assert shown.loc["PPO", "Re-learning AUC Δ vs own twin (pp) [95% CI]"] == "-6 [-6, -6]"
    assert shown.loc["layer_norm", "segment 1: Δ (pp)"] == "-62 [-62, -62]"

    panels = drawn["twins"]["panels"]   # the AUC per segment, then the paired Δ (in points)
    assert list(panels[0]["curves"]["layer_norm"]) == pytest.approx([62.5, 37.5, 12.5])
    assert list(panels[1]["curves"]["layer_norm"]) == pytest.approx([0.0, -62.5, -37.5])
    assert "twin" in panels[1]["ylabel"]


def test_a_twin_without_evaluations_leaves_its_cells_empty(tmp_path):
    """layer_norm_fresh ran without in-training evaluations: no pairs for LayerNorm ("–"), PPO's still there."""
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    log_segment_runs(MlflowClient(uri), "twins", [(a, TWIN_EVALS[a], [], "current") for a in ("ppo", "reset_all",
                                                                                               "layer_norm")]
                     + [("layer_norm_fresh", [[], [], []], [], "current")])
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "twins")
    assert code == 0, stdout + stderr
    shown = md_table(tmp_path / "out" / "twins.md").set_index("Agent")
    assert shown.loc["PPO", "Segment 0 the same run (pairs)"] == "2/2"
    assert shown.loc["layer_norm", "Segment 0 the same run (pairs)"] == "–"


def test_no_twins_no_twin_files(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    log_segment_runs(MlflowClient(uri), "seg", [("layer_norm", TWIN_EVALS["layer_norm"], [], "current"),
                                                ("reset_all", TWIN_EVALS["reset_all"], [], "current")])
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "seg")
    assert code == 0, stdout + stderr
    assert not (tmp_path / "out" / "twins.md").exists() and (tmp_path / "out" / "segment_scores.md").exists()


def test_a_failed_twin_job_is_filed_under_the_twins_name(tmp_path):
    """A twin job that ended FAILED without a run is reported as <agent>_fresh, its agent's as the agent."""
    import yaml

    from sweep.report.load import unrun_jobs
    from sweep.status import write_status

    for num, twin in ((0, None), (1, "fresh")):
        job = tmp_path / "sweep" / str(num)
        (job / ".hydra").mkdir(parents=True)
        agent = {"name": "layer_norm", "label": "LayerNorm PPO", **({"twin": twin} if twin else {})}
        (job / ".hydra" / "config.yaml").write_text(yaml.safe_dump(
            {"agent": agent, "wind": {"name": "flip"}, "seed": 3, "tracking": {"experiment": "twins"}}))
        write_status(job, "FAILED", reason="killed")
    cells = unrun_jobs([str(tmp_path / "sweep")], set(), "twins")
    assert [c["agent"] for c in cells] == ["layer_norm", "layer_norm_fresh"] and {c["seed"] for c in cells} == {3}
