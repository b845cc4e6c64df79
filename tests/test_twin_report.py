"""The report's twin columns (twins.py) on a hand-built store: each agent against its own fresh twin, paired by seed,
beside Δ vs reset_all; segment 0 counted as the same run; the figure twins."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from mlflow.tracking import MlflowClient

from conftest import new_store
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
    ReDo's twin differs from it in segment 0 on seed 1 (1 of 2 pairs the same run), and that twin run, stuck in
    segment 0, hovers later."""
    uri = new_store(tmp_path / "mlflow.db")
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
    # stuck from the start: ReDo's twin's seed 1 never hovers in segment 0 and hovers in segment 1 (1 of 1, Wilson's
    # [0.21, 1]); every ReDo run learned segment 0 (no such runs: "–")
    assert shown.loc["redo", "…, own twin"] == "1/1 [0.21, 1.00]"
    assert shown.loc["redo", "Never learned segment 0: hovered later, agent"] == "–"

    panels = drawn["twins"]["panels"]   # the AUC per segment, then the paired Δ (in points)
    assert list(panels[0]["curves"]["layer_norm"]) == pytest.approx([62.5, 37.5, 12.5])
    assert list(panels[1]["curves"]["layer_norm"]) == pytest.approx([0.0, -62.5, -37.5])
    assert "twin" in panels[1]["ylabel"]


def test_a_twin_without_evaluations_leaves_its_cells_empty(tmp_path):
    """layer_norm_fresh ran without in-training evaluations: no pairs for LayerNorm ("–"), PPO's still there."""
    uri = new_store(tmp_path / "mlflow.db")
    log_segment_runs(MlflowClient(uri), "twins", [(a, TWIN_EVALS[a], [], "current") for a in ("ppo", "reset_all",
                                                                                               "layer_norm")]
                     + [("layer_norm_fresh", [[], [], []], [], "current")])
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "twins")
    assert code == 0, stdout + stderr
    shown = md_table(tmp_path / "out" / "twins.md").set_index("Agent")
    assert shown.loc["PPO", "Segment 0 the same run (pairs)"] == "2/2"
    assert shown.loc["layer_norm", "Segment 0 the same run (pairs)"] == "–"


def test_no_twins_no_twin_files(tmp_path):
    uri = new_store(tmp_path / "mlflow.db")
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


START = [1.0, 0.5, 0.2, 0.1]   # segment 0's final distances (m): mean 0.45
TWIN_DISTANCES = {   # agent -> each evaluation's mean final distance (m), as TWIN_EVALS' evaluations
    "reset_all": [START] * 3,                                                   # 0.45 in every segment
    "ppo": [START, [0.2] * 4, [2.0] * 4],                                       # re-learning distance 1.1
    "layer_norm": [START, [0.4] * 4, [0.8] * 4],                                # 0.6
    "layer_norm_fresh": {0: [START, [0.2] * 4, [0.2] * 4],                      # 0.2
                         1: [START, [0.2] * 4, [0.4] * 4]},                     # 0.3
    "redo": [START, [0.3] * 4, [0.3] * 4],
    "redo_fresh": {0: [START, [0.3] * 4, [0.3] * 4],
                 1: [[1.0, 0.5, 0.2, 0.2], [0.3] * 4, [0.3] * 4]},   # seed 1: success alike, a distance not
}


