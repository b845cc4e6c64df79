"""The compiled SAC and TD3 updates (sweep.agents.jax_offpolicy) against SB3 2.9's own ``SAC.train`` / ``TD3.train``.

SB3 runs unchanged: its replay buffer's ``sample`` is wrapped (on the instance) to record the batches it returns, and
torch's global generator state is saved before ``train()``; afterwards the same state replays the normal draws SB3 made
(SAC: ``Normal.rsample`` = ``empty(B, A).normal_()`` for s, then for s'; TD3: ``normal_(0, sigma)`` on a (B, A) tensor,
= sigma x the standard draw, bit for bit, at B*A >= 16). The generator must end where SB3 left it, which proves no
draw was missed or added. The JAX update gets those batches and draws, from the same parameters (the targets moved away
from their online networks first, so that tau shows from the first step); two successive calls line the counters up.

Tolerances. In float64 (``test_float64_equality_is_exact``: SB3 and JAX both in double, SAC with the log_std clamp
acting) everything agrees to 3e-12 absolute, 2e-10 relative (bounds 1e-9): the semantics are the same, to the
operation. In float32 the order of operations differs (XLA vs torch: matmul sums, XLA's tanh within 4.5 ulp, torch's
within 0.5) and SAC amplifies it: SB3's squash correction log(1 - a^2 + 1e-6) takes 1 - a^2 from the rounded
a = tanh(u), so one ulp of a (6e-8) at a = 0.9967 is 3.6e-5 of log-prob (measured at the first step; the actor gradient
then differs by ~7e-6 relative). Adam then turns a component's relative gradient error into an absolute step error
of about lr x that error, however small the gradient. Measured after 2 x 3 SAC / 2 x 5 TD3 steps at lr 1e-3 (``pytest
-s`` prints them): parameters within 2.4e-6 absolute (TD3 tanh critic; 6.4e-7 SAC), Adam moments within 2.1e-5 (first)
and 3.9e-5 (second) of each tensor's largest entry, logged values within 8.4e-6 relative. Bounds: parameters rtol 1e-5
+ atol 5e-6, moments 2e-4 of the tensor's largest entry, logged values 5e-5 relative. A semantic error moves things by
far more (``test_a_wrong_tau_or_counter_fails_the_comparison``; tried by hand, each failed the tests: no squash
correction, tau x 1.1 in the Polyak update, squash epsilon 1e-5, no 0.5 in SAC's critic loss, no entropy term in SAC's
target, alpha read after its own step, TD3's counter without SB3's pre-increment, Q_1 instead of Q_0 in TD3's actor
loss, no clip of the smoothing noise, a decay of half the rate, and LOG_STD_MAX 2.2 (caught by the float64 test)).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.logger import Logger

from sweep.agents import jax_offpolicy as jo

torch.set_num_threads(1)

OBS, ACT = 13, 4      # the hover task's observation and action sizes
B = 64
TOL = {"rtol": 1e-5, "atol": 5e-6, "moment": 2e-4, "logged": 5e-5}   # float32; see the module docstring
TOL64 = {"rtol": 1e-9, "atol": 1e-11, "moment": 1e-9, "logged": 1e-9}


class Spaces(gym.Env):
    """Only the spaces: the replay buffer is filled directly."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (ACT,), np.float32)

    def reset(self, seed=None, options=None):
        return np.zeros(OBS, np.float32), {}

    def step(self, action):
        return np.zeros(OBS, np.float32), 0.0, False, False, {}


