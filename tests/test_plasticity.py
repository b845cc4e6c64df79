"""Dormant units, RECOM's update, the LR reaching the optimizer, and L2 differing only in the L2 term."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import compose_cfg, new_store, train_with
from sweep.agents import build_learner
from sweep.envs import HoverVecEnv, WindSchedule
from sweep.plasticity.dormant import dormant_mask, dormant_ratio, dormant_scores, srank
from sweep.plasticity.l2 import L2Regularization
from sweep.plasticity.recom import Recom, cost_gradient, recom_lr, retrospective_cost
from sweep.training.hooks import build_hooks, remedy_hooks
from sweep.training.records import Condition, Episode, RolloutRecord, UpdateRecord

LEARNERS = ["sb3", "jax"]


def learner(name: str, overrides=(), n_envs: int = 1, seed: int = 0, **env_kwargs):
    cfg = compose_cfg([f"agent.learner={name}", *overrides])
    env = HoverVecEnv(n_envs=n_envs, seed=seed, **env_kwargs)
    return cfg, build_learner(cfg.agent, env, seed)

# ---- dormant units (Sokar et al. 2023) ----------------------------------------------------------------


def test_dormant_ratio_on_hand_built_layer():
    """4 inputs -> 4 tanh units: unit 0 has zero weights and bias (dormant), unit 3 is scaled up."""
    w = np.array([[0.0, 0, 0, 0], [0.1, 0, 0, 0], [0, 0.1, 0, 0], [0, 0, 1.0, 0]])
    x = np.array([[1.0, 1.0, 1.0, 0.0], [-1.0, -1.0, -1.0, 0.0]])
    h = np.tanh(x @ w.T)
    # |h| means: 0, tanh(.1), tanh(.1), tanh(1); scores relative to their average
    m = np.array([0.0, np.tanh(0.1), np.tanh(0.1), np.tanh(1.0)])
    np.testing.assert_allclose(dormant_scores(h), m / m.mean())
    overall, per_layer = dormant_ratio([h], tau=0.025)
    assert overall == 0.25 and per_layer == [0.25]  # only the zero unit
    overall, _ = dormant_ratio([h], tau=0.5)        # tanh(.1)/mean = 0.33 <= 0.5: two more
    assert overall == 0.75


def test_scaled_up_unit_is_not_dormant_and_all_zero_layer_is_dormant():
    h = np.array([[0.0, 10.0], [0.0, -10.0]])
    assert dormant_ratio([h], 0.025)[0] == 0.5
    assert dormant_ratio([np.zeros((5, 3))], 0.025)[0] == 1.0
    assert dormant_ratio([h, np.ones((2, 2))], 0.025) == (0.25, [0.5, 0.0])


@pytest.mark.parametrize("name", LEARNERS)
def test_diagnostics_report_exactly_the_units_made_dormant(name):
    """Silence chosen units of a trained policy (zero incoming weights and bias: tanh(0) = 0 for every input):
    the dormant mask is exactly those units, the ratios count exactly them, and the value network is untouched."""
    cfg, model = learner(name, ["agent.ppo.n_steps=512"], n_envs=4, wind=WindSchedule([2.0]))
    model.learn(4096)  # a trained network, not a fresh one
    silenced = {0: [3, 17, 40], 1: [0, 5, 6, 63]}
    params = model.parameter_arrays()
    for layer, units in silenced.items():
        params[f"mlp_extractor.policy_net.{2 * layer}.weight"][units] = 0.0
        params[f"mlp_extractor.policy_net.{2 * layer}.bias"][units] = 0.0
    model.write_parameters(params)
    diagnostics = build_hooks(cfg)["diagnostics"]
    obs = model.recent_samples(cfg.plasticity.batch_size).observations
    pi_layers = [h.post for h in model.hidden_activations(obs)["policy"]]
    for layer, units in silenced.items():
        assert np.flatnonzero(dormant_mask(pi_layers[layer], 0.025)).tolist() == units
    stats = diagnostics.measure(model)
    assert stats["dormant_ratio_layer0"] == 3 / 64 and stats["dormant_ratio_layer1"] == 4 / 64
    assert stats["dormant_ratio"] == 7 / 128 and stats["value_dormant_ratio"] == 0.0


def test_diagnostics_agree_between_learners_on_the_same_weights_and_batch():
    (cfg, sb3), (_, jx) = learner("sb3", ["agent.ppo.n_steps=256"], n_envs=4), learner("jax", ["agent.ppo.n_steps=256"],
                                                                                          n_envs=4)
    sb3.learn(1024)
    jx.write_parameters(sb3.parameter_arrays())
    jx.rollout_buffer = sb3.rollout_buffer
    measured = []
    for model in (sb3, jx):
        measured.append(build_hooks(cfg)["diagnostics"].measure(model))
    assert measured[0].keys() == measured[1].keys()
    for key in measured[0]:
        assert measured[1][key] == pytest.approx(measured[0][key], rel=1e-4, abs=1e-6), key


def test_srank():
    assert srank(np.eye(8)) == 8
    assert srank(np.ones((10, 4))) == 1
    assert srank(np.diag([1.0, 1.0, 1e-6, 1e-6]), delta=0.01) == 2


# ---- RECOM (Eqs. 5-8) -----------------------------------------------------------------------------


def test_recom_equations_by_hand():
    assert retrospective_cost([-10.0, -20.0], [1.0, 3.0]) == pytest.approx((11 + 23) / 2)
    assert cost_gradient(110.0, 100.0) == 10.0 and cost_gradient(110.0, 100.0, "relative") == pytest.approx(0.1)
    assert cost_gradient(-90.0, -100.0, "relative") == pytest.approx(0.1)  # over |C_prev|: the sign is the change's
    lr, at_bound = recom_lr(3e-4, 10.0, gain=5e-6, lr_min=1e-5, lr_max=1e-3)
    assert lr == pytest.approx(3e-4 - 5e-5) and not at_bound
    assert recom_lr(3e-4, 100.0, 5e-6, 1e-5, 1e-3) == (1e-5, True)     # clipped below
    assert recom_lr(3e-4, -1000.0, 5e-6, 1e-5, 1e-3) == (1e-3, True)   # clipped above


class FakeLearner:
    """The part of the Learner contract RECOM uses: the learning rate it sets."""

    def __init__(self, lr: float = 3e-4) -> None:
        self.lr = lr

    def set_learning_rate(self, value=None) -> float:
        self.lr = self.lr if value is None else float(value)
        return self.lr


def update_record(loss: float) -> UpdateRecord:
    """An update whose mean total loss is ``loss`` (pg = loss, value and entropy 0)."""
    return UpdateRecord(index=0, timesteps=0, learning_rate=0.0, clip_range=0.2, policy_gradient_loss=loss,
                        value_loss=0.0, entropy_loss=0.0, loss=loss, approx_kl=0.0, clip_fraction=0.0,
                        explained_variance=0.0, epochs=1, n_updates=1, std=1.0, vf_coef=0.5, ent_coef=0.0)


def drive_recom(recom: Recom, rollouts: list[tuple[float, list[float]]]) -> list[float]:
    """Feed (loss of the update before the rollout, episode returns of the rollout) sequences, 100 steps per
    rollout; returns the learning rate after each rollout. ``recom.logged``: everything it returned."""
    learner = FakeLearner()
    recom.setup(learner, None)
    recom.logged = {}
    lrs, timesteps = [], 0
    for loss, returns in rollouts:
        if loss is not None:  # an update ran before this rollout
            recom.logged.update(recom.after_update(learner, update_record(loss)))
        episodes = tuple(Episode(*(r if isinstance(r, tuple) else (r, 1)), False) for r in returns)
        timesteps += 100
        rollout = RolloutRecord(index=0, timesteps=timesteps, episodes=episodes, mean_recent_return=None,
                                condition=Condition(0, (0.0, 0.0, 0.0)))
        recom.logged.update(recom.after_rollout(learner, rollout))
        lrs.append(learner.lr)
    return lrs


def test_recom_hook_on_synthetic_sequence():
    recom = Recom(interval=200, window=2, gain=1e-6, lr_min=1e-5, lr_max=1e-3, previous="last_update")
    # rollout 1 has no update before it: its episodes are not used.
    lrs = drive_recom(recom, [(None, [-50.0]), (2.0, [-10.0, -20.0]), (4.0, [-30.0]), (1.0, [-40.0, -60.0])])
    # update at t=200: episodes (-10,2), (-20,2): C = (12 + 22)/2 = 17, first update: LR unchanged.
    # update at t=400: last 2 = (-40,1), (-60,1): C = (41 + 61)/2 = 51; G = 51 - 17 = 34; lr = 3e-4 - 34e-6
    assert lrs[:3] == [3e-4, 3e-4, 3e-4]
    assert lrs[3] == pytest.approx(3e-4 - 34e-6)
    assert recom.logged["recom/cost"] == 51.0
    assert recom.logged["recom/cost_gradient"] == 34.0
    assert recom.logged["recom/at_bound"] == 0.0


def test_recom_per_step_reward_reading():
    """agent.recom.reward=per_step: R[t] is the episode's mean reward per step (return / length)."""
    recom = Recom(interval=200, window=2, gain=1e-6, lr_min=1e-5, lr_max=1e-3, reward="per_step")
    lrs = drive_recom(recom, [(None, [(-50.0, 5)]), (2.0, [(-10.0, 5), (-20.0, 10)]), (4.0, []),
                              (1.0, [(-40.0, 20), (-60.0, 20)])])
    # t=200: per-step rewards -2, -2 with loss 2: C = 4. t=400: -2, -3 with loss 1: C = (3 + 4)/2 = 3.5; G = -0.5
    assert recom.logged["recom/cost"] == 3.5
    assert lrs[3] == pytest.approx(3e-4 + 0.5e-6)


