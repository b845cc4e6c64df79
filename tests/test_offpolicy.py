"""SAC and TD3 on the ``Learner`` contract: the networks by name and role, the round of the loop, every remedy against
a hand-built expectation, the config's keys. The SIGKILL resume is in test_reliability.py."""
from __future__ import annotations

import random

import numpy as np
import pytest
import torch
from stable_baselines3.common.utils import configure_logger

from conftest import compose_cfg, new_store
from sweep.agents import build_learner
from sweep.agents.learner import Learner
from sweep.agents.networks import fresh_parameters
from sweep.checkpoint import job_key
from sweep.config import ConfigError, drop_unused_algorithm_blocks, one_line, validate
from sweep.envs.factory import make_env, vehicle_schedule, wind_schedule
from sweep.plasticity.cbp import ContinualBackprop
from sweep.plasticity.periodic_reset import PeriodicReset
from sweep.plasticity.redo import ReDo
from sweep.plasticity.reset_all import ResetAll
from sweep.plasticity.shrink_perturb import ShrinkPerturb
from sweep.plasticity.weight_clip import WeightClip
from sweep.training.records import OffPolicyUpdate

ALGORITHMS = ("sac", "td3")
IMPLEMENTATIONS = ("sb3", "jax")
BOTH = [(a, i) for a in ALGORITHMS for i in IMPLEMENTATIONS]
OBS = np.random.default_rng(11).normal(size=(128, 13)).astype(np.float32)


def learner(algorithm: str, overrides=(), seed: int = 0, steps: int = 0, impl: str = "sb3"):
    """A SAC/TD3 learner (``impl``: SB3's or the compiled one) of 2 x 16 units on the hover env, trained for ``steps``
    env steps (learning from 200)."""
    cfg = compose_cfg([f"agent={algorithm}", "agent.policy.net_arch=[16,16]", f"agent.{algorithm}.learning_starts=200",
                       f"agent.{algorithm}.batch_size=32", f"agent.{algorithm}.round_steps=256",
                       f"agent.learner={impl}", *overrides])
    validate(cfg)
    np.random.seed(seed)
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


@pytest.fixture(scope="module", params=BOTH, ids=[f"{a}-{i}" for a, i in BOTH])
def trained(request):
    algorithm, impl = request.param
    return learner(algorithm, steps=400, impl=impl)


def test_the_networks_are_named_with_their_roles(trained):
    assert isinstance(trained, Learner)
    assert [(n.name, n.role) for n in trained.networks] == [("actor", "policy"), ("critic_0", "value"),
                                                            ("critic_1", "value")]
    params, targets = trained.parameter_arrays(), trained.target_arrays()
    state = trained.policy.state_dict()   # the torch policy's names (a shell on JAX): SB3's
    assert set(params) | set(targets) == set(state) | ({"log_ent_coef"} if trained.algorithm == "sac" else set())
    assert targets and all(k.startswith(("critic_target.", "actor_target.")) for k in targets)
    assert ("actor_target.mu.0.weight" in targets) == (trained.algorithm == "td3")
    for net in trained.networks:
        for layer in net.linears:
            assert f"{layer}.weight" in params and f"{layer}.bias" in params
    acts = trained.hidden_activations(OBS)
    assert {k: [h.post.shape for h in v] for k, v in acts.items()} == {n.name: [(128, 16)] * 2 for n in trained.networks}
    assert np.isfinite(trained.loss_grad_norm(trained.recent_samples(64)))


