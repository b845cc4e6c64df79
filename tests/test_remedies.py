"""Remedies by mechanism, on both learners: each does exactly what its equation says, SB3 and JAX agree on it,
the controls (target_kl, LR schedules, LayerNorm) are SB3's semantics on both, and a run resumed from a
checkpoint taken between two resets is the run that would have happened."""
from __future__ import annotations

import math

import numpy as np
import pytest
from mlflow.tracking import MlflowClient
from stable_baselines3.common.utils import configure_logger

from conftest import compose_cfg, new_store
from sweep.training.hooks import remedy_hooks
from sweep.agents.networks import fresh_parameters
from sweep.agents.schedules import LRSchedule
from sweep.plasticity.cbp import ContinualBackprop
from sweep.plasticity.redo import ReDo
from sweep.plasticity.shrink_perturb import ShrinkPerturb
from sweep.checkpoint import load_checkpoint
from sweep.run import run
from sweep.status import read_json
from test_jax_learner import WEIGHT_ATOL, pair, sb3_rollout_into_both
from test_learner import LEARNERS, trained

OBS = np.random.default_rng(11).normal(size=(256, 13)).astype(np.float32)


def silence(model, net_index: int, layer: int, units: list[int]) -> None:
    """Make units dormant for every input: zero incoming weights and bias (tanh(0) = 0)."""
    net = model.networks[net_index]
    params = model.parameter_arrays()
    params[f"{net.hidden[layer]}.weight"][units] = 0.0
    params[f"{net.hidden[layer]}.bias"][units] = 0.0
    model.write_parameters({k: params[k] for k in (f"{net.hidden[layer]}.weight", f"{net.hidden[layer]}.bias")})


@pytest.mark.parametrize("name", LEARNERS)
def test_redo_resets_exactly_the_dormant_units(name):
    model = trained()[name]
    silence(model, 0, 0, [3, 17, 40])
    silence(model, 1, 1, [0, 63])
    before, moments = model.parameter_arrays(), model.optimizer_moments()
    stats = ReDo(tau=0.025).act(model, OBS)
    assert stats == {"reset_units": 5, "policy_layer0": 3, "policy_layer1": 0, "value_layer0": 0, "value_layer1": 2}
    after, new_moments = model.parameter_arrays(), model.optimizer_moments()
    touched = {  # name -> entries ReDo must write
        "mlp_extractor.policy_net.0.weight": np.s_[[3, 17, 40], :], "mlp_extractor.policy_net.0.bias": np.s_[[3, 17, 40]],
        "mlp_extractor.policy_net.2.weight": np.s_[:, [3, 17, 40]],
        "mlp_extractor.value_net.2.weight": np.s_[[0, 63], :], "mlp_extractor.value_net.2.bias": np.s_[[0, 63]],
        "value_net.weight": np.s_[:, [0, 63]]}
    for k in before:
        mask = np.zeros(before[k].shape, bool)
        if k in touched:
            mask[touched[k]] = True
        assert np.array_equal(after[k][~mask], before[k][~mask]), k   # everything else bitwise unchanged
        for b, a in zip(moments[k], new_moments[k]):
            assert np.array_equal(a[~mask], b[~mask]) and not a[mask].any(), k
    assert np.abs(after["mlp_extractor.policy_net.0.weight"][[3, 17, 40]]).sum() > 0   # fresh incoming rows
    assert not after["mlp_extractor.policy_net.0.bias"][[3, 17, 40]].any()
    assert not after["mlp_extractor.policy_net.2.weight"][:, [3, 17, 40]].any()          # zero outgoing columns
    assert not after["value_net.weight"][:, [0, 63]].any()
    # the network's outputs are unchanged at the moment of the reset (zero outgoing weights)
    np.testing.assert_allclose(model.predict(OBS, deterministic=True)[0], model.predict(OBS, deterministic=True)[0])
    # no unit is dormant any more
    assert ReDo(tau=0.025).act(model, OBS)["reset_units"] == 0