def test_recom_shifted_window_and_clipping():
    recom = Recom(interval=100, window=2, gain=1e-3, lr_min=1e-4, lr_max=5e-4, previous="shifted")
    lrs = drive_recom(recom, [(0.0, []), (1.0, [-10.0, -20.0, -90.0])])
    # episodes (-10,1), (-20,1), (-90,1): C_ret over last 2 = (21+91)/2 = 56, C_prev over (-10,-20) = 16
    # G = 40, lr = 3e-4 - 0.04 -> clipped to 1e-4
    assert lrs[-1] == 1e-4
    assert recom.logged["recom/cost_prev"] == 16.0
    assert recom.logged["recom/at_bound"] == 1.0


def test_recom_relative_gradient_is_the_change_over_the_previous_cost():
    recom = Recom(interval=200, window=2, gain=1e-4, lr_min=1e-5, lr_max=1e-3, gradient="relative")
    lrs = drive_recom(recom, [(None, [-50.0]), (2.0, [-10.0, -20.0]), (4.0, [-30.0]), (1.0, [-40.0, -60.0])])
    # C: 17 then 51 (see above): G = 34 / 17 = 2; lr = 3e-4 - 1e-4 * 2 = 1e-4
    assert lrs[3] == pytest.approx(1e-4)
    assert recom.logged["recom/cost_gradient"] == pytest.approx(2.0)


