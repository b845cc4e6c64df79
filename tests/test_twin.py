"""twin=fresh (issue 56): any agent's fresh twin, its own networks and optimizer drawn afresh at every change. It
composes with every agent but PPO (whose twin is agent=reset_all) on every learner, is named and coloured after its
agent, moves no existing job key, and shares segment 0 with its agent bit for bit."""
from __future__ import annotations

from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from conftest import CONF, compose_cfg, run_cli
from sweep.checkpoint import job_key
from sweep.config import TWIN_SUFFIX, ConfigError, agent_identity, validate
from sweep.report import style
from sweep.run import job_tags, run
from sweep.training.hooks import build_hooks
from test_config import DEFAULT_HOOKS, remedies_of

AGENTS = sorted(p.stem for p in (CONF / "agent").glob("*.yaml"))
TWINNED = [a for a in AGENTS if a not in ("ppo", "reset_all")]


@pytest.mark.parametrize("agent", TWINNED)
def test_every_agent_but_ppo_has_a_fresh_twin_on_each_of_its_learners(agent):
    """The twin runs the agent's own remedies, then ResetAll, then the default hooks; its tags name it."""
    for learner in compose_cfg([f"agent={agent}"]).agent.learners:
        own = compose_cfg([f"agent={agent}", f"agent.learner={learner}"])
        cfg = compose_cfg([f"agent={agent}", f"agent.learner={learner}", "twin=fresh"])
        validate(cfg)
        hooks = [type(h).__name__ for h in build_hooks(cfg)]
        assert hooks == remedies_of(own) + ["ResetAll"] + DEFAULT_HOOKS or (
            "ResetAll" in remedies_of(own) and hooks == remedies_of(own) + DEFAULT_HOOKS)
        assert agent_identity(cfg.agent) == (agent + "_fresh", own.agent.label + " (fresh)")
        tags = job_tags(cfg)
        assert (tags["agent"], tags["agent_label"]) == agent_identity(cfg.agent)
        assert tags["run_name"].startswith(agent + "_fresh-")


@pytest.mark.parametrize("overrides,message", [
    (["agent=ppo"], "twin=fresh with agent=ppo: PPO's fresh twin is agent=reset_all"),
    (["agent=reset_all"], "twin=fresh with agent=reset_all: PPO's fresh twin is agent=reset_all"),
    (["agent=layer_norm", "twin=fresh", "agent.reset_all.enabled=false"],
     "agent.reset_all.enabled=false with agent.twin=fresh: the twin needs the reset_all remedy on"),
    (["agent=layer_norm", "+agent.twin=fresh"], "no agent.reset_all block with agent.twin=fresh: the twin needs"),
    (["agent=layer_norm", "twin=fresh", "~agent.reset_all"], "no agent.reset_all block with agent.twin=fresh"),
])
def test_a_twin_that_would_not_be_one_is_refused_in_one_line(overrides, message):
    if not any(o.startswith(("twin=", "+agent.twin")) for o in overrides):
        overrides = [*overrides, "twin=fresh"]
    with pytest.raises(ConfigError, match="^" + message.replace("(", r"\(")):
        validate(compose_cfg(overrides))


def test_the_switch_moves_no_job_key_and_the_twin_is_its_own_job():
    """Without twin=fresh the composed config has no twin key at all (test_config's JOB_KEY pins the keys)."""
    for agent in AGENTS:
        assert "twin" not in compose_cfg([f"agent={agent}"]).agent
    own, twin = compose_cfg(["agent=layer_norm"]), compose_cfg(["agent=layer_norm", "twin=fresh"])
    assert job_key(own, "sqlite:///x.db") != job_key(twin, "sqlite:///x.db")


