"""SAC and TD3 on the ``Learner`` contract: the networks by name and role, the round of the loop, every remedy against
a hand-built expectation, the config's keys. The SIGKILL resume is in test_reliability.py."""
from __future__ import annotations

import copy
import random

import numpy as np
import pytest
import torch
from stable_baselines3.common.utils import configure_logger

from conftest import compose_cfg
from sweep.agents import build_learner
from sweep.agents.learner import Learner
from sweep.agents.networks import fresh_parameters
from sweep.checkpoint import job_key
from sweep.config import ConfigError, drop_unused_algorithm_blocks, one_line, validate
from sweep.envs.factory import make_env, vehicle_schedule, wind_schedule
from sweep.plasticity.cbp import ContinualBackprop
from sweep.plasticity.redo import ReDo
from sweep.plasticity.reset_all import ResetAll
from sweep.plasticity.shrink_perturb import ShrinkPerturb
from sweep.plasticity.weight_clip import WeightClip
from sweep.training.records import OffPolicyUpdate

ALGORITHMS = ("sac", "td3")
OBS = np.random.default_rng(11).normal(size=(128, 13)).astype(np.float32)


def learner(algorithm: str, overrides=(), seed: int = 0, steps: int = 0):
    """An SB3 SAC/TD3 learner of 2 x 16 units on the hover env, trained for ``steps`` env steps (learning from 200)."""
    cfg = compose_cfg([f"agent={algorithm}", "agent.policy.net_arch=[16,16]", f"agent.{algorithm}.learning_starts=200",
                       f"agent.{algorithm}.batch_size=32", f"agent.{algorithm}.round_steps=256", *overrides])
    validate(cfg)
    env = make_env(cfg.env, cfg.env.n_envs, wind_schedule(cfg.wind), seed, learning=True,
                   vehicle=vehicle_schedule(cfg.vehicle))
    torch.manual_seed(seed)
    model = build_learner(cfg.agent, env, seed, 10_000)
    model.set_logger(configure_logger(0, None, "", False))
    if steps:
        total = model.begin(steps)
        while model.num_timesteps < total:
            model.collect()
            model.update()
    return model


@pytest.fixture(scope="module", params=ALGORITHMS)
def trained(request):
    return learner(request.param, steps=400)


def test_the_networks_are_named_with_their_roles(trained):
    assert isinstance(trained, Learner)
    assert [(n.name, n.role) for n in trained.networks] == [("actor", "policy"), ("critic_0", "value"),
                                                            ("critic_1", "value")]
    params = trained.parameter_arrays()
    state = trained.policy.state_dict()
    assert not any(k.startswith(("critic_target.", "actor_target.")) for k in params)   # targets: not trained
    assert {k for k in params if k != "log_ent_coef"} == {k for k in state if not k.startswith(("critic_target.",
                                                                                                "actor_target."))}
    assert ("log_ent_coef" in params) == (trained.algorithm == "sac")
    for net in trained.networks:
        for layer in net.linears:
            assert f"{layer}.weight" in params and f"{layer}.bias" in params
    acts = trained.hidden_activations(OBS)
    assert {k: [h.post.shape for h in v] for k, v in acts.items()} == {n.name: [(128, 16)] * 2 for n in trained.networks}


def test_written_parameters_are_read_back_and_targets_follow_only_on_reset(trained):
    model = copy.deepcopy(trained)
    before = model.parameter_arrays()
    model.write_parameters({"critic.qf0.0.bias": before["critic.qf0.0.bias"] + 1.0})
    assert np.array_equal(model.parameter_arrays()["critic.qf0.0.bias"], before["critic.qf0.0.bias"] + 1.0)
    target = model.critic_target.state_dict()["qf0.0.bias"].numpy()
    assert not np.array_equal(target, before["critic.qf0.0.bias"] + 1.0)
    model.reset_targets()
    assert np.array_equal(model.critic_target.state_dict()["qf0.0.bias"].numpy(), before["critic.qf0.0.bias"] + 1.0)


