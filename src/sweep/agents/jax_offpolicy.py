"""SB3's SAC and TD3 updates (``MlpPolicy``), compiled: pure JAX functions equal to ``SAC.train`` / ``TD3.train``.

tests/test_jax_offpolicy.py holds them to SB3 2.9 (same start, same replay batches, same normal draws).

Parameters: one flat dict ``params`` whose keys are SB3's policy ``state_dict()`` keys, torch's (out, in) layout:

* SAC: ``actor.latent_pi.{0,2,..}``, ``actor.mu``, ``actor.log_std``, ``critic.qf{j}.{0,2,..}``,
  ``critic_target.qf{j}.*``; with ``ent_coef='auto'`` also ``log_ent_coef`` (shape (1,), SB3's ``model.log_ent_coef``).
* TD3: ``actor.mu.{0,2,..}``, ``actor_target.mu.*``, ``critic.qf{j}.*``, ``critic_target.qf{j}.*``.

Each ``...{i}`` is an index of the torch ``nn.Sequential`` SB3's ``create_mlp`` builds (Linear, activation, ...,
Linear). LayerNorm (Linear -> LayerNorm(eps 1e-5) -> activation, as the project's PPO) is named as the same
Sequential with a ``torch.nn.LayerNorm`` inserted after each hidden Linear would be: hidden Linear k at ``3k``, its
LayerNorm at ``3k+1`` (``.weight`` scale, ``.bias`` shift), the head at ``3n`` (e.g. ``critic.qf0.0``, ``critic.qf0.1``,
``critic.qf0.3``, ``critic.qf0.4``, ``critic.qf0.6``). SAC's ``latent_pi`` has no head: every Linear there gets one.
The layout is read from the keys (2-D ``weight``: Linear; 1-D: LayerNorm), so any depth works with no settings.
``insert_layer_norm`` turns SB3's plain initial weights into that layout.

Optimizers (``tx``, ``opt_states``): dicts keyed by optimizer name, ``"actor"`` (the ``actor.*`` parameters),
``"critic"`` (``critic.*``) and, SAC with a learned entropy coefficient, ``"ent_coef"`` (``log_ent_coef``), as SB3's
``actor.optimizer``, ``critic.optimizer``, ``ent_coef_optimizer``. A ``tx`` gives the step direction without the
learning rate (``adam()``: torch's Adam), as in ``jax_ppo``; theta <- theta - lr * direction. ``lr`` is one value for
every optimizer (SB3 reads one ``lr_schedule`` for all) or a dict by optimizer name.

After each optimizer step, in this order (as ``jax_ppo``): the decoupled decay ``decay`` on the ``mask``-ed parameters
of that optimizer (toward ``anchor`` if given: L2-Init), the step, then each ``post`` transform
(``sweep.agents.learner.StepTransform``): it sees all parameters, only its values for that optimizer's parameters are
kept (a step hook on that optimizer; target networks are never touched).
"""
from __future__ import annotations

from functools import partial
from typing import Any, Callable, Mapping

# first: jax_ppo's XLA flags and one-thread CPU client apply here too
from sweep.agents.jax_ppo import ACTIVATIONS, layer_norm

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402
import torch  # noqa: E402

Params = dict[str, jax.Array]

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0   # stable_baselines3.sac.policies
SQUASH_EPS = 1e-6                       # SquashedDiagGaussianDistribution's epsilon
_HALF_LOG_2PI = float(np.log(np.sqrt(2 * np.pi)))
_HEADLESS = ("latent_pi",)              # Sequentials without an output Linear


