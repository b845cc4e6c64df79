"""The ``Learner`` contract (sweep.agents.learner), held once for both learners, and the rule that remedies
and diagnostics use nothing else."""
from __future__ import annotations

import re
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
import torch
from stable_baselines3.common.utils import configure_logger

from conftest import ROOT
from sweep.agents.learner import Learner
from sweep.agents.networks import fresh_parameters, orthogonal
from test_jax_learner import pair, sb3_rollout_into_both

LEARNERS = ("sb3", "jax")


def trained(overrides=(), seed=0):
    """(sb3, jax) learners after one update on the same SB3 rollout (so Adam's moments are non-zero)."""
    sb3, jx = pair(overrides, seed=seed)
    sb3_rollout_into_both(sb3, jx)
    for model in (sb3, jx):
        model.set_logger(configure_logger(0, None, "", False))
        np.random.seed(3)
        model.train()
    return {"sb3": sb3, "jax": jx}


def test_both_learners_implement_the_contract():
    for model in pair():
        assert isinstance(model, Learner)
        names = model.parameter_arrays().keys()
        for net in model.networks:
            for layer in net.linears:
                assert f"{layer}.weight" in names and f"{layer}.bias" in names


@pytest.mark.parametrize("name", LEARNERS)
def test_written_parameters_are_read_back_and_acted_on(name):
    model = trained()[name]
    before = model.parameter_arrays()
    obs = np.random.default_rng(0).normal(size=(16, 13)).astype(np.float32)
    acted = model.predict(obs, deterministic=True)[0]
    new = {"action_net.bias": before["action_net.bias"] + 0.25}
    model.write_parameters(new)
    after = model.parameter_arrays()
    assert np.array_equal(after["action_net.bias"], new["action_net.bias"])
    assert all(np.array_equal(after[k], before[k]) for k in before if k != "action_net.bias")
    np.testing.assert_allclose(model.predict(obs, deterministic=True)[0], np.clip(acted + 0.25, -1, 1), atol=1e-5)