def test_fresh_parameters_draw_torchs_linear_init():
    model = learner("td3", overrides=["agent.policy.net_arch=[256,256]"])
    shapes = {k: v.shape for k, v in model.parameter_arrays().items()}
    fresh = fresh_parameters(shapes, model.networks, np.random.default_rng(0))
    built = model.parameter_arrays()
    for layer in ("actor.mu.0", "actor.mu.2", "critic.qf1.4"):
        bound = 1 / np.sqrt(shapes[f"{layer}.weight"][1])
        for kind in ("weight", "bias"):
            new, old = fresh[f"{layer}.{kind}"], built[f"{layer}.{kind}"]
            assert np.abs(new).max() <= bound and np.abs(old).max() <= bound
            if new.size > 1000:   # the same uniform law as torch's draw: its std, bound / sqrt 3
                assert abs(new.std() / (bound / np.sqrt(3)) - 1) < 0.05 and abs(old.std() / (bound / np.sqrt(3)) - 1) < 0.05


def test_a_round_is_many_turns_and_its_update_reports_all_their_gradient_steps():
    model = learner("td3", overrides=["agent.td3.train_freq=2", "agent.td3.gradient_steps=3"])
    total = model.begin(768)
    rounds, inside = [], 0
    while model.num_timesteps < total:
        rollout = model.collect()
        update = model.update()
        if rollout.ends_round:
            rounds.append((rollout, update))
        else:
            inside += 1
    assert [r.timesteps for r, _ in rounds] == [256, 512, 768] and inside == 3 * 128 - 3
    # learning starts after 200 steps: turns ending at 202..256 train, 28 turns x 3 gradient steps in round 1
    assert [u.gradient_steps for _, u in rounds] == [28 * 3, 128 * 3, 128 * 3]
    assert [u.n_updates for _, u in rounds] == [84, 468, 852]
    assert sum(len(r.episodes) for r, _ in rounds) == model._episode_num
    first = rounds[0][1]
    assert isinstance(first, OffPolicyUpdate) and set(first.metrics()) == {
        "train/actor_loss", "train/critic_loss", "train/learning_rate", "train/n_updates"}


def test_td3s_actor_loss_is_the_mean_over_its_delayed_steps():
    """SB3 logs the mean actor loss of one train() call over the steps that updated the actor (every policy_delay-th
    counted from the first gradient step); a round weighs each call's mean by its delayed steps."""
    model = learner("td3", overrides=["agent.td3.gradient_steps=3"])
    model._n_updates = 7   # after a call whose steps were 5, 6, 7: one actor step (6)
    assert model._train_counts("actor_loss", 3) == 1 and model._train_counts("critic_loss", 3) == 3
    model._n_updates = 6   # steps 4, 5, 6: two (4, 6)
    assert model._train_counts("actor_loss", 3) == 2


def one_gradient_step(model):
    """One SB3 train() step from a saved state of every RNG, so two calls see the same batch and noise."""
    state = (torch.get_rng_state(), np.random.get_state(), random.getstate())
    model.train(gradient_steps=1, batch_size=32)
    torch.set_rng_state(state[0]), np.random.set_state(state[1]), random.setstate(state[2])


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_decoupled_l2_is_adamws_shrink_on_the_chosen_networks(algorithm):
    """theta_l2 = theta_plain - lr x coef x theta_before on the decayed parameters (AdamW multiplies by 1 - lr coef
    before the Adam step, whose gradient was taken at theta_before); nothing else moves. The actor's weights: its
    step comes after the critics' (SB3's order), so no other parameter sees the decay within the step."""
    base = learner(algorithm, steps=300)
    base._n_updates += 1 - base._n_updates % 2   # odd: TD3's next step is an actor step (policy_delay 2)
    plain, decayed = copy.deepcopy(base), copy.deepcopy(base)
    decayed.use_l2(0.5, mode="decoupled", params=("policy",), biases=False)
    before = base.parameter_arrays()
    one_gradient_step(plain)
    one_gradient_step(decayed)
    lr = decayed.lr_schedule(1)
    a, b = plain.parameter_arrays(), decayed.parameter_arrays()
    assert decayed.l2_decayed == sorted(k for k in before if k.startswith("actor.") and k.endswith("weight"))
    for k in before:
        if k in decayed.l2_decayed:
            np.testing.assert_allclose(b[k], a[k] - lr * 0.5 * before[k], atol=2e-7)
            assert not np.allclose(b[k], a[k])
        else:
            np.testing.assert_array_equal(b[k], a[k])