@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_written_parameters_are_acted_on_and_targets_follow_only_on_reset(algorithm, impl):
    model = learner(algorithm, steps=250, impl=impl)
    before = model.parameter_arrays()
    acted = model.predict(OBS, deterministic=True)[0]
    head = "actor.mu.bias" if algorithm == "sac" else "actor.mu.4.bias"
    model.write_parameters({"critic.qf0.0.bias": before["critic.qf0.0.bias"] + 1.0, head: before[head] + 0.5})
    after = model.parameter_arrays()
    assert np.array_equal(after["critic.qf0.0.bias"], before["critic.qf0.0.bias"] + 1.0)
    assert not np.allclose(model.predict(OBS, deterministic=True)[0], acted)   # the next action reads the write
    target = "critic_target.qf0.0.bias"
    assert not np.array_equal(model.target_arrays()[target], after["critic.qf0.0.bias"])
    model.reset_targets()
    assert np.array_equal(model.target_arrays()[target], after["critic.qf0.0.bias"])


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


@pytest.mark.parametrize("impl", IMPLEMENTATIONS)
def test_a_round_is_many_turns_and_its_update_reports_all_their_gradient_steps(impl):
    model = learner("td3", overrides=["agent.td3.train_freq=2", "agent.td3.gradient_steps=3"], impl=impl)
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
    buf = model.replay_buffer
    assert buf.pos == 768 and not buf.full and np.abs(buf.actions[:768]).max() <= 1.0
    assert buf.timeouts[:768].sum() == sum(1 for r, _ in rounds for e in r.episodes if not e.crashed)


def test_td3s_round_actor_loss_weighs_each_update_by_its_actor_steps():
    """SB3 logs one train() call's actor loss as the mean over the steps that updated the actor (every policy_delay-th,
    counted from the first gradient step); the round's train/actor_loss is the mean over all the round's actor steps:
    each call's logged mean weighed by the actor steps it ran, counted here on the actor's optimizer itself."""
    model = learner("td3", overrides=["agent.td3.gradient_steps=3"])
    calls, steps = [], []
    optimizer_step = model.actor.optimizer.step

    def counted_step(*args, **kwargs):
        steps[-1] += 1
        return optimizer_step(*args, **kwargs)
    model.actor.optimizer.step = counted_step
    train = model.train

    def recorded_train(gradient_steps, batch_size):
        steps.append(0)
        train(gradient_steps=gradient_steps, batch_size=batch_size)
        calls.append(model.logger.name_to_value.get("train/actor_loss"))
    model.train = recorded_train
    total = model.begin(256)
    while model.num_timesteps < total:
        model.collect()
        record = model.update()
    assert sum(steps) == record.gradient_steps // 2 and set(steps) == {1, 2}   # 3 steps per call: 1 or 2 actor steps
    expected = sum(loss * n for loss, n in zip(calls, steps) if n) / sum(steps)
    assert record.actor_loss == pytest.approx(expected, rel=1e-9)


def test_a_checkpoint_holds_the_replay_at_its_own_size_and_restores_it(trained, tmp_path):
    """torch.save writes the replay buffer's filled part at its size in bytes (a NumPy array would pickle through a
    latin-1 string at ~1.4x, with copies that took a 145-column run past 10 GB at 500k), and loading it restores the
    buffer row for row."""
    buf = trained.replay_buffer
    keys = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")
    filled = {k: getattr(buf, k)[:buf.pos].copy() for k in keys}
    assert buf.pos >= 400 // trained.n_envs and np.abs(filled["observations"]).sum() > 0
    path, without = tmp_path / "state.pt", tmp_path / "without_replay.pt"
    state = trained.training_state()
    torch.save(state, path)
    torch.save({**state, "replay": {**state["replay"], "arrays": {}}}, without)
    replay_bytes = sum(a.nbytes for a in filled.values())
    assert path.stat().st_size - without.stat().st_size < 1.05 * replay_bytes + 4096
    for k in keys:
        getattr(buf, k)[:buf.pos] = 0
    trained.load_training_state(torch.load(path, weights_only=False))
    for k in keys:
        np.testing.assert_array_equal(getattr(buf, k)[:buf.pos], filled[k])