# ------------------------------------------------------------------------------------------------
# Networks
# ------------------------------------------------------------------------------------------------
def sequential(params: Mapping[str, Any], prefix: str) -> tuple[tuple[str, str | None], ...]:
    """(Linear, its LayerNorm or None) module names of the torch Sequential ``prefix``, in order (from the keys)."""
    indices = sorted({int(k[len(prefix) + 1:].split(".")[0]) for k in params
                      if k.startswith(prefix + ".") and k[len(prefix) + 1:].split(".")[0].isdigit()})
    modules: list[list] = []
    for i in indices:
        name = f"{prefix}.{i}"
        if np.ndim(params[f"{name}.weight"]) == 2:
            modules.append([name, None])
        else:
            modules[-1][1] = name
    return tuple((lin, norm) for lin, norm in modules)


def linear(params: Params, name: str, x: jax.Array) -> jax.Array:
    """torch.nn.Linear: x W^T + b."""
    return x @ params[f"{name}.weight"].T + params[f"{name}.bias"]


def mlp(params: Params, prefix: str, x: jax.Array, act: Callable, head: bool = True):
    """(output, [(pre, post) per hidden layer]) of SB3's ``create_mlp`` Sequential ``prefix``: Linear [-> LayerNorm]
    -> ``act`` per hidden layer, then (``head``) a Linear without activation. A first layer that takes fewer inputs than
    ``x`` has columns reads the leading ones (an asymmetric actor)."""
    modules = sequential(params, prefix)
    x = x[..., :params[f"{modules[0][0]}.weight"].shape[1]]
    hidden = []
    for k, (lin, norm) in enumerate(modules):
        x = linear(params, lin, x)
        if head and k == len(modules) - 1:
            return x, hidden
        pre = layer_norm(x, params[f"{norm}.weight"], params[f"{norm}.bias"]) if norm else x
        x = act(pre)
        hidden.append((pre, x))
    return x, hidden


def critic(params: Params, obs: jax.Array, actions: jax.Array, act: Callable, prefix: str = "critic",
           ) -> tuple[jax.Array, ...]:
    """SB3's ``ContinuousCritic.forward``: one (B, 1) Q per ``{prefix}.qf{j}``, each on concat(obs, actions)."""
    x = jnp.concatenate([obs, actions], axis=-1)
    n = sum(1 for k in params if k.startswith(f"{prefix}.qf") and k.endswith(".0.weight"))
    return tuple(mlp(params, f"{prefix}.qf{j}", x, act)[0] for j in range(n))


def sac_actor(params: Params, obs: jax.Array, act: Callable, prefix: str = "actor"):
    """SB3 SAC ``Actor.get_action_dist_params``: (mean, log_std clamped to [-20, 2], hidden) (Haarnoja et al. 2018)."""
    latent, hidden = mlp(params, f"{prefix}.latent_pi", obs, act, head=False)
    log_std = jnp.clip(linear(params, f"{prefix}.log_std", latent), LOG_STD_MIN, LOG_STD_MAX)
    return linear(params, f"{prefix}.mu", latent), log_std, hidden


def sac_action_log_prob(params: Params, obs: jax.Array, eps: jax.Array, act: Callable, prefix: str = "actor"):
    """SB3 ``Actor.action_log_prob`` with the standard normal draw ``eps`` (B, A): u = mean + eps * std
    (torch ``Normal.rsample``), a = tanh(u), log pi(a) = sum log N(u) - sum log(1 - a^2 + 1e-6)
    (``SquashedDiagGaussianDistribution.log_prob``, Haarnoja et al. 2018 appendix C). Returns (a, log_prob (B,))."""
    mean, log_std, _ = sac_actor(params, obs, act, prefix)
    std = jnp.exp(log_std)
    gaussian = mean + eps * std
    log_prob = jnp.sum(-((gaussian - mean) ** 2) / (2 * std ** 2) - jnp.log(std) - _HALF_LOG_2PI, axis=-1)
    action = jnp.tanh(gaussian)
    return action, log_prob - jnp.sum(jnp.log(1 - action ** 2 + SQUASH_EPS), axis=-1)


