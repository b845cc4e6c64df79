"""``JaxSAC`` and ``JaxTD3``: SB3's SAC and TD3, compiled. The update runs in JAX (``sweep.agents.jax_offpolicy``), the
collect in numba (``sweep.agents.replay_rollout``); everything else is SB3's (the replay buffer, the logger, the episode
buffer, ``learn()``'s bookkeeping) through the SB3 classes they extend (``SB3SAC``, ``SB3TD3``).

The same algorithm, hyperparameters, networks, initial weights (SB3's draw for the seed) and logged names as the
reference (tests/test_jax_offpolicy.py holds one update to SB3's; tests/test_offpolicy.py the learners to the contract):

* collect (``collect_rollouts``): ``train_freq`` vector steps into SB3's ``ReplayBuffer`` arrays, with SB3's exploration
  (uniform actions before ``learning_starts``, then SAC's squashed sample or TD3's tanh(mu), plus ``action_noise``);
* update (``train``): G = ``gradient_steps`` steps in one jitted call. The replay indices are drawn as SB3's
  ``ReplayBuffer.sample`` draws them (NumPy's global RNG, per step: from the same buffer and RNG state, the same
  transitions; SB3's exploration noise draws from that RNG too, so over a run with ``action_noise_std`` the streams part);
  the Gaussian draws (SAC's reparameterisation, TD3's target smoothing, the exploration) come from the
  learner's own generator (``noise_rng``, checkpointed), as JaxPPO's action noise does.
* the weights live in JAX (``params``: the trained networks and their targets, ``opt_states``: one Adam per optimizer
  name); the collect reads a float32 export of the actor, refreshed after every write; the torch policy of the SB3
  class is a shell, filled only to save an SB3 zip (``save``: ``SAC.load`` / ``TD3.load`` read a JAX run's model).
"""
from __future__ import annotations

from functools import partial
from typing import Any, Mapping

from sweep.agents import jax_offpolicy as core   # first: jax_ppo's XLA flags and one-thread CPU client

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402
from stable_baselines3.common.type_aliases import RolloutReturn  # noqa: E402

from sweep.agents import replay_rollout  # noqa: E402
from sweep.agents.jax_ppo import ACTIVATIONS, toward_anchor  # noqa: E402
from sweep.agents.learner import Hidden  # noqa: E402
from sweep.agents.rollout import Mlp  # noqa: E402
from sweep.agents.sb3_offpolicy import GROUPS, TARGETS, SB3SAC, SB3TD3, target_of  # noqa: E402
from sweep.plasticity.l2 import penalized  # noqa: E402
from sweep.training.records import Samples  # noqa: E402


class Packing:
    """A pytree of arrays <-> one float32 vector and one int32 vector (its float leaves, then its integer leaves, in
    tree order): the compiled update takes and returns the learner's state as these few arrays, since a jitted call
    costs ~3.5 us per array it takes or returns (~85 here: ~0.3 ms a turn, measured)."""

    def __init__(self, tree) -> None:
        leaves, self.treedef = jax.tree_util.tree_flatten(tree)
        self.shapes = [tuple(np.shape(x)) for x in leaves]
        self.ints = [bool(np.issubdtype(np.asarray(x).dtype, np.integer)) for x in leaves]
        self.offsets, offset = [], 0
        for shape, is_int in zip(self.shapes, self.ints):
            self.offsets.append(offset)
            offset += 0 if is_int else int(np.prod(shape, dtype=np.int64))

    def pack(self, tree, xp=jnp):
        leaves = jax.tree_util.tree_leaves(tree)
        floats = [xp.ravel(x).astype(xp.float32) for x, i in zip(leaves, self.ints) if not i]
        ints = [xp.reshape(x, (-1,)).astype(xp.int32) for x, i in zip(leaves, self.ints) if i]
        return (xp.concatenate(floats) if floats else xp.zeros(0, xp.float32),
                xp.concatenate(ints) if ints else xp.zeros(0, xp.int32))

    def unpack(self, floats, ints):
        """The tree from the two vectors (inside a jitted function: static slices; on the host: NumPy views)."""
        leaves, k = [], 0
        for shape, is_int, offset in zip(self.shapes, self.ints, self.offsets):
            if is_int:
                leaves.append(ints[k].reshape(shape))
                k += 1
            else:
                leaves.append(floats[offset:offset + int(np.prod(shape, dtype=np.int64))].reshape(shape))
        return jax.tree_util.tree_unflatten(self.treedef, leaves)