def test_sb3_and_jax_sample_the_same_transitions():
    """The JAX learner draws its replay indices as SB3's ReplayBuffer.sample does, from NumPy's global RNG."""
    model = learner("sac", steps=300, impl="jax")
    np.random.seed(5)
    batches = model.replay_batches(3, 32)
    np.random.seed(5)
    for g in range(3):
        sample = model.replay_buffer.sample(32)
        for key in ("observations", "actions", "next_observations", "rewards", "dones"):
            np.testing.assert_array_equal(batches[key][g].reshape(32, -1), sample._asdict()[key].numpy().reshape(32, -1))


def one_gradient_step(model):
    """One train() step from a saved state of every RNG, so two learners see the same batch and noise."""
    state = (torch.get_rng_state(), np.random.get_state(), random.getstate())
    model.train(gradient_steps=1, batch_size=32)
    torch.set_rng_state(state[0]), np.random.set_state(state[1]), random.setstate(state[2])


@pytest.mark.parametrize("anchor", ["zero", "init"])
@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_decoupled_l2_is_adamws_shrink_on_the_chosen_networks(algorithm, impl, anchor):
    """theta_l2 = theta_plain - lr x coef x (theta_before - anchor) on the decayed parameters (AdamW multiplies by
    1 - lr coef before the Adam step, whose gradient was taken at theta_before; L2-Init pulls toward theta_0 instead of
    0); nothing else moves. The actor's weights: its step comes after the critics' (SB3's order), so no other
    parameter sees the decay within the step."""
    plain, decayed = (learner(algorithm, steps=301, impl=impl) for _ in range(2))   # twice the same learner
    for model in (plain, decayed):
        model._n_updates += 1 - model._n_updates % 2   # odd: TD3's next step is an actor step (policy_delay 2)
    decayed.use_l2(0.5, mode="decoupled", params=("policy",), biases=False, anchor=anchor)
    theta_0 = decayed.initial_parameters() if anchor == "init" else {k: 0.0 for k in decayed.initial_parameters()}
    before = plain.parameter_arrays()
    assert all(np.array_equal(before[k], v) for k, v in decayed.parameter_arrays().items())
    one_gradient_step(plain)
    one_gradient_step(decayed)
    lr = decayed.lr_schedule(1)
    a, b = plain.parameter_arrays(), decayed.parameter_arrays()
    assert decayed.l2_decayed == sorted(k for k in before if k.startswith("actor.") and k.endswith("weight"))
    for k in before:
        if k in decayed.l2_decayed:
            np.testing.assert_allclose(b[k], a[k] - lr * 0.5 * (before[k] - theta_0[k]), atol=2e-7)
            assert not np.allclose(b[k], a[k])
        else:
            np.testing.assert_array_equal(b[k], a[k])


def silence(model, net, layer: int, units: list[int]) -> None:
    """Zero the units' incoming weights and bias: ReLU(0) = 0 on every input, dormant."""
    params = model.parameter_arrays()
    for kind in ("weight", "bias"):
        params[f"{net.hidden[layer]}.{kind}"][units] = 0.0
    model.write_parameters({f"{net.hidden[layer]}.{k}": params[f"{net.hidden[layer]}.{k}"] for k in ("weight", "bias")})


@pytest.mark.parametrize("impl", IMPLEMENTATIONS)
def test_redo_on_sacs_last_hidden_layer_zeroes_both_heads_columns(impl):
    model = learner("sac", steps=400, impl=impl)
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


@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_reset_all_draws_fresh_networks_copies_them_to_the_targets_and_restarts_adam(algorithm, impl):
    model = learner(algorithm, steps=400, impl=impl)
    before = model.parameter_arrays()
    ResetAll().at_change(model, None)
    after, targets = model.parameter_arrays(), model.target_arrays()
    assert all(not np.array_equal(after[k], before[k]) for k in before if k.endswith("weight"))
    for k, v in targets.items():
        assert np.array_equal(v, after[k.replace("_target", "")]), k
    assert all(not m.any() and not v.any() for m, v in model.optimizer_moments().values())
    if algorithm == "sac":
        assert after["log_ent_coef"] == 0.0   # ent_coef back to its init, 1
    model.train(gradient_steps=2, batch_size=32)   # and it trains on
    assert np.isfinite(model.parameter_arrays()["critic.qf0.0.weight"]).all()