@pytest.mark.parametrize("name", LEARNERS)
def test_recom_learning_rate_reaches_the_optimizer(name):
    cfg = compose_cfg([f"agent.learner={name}", "agent=recom_l2", "agent.ppo.n_steps=256", "agent.ppo.n_epochs=1",
                       "agent.recom.interval=256", "agent.recom.gain=1e-3"])
    env = HoverVecEnv(n_envs=2, seed=0, episode_seconds=0.5, wind=WindSchedule(speeds=[0.0]))
    model = build_learner(cfg.agent, env, seed=0)
    remedies = remedy_hooks(cfg.agent)
    recom = remedies[-1]
    seen = []   # per update: (RECOM's LR, the LRs the update used, the LR its record reports)
    original_update = model.update
    if name == "sb3":  # the LR of both param groups of the torch optimizer during the update

        def update_and_record():
            record = original_update()
            seen.append((recom.lr, [g["lr"] for g in model.policy.optimizer.param_groups], record.learning_rate))
            return record
    else:  # the LR argument of the jitted update
        jitted = model._update

        def update_and_record():
            used = []
            model._update = lambda *args: used.append(args[4]) or jitted(*args)
            record = original_update()
            seen.append((recom.lr, used, record.learning_rate))
            return record
    model.update = update_and_record
    train_with(model, remedies, 256 * 2 * 4)
    lrs = [s[0] for s in seen]
    assert len(set(lrs)) > 1, "RECOM never changed the learning rate"
    for target, used, logged in seen:
        assert used and all(lr == pytest.approx(target) for lr in used) and logged == pytest.approx(target)
    assert len(model.l2_decayed) == 12  # RECOM + L2: L2 is on too, on every parameter but log_std