def silence(model, net, layer: int, units: list[int]) -> None:
    """Zero the units' incoming weights and bias: ReLU(0) = 0 on every input, dormant."""
    params = model.parameter_arrays()
    for kind in ("weight", "bias"):
        params[f"{net.hidden[layer]}.{kind}"][units] = 0.0
    model.write_parameters({f"{net.hidden[layer]}.{k}": params[f"{net.hidden[layer]}.{k}"] for k in ("weight", "bias")})


def test_redo_on_sacs_last_hidden_layer_zeroes_both_heads_columns():
    model = learner("sac", steps=400)
    actor = model.networks[0]
    silence(model, actor, 1, [2, 9])
    before, moments = model.parameter_arrays(), model.optimizer_moments()
    stats = ReDo(tau=0.0, networks=("policy",)).act(model, OBS)
    assert stats["reset_units"] >= 2 and stats["actor_layer1"] >= 2
    after, new_moments = model.parameter_arrays(), model.optimizer_moments()
    for head in ("actor.mu.weight", "actor.log_std.weight"):
        assert not after[head][:, [2, 9]].any() and before[head][:, [2, 9]].any()
        assert not new_moments[head][0][:, [2, 9]].any() and moments[head][0][:, [2, 9]].any()
    bound = 1 / np.sqrt(16)
    rows = after["actor.latent_pi.2.weight"][[2, 9]]
    assert np.abs(rows).max() <= bound and np.abs(rows).sum() > 0   # fresh incoming weights, torch's uniform law
    for k in before:
        if k.startswith("critic."):
            assert np.array_equal(after[k], before[k]), k   # the critics (role value) untouched


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_reset_all_draws_fresh_networks_copies_them_to_the_targets_and_restarts_adam(algorithm):
    model = learner(algorithm, steps=400)
    before = model.parameter_arrays()
    ResetAll().at_change(model, None)
    after = model.parameter_arrays()
    assert all(not np.array_equal(after[k], before[k]) for k in before if k.endswith("weight"))
    critic = model.critic.state_dict()
    for k, v in model.critic_target.state_dict().items():
        assert torch.equal(v, critic[k])
    assert all(not opt.state for opt in model.optimizers().values())
    if algorithm == "sac":
        assert after["log_ent_coef"] == 0.0   # ent_coef back to its init, 1


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_shrink_perturb_and_cbp_write_only_trained_parameters(algorithm):
    model = learner(algorithm, steps=400)
    targets = {k: v.clone() for k, v in model.critic_target.state_dict().items()}
    before = model.parameter_arrays()
    ShrinkPerturb(shrink=0.5, perturb=0.5).act(model, OBS)
    after = model.parameter_arrays()
    assert all(not np.array_equal(after[k], before[k]) for k in before if k.endswith("weight"))
    cbp = ContinualBackprop(replacement_rate=0.5, maturity=0)
    cbp.setup(model, None)
    stats = cbp.act(model, OBS)
    assert stats["replaced_units"] > 0
    assert all(torch.equal(v, targets[k]) for k, v in model.critic_target.state_dict().items())


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_weight_clip_holds_every_step_of_both_optimizers(algorithm):
    model = learner(algorithm, steps=250)
    clip = WeightClip(kappa=0.5, heads=True)
    clip.setup(model, None)
    calls = []
    model.add_step_transform(lambda params, xp: calls.append(1) or {})
    model.train(gradient_steps=4, batch_size=32)
    per_step = 2 if algorithm == "sac" else 1.5   # actor + critic optimizers; TD3's actor every 2nd step
    assert len(calls) == int(4 * per_step)
    params = model.parameter_arrays()
    for name, bound in clip.bounds.items():
        assert np.abs(params[name]).max() <= bound + 1e-7, name
    assert any(np.isclose(np.abs(params[n]).max(), b) for n, b in clip.bounds.items())   # some weight at its bound


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_one_learning_rate_drives_every_optimizer(algorithm):
    model = learner(algorithm, steps=250)
    assert model.set_learning_rate(1.5e-5) == 1.5e-5
    model.train(gradient_steps=2, batch_size=32)
    for opt in model.optimizers().values():
        assert {g["lr"] for g in opt.param_groups} == {1.5e-5}


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_layer_norm_networks_train_their_norms(algorithm):
    model = learner(algorithm, overrides=["agent.policy.layer_norm=true"], steps=300)
    norms = [n for net in model.networks for n in net.norms]
    assert all(norms) and len(norms) == 6
    params = model.parameter_arrays()
    optimized = {id(p) for opt in model.optimizers().values() for g in opt.param_groups for p in g["params"]}
    named = model._trained()
    for norm in norms:
        assert f"{norm}.weight" in params and id(named[f"{norm}.weight"]) in optimized
    assert not np.allclose(params[f"{norms[0]}.weight"], 1.0)   # trained away from its init
    assert set(model.hidden_activations(OBS)) == {"actor", "critic_0", "critic_1"}