def sb3_model(cls, seed=0, net_arch=(32, 32), policy="MlpPolicy", **kwargs):
    """An SB3 model whose buffer holds 300 random transitions (terminations, some of them time-outs), with its target
    networks moved away from the online ones."""
    kwargs.setdefault("policy_kwargs", {"net_arch": list(net_arch)})
    model = cls(policy, Spaces(), learning_rate=1e-3, buffer_size=1000, batch_size=B, seed=seed, device="cpu",
                **kwargs)
    model.set_logger(Logger(folder=None, output_formats=[]))
    rng = np.random.default_rng(seed)
    for _ in range(300):
        done = rng.random() < 0.3
        model.replay_buffer.add(rng.standard_normal((1, OBS)).astype(np.float32),
                                rng.standard_normal((1, OBS)).astype(np.float32),
                                rng.uniform(-1, 1, (1, ACT)).astype(np.float32),
                                rng.standard_normal(1).astype(np.float32),
                                np.array([done]), [{"TimeLimit.truncated": bool(done and rng.random() < 0.3)}])
    with torch.no_grad():
        for name, p in model.policy.named_parameters():
            if "_target." in name:
                p.add_(0.05 * torch.randn(p.shape, generator=torch.Generator().manual_seed(len(name))))
    return model


def sb3_train(model, steps: int, draws_per_step: int):
    """SB3's ``train(steps, B)``; returns (batches (G, B, .), standard normal draws (G, draws, B, A), logged values)."""
    recorded = []
    sample = model.replay_buffer.sample

    def recording(*args, **kwargs):
        out = sample(*args, **kwargs)
        recorded.append(out)
        return out

    model.replay_buffer.sample = recording
    model.logger.name_to_value.clear()
    before = torch.get_rng_state()
    try:
        model.train(gradient_steps=steps, batch_size=B)
    finally:
        del model.replay_buffer.sample
    after = torch.get_rng_state()
    torch.set_rng_state(before)
    dtype = next(model.policy.parameters()).dtype
    draws = np.stack([np.stack([torch.empty(B, ACT, dtype=dtype).normal_().numpy() for _ in range(draws_per_step)])
                      for _ in range(steps)])
    assert torch.equal(torch.get_rng_state(), after), "SB3 drew other random numbers than those replayed"
    assert all(r.discounts is None for r in recorded)
    batches = {key: np.stack([getattr(r, key).numpy() for r in recorded])
               for key in ("observations", "actions", "next_observations", "dones", "rewards")}
    assert batches["observations"].dtype == draws.dtype == model.replay_buffer.observations.dtype
    return batches, draws, dict(model.logger.name_to_value)


def torch_state(model) -> tuple[dict[str, np.ndarray], dict[str, dict[str, np.ndarray]]]:
    """(parameters, per optimizer {name: (step, exp_avg, exp_avg_sq)}) of an SB3 model, by our names."""
    params = {k: v.detach().numpy().copy() for k, v in model.policy.state_dict().items()}
    if getattr(model, "ent_coef_optimizer", None) is not None:
        params["log_ent_coef"] = model.log_ent_coef.detach().numpy().copy()
    moments = {}
    for name, (optimizer, named) in jo.torch_optimizers(model).items():
        moments[name] = {k: (float(optimizer.state[p]["step"]), optimizer.state[p]["exp_avg"].numpy().copy(),
                             optimizer.state[p]["exp_avg_sq"].numpy().copy()) for k, p in named.items()}
    return params, moments


def jax_state(params, opt_states):
    moments = {}
    for name, state in opt_states.items():
        adam = jo.adam_state(state)
        moments[name] = {k: (float(adam.count), np.asarray(adam.mu[k]), np.asarray(adam.nu[k])) for k in adam.mu}
    return {k: np.asarray(v) for k, v in params.items()}, moments


MEASURED: dict[str, float] = {}