def td3_actor(params: Params, obs: jax.Array, act: Callable, prefix: str = "actor") -> jax.Array:
    """SB3 TD3 ``Actor.forward``: the MLP ``{prefix}.mu`` with a tanh output (Fujimoto et al. 2018)."""
    return jnp.tanh(mlp(params, f"{prefix}.mu", obs, act)[0])


# ------------------------------------------------------------------------------------------------
# Parameters and optimizers <-> SB3
# ------------------------------------------------------------------------------------------------
def optimizer_names(params: Mapping[str, Any]) -> tuple[str, ...]:
    return ("actor", "critic", "ent_coef") if "log_ent_coef" in params else ("actor", "critic")


def trained(params: Mapping[str, Any], name: str) -> tuple[str, ...]:
    """The parameters optimizer ``name`` steps (SB3: ``actor.parameters()``, ``critic.parameters()``, log_ent_coef)."""
    if name == "ent_coef":
        return ("log_ent_coef",)
    return tuple(k for k in params if k.startswith(name + "."))


def adam(eps: float = 1e-8, b1: float = 0.9, b2: float = 0.999) -> optax.GradientTransformation:
    """torch.optim.Adam's direction (its defaults; SB3's off-policy optimizers), without the learning rate."""
    return optax.scale_by_adam(b1=b1, b2=b2, eps=eps)


def init_opt_states(tx: Mapping[str, optax.GradientTransformation], params: Params) -> dict[str, Any]:
    """Each optimizer's initial state over its own parameters."""
    return {name: t.init({k: params[k] for k in trained(params, name)}) for name, t in tx.items()}


def initial_params(model, dtype=np.float32) -> Params:
    """An SB3 ``SAC`` / ``TD3`` model's parameters (its policy's ``state_dict``, and ``log_ent_coef`` when SAC learns
    the entropy coefficient), copied (``jnp.asarray`` of a tensor's numpy view may share its memory on the CPU, and SB3
    updates its tensors in place)."""
    def copy(tensor):
        return jnp.asarray(np.array(tensor.detach().cpu().numpy(), dtype, copy=True))
    params = {k: copy(v) for k, v in model.policy.state_dict().items()}
    if getattr(model, "ent_coef_optimizer", None) is not None:
        params["log_ent_coef"] = copy(model.log_ent_coef)
    return params


def insert_layer_norm(params: Mapping[str, Any]) -> Params:
    """SB3's plain parameters in the LayerNorm layout (module docstring): the Linear weights as they are, a LayerNorm
    of scale 1 and shift 0 after each hidden Linear (SB3 draws only the Linears; LayerNorm draws nothing)."""
    out = {k: jnp.asarray(v) for k, v in params.items()}
    parts = [k.rsplit(".", 2) for k in params]
    prefixes = {p[0] for p in parts if len(p) == 3 and p[1].isdigit()}
    for prefix in prefixes:
        modules = sequential(params, prefix)
        if any(norm for _, norm in modules):
            raise ValueError(f"{prefix} has LayerNorms already")
        head = not prefix.endswith(_HEADLESS)
        for lin, _ in modules:
            del out[f"{lin}.weight"], out[f"{lin}.bias"]
        for k, (lin, _) in enumerate(modules):
            new = f"{prefix}.{3 * k}"
            out[f"{new}.weight"] = jnp.asarray(params[f"{lin}.weight"])
            out[f"{new}.bias"] = jnp.asarray(params[f"{lin}.bias"])
            if not (head and k == len(modules) - 1):
                width = params[f"{lin}.bias"].shape[0]
                dtype = jnp.asarray(params[f"{lin}.bias"]).dtype
                out[f"{prefix}.{3 * k + 1}.weight"] = jnp.ones(width, dtype)
                out[f"{prefix}.{3 * k + 1}.bias"] = jnp.zeros(width, dtype)
    return out


def to_state_dict(params: Mapping[str, Any]) -> dict[str, torch.Tensor]:
    """The policy's ``state_dict`` tensors (``log_ent_coef`` left out: it is not the policy's)."""
    return {k: torch.as_tensor(np.array(v)) for k, v in params.items() if k != "log_ent_coef"}