@pytest.mark.parametrize("name", LEARNERS)
def test_shrink_and_perturb_is_its_formula(name):
    model = trained()[name]
    theta = model.parameter_arrays()
    model.rng = np.random.default_rng(123)
    ShrinkPerturb(shrink=0.7, perturb=0.3).act(model, None)
    eps = fresh_parameters({k: v.shape for k, v in theta.items()}, model.networks, np.random.default_rng(123))
    after = model.parameter_arrays()
    for k in theta:
        expected = theta[k] if k == "log_std" else (0.7 * theta[k] + 0.3 * eps[k]).astype(np.float32)
        assert np.array_equal(after[k], expected), k


@pytest.mark.parametrize("name", LEARNERS)
def test_cbp_replaces_the_lowest_utility_mature_unit_and_no_immature_one(name):
    model = trained()[name]
    cbp = ContinualBackprop(replacement_rate=1.0, maturity=1000, decay=0.0, networks=["policy"])
    steps = model.minibatches_per_update
    # layer 0: units 0..9 mature (age > maturity after this update), the others newborn
    age = np.zeros(64, np.int64)
    age[:10] = 1000
    cbp.age = {"policy/0": age, "policy/1": np.zeros(64, np.int64)}
    # the weakest unit overall (12) is immature; the weakest mature one is 6
    params = model.parameter_arrays()
    params["mlp_extractor.policy_net.2.weight"][:, 12] = 0.0   # outgoing of layer-0 unit 12: utility 0
    params["mlp_extractor.policy_net.2.weight"][:, 6] *= 1e-3  # small but not 0
    model.write_parameters(params)
    cbp.rate = 1.0 / (10 * steps)   # exactly one replacement among the 10 eligible units this update
    before = model.parameter_arrays()
    stats = cbp.act(model, OBS)
    after = model.parameter_arrays()
    assert stats == {"replaced_units": 1, "eligible_units": 10}
    changed = np.flatnonzero(np.any(after["mlp_extractor.policy_net.0.weight"] != before["mlp_extractor.policy_net.0.weight"], 1))
    assert changed.tolist() == [6]
    assert not after["mlp_extractor.policy_net.2.weight"][:, 6].any()
    assert cbp.age["policy/0"][6] == 0 and cbp.age["policy/0"][12] == steps and cbp.utility["policy/0"][6] == 0
    assert cbp.pending["policy/0"] == pytest.approx(0.0, abs=1e-9)
    # the value network was not part of it; its weights are untouched
    assert all(np.array_equal(after[k], before[k]) for k in after if "value" in k)


def test_cbp_replacement_rate_accrues_fractions_across_updates():
    model = trained()["jax"]
    steps = model.minibatches_per_update
    cbp = ContinualBackprop(replacement_rate=1e-4, maturity=0, networks=["policy"])
    replaced = sum(cbp.act(model, OBS)["replaced_units"] for _ in range(20))
    expected = 20 * 2 * 1e-4 * 64 * steps   # updates x layers x rate x eligible units x minibatch steps
    assert abs(replaced - expected) <= 2


@pytest.mark.parametrize("name", LEARNERS)
def test_l2_init_at_zero_is_bitwise_ppo_and_pulls_toward_theta_0(name):
    i = LEARNERS.index(name)
    plain = trained()[name].parameter_arrays()
    zero = trained(["agent=l2_init", "agent.l2_init.coef=0.0"])[name].parameter_arrays()
    assert all(np.array_equal(plain[k], zero[k]) for k in plain)
    theta_0 = pair()[i].parameter_arrays()
    pulled = trained(["agent=l2_init", "agent.l2_init.coef=50.0"])[name].parameter_arrays()
    to_zero = trained(["agent=l2", "agent.l2.coef=50.0"])[name].parameter_arrays()
    dist = lambda p, q: sum(float(((p[k] - q[k]) ** 2).sum()) for k in p if k != "log_std")  # noqa: E731
    assert dist(pulled, theta_0) < 0.5 * dist(plain, theta_0)
    norm = lambda p: sum(float((p[k] ** 2).sum()) for k in p if k != "log_std")  # noqa: E731
    assert norm(to_zero) < norm(pulled)


REMEDY_OVERRIDES = {
    "redo": ["agent=redo"],   # the units made dormant below
    "shrink_perturb": ["agent=shrink_perturb"],
    "cbp": ["agent=cbp_l2", "agent.cbp.maturity=0", "agent.cbp.replacement_rate=1e-3"],
}