@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_periodic_reset_rebuilds_everything_on_its_clock_and_keeps_the_buffer(algorithm, impl):
    model = learner(algorithm, steps=400, impl=impl)
    buffer = model.replay_buffer.observations[:400].copy()
    reset = PeriodicReset(every_steps=300, layers="all")
    before = model.parameter_arrays()
    assert reset.after_update(model, OffPolicyUpdate(1, 256, 1e-3, 1, 1)) == {}   # before its first multiple
    assert reset.after_update(model, OffPolicyUpdate(2, 400, 1e-3, 1, 1)) == {"remedy/periodic_reset/resets": 1.0}
    assert reset.after_update(model, OffPolicyUpdate(3, 512, 1e-3, 1, 1)) == {}   # next at 600
    after = model.parameter_arrays()
    assert all(not np.array_equal(after[k], before[k]) for k in before if k.endswith("weight"))
    assert all(np.array_equal(v, after[k.replace("_target", "")]) for k, v in model.target_arrays().items())
    assert all(not m.any() for m, _ in model.optimizer_moments().values())
    assert np.array_equal(model.replay_buffer.observations[:400], buffer)   # the buffer kept
    assert reset.state_dict() == {"resets": 1, "next_at": 600}


@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_periodic_reset_of_the_heads_touches_exactly_the_output_layers(algorithm, impl):
    model = learner(algorithm, steps=400, impl=impl)
    before, targets, moments = model.parameter_arrays(), model.target_arrays(), model.optimizer_moments()
    PeriodicReset(every_steps=100, layers="heads").reset(model)
    after, new_targets, new_moments = model.parameter_arrays(), model.target_arrays(), model.optimizer_moments()
    heads = {f"{layer}.{kind}" for net in model.networks for layer in (net.head, *net.extra_heads)
             for kind in ("weight", "bias")}
    assert len(heads) == (8 if algorithm == "sac" else 6)
    for k in before:
        if k in heads:
            assert not np.array_equal(after[k], before[k]) and not new_moments[k][0].any(), k
            target = k.replace("actor.", "actor_target.").replace("critic.", "critic_target.")
            if target in new_targets:
                assert np.array_equal(new_targets[target], after[k]), target
        else:
            assert np.array_equal(after[k], before[k]) and np.array_equal(new_moments[k][0], moments[k][0]), k
    for k in targets:
        if k.replace("_target", "") not in heads:
            assert np.array_equal(new_targets[k], targets[k]), k


@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_shrink_and_perturb_is_its_formula_on_the_trained_networks(algorithm, impl):
    """theta <- shrink theta + perturb eps, eps a fresh draw of each layer's init from the learner's generator, on the
    actor and the critics (and SAC's log_ent_coef, a parameter of no network: its fresh value is 0)."""
    model = learner(algorithm, steps=300, impl=impl)
    theta = model.parameter_arrays()
    rng = np.random.default_rng()
    rng.bit_generator.state = model.rng.bit_generator.state
    eps = fresh_parameters({k: v.shape for k, v in theta.items()}, model.networks, rng)
    ShrinkPerturb(shrink=0.8, perturb=0.2).act(model, OBS)
    after = model.parameter_arrays()
    for k in theta:
        if k.startswith(("actor.", "critic.")):
            np.testing.assert_allclose(after[k], 0.8 * theta[k] + 0.2 * eps[k], rtol=1e-6, atol=1e-7)
        else:
            np.testing.assert_array_equal(after[k], theta[k])