def adam_state(state) -> optax.ScaleByAdamState:
    """The ``ScaleByAdamState`` inside an optimizer's (chain) state."""
    if isinstance(state, optax.ScaleByAdamState):
        return state
    for part in state if isinstance(state, tuple) else ():
        try:
            return adam_state(part)
        except ValueError:
            pass
    raise ValueError("no Adam state in this optimizer state")


def torch_optimizers(model) -> dict[str, tuple[torch.optim.Optimizer, dict[str, torch.nn.Parameter]]]:
    """SB3's optimizers by name, each with its parameters by our names."""
    out = {}
    for name in ("actor", "critic"):
        module = getattr(model, name)
        out[name] = (module.optimizer, {f"{name}.{n}": p for n, p in module.named_parameters()})
    if getattr(model, "ent_coef_optimizer", None) is not None:
        out["ent_coef"] = (model.ent_coef_optimizer, {"log_ent_coef": model.log_ent_coef})
    return out


@torch.no_grad()
def load_into(model, params: Mapping[str, Any], opt_states: Mapping[str, Any] | None = None) -> None:
    """Write ``params`` (and Adam's moments and step counts from ``opt_states``) into an SB3 ``SAC`` / ``TD3`` of the
    same architecture, e.g. to save a JAX run as an SB3 zip."""
    model.policy.load_state_dict(to_state_dict(params))
    if "log_ent_coef" in params:
        model.log_ent_coef.copy_(torch.as_tensor(np.array(params["log_ent_coef"])))
    for name, (optimizer, named) in torch_optimizers(model).items():
        if opt_states is None or name not in opt_states:
            continue
        state = adam_state(opt_states[name])
        for key, p in named.items():
            optimizer.state[p] = {"step": torch.tensor(float(state.count)),
                                  "exp_avg": torch.as_tensor(np.array(state.mu[key])).to(p.dtype),
                                  "exp_avg_sq": torch.as_tensor(np.array(state.nu[key])).to(p.dtype)}


# ------------------------------------------------------------------------------------------------
# The updates
# ------------------------------------------------------------------------------------------------
def _optimizer_step(name, params, opt_states, grads, lr, *, tx, decay, mask, anchor, post):
    """One step of optimizer ``name`` on its parameters (the keys of ``grads``): decay, step, ``post``."""
    sub = {k: params[k] for k in grads}
    updates, state = tx[name].update(grads, opt_states[name], sub)
    new = {}
    for k, theta in sub.items():
        if decay and (mask[k] if mask is not None else name != "ent_coef"):
            theta = theta * (1.0 - lr * decay) if anchor is None else theta - lr * decay * (theta - anchor[k])
        new[k] = theta - lr * updates[k]
    params = {**params, **new}
    for transform in post:
        params = {**params, **{k: v for k, v in transform(params, jnp).items() if k in sub}}
    return params, {**opt_states, name: state}


def _polyak(params: Params, source: str, target: str, tau: float, on) -> Params:
    """SB3 ``polyak_update``: target <- target * (1 - tau) + tau * source, where ``on``."""
    out = dict(params)
    for k in params:
        if k.startswith(source + "."):
            t = target + k[len(source):]
            out[t] = jnp.where(on, params[t] * (1 - tau) + tau * params[k], params[t])
    return out


def _lrs(lr, names):
    return {n: lr[n] for n in names} if isinstance(lr, Mapping) else {n: lr for n in names}


def _column(batch, key):
    """rewards / dones / discounts as (B, 1), SB3's ReplayBufferSamples shape."""
    return batch[key].reshape(-1, 1)