@pytest.mark.parametrize("remedy", list(REMEDY_OVERRIDES))
def test_one_update_with_each_remedy_agrees_between_sb3_and_jax(remedy):
    models = trained(REMEDY_OVERRIDES[remedy])
    stats = []
    for model in models.values():
        silence(model, 0, 1, [2, 30])
        (callback,) = [cb for cb in remedy_hooks(compose_cfg(REMEDY_OVERRIDES[remedy]).agent)
                       if getattr(cb, "name", "") == remedy]
        stats.append(callback.act(model, OBS))
    assert stats[0] == pytest.approx(stats[1], rel=1e-4)
    assert max(stats[0].values()) > 0
    a, b = models["sb3"].parameter_arrays(), models["jax"].parameter_arrays()
    for k in a:
        np.testing.assert_allclose(b[k], a[k], atol=WEIGHT_ATOL["decoupled"], err_msg=k)


@pytest.mark.parametrize("overrides", [["agent=l2_init", "agent.l2_init.coef=1e-2"],
                                       ["agent=l2_init", "agent.l2_init.coef=1e-2", "agent.l2_init.mode=coupled"],
                                       ["agent=layer_norm"], ["agent=ppo_target_kl", "agent.ppo.target_kl=0.002"],
                                       ["agent=layer_norm_l2_lr_decay_8m", "agent.l2.coef=1e-2"]])
def test_one_update_agrees_between_sb3_and_jax(overrides):
    """The agents without a remedy hook of their own, and the combination (its L2 decays the LayerNorm parameters
    alike on both learners; the plasticity study's 18M run places its 8M decay)."""
    sb3, jx = pair(overrides, total_timesteps=18_000_000)
    if "agent=layer_norm_l2_lr_decay_8m" in overrides:   # both learners put the LayerNorm scales in the L2
        scale = "mlp_extractor.policy_net.1.weight"
        decayed = {id(p) for g in sb3.policy.optimizer.param_groups if g["weight_decay"] for p in g["params"]}
        assert id(dict(sb3.policy.named_parameters())[scale]) in decayed and scale in jx.l2_decayed
    sb3_rollout_into_both(sb3, jx)
    states = []
    for model in (sb3, jx):
        model.set_logger(configure_logger(0, None, "", False))
        np.random.seed(123)
        model.train()
        states.append(np.random.get_state()[1].copy())
    assert np.array_equal(*states)   # the global RNG advanced alike (target_kl: only the epochs that ran)
    a, b = sb3.parameter_arrays(), jx.parameter_arrays()
    for k in a:
        np.testing.assert_allclose(b[k], a[k], atol=WEIGHT_ATOL["decoupled"], err_msg=k)
    for key in ("train/n_updates", "train/value_loss", "train/clip_fraction", "train/loss"):
        assert jx.logger.name_to_value[key] == pytest.approx(sb3.logger.name_to_value[key], rel=1e-4, abs=1e-6), key
    if "agent=ppo_target_kl" in overrides:   # the early stop happened, within the first epochs
        assert 1 <= sb3.logger.name_to_value["train/n_updates"] < sb3.n_epochs


@pytest.mark.parametrize("kind", ["constant", "linear", "cosine"])
def test_lr_schedules(kind):
    s = LRSchedule(kind, 3e-4, 3e-5)
    assert s(1.0) == pytest.approx(3e-4)
    assert s(0.0) == pytest.approx(3e-4 if kind == "constant" else 3e-5)
    mid = {"constant": 3e-4, "linear": 1.65e-4, "cosine": 3e-5 + 2.7e-4 * 0.5 * (1 + math.cos(math.pi * 0.5))}
    assert s(0.5) == pytest.approx(mid[kind])
    assert s(-0.2) == s(0.0)   # SB3's last rollout can overshoot the total: never below the floor
    early = LRSchedule(kind, 3e-4, 3e-5, until=0.4)   # the decay done by 40% of the run, the floor held after
    assert early(1.0) == pytest.approx(3e-4) and early(0.8) == pytest.approx(s(0.5))
    assert early(0.6) == early(0.3) == early(0.0) == pytest.approx(s(0.0))