def test_the_re_learning_distance_against_its_own_twin_on_hand_built_evaluations(tmp_path):
    """The evaluations' final distances beside their success: LayerNorm flies 0.4 and 0.8 m out after the changes
    where its twin flies 0.2/0.2 and 0.2/0.4 m (by seed): Δ +0.35 m [0.3, 0.4], P(nearer than own twin) 0; PPO
    1.1 m against reset_all's 0.45 (+0.65); ReDo's twin flew segment 0 with the same success but not the same
    distances on seed 1, so 1 of 2 pairs is the same run."""
    uri = new_store(tmp_path / "mlflow.db")
    evals = {**TWIN_EVALS, "redo_fresh": [SAME_0, [1.0] * 4, [1.0] * 4]}
    log_segment_runs(MlflowClient(uri), "twins", [(a, evals[a], [], "current") for a in TWIN_DISTANCES],
                     distances=TWIN_DISTANCES)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "twins")
    assert code == 0, stdout + stderr
    runs = pd.read_csv(tmp_path / "out" / "relearning_runs.csv").groupby("agent")
    assert runs["relearning_distance"].mean().to_dict() == pytest.approx(
        {"reset_all": 0.45, "ppo": 1.1, "layer_norm": 0.6, "layer_norm_fresh": 0.25, "redo": 0.3, "redo_fresh": 0.3})
    assert runs["first_distance"].mean().to_dict() == pytest.approx(
        {"reset_all": 0.45, "ppo": 0.45, "layer_norm": 0.45, "layer_norm_fresh": 0.45, "redo": 0.45,
         "redo_fresh": 0.4625})

    got = pd.read_csv(tmp_path / "out" / "twins.csv").set_index(["agent", "segment"])
    assert list(got.loc["layer_norm", "distance_vs_twin"]) == pytest.approx([0.0, 0.2, 0.5])
    assert got.loc[("layer_norm", 2), "distance_vs_twin_low"] == pytest.approx(0.4)
    assert got.loc[("layer_norm", 2), "distance_vs_twin_high"] == pytest.approx(0.6)
    assert got.loc[("layer_norm", 0), "same_pairs"] == 2 and got.loc[("redo", 0), "same_pairs"] == 1

    shown = md_table(tmp_path / "out" / "twins.md").set_index("Agent")
    assert shown.loc["layer_norm", "Re-learning distance Δ vs own twin (m) [95% CI]"] == "0.35 [0.30, 0.40]"
    assert shown.loc["layer_norm", "P(nearer than own twin) [95% CI]"] == "0.00 [0.00, 0.00]"
    assert shown.loc["PPO", "Re-learning distance Δ vs own twin (m) [95% CI]"] == "0.65 [0.65, 0.65]"
    assert shown.loc["redo", "Segment 0 the same run (pairs)"] == "1/2"
    assert shown.loc["redo", "P(nearer than own twin) [95% CI]"] == "0.50 [0.50, 0.50]"   # ties count half

    table = md_table(tmp_path / "out" / "relearning.md").set_index("Agent")
    assert table.loc["PPO", "Re-learning distance (m)"] == "1.10 ± 0.00"
    assert table.loc["PPO", "Distance Δ vs reset_all (m) [95% CI]"] == "0.65 [0.65, 0.65]"
    assert (tmp_path / "out" / "interval_relearning_distance.png").exists()
    assert (tmp_path / "out" / "eval_distance_flip.png").exists()


def test_without_logged_distances_the_distances_are_nan():
    """Runs that did not log eval/final_distance during training (older stores): the segments' distances and the
    run's re-learning distance are NaN, its re-learning AUC as before."""
    from sweep.report import relearning

    histories = pd.DataFrame({"run_id": "a", "key": "eval/success_rate", "step": [100, 200, 300, 400],
                              "value": [0.0, 1.0, 0.5, 1.0]})
    runs = pd.DataFrame({"run_id": ["a"], "segment_steps": [200.0], "total_timesteps": [400],
                         "eval_condition": ["current"]})
    seg = stats.segment_evaluations(histories, runs)
    assert list(seg["auc"]) == [0.5, 0.75] and seg["distance_auc"].isna().all()
    per_run = relearning.per_run(seg, runs)
    assert per_run["relearning"].iloc[0] == 0.75 and np.isnan(per_run["relearning_distance"].iloc[0])


def test_a_lower_is_better_interval_measure_draws_its_lowest_row_on_top():
    from sweep.report import intervals
    from sweep.report.conditions import build

    runs = pd.DataFrame({"run_id": list("abcd"), "agent": ["ppo", "ppo", "layer_norm", "layer_norm"],
                         "wind": "flip", "seed": [0, 1, 0, 1], "start_time": 0, "label": ["PPO", "PPO", "LN", "LN"],
                         "relearning_distance": [1.0, 1.2, 0.2, 0.4]})
    runs, conds = build(runs, [])
    table = intervals.estimates(runs, intervals.MEASURES["relearning_distance"], conds)
    assert list(table["agent"]) == ["ppo", "layer_norm"]   # the last row is drawn at the top: the nearest
    assert table["point"].tolist() == pytest.approx([1.1, 0.3])
    wide = runs.assign(relearning_distance=[1.0, 1.02, 0.0, 0.6])   # LayerNorm's t-interval reaches below 0
    cut = intervals.estimates(wide, intervals.MEASURES["relearning_distance"], conds).set_index("agent")
    assert cut.loc["layer_norm", "low"] == 0.0 and cut.loc["layer_norm", "cut"]
    assert cut.loc["layer_norm", "high"] > 2.0 and not cut.loc["ppo", "cut"]


def test_the_fresh_twins_are_left_out_of_the_reading_correlation():
    """A twin's probe at a change reads its fresh draw (as reset_all's): only the continual runs are correlated."""
    from sweep.report import relearning

    agents = ["layer_norm"] * 3 + ["layer_norm_fresh"] * 3 + ["reset_all"] * 3
    runs = pd.DataFrame({"run_id": [f"r{i}" for i in range(9)], "agent": agents, "wind": "flip",
                         "condition": agents})
    relearn = pd.DataFrame({"run_id": runs["run_id"], "relearning": np.linspace(0.1, 0.9, 9), "learned_first": 1.0})
    readings = pd.DataFrame({"run_id": runs["run_id"], "probe_first": np.linspace(1.0, 0.2, 9)})
    corr = relearning.reading_correlation(runs, relearn, readings).set_index("across")
    assert corr.loc[relearning.ALL_RUNS, "n"] == 3 and corr.loc[relearning.ALL_RUNS, "rho"] == pytest.approx(-1.0)