def test_a_twin_is_drawn_in_its_agents_colour_with_its_own_dash():
    assert style.TWIN_SUFFIX == TWIN_SUFFIX
    for agent in ["layer_norm", "l2", "some_new_agent"]:
        assert style.twinned(agent + "_fresh") == agent
        assert style.agent_colour(agent + "_fresh") == style.agent_colour(agent)
        assert style.dashes(agent + "_fresh") == style.TWIN_DASH != style.dashes(agent)
    assert style.twinned("reset_all") is None and style.agent_colour("reset_all") == "#000000"
    # in a report, a twin takes the colour its agent has there (a new agent may have stepped off its hashed colour)
    colours = style.agent_colours(["new_a", "new_b", "new_a_fresh", "new_b_fresh"])
    assert colours["new_a_fresh"] == colours["new_a"] and colours["new_b_fresh"] == colours["new_b"]
    looks = style.looks({a: a for a in ["layer_norm", "layer_norm_fresh", "l2", "l2_fresh"]})
    assert len(set(looks.values())) == 4 and looks["layer_norm"][0] == looks["layer_norm_fresh"][0]


RUN = ["seed=3", "train.total_timesteps=2048", "wind.segment_steps=768", "eval.episodes=2", "env.episode_seconds=1.0",
       "train.progress_every_s=1000", "plasticity.probe.steps=20", "agent.learner=jax"]


@pytest.mark.parametrize("agent,overrides", [
    ("layer_norm", ["agent.ppo.n_steps=512", "agent.ppo.n_epochs=2"]),
    pytest.param("sac_reset", ["agent.sac.round_steps=512", "agent.sac.learning_starts=300", "agent.sac.batch_size=32",
                   "agent.policy.net_arch=[16,16]", "agent.periodic_reset.every_steps=1280"],
                 marks=pytest.mark.slow),   # ResetAll on SAC is in the default suite (test_offpolicy); this runs a twin
])
def test_a_twin_shares_segment_0_with_its_agent_bit_for_bit_then_draws_fresh_networks(agent, overrides, store,
                                                                                     tmp_path):
    """Rounds of 512 steps, segments of 768: the first change is seen at 1,024. Up to the round before it the twin's
    histories equal its agent's; the twin then logs a reset at each change and its losses leave the agent's."""
    client = MlflowClient(store)
    runs = {}
    for twin in (False, True):
        cfg = compose_cfg([f"agent={agent}", *RUN, *overrides, *(["twin=fresh"] if twin else [])])
        runs[twin] = run(cfg, tmp_path / str(twin))
    tags = client.get_run(runs[True]).data.tags
    assert tags["agent"] == agent + "_fresh" and tags["agent_label"].endswith(" (fresh)")
    resets = sorted((m.step, m.value) for m in client.get_metric_history(runs[True], "remedy/reset_all/resets"))
    assert resets == [(1024, 1.0), (1536, 2.0)]

    def history(run_id: str, key: str) -> list[tuple[int, float]]:
        return sorted((m.step, m.value) for m in client.get_metric_history(run_id, key))

    keys = set(client.get_run(runs[False]).data.metrics) - {"time/fps", "time/time_elapsed"}   # the wall clock's
    assert keys | {"remedy/reset_all/resets"} == set(client.get_run(runs[True]).data.metrics) - {"time/fps",
                                                                                                  "time/time_elapsed"}
    segment_0 = {k: [p for p in history(runs[False], k) if p[0] < 1024] for k in sorted(keys)}
    assert segment_0 == {k: [p for p in history(runs[True], k) if p[0] < 1024] for k in sorted(keys)}
    assert sum(map(len, segment_0.values())) >= 30   # the rollout-time metrics (env, plasticity, rollout) at 512
    assert [p for p in history(runs[False], "plasticity/weight_norm") if p[0] >= 1024] != \
           [p for p in history(runs[True], "plasticity/weight_norm") if p[0] >= 1024]


def test_the_cli_refuses_ppos_twin_before_training(store, tmp_path):
    out = run_cli(["agent=ppo", "twin=fresh", "train.total_timesteps=512"], store, Path(tmp_path))
    assert out.returncode != 0
    assert "twin=fresh with agent=ppo: PPO's fresh twin is agent=reset_all" in out.stderr + out.stdout
    assert MlflowClient(store).search_runs(experiment_ids=[e.experiment_id for e in
                                                           MlflowClient(store).search_experiments()]) == []