def assert_same(sb3, jax_, label=""):
    """Every parameter (rtol, atol), every optimizer's step count, and Adam's moments (each tensor within
    TOL["moment"] x its largest entry: a moment of a near-zero gradient has no relative precision); records the
    largest differences in MEASURED."""
    (p_ref, m_ref), (p, m) = sb3, jax_
    assert p_ref.keys() == p.keys() and m_ref.keys() == m.keys()
    for k in p_ref:
        assert p[k].dtype == p_ref[k].dtype, k
        np.testing.assert_allclose(p[k], p_ref[k], rtol=TOL["rtol"], atol=TOL["atol"], err_msg=f"{label} {k}")
        _measure("param_abs", np.abs(p[k] - p_ref[k]).max())
    for name in m_ref:
        assert m_ref[name].keys() == m[name].keys(), name
        for k, (step_ref, *ref) in m_ref[name].items():
            step, *ours = m[name][k]
            assert step == step_ref, f"{label} {name} {k}: {step} Adam steps, SB3 {step_ref}"
            for moment, a, b in zip(("exp_avg", "exp_avg_sq"), ours, ref):
                scale = np.abs(b).max()
                _measure(moment, np.abs(a - b).max() / scale if scale else np.abs(a).max())
                assert np.abs(a - b).max() <= TOL["moment"] * scale, (label, name, k, moment, np.abs(a - b).max())


@pytest.fixture(scope="module", autouse=True)
def report_measured():
    """The largest differences seen (``pytest -s`` prints them)."""
    yield
    print("\njax_offpolicy vs SB3, largest differences:", {k: f"{v:.1e}" for k, v in sorted(MEASURED.items())})


def _measure(what, value):
    MEASURED[what] = max(MEASURED.get(what, 0.0), float(value))


def assert_logs(ref: dict, ours: dict, label=""):
    assert set(ref) == set(ours), (label, sorted(ref), sorted(ours))
    for key in ref:
        _measure("logged_rel", abs(ours[key] - ref[key]) / max(abs(ref[key]), 1e-30))
        np.testing.assert_allclose(ours[key], ref[key], rtol=TOL["logged"], atol=0, err_msg=f"{label} {key}")


def run_both(kind, model, calls, steps, update, tx=None, lr_per_optimizer=False, **jax_settings):
    """``calls`` x SB3 ``train(steps)`` and the compiled update on the same data; checked after every call."""
    sac = kind == "sac"
    params = jo.initial_params(model, next(model.policy.parameters()).detach().numpy().dtype)
    tx = tx or {name: jo.adam() for name in jo.optimizer_names(params)}
    opt_states = jo.init_opt_states(tx, params)
    fn = jo.compiled(update, tx=tx, **jax_settings)
    lr = float(model.lr_schedule(1.0))
    n_updates = 0
    for call in range(calls):
        batches, draws, logged = sb3_train(model, steps, 2 if sac else 1)
        noise = {"pi": draws[:, 0], "next": draws[:, 1]} if sac else draws[:, 0]
        lrs = {name: lr for name in tx} if lr_per_optimizer else lr
        params, opt_states, stats = fn(params, opt_states, batches, noise, lrs, n_updates)
        assert_same(torch_state(model), jax_state(params, opt_states), f"call {call}")
        assert_logs(logged, jo.sb3_logs(stats, n_updates, lr), f"call {call}")
        n_updates += steps
        assert model._n_updates == n_updates
    return params, opt_states, stats


# ---- equality with SB3 -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("ent_coef", ["auto", 0.2])
def test_sac_update_equals_sb3(ent_coef, tmp_path):
    """2 calls x 3 steps, target_update_interval 2: SB3 updates the targets at gradient_step 0 and 2 of EVERY call
    (its index restarts per call), i.e. at steps 0, 2, 3, 5 overall, not 0, 2, 4."""
    model = sb3_model(SAC, ent_coef=ent_coef, tau=0.05, target_update_interval=2)
    settings = dict(tau=0.05, target_update_interval=2, gamma=0.99, ent_coef=None if ent_coef == "auto" else ent_coef)
    params, opt_states, stats = run_both("sac", model, 2, 3, jo.sac_update, **settings)
    assert np.asarray(stats["target_updated"]).tolist() == [True, False, True]
    assert ("ent_coef" in opt_states) == (ent_coef == "auto")
    # the inverse: the JAX state written into a fresh SB3 model reads back as SB3's trained one
    fresh = sb3_model(SAC, ent_coef=ent_coef, tau=0.05, seed=1)
    jo.load_into(fresh, params, opt_states)
    assert_same(torch_state(model), torch_state(fresh), "load_into")
    fresh.save(tmp_path / "sac.zip")  # and as an SB3 zip
    loaded = SAC.load(tmp_path / "sac.zip", device="cpu")
    assert_same(torch_state(model), torch_state(loaded), "SAC.load")