class _JaxOffPolicy:
    """The compiled learner over an SB3 SAC/TD3 (mixed in before ``SB3SAC`` / ``SB3TD3``: see the module docstring).

    Its state lives packed (``Packing``): the parameters (networks, targets, ``log_ent_coef``) as one float vector, the
    optimizers' states as a float and an int vector; ``params`` and ``opt_states`` are their views as SB3-named dicts
    (set either to write)."""

    _params_view = None
    _opt_view = None

    @property
    def params(self) -> dict[str, jax.Array]:
        if self._params_view is None:
            self._params_view = self._param_packing.unpack(self._fp, self._ip)
        return dict(self._params_view)

    @params.setter
    def params(self, value) -> None:
        value = {k: jnp.asarray(v) for k, v in value.items()}
        if getattr(self, "_param_packing", None) is None:
            self._param_packing = Packing(value)
        self._fp, self._ip = self._param_packing.pack(value)
        self._params_view = value

    @property
    def opt_states(self) -> dict[str, Any]:
        if self._opt_view is None:
            self._opt_view = self._opt_packing.unpack(self._fo, self._io)
        return dict(self._opt_view)

    @opt_states.setter
    def opt_states(self, value) -> None:
        self._opt_packing = Packing(value)
        self._fo, self._io = self._opt_packing.pack(value)
        self._opt_view = value

    def _contract_setup(self, seed: int, n_hidden: int, layer_norm: bool, round_steps: int) -> None:
        """The SB3 class's set-up (networks named, theta_0), then the JAX state: the parameters SB3 drew for the seed
        (torch's LayerNorm layout is the JAX one: Linear 3k, LayerNorm 3k+1) and the optimizers."""
        self.layer_norm_on, self.noise_rng = bool(layer_norm), np.random.default_rng([int(seed), 0xC011EC7])
        self.l2_spec: dict[str, Any] | None = None
        self.params = core.initial_params(self)
        super()._contract_setup(seed, n_hidden, layer_norm, round_steps)
        self._act = ACTIVATIONS[self._activation_name()]
        self._build_optimizer()

    def _activation_name(self) -> str:
        return "relu" if self.policy.activation_fn.__name__ == "ReLU" else "tanh"

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_fp", "_ip", "_fo", "_io", "_param_packing", "_opt_packing",
                "_params_view", "_opt_view", "_tx", "_update", "_actor", "noise_rng", "_act", "_activations",
                "_grad_norm", "_decay", "l2_spec"]

    # ---- optimizers and the compiled update -------------------------------------------------------------
    def _build_optimizer(self, carry: bool = False) -> None:
        """One Adam per optimizer name (torch's betas, ``adam_eps``), with L2 if ``use_l2`` set it: coupled in the
        chain (torch Adam's ``weight_decay``), decoupled as the update's ``decay`` (AdamW). ``carry``: Adam's moments
        and step counts carry over into the new chain."""
        eps = float(self.policy.optimizer_kwargs.get("eps", 1e-8))
        l2 = self.l2_spec or {"coef": 0.0, "mode": "coupled", "params": (), "biases": True, "anchor": "zero"}
        mask = {k: bool(l2["coef"]) and not k.startswith(TARGETS) and k != "log_ent_coef"
                and penalized(k, list(l2["params"]), l2["biases"], GROUPS) for k in self.params}
        self.l2_decayed = sorted(k for k, on in mask.items() if on)
        anchor = ({k: jnp.asarray(v) for k, v in self._initial.items()}
                  if l2["anchor"] == "init" and l2["coef"] else None)
        coupled = l2["coef"] if l2["mode"] == "coupled" else 0.0
        tx = {}
        for name in core.optimizer_names(self.params):
            sub = {k: mask[k] for k in core.trained(self.params, name)}
            parts = []
            if coupled and any(sub.values()):
                parts.append(optax.add_decayed_weights(coupled, mask=sub) if anchor is None
                             else toward_anchor(coupled, sub, anchor))
            parts.append(core.adam(1e-8 if name == "ent_coef" else eps))   # SB3 builds the ent_coef Adam with torch's eps
            tx[name] = optax.chain(*parts)
        old = getattr(self, "opt_states", None)
        self._tx, self.opt_states = tx, core.init_opt_states(tx, self.params)
        if carry and old is not None:
            self.opt_states = {k: _with_adam(s, core.adam_state(old[k])) for k, s in self.opt_states.items()}
        self._decay = {"decay": l2["coef"] if l2["mode"] == "decoupled" else 0.0, "mask": mask,
                       "anchor": anchor if l2["mode"] == "decoupled" else None}
        self._compile()
        self._export_actor()

    def _compile(self) -> None:
        settings = dict(tx=self._tx, activation=self._activation_name(), gamma=float(self.gamma), tau=float(self.tau),
                        post=tuple(self.step_transforms), **self._decay)
        if self.algorithm == "sac":
            auto = getattr(self, "ent_coef_optimizer", None) is not None
            target = None if self.target_entropy == -float(self.action_space.shape[0]) else float(self.target_entropy)
            update = partial(core.sac_update, **settings, target_update_interval=self.target_update_interval,
                             ent_coef=None if auto else float(self.ent_coef_tensor), target_entropy=target)
        else:
            update = partial(core.td3_update, **settings, policy_delay=self.policy_delay,
                             target_policy_noise=float(self.target_policy_noise),
                             target_noise_clip=float(self.target_noise_clip))
        params, opt = self._param_packing, self._opt_packing

        def packed(fp, ip, fo, io, batches, noise, lr, n_updates):
            new_params, new_opt, stats = update(params.unpack(fp, ip), opt.unpack(fo, io), batches, noise, lr, n_updates)
            return (*params.pack(new_params), *opt.pack(new_opt), stats)
        self._update = jax.jit(packed)
        act, sac = self._act, self.algorithm == "sac"
        self._activations = jax.jit(lambda p, obs: _hidden(p, obs, act, sac))
        self._grad_norm = jax.jit(lambda p, batch: _critic_grad_norm(p, batch, act, sac, float(self.gamma)))

    def use_l2(self, coef: float, mode: str = "decoupled", params=("policy", "value"), biases: bool = True,
               anchor: str = "zero") -> None:
        self.l2_spec = {"coef": float(coef), "mode": mode, "params": tuple(params), "biases": bool(biases),
                        "anchor": anchor}
        self._build_optimizer(carry=True)

    def add_step_transform(self, transform) -> None:
        """``transform(params, jnp)`` after every optimizer step from now on, inside the compiled update (re-jitted);
        each step keeps only its values for that optimizer's parameters."""
        self.step_transforms.append(transform)
        self._compile()

    # ---- collect ------------------------------------------------------------------------------------------
    def _actor_on_host(self) -> dict[str, np.ndarray]:
        """The actor's parameters as host arrays, fetched in one batched transfer (one array at a time costs ~30 us
        each: a host sync per array)."""
        return jax.device_get({k: v for k, v in self.params.items() if k.startswith("actor.")})

    def _export_actor(self, host: Mapping[str, np.ndarray] | None = None) -> None:
        """numba's float32 copy of the actor: per layer (in, out) weights, biases, LayerNorm scale and shift (``host``:
        the actor's parameters already fetched)."""
        actor = self.networks[0]
        host = self._actor_on_host() if host is None else host
        widths = [host[f"{h}.bias"].shape[0] for h in actor.hidden]
        norms = [(host[f"{n}.weight"], host[f"{n}.bias"]) if n else (np.ones(w, np.float32), np.zeros(w, np.float32))
                 for n, w in zip(actor.norms, widths)]

        def layers(head: str) -> Mlp:
            names = (*actor.hidden, head)
            return Mlp(tuple(np.ascontiguousarray(host[f"{n}.weight"].T) for n in names),
                       tuple(np.ascontiguousarray(host[f"{n}.bias"]) for n in names),
                       tuple(np.ascontiguousarray(g) for g, _ in norms), tuple(np.ascontiguousarray(c) for _, c in norms))
        mu = layers(actor.head)
        log_std = layers(actor.extra_heads[0]) if actor.extra_heads else mu
        self._actor = replay_rollout.Actor(mu, log_std, self.algorithm == "sac", self._activation_name() == "relu",
                                           self.layer_norm_on)

    def _noise_sigma(self) -> np.ndarray:
        n_act = self.action_space.shape[0]
        noise = self.action_noise
        noise = getattr(noise, "base_noise", noise)   # SB3's VectorizedActionNoise wraps one per env
        return np.full(n_act, 0.0, np.float32) if noise is None else np.asarray(noise._sigma, np.float32)

    def collect_rollouts(self, env, callback, train_freq, replay_buffer, action_noise=None, learning_starts: int = 0,
                         log_interval=None) -> RolloutReturn:
        """``train_freq`` vector steps into the replay buffer, compiled (``replay_rollout.fly_replay``)."""
        n, n_act, k = env.num_envs, self.action_space.shape[0], int(train_freq.frequency)
        buf = replay_buffer
        callback.on_rollout_start()
        obs = np.array(self._last_obs, dtype=np.float32)
        dones = np.zeros(n, np.bool_)
        draws = replay_rollout.Draws(eps=self.noise_rng.standard_normal((k, n, n_act), dtype=np.float32),
                                     uniform=self.noise_rng.uniform(-1, 1, (k, n, n_act)).astype(np.float32),
                                     noise=self.noise_rng.standard_normal((k, n, n_act), dtype=np.float32))
        warm = int(min(max(-(-(learning_starts - self.num_timesteps) // n), 0), k))
        replay = replay_rollout.Replay(buf.observations, buf.next_observations, buf.actions, buf.rewards, buf.dones,
                                       buf.timeouts)
        wind, sigma = env.rollout_wind(k), self._noise_sigma()
        t = episodes = 0
        while t < k:
            env.sync_condition()
            to_change = env.steps_to_task_change()
            t_stop = k if to_change is None else min(k, t + to_change)
            t_next, pos, wrapped = replay_rollout.fly_replay(t, t_stop, warm, obs, dones, draws, sigma, wind,
                                                             self._actor, replay, buf.pos, env.kernel)
            buf.pos, buf.full = int(pos), buf.full or bool(wrapped)
            env.global_step += n * (t_next - t)
            self.num_timesteps += n * (t_next - t)
            t = t_next
            infos = env.end_episodes(obs, dones)
            callback.update_locals({"infos": infos, "dones": dones, "new_obs": obs})
            if not callback.on_step():
                return RolloutReturn(t * n, episodes, continue_training=False)
            self._update_info_buffer(infos, dones)
            episodes += int(dones.sum())
            self._episode_num += int(dones.sum())
            dones[:] = False
        self._last_obs = self._last_original_obs = obs
        self._update_current_progress_remaining(self.num_timesteps, self._total_timesteps)
        callback.on_rollout_end()
        return RolloutReturn(k * n, episodes, continue_training=True)

    # ---- update -------------------------------------------------------------------------------------------
    def replay_batches(self, gradient_steps: int, batch_size: int) -> dict[str, np.ndarray]:
        """G batches drawn as SB3's ``ReplayBuffer.sample`` draws them (per step: rows, then envs, from NumPy's
        global RNG), as SB3's ``ReplayBufferSamples`` (done x (1 - timeout))."""
        buf = self.replay_buffer
        upper = buf.buffer_size if buf.full else buf.pos
        rows = np.empty((gradient_steps, batch_size), np.int64)
        envs = np.empty((gradient_steps, batch_size), np.int64)
        for g in range(gradient_steps):
            rows[g] = np.random.randint(0, upper, size=batch_size)
            envs[g] = np.random.randint(0, high=buf.n_envs, size=batch_size)
        return {"observations": buf.observations[rows, envs], "actions": buf.actions[rows, envs],
                "next_observations": buf.next_observations[rows, envs], "rewards": buf.rewards[rows, envs],
                "dones": buf.dones[rows, envs] * (1.0 - buf.timeouts[rows, envs])}

    def train(self, gradient_steps: int, batch_size: int = 256) -> None:
        """G gradient steps in one compiled call; logs SB3's ``train/*`` values of the call."""
        lr = float(self.lr_schedule(self._current_progress_remaining))
        batches = self.replay_batches(gradient_steps, batch_size)
        shape = (gradient_steps, batch_size, self.action_space.shape[0])
        if self.algorithm == "sac":
            noise = {"pi": self.noise_rng.standard_normal(shape, dtype=np.float32),
                     "next": self.noise_rng.standard_normal(shape, dtype=np.float32)}
        else:
            noise = self.noise_rng.standard_normal(shape, dtype=np.float32)
        self._fp, self._ip, self._fo, self._io, stats = self._update(self._fp, self._ip, self._fo, self._io, batches,
                                                                     noise, lr, self._n_updates)
        self._params_view = self._opt_view = None
        stats, host = jax.device_get((stats, self._fp))   # one transfer: the logged values and the actor's weights
        for key, value in core.sb3_logs(stats, self._n_updates, lr).items():
            self.logger.record(key, value)
        self._n_updates += gradient_steps
        self._export_actor(self._param_packing.unpack(host, np.zeros(0, np.int32)))

    # ---- the contract ---------------------------------------------------------------------------------------
    def _trained(self):
        raise TypeError("the JAX learner's parameters are in params, not in its torch shell")

    def parameter_arrays(self) -> dict[str, np.ndarray]:
        return {k: np.array(v) for k, v in self.params.items() if not k.startswith(TARGETS)}

    def write_parameters(self, arrays: Mapping[str, np.ndarray]) -> None:
        params = self.params
        for name, value in arrays.items():
            if name.startswith(TARGETS) or np.shape(value) != params[name].shape:
                raise ValueError(f"{name}: not a trained parameter of shape {params[name].shape}")
            params[name] = jnp.asarray(np.array(value, dtype=np.float32))
        self.params = params
        self._export_actor()

    def target_arrays(self) -> dict[str, np.ndarray]:
        return {k: np.array(v) for k, v in self.params.items() if k.startswith(TARGETS)}

    def reset_targets(self, names=None) -> None:
        params = self.params
        names = [k for k in params if k.startswith(("critic.", "actor."))] if names is None else names
        for name in names:
            target = target_of(name)
            if target in params:
                params[target] = params[name]
        self.params = params

    def optimizers(self):
        raise TypeError("the JAX learner's optimizers are opt_states, by name")

    def optimizer_moments(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        out = {}
        for name, state in self.opt_states.items():
            adam = core.adam_state(state)
            out.update({k: (np.array(adam.mu[k]), np.array(adam.nu[k])) for k in adam.mu})
        return out

    def reset_optimizer_state(self) -> None:
        self.opt_states = core.init_opt_states(self._tx, self.params)

    def reset_optimizer(self, masks: Mapping[str, np.ndarray]) -> None:
        states = self.opt_states
        for name, state in states.items():
            adam = core.adam_state(state)
            keep = {k: jnp.asarray(~np.asarray(masks[k], bool)) for k in adam.mu if k in masks}
            if keep:
                zeroed = adam._replace(mu={k: v * keep[k] if k in keep else v for k, v in adam.mu.items()},
                                       nu={k: v * keep[k] if k in keep else v for k, v in adam.nu.items()})
                states[name] = _with_adam(state, zeroed)
        self.opt_states = states

    def hidden_activations(self, obs: np.ndarray) -> dict[str, list[Hidden]]:
        """Per network, each hidden layer's (pre, post): the actor on ``obs``, the critics at its deterministic action."""
        out = jax.device_get(self._activations(self.params, np.asarray(obs, np.float32)))
        return {name: [Hidden(np.asarray(a), np.asarray(b)) for a, b in layers] for name, layers in out.items()}

    def loss_grad_norm(self, samples: Samples) -> float:
        """As ``SB3SAC.loss_grad_norm``: the critics' TD loss gradient norm, the target policy deterministic."""
        batch = {"observations": samples.observations, "actions": samples.actions,
                 "next_observations": samples.next_observations, "rewards": samples.rewards, "dones": samples.dones}
        return float(self._grad_norm(self.params, {k: np.asarray(v, np.float32) for k, v in batch.items()}))

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = False):
        obs = np.ascontiguousarray(np.atleast_2d(observation), dtype=np.float32)
        n_act = self.action_space.shape[0]
        out = np.empty((len(obs), n_act), np.float32)
        eps = (np.zeros((len(obs), n_act), np.float32) if deterministic or self.algorithm != "sac"
               else self.noise_rng.standard_normal((len(obs), n_act), dtype=np.float32))
        replay_rollout.actions_of(obs, self._actor, eps, out)
        return out, state

    def learner_state(self) -> dict[str, Any]:
        return {"params": {k: np.array(v) for k, v in self.params.items()},
                "opt_states": jax.tree.map(np.asarray, self.opt_states),
                "noise_rng": self.noise_rng.bit_generator.state, "rng": self.rng.bit_generator.state}

    def load_learner_state(self, state: dict[str, Any]) -> None:
        self.params = {k: jnp.asarray(v) for k, v in state["params"].items()}
        self.opt_states = jax.tree.map(jnp.asarray, state["opt_states"])
        self.noise_rng.bit_generator.state = state["noise_rng"]
        self.rng.bit_generator.state = state["rng"]
        self._export_actor()

    def save(self, path, exclude=None, include=None) -> None:
        """An SB3 zip (``SAC.load`` / ``TD3.load`` read it): the weights written into the torch shell first."""
        core.load_into(self, self.params)
        super().save(path, exclude=exclude, include=include)


class JaxSAC(_JaxOffPolicy, SB3SAC):
    """SAC with SB3's semantics, compiled (see the module docstring)."""


class JaxTD3(_JaxOffPolicy, SB3TD3):
    """TD3 with SB3's semantics, compiled (see the module docstring)."""


# ---- jitted helpers --------------------------------------------------------------------------------------------
def _with_adam(state, adam: optax.ScaleByAdamState):
    """``state`` (an optax chain's) with its Adam part replaced by ``adam``."""
    if isinstance(state, optax.ScaleByAdamState):
        return adam
    if isinstance(state, tuple) and not hasattr(state, "_fields"):
        return tuple(_with_adam(s, adam) for s in state)
    return state


def _hidden(params, obs, act, sac: bool):
    """(pre, post) of every hidden layer: the actor on ``obs``, each critic on (obs, the deterministic action)."""
    if sac:
        mean, _, actor = core.sac_actor(params, obs, act)
        action = jnp.tanh(mean)
    else:
        _, actor = core.mlp(params, "actor.mu", obs, act)
        action = core.td3_actor(params, obs, act)
    x = jnp.concatenate([obs, action], axis=-1)
    n = sum(1 for k in params if k.startswith("critic.qf") and k.endswith(".0.weight"))
    return {"actor": actor, **{f"critic_{j}": core.mlp(params, f"critic.qf{j}", x, act)[1] for j in range(n)}}


def _critic_grad_norm(params, batch, act, sac: bool, gamma: float):
    """Global norm of the critics' TD loss gradient; target from the target critics at the target policy's
    deterministic next action (SAC: tanh(mu) of the actor; TD3: the target actor)."""
    obs, next_obs = batch["observations"], batch["next_observations"]
    next_actions = jnp.tanh(core.sac_actor(params, next_obs, act)[0]) if sac else \
        core.td3_actor(params, next_obs, act, "actor_target")
    next_q = jnp.min(jnp.concatenate(core.critic(params, next_obs, next_actions, act, "critic_target"), axis=1),
                     axis=1, keepdims=True)
    target = jax.lax.stop_gradient(batch["rewards"].reshape(-1, 1)
                                   + (1 - batch["dones"].reshape(-1, 1)) * gamma * next_q)
    names = core.trained(params, "critic")

    def loss(sub):
        qs = core.critic({**params, **sub}, obs, batch["actions"], act)
        return sum(jnp.mean((q - target) ** 2) for q in qs) * (0.5 if sac else 1.0)
    return optax.global_norm(jax.grad(loss)({k: params[k] for k in names}))


__all__ = ["JaxSAC", "JaxTD3"]