@pytest.mark.parametrize("name", LEARNERS)
def test_lr_schedule_reaches_the_update(name):
    model = dict(zip(LEARNERS, pair(["agent=l2_lr_decay"])))[name]   # rollouts of 8 x 256 = 2048 steps
    seen = []
    model.train = (lambda train: lambda: (seen.append(model.lr_schedule(model._current_progress_remaining)),
                                          train()))(model.train)
    model.learn(6144)
    assert seen == pytest.approx([3e-4 - 2.7e-4 / 3, 3e-4 - 2.7e-4 * 2 / 3, 3e-5], rel=1e-6)
    assert model.logger.name_to_value["train/learning_rate"] == pytest.approx(3e-5)


@pytest.mark.parametrize("name", LEARNERS)
def test_lr_decay_timesteps_reaches_the_floor_early_on_both_learners(name):
    """agent.ppo.lr_decay_timesteps (l2_lr_decay_8m's key): the decay ends at that timestep, the floor is held."""
    overrides = ["agent=l2_lr_decay", "agent.ppo.lr_decay_timesteps=4096"]
    model = dict(zip(LEARNERS, pair(overrides, total_timesteps=8192)))[name]   # rollouts of 2048 steps
    seen = []
    model.train = (lambda train: lambda: (seen.append(model.lr_schedule(model._current_progress_remaining)),
                                          train()))(model.train)
    model.learn(8192)
    assert seen == pytest.approx([3e-4 - 2.7e-4 / 2, 3e-5, 3e-5, 3e-5], rel=1e-6)
    assert model.logger.name_to_value["train/learning_rate"] == pytest.approx(3e-5)


@pytest.mark.parametrize("learner", LEARNERS)
def test_resume_between_two_resets_is_the_uninterrupted_run(tmp_path, monkeypatch, checkpoint_dir, learner):
    """ReDo (every 2 updates), shrink-and-perturb (every 3) and CBP + L2 in one run; killed by a fault after a
    checkpoint taken between two ReDo resets, resumed from that checkpoint: identical histories."""
    config = ["agent=cbp_l2", "+remedy@agent.redo=redo", "agent.redo.every_updates=2", "agent.redo.tau=0.6",
              "+remedy@agent.shrink_perturb=shrink_perturb", "agent.shrink_perturb.every_updates=3", "agent.cbp.maturity=0",
              "agent.cbp.replacement_rate=1e-3", f"agent.learner={learner}", "agent.ppo.n_steps=256",
              "agent.ppo.n_epochs=2", "train.total_timesteps=2048", "train.checkpoint_every=768", "seed=3",
              "eval.episodes=1", "env.episode_seconds=1.0"]
    keys = ("remedy/redo/reset_units", "remedy/cbp/replaced_units", "remedy/shrink_perturb/weight_norm_after",
            "train/loss", "rollout/ep_rew_mean", "plasticity/weight_norm", "eval_best/return", "eval_best/source_step",
            "plasticity/probe_loss", "plasticity/dead_tanh_ratio")

    def histories(uri, run_id):
        client = MlflowClient(uri)
        return {k: [(m.step, m.value) for m in client.get_metric_history(run_id, k)] for k in keys}

    monkeypatch.setenv("MLFLOW_TRACKING_URI", ref_uri := new_store(tmp_path / "ref.db"))
    reference = histories(ref_uri, run(compose_cfg(config), tmp_path / "ref"))
    assert len(reference["remedy/redo/reset_units"]) == 3 and len(reference["remedy/shrink_perturb/weight_norm_after"]) == 2
    assert reference["eval_best/source_step"] and reference["plasticity/probe_loss"]   # the resumed run must keep the best

    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri := new_store(tmp_path / "cut.db"))
    fault = ["+agent.fault._target_=faults.Fault", "+agent.fault.seed=3", "+agent.fault.at_step=1280"]
    with pytest.raises(RuntimeError, match="injected failure"):
        run(compose_cfg([*config, *fault]), tmp_path / "cut")
    (job,) = [p.parent for p in checkpoint_dir.glob("*/job.json") if read_json(p)["status"] == "RUNNING"]
    assert load_checkpoint(job / "checkpoint.pt")["num_timesteps"] == 768   # after ReDo's reset 1, before reset 2
    resumed = run(compose_cfg([*config, f"resume={job}"]), tmp_path / "resumed")
    assert histories(uri, resumed) == reference