def test_jax_keeps_params_optimizer_and_compiled_rollout_in_step_after_a_write():
    """The JAX learner's three copies of the weights: params, Adam's moments (same tree) and numba's export."""
    from sweep.agents.jax_ppo import mlp_forward

    jx = trained()["jax"]
    rng = np.random.default_rng(1)
    written = {k: (v + 0.1 * rng.standard_normal(v.shape)).astype(np.float32) for k, v in jx.parameter_arrays().items()}
    jx.write_parameters(written)
    obs = rng.normal(size=(32, 13)).astype(np.float32)
    mean, _ = mlp_forward(jx.params, jx.networks[0], jnp.asarray(obs), jnp.tanh)
    np.testing.assert_allclose(jx.predict(obs, deterministic=True)[0], np.clip(np.asarray(mean), -1, 1), atol=2e-6)
    for name, (m, v) in jx.optimizer_moments().items():
        assert m.shape == v.shape == written[name].shape
    assert all(np.array_equal(np.asarray(jx.params[k]), written[k]) for k in written)
    assert jx.to_sb3().policy.state_dict()["action_net.weight"].numpy().tolist() == written["action_net.weight"].tolist()
    # and the next update starts from the written weights: same result as a learner built with them
    twin = pair()[1]
    twin.write_parameters(written)
    twin.opt_state = jx.opt_state
    sb3, _ = pair()
    sb3_rollout_into_both(sb3, jx, twin)
    for model in (jx, twin):
        model.set_logger(configure_logger(0, None, "", False))
        np.random.seed(9)
        model.train()
    a, b = jx.parameter_arrays(), twin.parameter_arrays()
    assert all(np.array_equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("name", LEARNERS)
def test_initial_parameters_are_theta_0(name):
    fresh = pair()[LEARNERS.index(name)].parameter_arrays()
    model = trained()[name]
    theta_0 = model.initial_parameters()
    assert all(np.array_equal(theta_0[k], fresh[k]) for k in fresh)
    assert any(not np.array_equal(theta_0[k], model.parameter_arrays()[k]) for k in fresh)


@pytest.mark.parametrize("layer_norm", [False, True])
@pytest.mark.parametrize("name", LEARNERS)
def test_hidden_activations_pre_and_post(name, layer_norm):
    model = pair([f"agent.policy.layer_norm={layer_norm}"])[LEARNERS.index(name)]
    obs = np.random.default_rng(2).normal(size=(64, 13)).astype(np.float32)
    acts = model.hidden_activations(obs)
    assert set(acts) == {"policy", "value"}
    for net in model.networks:
        assert len(acts[net.name]) == 2
        for h in acts[net.name]:
            assert h.pre.shape == h.post.shape == (64, 64)
            np.testing.assert_allclose(h.post, np.tanh(h.pre), atol=1e-6)
            if layer_norm:  # scale 1, shift 0 at init: each row normalised
                np.testing.assert_allclose(h.pre.mean(1), 0, atol=1e-5)
                np.testing.assert_allclose(h.pre.std(1), 1, atol=1e-3)


def test_hidden_activations_agree_between_learners():
    sb3, jx = pair(["agent.policy.layer_norm=true"])
    obs = np.random.default_rng(3).normal(size=(64, 13)).astype(np.float32)
    a, b = sb3.hidden_activations(obs), jx.hidden_activations(obs)
    for net in ("policy", "value"):
        for ha, hb in zip(a[net], b[net]):
            np.testing.assert_allclose(hb.pre, ha.pre, atol=2e-5)
            np.testing.assert_allclose(hb.post, ha.post, atol=2e-5)


@pytest.mark.parametrize("name", LEARNERS)
def test_reset_optimizer_zeroes_exactly_the_masked_moments_and_keeps_the_step(name):
    model = trained()[name]
    before = model.optimizer_moments()
    w = "mlp_extractor.policy_net.2.weight"
    assert np.abs(before[w][0]).sum() > 0 and np.abs(before[w][1]).sum() > 0
    mask = np.zeros(before[w][0].shape, bool)
    mask[[1, 5], :] = True
    mask[:, 7] = True
    step = _adam_step(model)
    model.reset_optimizer({w: mask})
    after = model.optimizer_moments()
    for k in before:
        for b, a in zip(before[k], after[k]):
            if k == w:
                assert np.all(a[mask] == 0) and np.array_equal(a[~mask], b[~mask])
            else:
                assert np.array_equal(a, b), k
    assert _adam_step(model) == step > 0


def _adam_step(model) -> int:
    state = model.learner_state()
    if "opt_state" in state:
        import optax
        return int(next(s for s in model.opt_state if isinstance(s, optax.ScaleByAdamState)).count)
    return int(next(iter(state["optimizer"]["state"].values()))["step"])


@pytest.mark.parametrize("name", LEARNERS)
def test_remedy_generator_is_the_learners_own_and_checkpointed(name):
    model = trained()[name]
    global_state = np.random.get_state()[1].copy()
    state = model.learner_state()
    first = model.rng.standard_normal(4)
    model.load_learner_state(state)
    assert np.array_equal(model.rng.standard_normal(4), first)
    assert np.array_equal(np.random.get_state()[1], global_state)  # the global RNG was not touched
    other = pair(seed=1)[LEARNERS.index(name)]
    assert not np.array_equal(other.rng.standard_normal(4), pair()[LEARNERS.index(name)].rng.standard_normal(4))


def test_a_checkpoint_written_before_the_fused_adam_resumes_with_it():
    """torch's load_state_dict would take a checkpoint's ``fused: None`` (the loop Adam, MKL's square root); the
    learner keeps the kernel it was built with (networks.adam_kwargs), and the moments load as saved."""
    model = trained()["sb3"]
    state = model.learner_state()
    for group in state["optimizer"]["param_groups"]:
        group["fused"] = None
    model.load_learner_state(state)
    assert all(group["fused"] is True for group in model.policy.optimizer.param_groups)
    saved = state["optimizer"]["state"]
    assert all(torch.equal(model.policy.optimizer.state_dict()["state"][i]["exp_avg_sq"], saved[i]["exp_avg_sq"])
               for i in saved)


def test_fresh_parameters_draw_sb3s_init_distribution():
    """Orthogonal rows with the layer's gain, zero biases: the distribution SB3's ortho_init draws from."""
    sb3 = pair()[0]
    shapes = {k: v.shape for k, v in sb3.parameter_arrays().items()}
    fresh = fresh_parameters(shapes, sb3.networks, np.random.default_rng(0))
    for k, v in fresh.items():
        assert v.shape == shapes[k] and v.dtype == np.float32
    w = fresh["mlp_extractor.policy_net.2.weight"]
    np.testing.assert_allclose(w @ w.T, 2.0 * np.eye(64), atol=1e-5)  # gain sqrt(2)
    head = fresh["action_net.weight"]  # 4 x 64: orthonormal rows x 0.01
    np.testing.assert_allclose(head @ head.T, 1e-4 * np.eye(4), atol=1e-9)
    assert not fresh["value_net.bias"].any() and not fresh["log_std"].any()
    first = orthogonal((64, 13), 1.0, np.random.default_rng(5))
    np.testing.assert_allclose(first.T @ first, np.eye(13), atol=1e-5)  # tall: orthonormal columns


def test_remedies_and_diagnostics_use_only_the_contract():
    """No isinstance on a learner, no ``.policy`` (SB3's torch policy), no private SB3 fields."""
    sources = [*(ROOT / "src/sweep/plasticity").glob("*.py"), ROOT / "src/sweep/monitor.py"]
    forbidden = re.compile(r"isinstance\([^)]*model|\.policy\b|\bmodel\._|\.opt_state|\._n_updates|optimizer\.state")
    for path in sources:
        for number, line in enumerate(Path(path).read_text().splitlines(), 1):
            assert not forbidden.search(line), f"{path.name}:{number}: {line.strip()}"


# What only the learner modules (sweep/agents/sb3.py, jax_ppo.py, onpolicy.py) may touch: SB3's loop fields and
# the logger's values. Hooks read records and the Learner contract; the logger is written to, never read.
LOOP_FIELDS = re.compile(r"\.(name_to_value|name_to_count|ep_info_buffer|ep_success_buffer|rollout_buffer|lr_schedule"
                         r"|_last_obs|_last_episode_starts)\b")   # attributes, outside string literals (a message may name
                                                                   # the config key agent.ppo.lr_schedule)
HOOK_SOURCES = [*sorted((ROOT / "src/sweep/plasticity").glob("*.py")), *sorted((ROOT / "src/sweep/training").glob("*.py")),
                *(ROOT / "src/sweep" / f for f in ("best_policy.py", "monitor.py", "checkpoint.py", "evaluate.py", "run.py"))]


def loop_field_reads(text: str) -> list[str]:
    """The lines of ``text`` that name one of SB3's loop fields or the logger's values."""
    return [f"{n}: {line.strip()}" for n, line in enumerate(text.splitlines(), 1)
            if LOOP_FIELDS.search(re.sub(r"([\"']).*?\1", "", line))]


def test_hooks_read_records_not_the_logger_or_sb3_fields():
    assert len(HOOK_SOURCES) >= 17
    found = {path.name: loop_field_reads(path.read_text()) for path in HOOK_SOURCES}
    assert not any(found.values()), {k: v for k, v in found.items() if v}
    # the check fails on a planted read (the couplings issue 31 removed)
    planted = (ROOT / "src/sweep/best_policy.py").read_text().replace(
        "latest = self.evaluation.latest", "latest = learner.logger.name_to_value.get('eval/return')")
    assert [line.split(": ", 1)[1] for line in loop_field_reads(planted)] == [
        "latest = learner.logger.name_to_value.get('eval/return')"]
    assert loop_field_reads("episodes = self.model.ep_info_buffer") and loop_field_reads("model.lr_schedule = s")