# ---- L2 ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("mode, optimizer", [("coupled", torch.optim.Adam), ("decoupled", torch.optim.AdamW)])
def test_l2_optimizer_differs_from_ppo_only_in_the_l2_term(mode, optimizer):
    env = HoverVecEnv(n_envs=1, seed=0)
    ppo = build_learner(compose_cfg(["agent=ppo"]).agent, env, seed=0)
    l2_cfg = compose_cfg(["agent=l2", f"agent.l2.mode={mode}"]).agent
    l2 = build_learner(l2_cfg, env, seed=0)
    (remedy,) = remedy_hooks(l2_cfg)
    remedy.setup(l2, None)
    base = ppo.policy.optimizer
    new = l2.policy.optimizer
    assert type(base) is torch.optim.Adam and type(new) is optimizer
    keys = set(base.defaults) - {"weight_decay", "decoupled_weight_decay"}  # the L2 term itself
    for group in new.param_groups:
        assert {k: group[k] for k in keys} == {k: base.param_groups[0][k] for k in keys}
    assert base.param_groups[0]["eps"] == 1e-5 and base.param_groups[0]["fused"] is True   # networks.adam_kwargs
    assert base.param_groups[0]["weight_decay"] == 0
    decayed, plain = new.param_groups
    assert decayed["weight_decay"] == l2_cfg.l2.coef and plain["weight_decay"] == 0.0
    names = {id(p): n for n, p in l2.policy.named_parameters()}
    assert {names[id(p)] for p in plain["params"]} == {"log_std"}
    assert sum(p.numel() for g in new.param_groups for p in g["params"]) == sum(p.numel() for p in l2.policy.parameters())


@pytest.mark.parametrize("name", LEARNERS)
def test_l2_scope_is_configurable(name):
    _, model = learner(name)
    L2Regularization(coef=0.1, params=["policy"], biases=False).setup(model, None)
    assert model.l2_decayed == ["action_net.weight", "mlp_extractor.policy_net.0.weight",
                                "mlp_extractor.policy_net.2.weight"]
    L2Regularization(coef=0.1, params=["value", "log_std"], biases=True).setup(model, None)
    assert model.l2_decayed == sorted(["log_std", "value_net.weight", "value_net.bias",
                                       *(f"mlp_extractor.value_net.{i}.{p}" for i in (0, 2) for p in ("weight", "bias"))])