@pytest.mark.parametrize("activation", ["relu", "tanh"])
def test_td3_update_equals_sb3(activation):
    """2 calls x 5 steps, policy_delay 2: SB3's counter is incremented before the check, so the actor steps at counters
    2, 4 | 6, 8, 10 (the second call starts on an actor step only if n_updates carries over)."""
    model = sb3_model(TD3, tau=0.05, policy_delay=2, target_policy_noise=0.2, target_noise_clip=0.5,
                      policy_kwargs={"net_arch": [32, 32], "activation_fn": {"relu": torch.nn.ReLU,
                                                                             "tanh": torch.nn.Tanh}[activation]})
    settings = dict(tau=0.05, policy_delay=2, target_policy_noise=0.2, target_noise_clip=0.5, gamma=0.99,
                    activation=activation)
    _, _, stats = run_both("td3", model, 2, 5, jo.td3_update, **settings)
    assert np.asarray(stats["actor_updated"]).tolist() == [True, False, True, False, True]


@pytest.mark.parametrize("algorithm", ["sac", "td3"])
def test_an_asymmetric_actor_critic_update_equals_sb3(algorithm):
    """The actor reads the leading columns of the observation, the critics all of them (env.observe.critic_*): SB3's
    Asymmetric*Policy and the compiled update, which reads the columns a network's first layer takes."""
    from sweep.agents.sb3_offpolicy import AsymmetricSACPolicy, AsymmetricTD3Policy
    cls, policy = (SAC, AsymmetricSACPolicy) if algorithm == "sac" else (TD3, AsymmetricTD3Policy)
    model = sb3_model(cls, tau=0.05, policy=policy, policy_kwargs={"net_arch": [32, 32], "actor_columns": OBS - 3})
    first = model.actor.latent_pi[0] if algorithm == "sac" else model.actor.mu[0]
    assert first.in_features == OBS - 3
    assert model.critic.qf0[0].in_features == OBS + ACT
    update = jo.sac_update if algorithm == "sac" else jo.td3_update
    settings = dict(tau=0.05, gamma=0.99, target_update_interval=1, ent_coef=None) if algorithm == "sac" else \
        dict(tau=0.05, gamma=0.99, policy_delay=2, target_policy_noise=0.2, target_noise_clip=0.5)
    run_both(algorithm, model, 2, 4, update, **settings)


def float64_check() -> dict[str, float]:
    """SAC (learned ent_coef) and TD3 against SB3, both in float64; run by ``test_float64_equality_is_exact`` in a
    process with JAX_ENABLE_X64=1. SB3 casts Box observations to float32 (``preprocess_obs``: ``obs.float()``): that
    cast alone is replaced, by the identity; the replay buffer holds float64 and the draws are float64."""
    import stable_baselines3.common.policies as policies

    assert jax.config.jax_enable_x64
    policies.preprocess_obs = lambda obs, space, normalize_images=True: obs
    TOL.update(TOL64)
    for cls, update, steps, kw in ((SAC, jo.sac_update, 3, {"target_update_interval": 2}),
                                   (TD3, jo.td3_update, 5, {"policy_delay": 2})):
        model = sb3_model(cls, tau=0.05, **kw)
        if cls is SAC:  # log_std of action 0 above LOG_STD_MAX: the clamp acts (in float32, tanh(u) would saturate
            with torch.no_grad():  # to 1 - a few ulp, where XLA's and torch's tanh differ by 100% in 1 - a^2)
                model.actor.log_std.bias[0] += 2.5
        model.policy.double()  # the same Parameter objects (the optimizers keep them), now float64
        if getattr(model, "log_ent_coef", None) is not None:
            model.log_ent_coef.data = model.log_ent_coef.data.double()
        for key in ("observations", "next_observations", "actions", "rewards", "dones"):
            setattr(model.replay_buffer, key, getattr(model.replay_buffer, key).astype(np.float64))
        params, _, _ = run_both("sac" if cls is SAC else "td3", model, 2, steps, update, tau=0.05, **kw)
        assert all(v.dtype == jnp.float64 for v in params.values())
    return MEASURED


