"""The metric registry (sweep.metrics) names what the runs really log, and the report reads only from it."""
from __future__ import annotations

import json
from pathlib import Path

from sweep import metrics
from sweep.report import figures, stats, tables

LOGGED = {name: set(h) for name, h in json.loads((Path(__file__).parent / "data" / "reference_histories.json")
                                                  .read_text())["runs"].items()}


def test_every_registered_key_is_logged_by_a_real_run():
    """The reference runs (tests/test_reference_history.py: real SB3 / JAX runs, eval during training, both best
    policies, RECOM) log every key the report reads; a renamed producer or a typo in the registry fails here."""
    for name in ("sb3_recom_l2", "jax_recom_l2"):
        missing = (set(metrics.EVAL_KEYS) | {c.key for c in metrics.CURVES}) - LOGGED[name]
        assert not missing, f"{name} does not log {sorted(missing)}"
    assert metrics.AT_BOUND not in LOGGED["jax_rare_paths"]  # and the RECOM key is RECOM's: a ReDo run lacks it


def test_the_report_reads_its_panels_and_columns_from_the_registry():
    """The figures, Table III and the summary columns the report writes are the registry's (the keys they read
    are checked against real runs above)."""
    assert list(figures.CURVES) == ["reward", "episode_length", "dormant", "weight_norm", "learning_rate",
                                    "eval_success", "eval_crash", "eval_distance", "ppo_update", "probe"]
    assert [c.key for c in figures.CURVES["dormant"]] == [
        "plasticity/dormant_ratio", "plasticity/dormant_ratio_tau0.1", "plasticity/dead_tanh_ratio",
        "plasticity/signed_mean_ratio", "plasticity/saturated_ratio"]
    assert stats.FINALS["final_reward"] == "rollout/ep_rew_mean" and stats.FINALS["final_probe_loss"] == metrics.PROBE
    assert [f.name for f in tables.TABLE3] == ["success_rate", "mse_x", "mse_y", "mse_z"]
    assert all(c.title for c in metrics.CURVES if c.final)  # every final value has its summary column title


def test_eval_keys_have_one_prefix_per_scored_policy():
    assert metrics.eval_key("final", "success_rate") == "eval/success_rate"
    assert metrics.eval_key("best", "return") == "eval_best/return"
    assert metrics.eval_key("best_eval", "source_step") == "eval_best_eval/source_step"
    assert len(metrics.EVAL_KEYS) == len(set(metrics.EVAL_KEYS)) == 7 + 2 * (7 + 2)
    assert set(metrics.KEPT.values()) == set(metrics.POLICIES) - {"final"}