def sac_update(params: Params, opt_states: Mapping[str, Any], batches: Mapping[str, jax.Array],
               noise: Mapping[str, jax.Array], lr, n_updates=0, *, tx: Mapping[str, optax.GradientTransformation],
               activation: str = "relu", gamma: float = 0.99, tau: float = 0.005, target_update_interval: int = 1,
               ent_coef: float | None = None, target_entropy: float | None = None, decay: float = 0.0,
               mask: Mapping[str, bool] | None = None, anchor: Params | None = None, post: tuple = (),
               targets_per_call: bool = True):
    """G gradient steps of SB3's ``SAC.train`` in one ``lax.scan`` (Haarnoja et al. 2018, with the learned
    temperature of Haarnoja et al. 2018b). Per step, as SB3's loop body:

    1. a_pi, log pi(a_pi|s) from the actor with ``noise["pi"]``;
    2. ``ent_coef=None`` (SB3 'auto'): alpha = exp(log_ent_coef) (before its step, detached),
       loss_alpha = -mean(log_ent_coef * (log pi + target_entropy)), ent_coef optimizer step; else alpha = ent_coef;
    3. target y = r + (1 - done) * gamma * (min_j Q_target_j(s', a') - alpha log pi(a'|s')), a' from the actor with
       ``noise["next"]``; critic loss 0.5 * sum_j MSE(Q_j(s, a), y); critic step;
    4. actor loss mean(alpha log pi(a_pi|s) - min_j Q_j(s, a_pi)) with the critic just stepped; actor step;
    5. Polyak (tau) of critic_target toward critic when the step index % target_update_interval == 0. SB3's index is
       ``gradient_step`` of its ``train()`` loop, which restarts at 0 in every call (``targets_per_call=True``);
       ``targets_per_call=False`` counts from ``n_updates`` instead.

    ``batches``: observations, actions, next_observations (G, B, .), rewards, dones (G, B[, 1]) (SB3's done * (1 -
    timeout)), optional discounts (n-step). ``noise``: {"pi", "next"} standard normal (G, B, A), SB3's draw order.
    ``target_entropy`` defaults to -dim(A). Jit a ``partial`` binding the keywords. Returns (params, opt_states,
    stats): per-step ent_coef, ent_coef_loss (auto only), critic_loss, actor_loss, target_updated (see ``sb3_logs``)."""
    act = ACTIVATIONS[activation]
    auto = ent_coef is None
    if target_entropy is None:
        target_entropy = -float(batches["actions"].shape[-1])
    lrs = _lrs(lr, tx)
    step_kw = dict(tx=tx, decay=decay, mask=mask, anchor=anchor, post=post)

    def step(carry, xs):
        params, opt_states = carry
        batch, eps_pi, eps_next, index = xs
        obs, next_obs = batch["observations"], batch["next_observations"]
        _, log_prob = sac_action_log_prob(params, obs, eps_pi, act)
        log_prob = log_prob.reshape(-1, 1)
        stats = {}
        if auto:
            alpha = jnp.exp(params["log_ent_coef"])
            fixed = jax.lax.stop_gradient(log_prob + target_entropy)
            loss, grads = jax.value_and_grad(lambda p: -(p["log_ent_coef"] * fixed).mean())(
                {"log_ent_coef": params["log_ent_coef"]})
            params, opt_states = _optimizer_step("ent_coef", params, opt_states, grads, lrs["ent_coef"], **step_kw)
            stats["ent_coef_loss"] = loss
        else:
            alpha = jnp.asarray(ent_coef, log_prob.dtype)
        stats["ent_coef"] = alpha.reshape(-1)[0]

        next_actions, next_log_prob = sac_action_log_prob(params, next_obs, eps_next, act)
        next_q = jnp.min(jnp.concatenate(critic(params, next_obs, next_actions, act, "critic_target"), axis=1),
                         axis=1, keepdims=True)
        next_q = next_q - alpha * next_log_prob.reshape(-1, 1)
        discounts = _column(batch, "discounts") if "discounts" in batch else gamma
        target_q = jax.lax.stop_gradient(
            _column(batch, "rewards") + (1 - _column(batch, "dones")) * discounts * next_q)

        def critic_loss(sub):
            qs = critic({**params, **sub}, obs, batch["actions"], act)
            return 0.5 * sum(jnp.mean((q - target_q) ** 2) for q in qs)

        loss, grads = jax.value_and_grad(critic_loss)({k: params[k] for k in trained(params, "critic")})
        params, opt_states = _optimizer_step("critic", params, opt_states, grads, lrs["critic"], **step_kw)
        stats["critic_loss"] = loss

        def actor_loss(sub):
            p = {**params, **sub}
            actions_pi, lp = sac_action_log_prob(p, obs, eps_pi, act)
            min_q = jnp.min(jnp.concatenate(critic(p, obs, actions_pi, act), axis=1), axis=1, keepdims=True)
            return (alpha * lp.reshape(-1, 1) - min_q).mean()

        loss, grads = jax.value_and_grad(actor_loss)({k: params[k] for k in trained(params, "actor")})
        params, opt_states = _optimizer_step("actor", params, opt_states, grads, lrs["actor"], **step_kw)
        stats["actor_loss"] = loss

        counted = index if targets_per_call else n_updates + index
        on = counted % target_update_interval == 0
        params = _polyak(params, "critic", "critic_target", tau, on)
        stats["target_updated"] = on
        return (params, opt_states), stats

    xs = (batches, noise["pi"], noise["next"], jnp.arange(batches["observations"].shape[0]))
    (params, opt_states), stats = jax.lax.scan(step, (params, dict(opt_states)), xs)
    return params, opt_states, stats