def test_float64_equality_is_exact():
    """In float64 the compiled updates equal SB3's to ~1e-15: what float32 leaves is rounding (module docstring)."""
    code = (f"import sweep, sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import test_jax_offpolicy as t; "
            "print('MEASURED', t.float64_check())")
    run = subprocess.run([sys.executable, "-c", code], env={**os.environ, "JAX_ENABLE_X64": "1"}, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-4000:]
    print(run.stdout.strip().splitlines()[-1])


def test_post_transform_equals_sb3_step_hooks():
    """A clip of every weight after each optimizer step, as a torch step post-hook on each of SB3's optimizers."""
    bound = 0.12

    def clip(params, xp):
        return {k: xp.clip(params[k], -bound, bound) for k in params if k.endswith(".weight")}

    model = sb3_model(SAC, tau=0.05)
    for name, (optimizer, named) in jo.torch_optimizers(model).items():
        def hook(opt, args, kwargs, named=named):
            with torch.no_grad():
                for k, v in clip(named, torch).items():
                    named[k].copy_(v)
        optimizer.register_step_post_hook(hook)
    params0 = jo.initial_params(model)
    assert max(float(jnp.abs(v).max()) for k, v in params0.items() if k.startswith("actor.")) > bound  # it binds
    params, _, _ = run_both("sac", model, 1, 3, jo.sac_update, tau=0.05, post=(clip,))
    for k, v in params.items():
        if k.endswith(".weight") and not k.startswith("critic_target."):
            assert float(jnp.abs(v).max()) <= bound, k


def test_decoupled_decay_equals_torch_adamw():
    """``decay`` (all actor and critic parameters by default) = SB3 with ``optimizer_class=AdamW``; one lr each."""
    model = sb3_model(TD3, tau=0.05, policy_kwargs={"net_arch": [32, 32], "optimizer_class": torch.optim.AdamW,
                                                    "optimizer_kwargs": {"weight_decay": 0.5}})
    run_both("td3", model, 1, 4, jo.td3_update, tau=0.05, decay=0.5, lr_per_optimizer=True)


def test_a_wrong_tau_or_counter_fails_the_comparison():
    """The comparison can fail: tau x 2, or SAC's target index counted across calls, break it."""
    seen = dict(MEASURED)
    model = sb3_model(TD3, tau=0.05)
    with pytest.raises(AssertionError):
        run_both("td3", model, 1, 4, jo.td3_update, tau=0.1)
    model = sb3_model(SAC, tau=0.05, target_update_interval=2)
    with pytest.raises(AssertionError):
        run_both("sac", model, 2, 3, jo.sac_update, tau=0.05, target_update_interval=2, targets_per_call=False)
    MEASURED.clear()
    MEASURED.update(seen)


