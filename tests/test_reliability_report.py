"""The reliability table (sweep.report.reliability) on a hand-built MLflow store: shares within each budget with their
Wilson intervals and censored seeds, the steps and wall seconds to the first hovering evaluation, the share hovering at
the end, and the share-hovering curve of the figure."""
from __future__ import annotations

import contextlib
import io

import numpy as np
import pandas as pd
import pytest
from mlflow.entities import Metric, Param
from mlflow.tracking import MlflowClient

from sweep.report import reliability, stats

START = 1_700_000_000_000   # ms
K = 1000
# row A (no action history): per seed, (step, success) evaluations, taken after the update that passes each multiple of
# eval.every_timesteps (100k; +1,472 as rollouts of 2048 steps place them). s0 hovers at 200k and keeps it; s1 never;
# s2 reaches 50% exactly at 800k, 95% at 2M, then loses it; s3's run ended at 500k without hovering (censored after).
LATE = 1472
A = {0: [(100 * K, 0.0), (200 * K + LATE, 0.6), (500 * K, 1.0), (1000 * K + LATE, 1.0), (3000 * K + LATE, 1.0)],
     1: [(100 * K, 0.0), (1000 * K, 0.1), (3000 * K, 0.0)],
     2: [(100 * K, 0.0), (800 * K + LATE, 0.5), (2000 * K + LATE, 0.95), (3000 * K + LATE, 0.2)],
     3: [(100 * K, 0.0), (500 * K + LATE, 0.0)]}
B = {0: [(100 * K, 1.0), (1000 * K, 1.0)], 1: [(100 * K, 0.9), (1000 * K + LATE, 0.7)]}


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> str:
    uri = f"sqlite:///{tmp_path_factory.mktemp('rel')}/mlflow.db"
    client = MlflowClient(uri)
    exp = client.create_experiment("rel")
    for history, k in ((A, 0), (B, 8)):
        for seed, evals in history.items():
            run = client.create_run(exp, start_time=START, tags={
                "agent": "td3", "agent_label": "TD3", "learner": "jax", "wind": "none", "seed": str(seed),
                "run_name": f"td3-h{k}-s{seed}", "sweep": "hand"})
            metrics = [Metric("eval/success_rate", v, START + step, step) for step, v in evals]  # 1 s per 1k steps
            client.log_batch(run.info.run_id, metrics=metrics, params=[Param("env.observe.action_history", str(k)),
                                                                        Param("eval.every_timesteps", "100000")])
            client.set_terminated(run.info.run_id)
    return uri


def run(store: str, tmp_path, *args: str) -> tuple[int, str, str]:
    mp = pytest.MonkeyPatch()
    mp.setenv("MLFLOW_TRACKING_URI", store)
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = reliability.main(["--out", str(tmp_path), *args])
    finally:
        mp.undo()
    return code, out.getvalue(), err.getvalue()