def td3_update(params: Params, opt_states: Mapping[str, Any], batches: Mapping[str, jax.Array], noise: jax.Array,
               lr, n_updates=0, *, tx: Mapping[str, optax.GradientTransformation], activation: str = "relu",
               gamma: float = 0.99, tau: float = 0.005, policy_delay: int = 2, target_policy_noise: float = 0.2,
               target_noise_clip: float = 0.5, decay: float = 0.0, mask: Mapping[str, bool] | None = None,
               anchor: Params | None = None, post: tuple = ()):
    """G gradient steps of SB3's ``TD3.train`` in one ``lax.scan`` (Fujimoto et al. 2018). Per step, as SB3:

    1. ``_n_updates += 1`` (before anything: the step's counter is n_updates + index + 1);
    2. a' = clip(actor_target(s') + clip(target_policy_noise * ``noise``, +-target_noise_clip), -1, 1) (target policy
       smoothing); y = r + (1 - done) * gamma * min_j Q_target_j(s', a'); critic loss sum_j MSE(Q_j(s, a), y);
       critic step;
    3. if counter % policy_delay == 0: actor loss -mean Q_0(s, actor(s)) (the first critic only, just stepped);
       actor step; Polyak (tau) of critic_target and actor_target.

    ``batches`` as ``sac_update``; ``noise``: standard normal (G, B, A) (SB3's ``normal_(0, target_policy_noise)``
    on a tensor of B*A >= 16 elements is that draw times the scale, bit for bit). Returns (params, opt_states, stats):
    per-step critic_loss, actor_loss (0 where no actor step), actor_updated."""
    act = ACTIVATIONS[activation]
    lrs = _lrs(lr, tx)
    step_kw = dict(tx=tx, decay=decay, mask=mask, anchor=anchor, post=post)

    def step(carry, xs):
        params, opt_states = carry
        batch, z, index = xs
        counter = n_updates + index + 1
        obs, next_obs = batch["observations"], batch["next_observations"]
        smoothing = jnp.clip(z * target_policy_noise, -target_noise_clip, target_noise_clip)
        next_actions = jnp.clip(td3_actor(params, next_obs, act, "actor_target") + smoothing, -1, 1)
        next_q = jnp.min(jnp.concatenate(critic(params, next_obs, next_actions, act, "critic_target"), axis=1),
                         axis=1, keepdims=True)
        discounts = _column(batch, "discounts") if "discounts" in batch else gamma
        target_q = jax.lax.stop_gradient(
            _column(batch, "rewards") + (1 - _column(batch, "dones")) * discounts * next_q)

        def critic_loss(sub):
            return sum(jnp.mean((q - target_q) ** 2) for q in critic({**params, **sub}, obs, batch["actions"], act))

        c_loss, grads = jax.value_and_grad(critic_loss)({k: params[k] for k in trained(params, "critic")})
        params, opt_states = _optimizer_step("critic", params, opt_states, grads, lrs["critic"], **step_kw)

        def actor_step(params, opt_states):
            def actor_loss(sub):
                p = {**params, **sub}
                return -critic(p, obs, td3_actor(p, obs, act), act)[0].mean()
            a_loss, grads = jax.value_and_grad(actor_loss)({k: params[k] for k in trained(params, "actor")})
            params, opt_states = _optimizer_step("actor", params, opt_states, grads, lrs["actor"], **step_kw)
            params = _polyak(params, "critic", "critic_target", tau, True)
            params = _polyak(params, "actor", "actor_target", tau, True)
            return params, opt_states, a_loss

        def no_actor_step(params, opt_states):
            return params, opt_states, jnp.zeros((), c_loss.dtype)

        on = counter % policy_delay == 0
        params, opt_states, a_loss = jax.lax.cond(on, actor_step, no_actor_step, params, opt_states)
        return (params, opt_states), {"critic_loss": c_loss, "actor_loss": a_loss, "actor_updated": on}

    xs = (batches, noise, jnp.arange(batches["observations"].shape[0]))
    (params, opt_states), stats = jax.lax.scan(step, (params, dict(opt_states)), xs)
    return params, opt_states, stats