# ---- config ------------------------------------------------------------------------------------------------------
INVALID = [
    (["agent=sac", "agent.sac.tau=0"], "agent.sac.tau=0: must be a number in (0, 1]"),
    (["agent=sac", "agent.sac.gradient_steps=-2"], "agent.sac.gradient_steps=-2"),
    (["agent=sac", "agent.sac.ent_coef=-1"], "agent.sac.ent_coef=-1: must be auto"),
    (["agent=td3", "agent.td3.action_noise_std=0"], "agent.td3.action_noise_std=0"),
    (["agent=td3", "agent.td3.policy_delay=0"], "agent.td3.policy_delay=0"),
    (["agent=td3", "agent.td3.buffer_size=100", "agent.td3.batch_size=256"], "agent.td3.batch_size=256: must be <="),
    (["agent=sac", "agent.sac.round_steps=1", "env.n_envs=2"], "agent.sac.round_steps=1: must be >= one turn"),
    (["agent=sac", "agent.sac.learning_starts=-1"], "agent.sac.learning_starts=-1"),
    (["agent=sac", "agent.learner=jax"], "agent.learner='jax': must be one of sb3"),
    (["agent=td3", "+remedy@agent.l2=l2", "agent.l2.params=[log_std]"], "must leave out log_std with TD3"),
    (["agent=sac", "++agent.ppo.n_stepz=5"], "agent.ppo.n_stepz: not a config key"),
    (["agent=sac", "agent.algorithm=ppo"], "agent.ppo: missing"),
]


@pytest.mark.parametrize("overrides,message", INVALID)
def test_a_bad_off_policy_setting_is_one_line(overrides, message):
    with pytest.raises(ConfigError) as err:
        validate(compose_cfg(overrides))
    assert message in str(err.value) and "\n" not in one_line(err.value)


def test_ppo_settings_of_an_experiment_are_not_used_by_an_off_policy_agent():
    """``experiment=smoke`` sets agent.ppo.n_steps: with agent=sac it is checked, dropped, and out of the key."""
    plain = compose_cfg(["agent=sac"])
    given = compose_cfg(["agent=sac", "++agent.ppo.n_steps=512"])
    validate(given)
    assert drop_unused_algorithm_blocks(given) == ["ppo"] and "ppo" not in given.agent
    assert job_key(given, "sqlite:///x.db") == job_key(plain, "sqlite:///x.db")


def test_a_hook_that_works_on_some_algorithms_refuses_the_others(monkeypatch):
    monkeypatch.setattr("sweep.plasticity.redo.ReDo.algorithms", ("ppo",))
    cfg = compose_cfg(["agent=sac", "+remedy@agent.redo=redo"])
    with pytest.raises(ConfigError, match=r"agent.redo: ReDo works with agent.algorithm=ppo, not with agent sac's sac"):
        validate(cfg)
    validate(compose_cfg(["agent=ppo", "+remedy@agent.redo=redo"]))