def test_weight_clipping_bounds_are_the_init_bounds_of_a_hand_built_network():
    """s_l = 1/sqrt(fan_in) of every Linear layer, weight and bias alike; LayerNorm and log_std are not clipped."""
    from sweep.plasticity.weight_clip import init_bounds

    sb3, _ = pair(["agent=layer_norm"])
    bounds = init_bounds(sb3, ("policy", "value"))
    expected = {}
    for prefix in ("mlp_extractor.policy_net", "mlp_extractor.value_net"):   # Linear, LayerNorm, tanh per layer
        expected.update({f"{prefix}.0.weight": 13 ** -0.5, f"{prefix}.0.bias": 13 ** -0.5,
                         f"{prefix}.3.weight": 64 ** -0.5, f"{prefix}.3.bias": 64 ** -0.5})
    for head in ("action_net", "value_net"):
        expected.update({f"{head}.weight": 64 ** -0.5, f"{head}.bias": 64 ** -0.5})
    assert bounds == pytest.approx(expected)
    assert set(init_bounds(sb3, ("value",))) == {k for k in expected if "value" in k}


def test_weight_clipping_acts_after_every_step_alike_on_both_learners():
    """kappa 0.5: the init already reaches past the bound, so every step clips. SB3 (a step hook on its optimizer)
    and JAX (the clip traced into the compiled update) agree after one update; every clipped parameter is within
    its bound, some sit on it; clipping once after an unclipped update instead gives other weights."""
    overrides = ["agent=weight_clip", "agent.weight_clip.kappa=0.5"]
    sb3, jx = pair(overrides)
    plain = pair()[1]
    sb3_rollout_into_both(sb3, jx, plain)
    calls = []
    sb3.add_step_transform(lambda params, xp: calls.append(1) or {})
    for model in (sb3, jx, plain):
        model.set_logger(configure_logger(0, None, "", False))
        np.random.seed(123)
        model.train()
    assert len(calls) == sb3.minibatches_per_update   # once per optimizer step
    a, b = sb3.parameter_arrays(), jx.parameter_arrays()
    for k in a:
        np.testing.assert_allclose(b[k], a[k], atol=WEIGHT_ATOL["decoupled"], err_msg=k)
    (clip,) = [h for h in remedy_hooks(compose_cfg(overrides).agent)]
    clip.setup(jx, None)
    for k, bound in clip.bounds.items():
        assert np.abs(a[k]).max() <= np.float32(bound), k
    assert clip.act(jx, None)["at_bound"] > 0.05
    once = plain.parameter_arrays()
    once = {k: np.clip(v, -clip.bounds[k], clip.bounds[k]) if k in clip.bounds else v for k, v in once.items()}
    assert max(float(np.abs(once[k] - b[k]).max()) for k in clip.bounds) > 100 * WEIGHT_ATOL["decoupled"]
    assert "log_std" not in clip.bounds


@pytest.mark.parametrize("learner", LEARNERS)
def test_the_final_policy_is_within_the_clip_bounds(tmp_path, learner, checkpoint_dir):
    """The stored model is the one after the last update's steps were clipped (issue 53: remedies used to skip the
    last update)."""
    from stable_baselines3 import PPO

    from sweep.plasticity.weight_clip import init_bounds

    cfg = compose_cfg(["agent=weight_clip", "agent.weight_clip.kappa=0.5", "agent.weight_clip.heads=true",
                       f"agent.learner={learner}",
                       "agent.ppo.n_steps=256", "agent.ppo.n_epochs=2", "train.total_timesteps=512", "eval.episodes=1",
                       f"tracking.uri=sqlite:///{tmp_path / 'x.db'}", "hooks.probe.steps=0"])
    run(cfg, tmp_path / "job")
    model = PPO.load(tmp_path / "job" / "model.zip", device="cpu")
    params = {k: v.numpy() for k, v in model.policy.state_dict().items()}
    built = pair(["agent=weight_clip"])[0]
    for k, s in init_bounds(built, ("policy", "value")).items():
        assert np.abs(params[k]).max() <= np.float32(0.5 * s), k