# ---- readings a tanh network can show (issue: the paper's ~11% dormant units) ----------------------------
def test_tanh_readings_on_hand_built_activations():
    """6 tanh units on 100 samples, each built to be caught by exactly the readings it should be."""
    rng = np.random.default_rng(0)
    b = 100
    h = np.empty((b, 6))
    h[:, 0] = 0.0                                     # silent: Sokar-dormant (and signed mean 0)
    h[:, 1] = 0.995                                   # stuck at +1 on every sample: dead tanh
    h[:, 2] = np.where(np.arange(b) < 99, -0.999, 0.3)  # saturated on exactly 99%: dead (>= 99%)
    h[:, 3] = np.where(np.arange(b) < 98, 0.999, 0.3)   # saturated on 98%: not dead
    h[:, 4] = np.where(np.arange(b) % 2 == 0, 0.8, -0.8)  # swings +-0.8: signed mean 0, fully active
    h[:, 5] = rng.uniform(0.2, 0.6, b)                 # an ordinary unit
    from sweep.plasticity.dormant import active_ratio, dead_tanh_mask, pooled, signed_mean_mask

    assert dead_tanh_mask(h, 0.99, 0.99).tolist() == [False, True, True, False, False, False]
    assert signed_mean_mask(h, 0.1).tolist() == [True, False, False, False, True, False]
    assert dormant_mask(h, 0.025).tolist() == [True, False, False, False, False, False]
    # Sokar at 0.1 catches nothing more here: every other unit's |h| is large
    assert dormant_mask(h, 0.1).tolist() == [True, False, False, False, False, False]
    saturated = (np.abs(h) > 0.99).mean()
    assert active_ratio([h], "tanh")[0] == pytest.approx(1 - saturated)
    assert active_ratio([np.array([[1.0, -1.0], [0.0, 2.0]])], "relu") == (0.5, [0.5])
    # pooled over layers vs per layer
    assert pooled([np.array([True, False]), np.array([True, True, False, False])]) == (0.5, [0.5, 0.5])


@pytest.mark.parametrize("name", LEARNERS)
def test_diagnostics_log_every_reading_per_layer_and_pooled(name):
    cfg, model = learner(name, ["agent.ppo.n_steps=256"], n_envs=4)
    model.learn(1024)
    params = model.parameter_arrays()   # make layer 1's units 0-9 stuck at +1: huge bias, zero weights
    params["mlp_extractor.policy_net.2.weight"][:10] = 0.0
    params["mlp_extractor.policy_net.2.bias"][:10] = 10.0
    model.write_parameters(params)
    stats = build_hooks(cfg)["diagnostics"].measure(model)
    assert stats["dead_tanh_ratio_layer1"] == 10 / 64 and stats["dead_tanh_ratio"] == 10 / 128
    assert stats["dead_tanh_ratio_layer0"] == 0.0
    assert stats["dormant_ratio_tau0.1"] >= stats["dormant_ratio"]
    for key in ("dormant_ratio_tau0.1", "signed_mean_ratio", "active_ratio"):
        assert key in stats and f"{key}_layer0" in stats and f"{key}_layer1" in stats
    assert stats["active_ratio_layer1"] <= 1 - 10 / 64 + 1e-9


@pytest.mark.parametrize("name", LEARNERS)
def test_diagnostics_cadence_changes_only_what_is_logged(name, tmp_path, monkeypatch):
    """plasticity.every_rollouts=3 (experiment=remedies uses 10) against 1 on the same seed, 8 rollouts: the run is
    the same run (training reward, losses, every evaluation and probe equal to the last digit); the diagnostics
    are logged at rollouts 1, 4 and 7 only, with the values the every-rollout run logged there."""
    from mlflow.tracking import MlflowClient

    from sweep.run import run

    config = [f"agent.learner={name}", "agent.ppo.n_steps=256", "agent.ppo.n_epochs=2", "train.total_timesteps=2048",
              "eval.every_timesteps=1024", "eval.episodes=2", "env.episode_seconds=1.0", "seed=4",
              "wind.segment_steps=1024"]
    kept = ("rollout/ep_rew_mean", "train/loss", "train/approx_kl", "eval/return", "eval_best/return",
            "plasticity/probe_loss")
    diagnostics = ("plasticity/weight_norm", "plasticity/dormant_ratio", "plasticity/grad_norm")
    got = {}
    for every in (1, 3):
        monkeypatch.setenv("MLFLOW_TRACKING_URI", uri := new_store(tmp_path / f"every{every}.db"))
        run_id = run(compose_cfg([*config, f"plasticity.every_rollouts={every}"]), tmp_path / f"every{every}")
        client = MlflowClient(uri)
        got[every] = {k: [(m.step, m.value) for m in client.get_metric_history(run_id, k)] for k in kept + diagnostics}
    for key in kept:
        assert got[3][key] == got[1][key] and got[1][key], key
    for key in diagnostics:
        every_rollout = got[1][key]
        assert len(every_rollout) == 8
        assert got[3][key] == [every_rollout[i] for i in (0, 3, 6)], key