@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_the_lr_decay_controls_drive_every_optimizer(algorithm, impl):
    """agent.<algorithm>.lr_schedule=linear: the rate each update uses falls with the run's progress, as PPO's."""
    model = learner(algorithm, overrides=[f"agent.{algorithm}.lr_schedule=linear", f"agent.{algorithm}.lr_floor=0.0"],
                    impl=impl)
    lr_0 = model.lr_schedule(1.0)
    total = model.begin(1024)
    rates = []
    while model.num_timesteps < total:
        model.collect()
        record = model.update()
        if record.gradient_steps:
            rates.append(record.learning_rate)
    assert rates == sorted(rates, reverse=True) and rates[-1] < 0.25 * lr_0 < rates[0]


@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_shrink_perturb_and_cbp_write_only_trained_parameters(algorithm, impl):
    model = learner(algorithm, steps=400, impl=impl)
    targets = model.target_arrays()
    before = model.parameter_arrays()
    ShrinkPerturb(shrink=0.5, perturb=0.5).act(model, OBS)
    after = model.parameter_arrays()
    assert all(not np.array_equal(after[k], before[k]) for k in before if k.endswith("weight"))
    cbp = ContinualBackprop(replacement_rate=0.5, maturity=0)
    cbp.setup(model, None)
    stats = cbp.act(model, OBS)
    assert stats["replaced_units"] > 0
    assert all(np.array_equal(v, targets[k]) for k, v in model.target_arrays().items())


@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_weight_clip_holds_after_every_step(algorithm, impl):
    model = learner(algorithm, steps=250, impl=impl)
    clip = WeightClip(kappa=0.5, heads=True)
    clip.setup(model, None)
    if impl == "sb3":   # a step hook on each optimizer (traced once into the update on JAX)
        calls = []
        model.add_step_transform(lambda params, xp: calls.append(1) or {})
    model.train(gradient_steps=4, batch_size=32)
    if impl == "sb3":
        assert len(calls) == (8 if algorithm == "sac" else 6)   # actor + critic steps; TD3's actor every 2nd step
    params = model.parameter_arrays()
    for name, bound in clip.bounds.items():
        assert np.abs(params[name]).max() <= bound + 1e-7, name
    assert any(np.isclose(np.abs(params[n]).max(), b) for n, b in clip.bounds.items())   # some weight at its bound


@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_one_learning_rate_drives_every_optimizer(algorithm, impl):
    """set_learning_rate (RECOM's handle) is the rate every optimizer steps with: at 0 no trained parameter moves
    (Adam's step is lr x direction), at 1e-3 every optimizer's parameters move by about lr per step (Adam's first steps
    are ~lr in size), and the record logs it."""
    model = learner(algorithm, steps=250, impl=impl)
    before = model.parameter_arrays()
    assert model.set_learning_rate(0.0) == 0.0
    model.train(gradient_steps=2, batch_size=32)
    assert all(np.array_equal(v, before[k]) for k, v in model.parameter_arrays().items())
    model.set_learning_rate(1e-3)
    model.train(gradient_steps=2, batch_size=32)   # two: TD3's actor steps every 2nd
    after = model.parameter_arrays()
    record = model.update()   # the round's gradient steps, logged by the learner
    assert record.learning_rate == 1e-3 and record.gradient_steps == 1
    moved = {k: float(np.abs(after[k] - before[k]).max()) for k in before}
    for group in ("actor.", "critic.", "log_ent_coef"):
        biggest = max((v for k, v in moved.items() if k.startswith(group)), default=None)
        if biggest is not None:
            assert 2e-4 < biggest < 6e-3, (group, biggest)   # 2 steps of ~lr (Adam: |m| / sqrt(v) ~ 1)
    if impl == "sb3":
        for opt in model.optimizers().values():
            assert {g["lr"] for g in opt.param_groups} == {1e-3}