def compiled(update: Callable, **settings) -> Callable:
    """``update`` (``sac_update`` / ``td3_update``) jitted with its keyword settings bound (as ``JaxPPO`` does)."""
    return jax.jit(partial(update, **settings))


def sb3_logs(stats: Mapping[str, Any], n_updates: int, learning_rate: float | None = None) -> dict[str, float]:
    """SB3's ``train/*`` record of one ``train()`` call from its per-step ``stats``; ``n_updates``: SB3's
    ``_n_updates`` before the call; ``learning_rate`` (SB3's ``train/learning_rate``) if given. Means over the steps as
    SB3 logs them (TD3's actor loss: over the actor steps, absent if none; SAC's ent_coef_loss only when learned)."""
    stats = {k: np.asarray(v) for k, v in stats.items()}
    steps = len(stats["critic_loss"])
    out: dict[str, float] = {"train/n_updates": int(n_updates) + steps}
    if learning_rate is not None:
        out["train/learning_rate"] = float(learning_rate)
    if "ent_coef" in stats:
        out["train/ent_coef"] = float(np.mean(stats["ent_coef"].astype(np.float64)))
        out["train/actor_loss"] = float(np.mean(stats["actor_loss"].astype(np.float64)))
        if "ent_coef_loss" in stats:
            out["train/ent_coef_loss"] = float(np.mean(stats["ent_coef_loss"].astype(np.float64)))
    elif stats["actor_updated"].any():
        out["train/actor_loss"] = float(np.mean(stats["actor_loss"][stats["actor_updated"]].astype(np.float64)))
    out["train/critic_loss"] = float(np.mean(stats["critic_loss"].astype(np.float64)))
    return out


__all__ = ["LOG_STD_MIN", "LOG_STD_MAX", "SQUASH_EPS", "adam", "adam_state", "compiled", "critic", "init_opt_states",
           "initial_params", "insert_layer_norm", "load_into", "mlp", "optimizer_names", "sac_action_log_prob",
           "sac_actor", "sac_update", "sb3_logs", "sequential", "td3_actor", "td3_update", "to_state_dict", "trained"]