# ---- the plasticity probe (Lyle et al. 2022) ------------------------------------------------------------
@pytest.mark.parametrize("name", LEARNERS)
def test_probe_fits_worse_once_units_are_saturated(name):
    from sweep.plasticity.probe import probe_fit

    _, model = learner(name)
    obs = np.random.default_rng(4).normal(size=(512, 13)).astype(np.float32)
    fresh = probe_fit(model, obs, steps=300)
    params = model.parameter_arrays()
    for layer in ("mlp_extractor.policy_net.0", "mlp_extractor.policy_net.2"):
        params[f"{layer}.weight"] *= 30.0   # pre-activations x30: almost every tanh unit at +-1
    model.write_parameters(params)
    saturated = probe_fit(model, obs, steps=300)
    assert fresh[1] < fresh[0]                    # it learns
    assert saturated[1] > 1.5 * fresh[1], (fresh, saturated)


@pytest.mark.parametrize("name", LEARNERS)
def test_probe_fresh_reference_is_a_new_network_on_the_same_data(name):
    """fresh=True fits a newly drawn network: it does not depend on the learner's weights (the same loss after
    they are saturated), equals the fit of a learner whose weights are that draw, and a saturated network fits
    worse than it."""
    from sweep.agents.networks import fresh_parameters
    from sweep.plasticity.probe import probe_fit

    _, model = learner(name)
    obs = np.random.default_rng(4).normal(size=(512, 13)).astype(np.float32)
    reference = probe_fit(model, obs, steps=300, seed=7, fresh=True)
    params = model.parameter_arrays()
    for layer in ("mlp_extractor.policy_net.0", "mlp_extractor.policy_net.2"):
        params[f"{layer}.weight"] *= 30.0
    model.write_parameters(params)
    assert probe_fit(model, obs, steps=300, seed=7, fresh=True) == reference
    saturated = probe_fit(model, obs, steps=300, seed=7)
    assert saturated[1] > 1.5 * reference[1], (saturated, reference)
    drawn = fresh_parameters({k: v.shape for k, v in params.items()}, (model.networks[0],),
                             np.random.default_rng([7, 1]))
    model.write_parameters({**params, **{k: v for k, v in drawn.items() if k.startswith(("mlp_extractor.policy",
                                                                                         "action_net"))}})
    assert probe_fit(model, obs, steps=300, seed=7) == pytest.approx(reference, rel=1e-6)


@pytest.mark.parametrize("name", LEARNERS)
def test_probe_leaves_weights_optimizer_and_every_rng_alone(name):
    from sweep.plasticity.probe import PlasticityProbe

    cfg, model = learner(name, ["agent.ppo.n_steps=256"], n_envs=4)
    model.learn(512)
    before = (model.parameter_arrays(), model.optimizer_moments(), model.rng.bit_generator.state,
              np.random.get_state()[1].copy(), torch.get_rng_state().clone())
    probe = PlasticityProbe(**cfg.plasticity.probe)
    stats = probe.measure(model)
    assert stats["plasticity/probe_loss"] < stats["plasticity/probe_loss_early"]
    assert set(stats) == {"plasticity/probe_loss", "plasticity/probe_loss_early", "plasticity/probe_loss_fresh"}
    after = (model.parameter_arrays(), model.optimizer_moments(), model.rng.bit_generator.state,
             np.random.get_state()[1], torch.get_rng_state())
    assert all(np.array_equal(before[0][k], after[0][k]) for k in before[0])
    assert all(np.array_equal(a, b) for k in before[1] for a, b in zip(before[1][k], after[1][k]))
    assert before[2] == after[2] and np.array_equal(before[3], after[3]) and torch.equal(before[4], after[4])