@pytest.mark.parametrize("algorithm,impl", BOTH)
def test_layer_norm_networks_train_their_norms(algorithm, impl):
    model = learner(algorithm, overrides=["agent.policy.layer_norm=true"], steps=300, impl=impl)
    norms = [n for net in model.networks for n in net.norms]
    assert all(norms) and len(norms) == 6
    params, moments = model.parameter_arrays(), model.optimizer_moments()
    for norm in norms:
        assert f"{norm}.weight" in params and moments[f"{norm}.weight"][1].any()   # optimized
    assert not np.allclose(params[f"{norms[2]}.weight"], 1.0)   # trained away from its init
    assert set(model.hidden_activations(OBS)) == {"actor", "critic_0", "critic_1"}


@pytest.mark.parametrize("algorithm,impl", BOTH)
@pytest.mark.parametrize("layer_norm", [False, True])
def test_the_saved_model_is_an_sb3_zip_that_flies_the_same_policy(algorithm, impl, layer_norm, tmp_path):
    """model.zip of either implementation loads with SB3's own SAC.load / TD3.load (LayerNorm too) and its
    deterministic actions are the learner's."""
    from stable_baselines3 import SAC, TD3

    model = learner(algorithm, overrides=[f"agent.policy.layer_norm={str(layer_norm).lower()}"], steps=300, impl=impl)
    model.save(tmp_path / "model.zip")
    loaded = (SAC if algorithm == "sac" else TD3).load(tmp_path / "model.zip", device="cpu")
    np.testing.assert_allclose(loaded.predict(OBS, deterministic=True)[0], model.predict(OBS, deterministic=True)[0],
                               atol=2e-6)


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
    (["agent=sac", "agent.sac.target_update_interval=2"], "agent.sac.target_update_interval=2: must be 1, or <="),
    (["agent=sac", "agent.learners.sb3._target_=sweep.agents.sb3.SB3PPO.from_config"], "builds ppo: must build"),
    (["agent=sac", "agent.learner=jax", "env.backend=rotorpy"], "env.backend='rotorpy': must be fast with agent.learner=jax"),
    (["agent=td3", "+remedy@agent.l2=l2", "agent.l2.params=[log_std]"], "must leave out log_std with TD3"),
    (["agent=sac", "++agent.ppo.n_stepz=5"], "agent.ppo.n_stepz: not a config key"),
    (["agent=sac", "agent.algorithm=ppo"], "builds sac: must build agent.algorithm=ppo"),
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


@pytest.mark.slow
@pytest.mark.timeout(3 * 3600)
def test_learning_curves_of_sb3_and_jax_are_equivalent(tmp_path):
    """experiment=equivalence_offpolicy: SAC and TD3, 5 seeds x 50k timesteps per learner; for each algorithm the 95%
    bootstrap CI of the IQM difference of the final reward (jax - sb3), from the project's report, contains 0.
    ~30 min on 2 cores. The documented run: docs/offpolicy_learners.md."""
    import os

    import pandas as pd

    from conftest import run_cli
    from sweep.report.__main__ import main as report

    uri = new_store(tmp_path / "mlflow.db")
    proc = run_cli(["-m", "experiment=equivalence_offpolicy", "tracking.experiment=equiv",
                    f"hydra.sweep.dir={tmp_path / 'sweep'}"], uri, tmp_path, timeout=3 * 3600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    os.environ["MLFLOW_TRACKING_URI"] = uri
    try:
        for algorithm in ALGORITHMS:
            out = tmp_path / f"report_{algorithm}"
            assert report(["--experiment", "equiv", "--agents", algorithm, "--out", str(out), "--by", "agent.learner",
                           "--baseline", "agent.learner=sb3"]) == 0
            summary = pd.read_csv(out / "summary.csv")
            row = summary[summary["agent.learner"] == "jax"].iloc[0]
            assert row["n_seeds"] == 5
            assert row["delta_iqm_ci_low"] <= 0.0 <= row["delta_iqm_ci_high"], (algorithm, row.to_dict())
    finally:
        del os.environ["MLFLOW_TRACKING_URI"]
