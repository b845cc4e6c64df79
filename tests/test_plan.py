"""The expected wall time a sweep prints at its start (src/sweep/plan.py), from the measured rates."""
from __future__ import annotations

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from conftest import CONF
from sweep.plan import JOB_FIXED_S, RATES, TWO_CORE_SPEEDUP, announce, estimate, job_overrides


def base(overrides):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides, return_hydra_config=True)
    params = cfg.hydra.sweeper.get("params")
    return cfg, ({k: str(v) for k, v in OmegaConf.to_container(params).items()} if params else {})


def test_jobs_are_the_product_of_sweeps_and_the_command_line_wins():
    jobs = job_overrides(["seed=0,1", "agent.learner=jax"], {"agent": "ppo,l2", "seed": "0,1,2"})
    assert len(jobs) == 4 and {j["agent.learner"] for j in jobs} == {"jax"}
    assert sorted((j["agent"], j["seed"]) for j in jobs) == [("l2", "0"), ("l2", "1"), ("ppo", "0"), ("ppo", "1")]


def test_paper_study_estimates_follow_the_measured_rates(monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    cfg, params = base(["experiment=paper"])
    wall, n, learners = estimate(cfg, [], params, -1)
    rollout = 2048
    per_run = -(-20_000_000 // rollout) * rollout
    assert n == 30 and learners == {"sb3"}
    assert wall == pytest.approx(30 * (per_run / RATES[("sb3", False)] + JOB_FIXED_S) / TWO_CORE_SPEEDUP["sb3"])
    assert 49 * 3600 < wall < 52 * 3600   # ~50 h, the README's number
    jax_wall, _, _ = estimate(cfg, ["agent.learner=jax"], params, -1)
    assert 2.2 * 3600 < jax_wall < 2.5 * 3600   # measured: 2 h 13 min
    text = announce(cfg, [], params, -1)
    assert text.startswith("sweep: 30 jobs, expected wall time ~50.") and "agent.learner=jax" in text
    assert "hint" not in announce(cfg, ["agent.learner=jax"], params, -1)


def test_the_cards_command(monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    cfg, params = base(["agent=recom_l2"])
    wall, n, _ = estimate(cfg, ["agent=recom_l2", "seed=0,1,2,3,4"], params, -1)
    assert n == 5 and 8 * 3600 < wall < 9 * 3600   # ~8.4 h on SB3
    one, _, _ = estimate(cfg, ["agent=recom_l2", "seed=0,1,2,3,4"], params, 1)
    assert one == pytest.approx(wall * TWO_CORE_SPEEDUP["sb3"])   # one job at a time
