"""Re-evaluation (``sweep.reevaluate``) of real tiny runs' stored policies: under another protocol it scores what a
run evaluated under that protocol logged, under its own protocol what the run itself logged, on both learners;
bad input fails before any flight with one line."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from omegaconf import OmegaConf
from mlflow.tracking import MlflowClient

from conftest import TINY, compose_cfg, new_store
from sweep import metrics
from sweep.archive import export, import_
from sweep.reevaluate import main, parse_overrides, run_config, table
from sweep.run import run

EXP = "recom-hover"  # conf/config.yaml tracking.experiment
FIELDS = [f.name for f in metrics.EVAL_FIELDS]


def logged(uri: str, run_id: str, prefix: str = "") -> dict[str, dict[str, float]]:
    """{policy: {field: value}} of the policies the run scored under ``prefix`` (a tiny run keeps no best_eval)."""
    data = MlflowClient(uri).get_run(run_id).data.metrics
    return {p: {f: data[f"{prefix}{metrics.eval_key(p, f)}"] for f in FIELDS} for p in metrics.POLICIES
            if f"{prefix}{metrics.eval_key(p, 'success_rate')}" in data}


def test_another_protocol_scores_what_a_run_evaluated_under_it_logged(store, tmp_path, capsys):
    # Evaluation does not touch training: the same seed trained with eval.wind_speed 3 and 0 learns the same policy,
    # so re-evaluating the first run in still air must give exactly what the second logged.
    windy = run(compose_cfg(["agent=ppo", "seed=1", "wind=paper", *TINY]), tmp_path / "a")
    still = run(compose_cfg(["agent=ppo", "seed=1", "wind=paper", "eval.wind_speed=0", *TINY]), tmp_path / "b")
    assert main(["--experiment", EXP, "--where", "seed=1", "--where", "eval.wind_speed=3.0", "--name", "still_air",
                 "--out", str(tmp_path / "t.md"), "--vs", "ppo", "eval.wind_speed=0"]) == 0
    again, target, before = logged(store, windy, "still_air/"), logged(store, still), logged(store, windy)
    assert again == target and set(again) == {"final", "best"}
    assert again["final"] != before["final"]  # the wind did change the flights (else the check above shows nothing)
    client = MlflowClient(store)
    run_info = client.get_run(windy)
    assert run_info.info.status == "FINISHED" and run_info.data.tags["reeval.still_air"] == "eval.wind_speed=0"
    assert logged(store, windy) == before  # the run's own evaluation is untouched
    step = client.get_metric_history(windy, "still_air/eval/success_rate")[0].step
    assert step == client.get_metric_history(windy, "eval/success_rate")[-1].step
    out = capsys.readouterr().out
    assert "| Agent | Seeds | Success final (%) (per seed) | Success best (%) (per seed) | Δ final vs PPO (pp) |" in out
    assert "| PPO | 1 |" in out
    assert (tmp_path / "t.md").read_text().startswith("# Re-evaluation 'still_air' (eval.wind_speed=0) of 1 run(s)")
    assert not any(k.startswith("still_air/") for k in client.get_run(still).data.metrics)  # not selected

    # Without the eval filter both runs are agent ppo, wind paper, seed 1: like the report, the newest counts.
    assert main(["--experiment", EXP, "--where", "seed=1", "--name", "dup"]) == 0
    assert "left out 1 older run(s) of an agent, wind and seed run again: ppo-paper-s1" in capsys.readouterr().err
    assert not any(k.startswith("dup/") for k in client.get_run(windy).data.metrics)
    assert any(k.startswith("dup/") for k in client.get_run(still).data.metrics)

    # --policy: only that stored policy is flown (the transfer-gap study flies the kept one under each condition)
    assert main(["--experiment", EXP, "--where", "seed=1", "--name", "only", "--policy", "best"]) == 0
    flown = {k.split("/")[1] for k in client.get_run(still).data.metrics if k.startswith("only/")}
    assert flown == {"eval_best"}


def test_a_jax_run_under_its_own_protocol_matches_its_logged_evaluation(store, tmp_path):
    # The JAX learner stores its policy as an SB3 model, flown here with torch's forward pass instead of XLA's.
    run_id = run(compose_cfg(["agent=layer_norm", "agent.learner=jax", "seed=2", "wind=paper", *TINY]),
                 tmp_path / "a")
    assert main(["--experiment", EXP, "--where", "agent=layer_norm", "--name", "again"]) == 0
    again, own = logged(store, run_id, "again/"), logged(store, run_id)
    assert set(again) == set(own) == {"final", "best"}
    for policy in own:
        assert again[policy]["success_rate"] == own[policy]["success_rate"]
        assert again[policy]["crash_rate"] == own[policy]["crash_rate"]
        np.testing.assert_allclose([again[policy][f] for f in FIELDS], [own[policy][f] for f in FIELDS],
                                   rtol=1e-3, err_msg=policy)


def test_bad_input_fails_before_any_flight_with_one_line(store, tmp_path, capsys):
    run_id = run(compose_cfg(["agent=ppo", "seed=0", "wind=paper", *TINY]), tmp_path / "a")
    capsys.readouterr()
    cases = [
        (["agent.ppo.learning_rate=1"], "only eval.KEY=VALUE overrides, KEY one of condition, wind_speed, direction"),
        (["eval.policy=final"], "only eval.KEY=VALUE overrides"),
        (["eval.episodes=0"], "eval.episodes"),
        (["--where", "seed=9"], "no FINISHED run of 'recom-hover' matches seed=9"),
        (["--where", "nope=1"], "--where nope: no FINISHED run of 'recom-hover' has that tag or param"),
        (["--where", "seed=0", "--where", "seed=1"], "--where seed: given twice"),
        (["--where", "seed"], "expected KEY=VALUE"),
        (["--name", "eval_best"], "--name 'eval_best'"),
        (["--vs", "l2"], "--vs l2: no selected run of that agent"),
    ]
    for args, message in cases:
        name = [] if "--name" in args else ["--name", "x"]
        assert main(["--experiment", EXP, *name, *args]) == 2, args
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, (args, err)
    assert not any(key.startswith("x/") for key in MlflowClient(store).get_run(run_id).data.metrics)

    # Every run's config is checked before the first flight: a later run whose stored eval block lacks a key
    # (edited here on disk) stops the command before the earlier, valid run is flown.
    later = run(compose_cfg(["agent=ppo", "seed=1", "wind=paper", *TINY]), tmp_path / "b")
    stored = Path(MlflowClient(store).get_run(later).info.artifact_uri.removeprefix("file://")) / "config.yaml"
    cfg = OmegaConf.load(stored)
    del cfg.eval["success_hold_s"]
    OmegaConf.save(cfg, stored)
    assert main(["--experiment", EXP, "--name", "x", "eval.wind_speed=0"]) == 2
    assert "eval.success_hold_s: missing" in capsys.readouterr().err
    assert not any(key.startswith("x/") for key in MlflowClient(store).get_run(run_id).data.metrics)


def test_a_run_without_stored_models_is_skipped_and_named(store, tmp_path, capsys):
    run(compose_cfg(["agent=ppo", "seed=3", "wind=paper", "tracking.log_model=false", *TINY]), tmp_path / "a")
    assert main(["--experiment", EXP, "--name", "x"]) == 1
    assert "skipped 1 run(s) without a stored config or model: ppo-paper-s3" in capsys.readouterr().err


def test_a_run_archived_with_its_models_scores_the_same_after_import(store, tmp_path, monkeypatch):
    # docs/remedies_study.md re-makes its still-air table from the archive: models exported, imported, flown.
    run_id = run(compose_cfg(["agent=ppo", "seed=5", "wind=none", *TINY]), tmp_path / "a")
    [path] = export(store, EXP, tmp_path / "archive", artifacts=("config.yaml", "model*"), where={"wind": "none"})
    target = new_store(tmp_path / "b.db")
    assert import_([path], target) == (1, 0)
    for uri in (store, target):
        assert main(["--experiment", EXP, "--uri", uri, "--name", "still_air", "eval.wind_speed=0"]) == 0
    [copy] = [r.info.run_id for r in MlflowClient(target).search_runs(
        [MlflowClient(target).get_experiment_by_name(EXP).experiment_id])]
    assert logged(target, copy, "still_air/") == logged(store, run_id, "still_air/")


def test_a_run_whose_config_predates_a_newer_key_is_checked_on_eval_alone(tmp_path):
    # The remedies study's wind-none runs were trained before agent.ppo.lr_decay_timesteps existed.
    plain = OmegaConf.to_container(compose_cfg(TINY), resolve=True)
    del plain["agent"]["ppo"]["lr_decay_timesteps"]
    OmegaConf.save(OmegaConf.create(plain), tmp_path / "config.yaml")
    assert run_config(tmp_path / "config.yaml", parse_overrides(["eval.wind_speed=0"])).eval.wind_speed == 0
    with pytest.raises(ValueError, match=r"eval.wind_speed=-1: must be a number >= 0"):
        run_config(tmp_path / "config.yaml", parse_overrides(["eval.wind_speed=-1"]))


def test_the_table_gives_each_agent_its_seed_mean_ci_and_difference_to_the_baseline():
    rows = pd.DataFrame({"agent": ["ppo"] * 3 + ["layer_norm"] * 3, "label": ["PPO"] * 3 + ["LayerNorm"] * 3,
                         "wind": ["none"] * 6,
                         "seed": [2, 0, 1] * 2, "final_success_rate": [0.0, 0.0, 0.3, 1.0, 0.5, 0.9],
                         "best_success_rate": [1.0, 0.0, 0.0, 1.0, 1.0, 1.0], "final_crash_rate": [1, 1, 0, 0, 0, 0]})
    t = table(rows, vs="ppo").set_index("Agent")
    assert list(t.index) == ["LayerNorm", "PPO"]
    half = stats.t.ppf(0.975, 2) * stats.sem([50, 90, 100])
    assert t.loc["LayerNorm", "Success final (%) (per seed)"] == f"80 ± {half:.0f} (50, 90, 100)"  # sorted by seed
    assert t.loc["PPO", "Success best (%) (per seed)"].endswith("(0, 0, 100)")
    assert t.loc["LayerNorm", "Δ final vs PPO (pp)"].startswith("70 [") and t.loc["PPO", "Δ final vs PPO (pp)"] == "–"
    assert t.loc["PPO", "Crash final (%)"] == "67"