# ---- LayerNorm, logs ------------------------------------------------------------------------------------------------
def test_layer_norm_networks():
    """Linear -> LayerNorm -> activation under the names of a torch Sequential with the LayerNorms inserted; the
    forward equals that Sequential's; SAC and TD3 updates train such networks without NaN."""
    rng = np.random.default_rng(0)
    obs = jnp.asarray(rng.standard_normal((B, OBS)), jnp.float32)
    actions = jnp.asarray(rng.uniform(-1, 1, (B, ACT)), jnp.float32)
    for cls, update, kind in ((SAC, jo.sac_update, "sac"), (TD3, jo.td3_update, "td3")):
        model = sb3_model(cls, net_arch=(16, 16, 16))
        plain = jo.initial_params(model)
        params = jo.insert_layer_norm(plain)
        assert jo.sequential(params, "critic.qf1") == (
            ("critic.qf1.0", "critic.qf1.1"), ("critic.qf1.3", "critic.qf1.4"), ("critic.qf1.6", "critic.qf1.7"),
            ("critic.qf1.9", None))
        assert np.array_equal(params["critic.qf1.9.weight"], plain["critic.qf1.6.weight"])
        state = {k[len("critic.qf1."):]: torch.as_tensor(np.array(v)) for k, v in params.items()
                 if k.startswith("critic.qf1.")}
        torch_q = torch.nn.Sequential(*[m for i in (0, 3, 6) for m in (
            torch.nn.Linear(*state[f"{i}.weight"].shape[::-1]), torch.nn.LayerNorm(16, eps=1e-5), torch.nn.ReLU())],
            torch.nn.Linear(16, 1))
        torch_q.load_state_dict({**state, "1.weight": torch.full((16,), 1.5), "4.bias": torch.full((16,), 0.1)})
        params = {**params, "critic.qf1.1.weight": jnp.full(16, 1.5), "critic.qf1.4.bias": jnp.full(16, 0.1)}
        q = jo.critic(params, obs, actions, jax.nn.relu)
        assert len(q) == 2 and q[1].shape == (B, 1)
        ref = torch_q(torch.cat([torch.as_tensor(np.array(obs)), torch.as_tensor(np.array(actions))], 1)).detach()
        np.testing.assert_allclose(np.asarray(q[1]), ref.numpy(), rtol=1e-5, atol=1e-6)
        if kind == "sac":
            a, lp = jo.sac_action_log_prob(params, obs, jnp.zeros((B, ACT)), jax.nn.relu)
            assert "actor.latent_pi.7.weight" in params and "actor.latent_pi.9.weight" not in params  # no head
        else:
            a = jo.td3_actor(params, obs, jax.nn.relu)
        assert a.shape == (B, ACT) and bool(jnp.all(jnp.abs(a) <= 1))

        tx = {name: jo.adam() for name in jo.optimizer_names(params)}
        G = 4
        batches = {"observations": rng.standard_normal((G, B, OBS)),
                   "next_observations": rng.standard_normal((G, B, OBS)),
                   "actions": rng.uniform(-1, 1, (G, B, ACT)), "rewards": rng.standard_normal((G, B)),
                   "dones": (rng.random((G, B)) < 0.1).astype(np.float32)}
        batches = {k: np.asarray(v, np.float32) for k, v in batches.items()}
        z = rng.standard_normal((2, G, B, ACT)).astype(np.float32)
        noise = {"pi": z[0], "next": z[1]} if kind == "sac" else z[0]
        new, _, stats = jo.compiled(update, tx=tx, tau=0.05)(params, jo.init_opt_states(tx, params), batches, noise,
                                                              1e-3, 0)
        assert all(bool(jnp.all(jnp.isfinite(v))) for v in new.values())
        assert all(np.isfinite(v).all() for v in jax.tree.leaves(stats))
        for norm in ("critic.qf0.1.weight", "critic_target.qf0.1.weight", "actor.latent_pi.1.bias" if kind == "sac"
                     else "actor.mu.1.bias"):
            assert not np.array_equal(new[norm], params[norm]), norm  # LayerNorms train (and targets follow)


def test_sb3_logs_keys():
    stats = {"critic_loss": [1.0, 3.0], "actor_loss": [0.0, 4.0], "actor_updated": [False, True]}
    assert jo.sb3_logs(stats, 6, 1e-3) == {"train/n_updates": 8, "train/learning_rate": 1e-3, "train/actor_loss": 4.0,
                                           "train/critic_loss": 2.0}
    stats = {"critic_loss": [1.0], "actor_loss": [0.0], "actor_updated": [False]}
    assert "train/actor_loss" not in jo.sb3_logs(stats, 0)