def test_the_table_is_a_hand_count_with_censored_seeds_left_out(store, tmp_path):
    code, out, _ = run(store, tmp_path, "--experiment", "rel", "--by", "env.observe.action_history")
    assert code == 0 and "6 finished runs, 2 rows" in out
    numbers = pd.read_csv(tmp_path / "reliability.csv")
    a = numbers[numbers["row"] == "TD3 [jax, none] observe.action_history=0"].set_index("threshold")
    # 50%: s0 by 300k; s0 and s2 by 1M, of 3 seeds (s3 ended at 500k without it)
    assert (a.loc[0.5, "reached_300k"], a.loc[0.5, "n_300k"]) == (0.25, 4)
    assert (a.loc[0.5, "reached_1M"], a.loc[0.5, "n_1M"]) == (pytest.approx(2 / 3), 3)
    assert (a.loc[0.5, "reached_3M"], a.loc[0.5, "n_3M"]) == (pytest.approx(2 / 3), 3)
    lo, hi = stats.wilson(2, 3)[1:]
    assert (a.loc[0.5, "reached_1M_low"], a.loc[0.5, "reached_1M_high"]) == (pytest.approx(lo), pytest.approx(hi))
    assert lo == pytest.approx(0.2077, abs=1e-3) and hi == pytest.approx(0.9385, abs=1e-3)   # Wilson's, by hand
    assert a.loc[0.5, "median_steps"] == 500 * K   # 200k and 800k as scheduled
    assert a.loc[0.5, "median_wall_s"] == pytest.approx(500 + LATE / 1000)   # the wall clock as logged
    assert a.loc[0.5, "at_end"] == 0.25        # s2 lost it
    # 90%: s0 at 500k, s2 at 2M
    assert (a.loc[0.9, "reached_300k"], a.loc[0.9, "reached_1M"], a.loc[0.9, "reached_3M"]) == \
        (0.0, pytest.approx(1 / 3), pytest.approx(2 / 3))
    assert a.loc[0.9, "median_steps"] == 1250 * K and a.loc[0.9, "at_end"] == 0.25
    b = numbers[numbers["row"] == "TD3 [jax, none] observe.action_history=8"].set_index("threshold")
    assert b.loc[0.5, "reached_300k"] == 1.0 and b.loc[0.5, "at_end"] == 1.0 and b.loc[0.5, "reached_3M"] == 1.0
    assert b.loc[0.9, "at_end"] == 0.5 and b.loc[0.9, "censored_3M"] == 0   # both reached 90% by 100k: none censored
    assert a.loc[0.5, "censored_1M"] == 1 and a.loc[0.5, "censored_300k"] == 0   # s3 ran to 500k without hovering
    shown = (tmp_path / "reliability.md").read_text()
    assert "| TD3 [jax, none] observe.action_history=0 | 50% | 4 | 1/4 [5%, 70%] | ≥ 2/4, 1 ran < 1M | " \
           "≥ 2/4, 1 ran < 3M | 500k | 501 | 1/4 [5%, 70%] |" in shown
    assert "| TD3 [jax, none] observe.action_history=8 | 90% | 2 | 2/2 [34%, 100%] | 2/2 [34%, 100%] | " \
           "≥ 2/2, 0 ran < 3M" not in shown   # no seed ran short of 3M without reaching 90%: not a lower bound
    assert shown in out and (tmp_path / "hovering.png").stat().st_size > 10_000


def test_the_share_hovering_counts_a_seed_between_its_first_and_last_evaluation(store):
    from sweep.report import load
    client = MlflowClient(store)
    runs = load.read_runs(client, client.get_experiment_by_name("rel").experiment_id,
                          by=["env.observe.action_history", reliability.EVERY]).runs
    a = runs[runs["env.observe.action_history"] == "0"]
    histories = reliability.on_schedule(load.load_histories(client, a, ["eval/success_rate"]), a)
    steps, share, lo, hi = reliability.share_curve(histories, a)
    at = dict(zip(steps, share))
    assert at[100 * K] == 0 and at[200 * K] == 0.25 and at[1000 * K] == pytest.approx(2 / 3) and at[3000 * K] == 1 / 3
    assert np.all(lo <= share) and np.all(share <= hi)


def test_an_unknown_experiment_is_one_line(store, tmp_path):
    code, _, err = run(store, tmp_path, "--experiment", "nope")
    assert code == 2 and err.count("\n") == 1 and "nope" in err


def test_seeds_limits_the_table_to_the_seeds_named(store, tmp_path):
    assert reliability.seed_list("0-2,8") == [0, 1, 2, 8]
    code, out, _ = run(store, tmp_path, "--experiment", "rel", "--by", "env.observe.action_history", "--seeds", "0,2-3")
    assert code == 0 and "4 finished runs, 2 rows" in out   # A's s0, s2, s3 and B's s0
    a = pd.read_csv(tmp_path / "reliability.csv").set_index(["row", "threshold"])
    assert a.loc[("TD3 [jax, none] observe.action_history=0", 0.5), "n_300k"] == 3
    code, _, err = run(store, tmp_path, "--experiment", "rel", "--seeds", "50-60")
    assert code == 2 and "no finished runs of those seeds" in err
