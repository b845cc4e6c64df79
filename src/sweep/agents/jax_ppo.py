"""``JaxPPO``: SB3's PPO, compiled. The update runs in JAX, the rollout in numba (``sweep.agents.rollout``).

Same algorithm, hyperparameters and logged names as ``stable_baselines3.PPO`` with ``MlpPolicy``
(tests/test_jax_learner.py holds them together):

* networks: ``sweep.agents.networks`` (separate policy and value MLPs, optional LayerNorm, linear heads,
  state-independent ``log_std``), SB3's ``state_dict`` names and torch's (out, in) layout. Initial weights
  are those SB3's ``ActorCriticPolicy`` draws for the same seed: built once with torch and copied.
* rollout: SB3's ``collect_rollouts`` (Gaussian actions, clipped only for the env, timeout bootstrap,
  GAE(lambda)), compiled for the hover env.
* update, one jitted call per rollout: ``n_epochs`` epochs over minibatches of ``batch_size`` drawn
  with ``np.random.permutation`` (SB3's order and RNG), in a ``lax.scan``; per minibatch the advantages
  are normalised (Bessel-corrected std, as torch), the loss is the clipped surrogate + ``vf_coef`` x the
  unclipped value MSE + ``ent_coef`` x the entropy loss, the gradient is clipped to a global norm of
  ``max_grad_norm`` and Adam (torch's defaults, ``eps`` from the config) takes the step. With ``target_kl``,
  the update stops at the first minibatch whose approx KL exceeds 1.5 x target_kl, before its step, as
  SB3 does; the global RNG then advances by the permutations of the epochs that ran, as SB3's does.
* the learning rate is an argument of that call, read from ``lr_schedule`` before every update as SB3
  does, so RECOM (``set_learning_rate``) and ``agent.ppo.lr_schedule`` drive it unchanged; L2 (``use_l2``) is the
  same coupled (Adam ``weight_decay``) or decoupled (AdamW) decay on the same parameters, toward 0 or
  toward theta_0 (L2-Init).
* the ``Learner`` contract (``sweep.agents.learner``). The weights live in three copies kept in step after
  every write (``write_parameters``, an update, a checkpoint load): ``params`` (JAX), Adam's moments in
  ``opt_state`` (same tree), and the compiled rollout's float32 export (``_export_weights``).

It subclasses SB3's ``OnPolicyAlgorithm``, so ``learn()``, the logger, ``rollout/*`` and ``time/*``
metrics, the episode buffer and the steps the project's loop drives (``sweep.agents.onpolicy``) are SB3's own.
One difference: an SB3 callback's ``on_step`` (here only the rollout's episode collector) runs once per compiled
chunk of steps (a chunk ends where an episode ends, or at the end of the rollout), with ``locals["infos"]`` of
the chunk's last step, so every finished episode is seen.

Only the fast backend can be stepped from the compiled rollout (``env.backend=fast``).
"""
from __future__ import annotations

import os
from pathlib import Path

# One CPU thread (as torch: train.torch_threads; see _jax_cpu_client_on_one_thread), and compiled programs cached across runs (~3 s per job).
if "xla_cpu_multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):  # after train.portable's flags, if any
    os.environ["XLA_FLAGS"] = ("--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1 "
                               + os.environ.get("XLA_FLAGS", "")).strip()
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(Path.home() / ".cache" / "sweep" / "jax"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

import math  # noqa: E402
from functools import partial  # noqa: E402
from typing import Any, Mapping  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402
import torch  # noqa: E402
from gymnasium import spaces  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.buffers import RolloutBuffer  # noqa: E402
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm  # noqa: E402
from stable_baselines3.common.policies import ActorCriticPolicy  # noqa: E402
from stable_baselines3.common.utils import FloatSchedule, explained_variance  # noqa: E402
from stable_baselines3.common.vec_env import VecEnv  # noqa: E402

from sweep.agents import rollout  # noqa: E402
from sweep.agents.learner import Hidden  # noqa: E402
from sweep.agents.networks import (LAYER_NORM_EPS, Network, actor_columns, actor_critic, adam_kwargs,  # noqa: E402
                                   policy_class, remedy_rng)
from sweep.agents.onpolicy import StepwiseLearning  # noqa: E402
from sweep.agents.sb3 import ACTIVATIONS as SB3_ACTIVATIONS  # noqa: E402
from sweep.plasticity.l2 import penalized  # noqa: E402
from sweep.training.records import Samples, UpdateRecord  # noqa: E402

ACTIVATIONS = {"tanh": jnp.tanh, "relu": jax.nn.relu}

def _jax_cpu_client_on_one_thread() -> None:
    """Create JAX's CPU client while this thread may run on one core, so XLA sizes its intra-op thread pool
    to one thread, then give every thread of the process back all its cores.

    jaxlib 0.10 ignores the XLA_FLAGS above for that pool (one thread per core): a run used 1.4 CPUs for no
    speed-up, and two concurrent runs on two cores got 1.24x one run's rate (benchmarks/RESULTS.md). The
    affinity is the only limit XLA reads (jax-ml/jax#1539). No effect if the client already exists."""
    if not hasattr(os, "sched_setaffinity"):
        return
    cores = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(cores)})
    try:
        jax.devices()
    finally:
        for tid in os.listdir("/proc/self/task"):
            try:
                os.sched_setaffinity(int(tid), cores)
            except OSError:  # a thread that ended meanwhile
                pass


_jax_cpu_client_on_one_thread()

Params = dict[str, jax.Array]


# ------------------------------------------------------------------------------------------------
# The networks and the PPO loss, in SB3's terms (parameter names = ActorCriticPolicy.state_dict keys)
# ------------------------------------------------------------------------------------------------
def layer_norm(x: jax.Array, scale: jax.Array, shift: jax.Array) -> jax.Array:
    """torch.nn.LayerNorm over the last axis (biased variance)."""
    mean = x.mean(-1, keepdims=True)
    var = ((x - mean) ** 2).mean(-1, keepdims=True)
    return (x - mean) / jnp.sqrt(var + LAYER_NORM_EPS) * scale + shift


def mlp_forward(params: Params, net: Network, x: jax.Array, act) -> tuple[jax.Array, list[tuple[jax.Array, jax.Array]]]:
    """(output, [(pre, post) per hidden layer]) of an SB3 MLP + head: Linear (x W^T + b) [-> LayerNorm] -> ``act``.
    A network whose first layer takes fewer inputs than ``x`` has columns reads the leading ones (an asymmetric actor)."""
    x = x[..., :params[f"{net.hidden[0] if net.hidden else net.head}.weight"].shape[1]]
    hidden = []
    for name, norm in zip(net.hidden, net.norms):
        pre = x @ params[f"{name}.weight"].T + params[f"{name}.bias"]
        if norm:
            pre = layer_norm(pre, params[f"{norm}.weight"], params[f"{norm}.bias"])
        x = act(pre)
        hidden.append((pre, x))
    return x @ params[f"{net.head}.weight"].T + params[f"{net.head}.bias"], hidden


def gaussian_log_prob(actions, mean, log_std):
    """torch.distributions.Normal(mean, exp(log_std)).log_prob(actions).sum(-1), as SB3's DiagGaussian."""
    std = jnp.exp(log_std)
    return jnp.sum(-((actions - mean) ** 2) / (2 * std ** 2) - jnp.log(std) - math.log(math.sqrt(2 * math.pi)), -1)


def gaussian_entropy(log_std, batch: int):
    """torch Normal entropy summed over action dims, one value per sample."""
    per_dim = 0.5 + 0.5 * math.log(2 * math.pi) + jnp.log(jnp.exp(log_std))
    return jnp.broadcast_to(jnp.sum(per_dim), (batch,))


def ppo_loss(params: Params, batch: dict[str, jax.Array], clip_range, ent_coef: float, vf_coef: float,
             nets: tuple[list[str], list[str]], act, normalize_advantage: bool):
    """SB3 PPO's minibatch loss; returns (loss, (pg_loss, value_loss, entropy_loss, clip_fraction, approx_kl))."""
    pi_names, vf_names = nets
    mean, _ = mlp_forward(params, pi_names, batch["observations"], act)
    values, _ = mlp_forward(params, vf_names, batch["observations"], act)
    values = values.reshape(-1)
    log_prob = gaussian_log_prob(batch["actions"], mean, params["log_std"])
    entropy = gaussian_entropy(params["log_std"], log_prob.shape[0])
    advantages = batch["advantages"]
    if normalize_advantage and advantages.shape[0] > 1:
        advantages = (advantages - advantages.mean()) / (jnp.std(advantages, ddof=1) + 1e-8)
    log_ratio = log_prob - batch["old_log_prob"]
    ratio = jnp.exp(log_ratio)
    pg_loss = -jnp.minimum(advantages * ratio, advantages * jnp.clip(ratio, 1 - clip_range, 1 + clip_range)).mean()
    value_loss = jnp.mean((batch["returns"] - values) ** 2)
    entropy_loss = -jnp.mean(entropy)
    loss = pg_loss + ent_coef * entropy_loss + vf_coef * value_loss
    clip_fraction = jnp.mean((jnp.abs(ratio - 1) > clip_range).astype(jnp.float32))
    approx_kl = jnp.mean((jnp.exp(log_ratio) - 1) - log_ratio)
    return loss, (pg_loss, value_loss, entropy_loss, clip_fraction, approx_kl)


class JaxPPO(StepwiseLearning, OnPolicyAlgorithm):
    """PPO with SB3's semantics; see the module docstring. Keyword arguments are SB3 PPO's."""

    def __init__(self, env: VecEnv, *, learning_rate: float = 3e-4, n_steps: int = 2048, batch_size: int = 64,
                 n_epochs: int = 10, gamma: float = 0.99, gae_lambda: float = 0.95, clip_range: float = 0.2,
                 ent_coef: float = 0.0, vf_coef: float = 0.5, max_grad_norm: float = 0.5,
                 normalize_advantage: bool = True, target_kl: float | None = None,
                 net_arch: tuple[int, ...] = (64, 64), activation: str = "tanh", layer_norm: bool = False,
                 adam_eps: float = 1e-5, seed: int | None = None, verbose: int = 0) -> None:
        super().__init__(ActorCriticPolicy, env, learning_rate=learning_rate, n_steps=n_steps, gamma=gamma,
                         gae_lambda=gae_lambda, ent_coef=ent_coef, vf_coef=vf_coef, max_grad_norm=max_grad_norm,
                         use_sde=False, sde_sample_freq=-1, seed=seed, device="cpu", verbose=verbose,
                         _init_setup_model=False, supported_action_spaces=(spaces.Box,))
        rollout_size = n_steps * self.n_envs
        if rollout_size % batch_size:
            raise ValueError(f"batch_size={batch_size} must divide the rollout size n_steps x n_envs = {rollout_size}")
        self.batch_size, self.n_epochs = int(batch_size), int(n_epochs)
        self.clip_range, self.normalize_advantage = clip_range, bool(normalize_advantage)
        self.target_kl = None if target_kl is None else float(target_kl)
        self.net_arch, self.activation, self.adam_eps = tuple(int(h) for h in net_arch), activation, float(adam_eps)
        self.layer_norm = bool(layer_norm)
        self.l2_spec: dict[str, Any] | None = None
        self.step_transforms: list = []   # per-step remedies (add_step_transform), compiled into the update
        self._setup_model()

    @classmethod
    def from_config(cls, env: VecEnv, ppo: dict, net_arch: list[int], activation: str, adam_eps: float,
                    seed: int, layer_norm: bool = False) -> "JaxPPO":
        return cls(env, **ppo, net_arch=net_arch, activation=activation, layer_norm=layer_norm, adam_eps=adam_eps,
                   seed=seed)

    # ---- construction ---------------------------------------------------------------------------
    def torch_policy(self) -> ActorCriticPolicy:
        """An SB3 ``ActorCriticPolicy`` of this architecture (its parameters are SB3's initial draw)."""
        kwargs = self._policy_kwargs()
        cls = policy_class(self.layer_norm, "actor_columns" in kwargs)
        cls = ActorCriticPolicy if cls == "MlpPolicy" else cls
        return cls(self.observation_space, self.action_space, self.lr_schedule, **kwargs)

    def _policy_kwargs(self) -> dict[str, Any]:
        """SB3's ``policy_kwargs`` of this architecture (with ``actor_columns`` for an asymmetric actor-critic)."""
        arch = list(self.net_arch)
        kwargs = {"net_arch": {"pi": arch, "vf": arch}, "activation_fn": SB3_ACTIVATIONS[self.activation],
                  "optimizer_kwargs": adam_kwargs(self.adam_eps)}
        columns = actor_columns(self.env)
        return kwargs if columns is None else {**kwargs, "actor_columns": columns}

    def _setup_model(self) -> None:
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)  # as SB3 PPO: the same seed draws the same initial weights
        self.rollout_buffer = RolloutBuffer(self.n_steps, self.observation_space, self.action_space, device="cpu",
                                            gamma=self.gamma, gae_lambda=self.gae_lambda, n_envs=self.n_envs)
        self.policy = None  # no torch policy; ``to_sb3`` builds one
        self.clip_range_schedule = FloatSchedule(self.clip_range)
        self.networks = self._nets = actor_critic(len(self.net_arch), self.layer_norm)
        self._act = ACTIVATIONS[self.activation]
        self._initial = {k: v.numpy().copy() for k, v in self.torch_policy().state_dict().items()}
        self.params: Params = {k: jnp.asarray(v) for k, v in self._initial.items()}
        self.noise_rng = np.random.default_rng(self.seed)
        self.rng = remedy_rng(self.seed or 0)
        self._build_optimizer()

    def _build_optimizer(self) -> None:
        """Adam (torch's betas, ``adam_eps``) after SB3's global-norm clip, with L2 if ``use_l2`` set it."""
        l2 = self.l2_spec or {"coef": 0.0, "mode": "coupled", "params": (), "biases": True, "anchor": "zero"}
        mask = {k: bool(l2["coef"]) and penalized(k, list(l2["params"]), l2["biases"]) for k in self.params}
        self.l2_decayed = sorted(k for k, on in mask.items() if on)
        coupled = l2["coef"] if l2["mode"] == "coupled" else 0.0
        decoupled = l2["coef"] if l2["mode"] == "decoupled" else 0.0
        anchor = ({k: jnp.asarray(v) for k, v in self._initial.items()}
                  if l2["anchor"] == "init" and l2["coef"] else None)
        transforms = [optax.clip_by_global_norm(self.max_grad_norm)]
        if coupled and anchor is None:  # torch Adam(weight_decay): g <- g + coef * theta, before the moments
            transforms.append(optax.add_decayed_weights(coupled, mask=mask))
        elif coupled:  # L2-Init, coupled: g <- g + coef * (theta - theta_0)
            transforms.append(toward_anchor(coupled, mask, anchor))
        transforms.append(optax.scale_by_adam(b1=0.9, b2=0.999, eps=self.adam_eps))
        self._tx = optax.chain(*transforms)
        self.opt_state = self._tx.init(self.params)
        self._decay = {"decay": decoupled, "mask": mask, "anchor": anchor}
        self._compile_update()
        self._activations = jax.jit(partial(_hidden, nets=self._nets, act=self._act))
        self._grad_norm = jax.jit(partial(_grad_norm, nets=self._nets, act=self._act, ent_coef=float(self.ent_coef),
                                          vf_coef=float(self.vf_coef), normalize_advantage=self.normalize_advantage,
                                          clip_range=float(self.clip_range)))
        self._export_weights()

    def _compile_update(self) -> None:
        """The jitted update: the optax chain, the decoupled decay and the per-step transforms baked in."""
        self._update = jax.jit(partial(
            _update, tx=self._tx, **self._decay, post=tuple(self.step_transforms), n_epochs=self.n_epochs,
            batch_size=self.batch_size, ent_coef=float(self.ent_coef), vf_coef=float(self.vf_coef), nets=self._nets,
            act=self._act, normalize_advantage=self.normalize_advantage, target_kl=self.target_kl))

    def add_step_transform(self, transform) -> None:
        """``transform(params, jnp)`` after every Adam step from now on, inside the compiled update (re-jitted)."""
        self.step_transforms.append(transform)
        self._compile_update()

    def use_l2(self, coef: float, mode: str = "decoupled", params=("policy", "value"), biases: bool = True,
               anchor: str = "zero") -> None:
        """L2 regularization (``sweep.plasticity.l2``, ``l2_init``): rebuilds the optimizer with the decay."""
        self.l2_spec = {"coef": float(coef), "mode": mode, "params": tuple(params), "biases": bool(biases),
                        "anchor": anchor}
        self._build_optimizer()

    def _export_weights(self, written: Mapping[str, np.ndarray] | None = None) -> None:
        """numba's copy of the networks: per layer (in, out) float32 weights, biases, and log_std. ``written``:
        host values of the parameters just written (the others are taken from the previous export)."""
        if written is None:
            host = {k: np.array(v, dtype=np.float32) for k, v in self.params.items()}  # writable copies
        else:
            host = {**self._host, **written}
        self._host = host

        def layers(net: Network):
            norm = [(host[f"{n}.weight"], host[f"{n}.bias"]) if n else  # unused placeholders without LayerNorm
                    (np.ones(w, np.float32), np.zeros(w, np.float32)) for n, w in zip(net.norms, self.net_arch)]
            return (tuple(np.ascontiguousarray(host[f"{n}.weight"].T) for n in net.linears),
                    tuple(np.ascontiguousarray(host[f"{n}.bias"]) for n in net.linears),
                    tuple(np.ascontiguousarray(g) for g, _ in norm), tuple(np.ascontiguousarray(c) for _, c in norm))
        self._pi, self._vf = layers(self._nets[0]), layers(self._nets[1])
        self._log_std = np.ascontiguousarray(host["log_std"])
        self._relu = self.activation == "relu"

    # ---- rollout -------------------------------------------------------------------------------
    def collect_rollouts(self, env: VecEnv, callback: BaseCallback, rollout_buffer: RolloutBuffer,
                         n_rollout_steps: int) -> bool:
        buf = rollout_buffer
        buf.reset()
        callback.on_rollout_start()
        n = env.num_envs
        obs = np.array(self._last_obs, dtype=np.float32)
        episode_starts = np.array(self._last_episode_starts, dtype=np.float32)
        dones = np.zeros(n, dtype=np.bool_)
        noise = self.noise_rng.standard_normal((n_rollout_steps, n, self.action_space.shape[0]), dtype=np.float32)
        wind = env.rollout_wind(n_rollout_steps)
        buffer = rollout.Buffer(observations=buf.observations, actions=buf.actions, rewards=buf.rewards,
                                episode_starts=buf.episode_starts, values=buf.values, log_probs=buf.log_probs)
        t = 0
        while t < n_rollout_steps:  # the weights are read at every call (a written weight acts at once)
            env.sync_condition()  # the vehicle and reward weights in force (the wind of every step is in ``wind``)
            to_change = env.steps_to_task_change()
            t_stop = n_rollout_steps if to_change is None else min(n_rollout_steps, t + to_change)
            policy = rollout.Policy(pi=rollout.Mlp(*self._pi), vf=rollout.Mlp(*self._vf), log_std=self._log_std,
                                    relu=self._relu, layer_norm=self.layer_norm)
            t_next = rollout.fly(t, t_stop, obs, episode_starts, dones, noise, wind, policy, self.gamma, buffer,
                                 env.kernel)
            env.global_step += n * (t_next - t)
            self.num_timesteps += n * (t_next - t)
            t = t_next
            infos = env.end_episodes(obs, dones)
            callback.update_locals({"infos": infos, "dones": dones, "new_obs": obs, "n_steps": t})
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)
        buf.pos, buf.full = n_rollout_steps, True
        self._last_obs, self._last_episode_starts = obs, dones.copy()
        last_values = np.empty(n, np.float32)
        rollout.values_of(obs, *self._vf, self._relu, self.layer_norm, last_values)
        rollout.gae(buf.rewards, buf.values, buf.episode_starts, last_values, dones, self.gamma, self.gae_lambda,
                    buf.advantages, buf.returns)
        callback.update_locals({"infos": infos, "dones": dones, "new_obs": obs, "values": last_values})
        callback.on_rollout_end()
        return True

    # ---- update --------------------------------------------------------------------------------
    def rollout_batch(self) -> dict[str, np.ndarray]:
        """The rollout buffer flattened as SB3's ``RolloutBuffer.get`` does (env-major)."""
        buf = self.rollout_buffer

        def flat(a):
            return a.swapaxes(0, 1).reshape(a.shape[0] * a.shape[1], *a.shape[2:])
        return {"observations": flat(buf.observations), "actions": flat(buf.actions), "values": flat(buf.values),
                "old_log_prob": flat(buf.log_probs), "advantages": flat(buf.advantages), "returns": flat(buf.returns)}

    def train(self) -> None:
        """SB3's ``train()`` (what ``learn()`` calls): one update, its record logged as SB3 logs it."""
        for key, value in self.update().metrics().items():
            self.logger.record(key, value)

    def _train_record(self) -> UpdateRecord:
        lr = float(self.lr_schedule(self._current_progress_remaining))
        clip_range = float(self.clip_range_schedule(self._current_progress_remaining))
        batch = self.rollout_batch()
        values = batch.pop("values")
        size = len(batch["advantages"])
        rng_before = np.random.get_state() if self.target_kl is not None else None
        order = np.stack([np.random.permutation(size) for _ in range(self.n_epochs)])  # SB3's draws
        self.params, self.opt_state, stats = self._update(self.params, self.opt_state, batch, order, lr, clip_range)
        self._export_weights()
        pg, vf, ent, clip_frac, kl, loss, computed = (np.asarray(s) for s in stats)
        per_epoch = size // self.batch_size
        n = int(computed.sum())  # minibatches whose loss was computed (all, unless target_kl stopped the update)
        epochs = -(-n // per_epoch)
        if epochs < self.n_epochs:  # SB3 drew only the permutations of the epochs it ran
            np.random.set_state(rng_before)
            for _ in range(epochs):
                np.random.permutation(size)
        self._n_updates += epochs
        return UpdateRecord(
            index=self._updates, timesteps=int(self.num_timesteps), learning_rate=lr, clip_range=clip_range,
            policy_gradient_loss=float(pg[:n].mean()), value_loss=float(vf[:n].mean()), entropy_loss=float(ent[:n].mean()),
            loss=float(loss[n - 1]),  # SB3: the last minibatch's
            approx_kl=float(kl[(epochs - 1) * per_epoch:n].mean()),  # SB3: the last epoch's
            clip_fraction=float(clip_frac[:n].mean()),
            explained_variance=float(explained_variance(values, batch["returns"])), epochs=epochs,
            n_updates=int(self._n_updates), std=float(np.exp(self._log_std).mean()), vf_coef=float(self.vf_coef),
            ent_coef=float(self.ent_coef))

    # ---- what the rest of the project asks of a learner -------------------------------------------
    def predict(self, observation, state=None, episode_start=None, deterministic: bool = False):
        obs = np.ascontiguousarray(np.atleast_2d(observation), dtype=np.float32)
        mean = np.empty((len(obs), self.action_space.shape[0]), np.float32)
        rollout.actions_of(obs, *self._pi, self._relu, self.layer_norm, mean)
        if not deterministic:
            mean = mean + np.exp(self._log_std) * self.noise_rng.standard_normal(mean.shape, dtype=np.float32)
        return np.clip(mean, -1.0, 1.0), state

    @property
    def minibatches_per_update(self) -> int:
        return self.n_epochs * (self.n_steps * self.n_envs // self.batch_size)

    def parameter_arrays(self) -> dict[str, np.ndarray]:
        return {k: np.array(v) for k, v in self.params.items()}  # copies

    def write_parameters(self, arrays: Mapping[str, np.ndarray]) -> None:
        """New values of the named parameters; the compiled rollout's copy follows (Adam's moments are left)."""
        written = {}
        for name, value in arrays.items():
            if np.shape(value) != self.params[name].shape:
                raise ValueError(f"{name}: shape {np.shape(value)} != {self.params[name].shape}")
            written[name] = np.array(value, dtype=np.float32)
            self.params[name] = jnp.asarray(written[name])
        self._export_weights(written)

    def initial_parameters(self) -> dict[str, np.ndarray]:
        return {k: v.copy() for k, v in self._initial.items()}

    def _adam(self) -> optax.ScaleByAdamState:
        return next(s for s in self.opt_state if isinstance(s, optax.ScaleByAdamState))

    def optimizer_moments(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        adam = self._adam()
        return {k: (np.array(adam.mu[k]), np.array(adam.nu[k])) for k in self.params}

    def reset_optimizer_state(self) -> None:
        """The optax chain's initial state (zero moments, count 0), as the learner built it."""
        self.opt_state = self._tx.init(self.params)

    def reset_optimizer(self, masks: Mapping[str, np.ndarray]) -> None:
        adam = self._adam()
        keep = {k: jnp.asarray(~np.asarray(masks[k], bool)) if k in masks else None for k in adam.mu}
        zeroed = adam._replace(mu={k: v * keep[k] if keep[k] is not None else v for k, v in adam.mu.items()},
                               nu={k: v * keep[k] if keep[k] is not None else v for k, v in adam.nu.items()})
        self.opt_state = tuple(zeroed if isinstance(s, optax.ScaleByAdamState) else s for s in self.opt_state)

    def hidden_activations(self, obs: np.ndarray) -> dict[str, list[Hidden]]:
        """Per network, each hidden layer's (input of the activation, its output) on ``obs``."""
        pi_hidden, vf_hidden = jax.device_get(self._activations(self.params, np.asarray(obs, np.float32)))
        return {"policy": [Hidden(np.asarray(a), np.asarray(b)) for a, b in pi_hidden],
                "value": [Hidden(np.asarray(a), np.asarray(b)) for a, b in vf_hidden]}

    def loss_grad_norm(self, samples: Samples) -> float:
        """Norm of the PPO loss gradient at the current parameters (ratio 1), before clipping."""
        batch = {"observations": samples.observations, "actions": samples.actions, "advantages": samples.advantages,
                 "returns": samples.returns}
        return float(self._grad_norm(self.params, {k: np.asarray(v, np.float32) for k, v in batch.items()}))

    def learner_state(self) -> dict[str, Any]:
        return {"params": self.parameter_arrays(), "opt_state": jax.tree.map(np.asarray, self.opt_state),
                "noise_rng": self.noise_rng.bit_generator.state, "rng": self.rng.bit_generator.state}

    def load_learner_state(self, state: dict[str, Any]) -> None:
        self.params = {k: jnp.asarray(v) for k, v in state["params"].items()}
        self._export_weights()
        self.opt_state = jax.tree.map(jnp.asarray, state["opt_state"])
        self.noise_rng.bit_generator.state = state["noise_rng"]
        if "rng" in state:
            self.rng.bit_generator.state = state["rng"]

    def to_sb3(self) -> PPO:
        """An SB3 ``PPO`` with this learner's weights (``PPO.load``-able once saved)."""
        kwargs = self._policy_kwargs()
        model = PPO(policy_class(self.layer_norm, "actor_columns" in kwargs), self.env, learning_rate=self.learning_rate,
                    n_steps=self.n_steps,
                    batch_size=self.batch_size, n_epochs=self.n_epochs, gamma=self.gamma, gae_lambda=self.gae_lambda,
                    clip_range=self.clip_range, ent_coef=self.ent_coef, vf_coef=self.vf_coef,
                    max_grad_norm=self.max_grad_norm, target_kl=self.target_kl, device="cpu", policy_kwargs=kwargs)
        model.policy.load_state_dict({k: torch.as_tensor(v) for k, v in self.parameter_arrays().items()})
        model.num_timesteps = self.num_timesteps
        return model

    def save(self, path, exclude=None, include=None) -> None:
        """Saved as an SB3 PPO zip, so ``stable_baselines3.PPO.load`` reads a JAX run's model too."""
        self.to_sb3().save(path)


# ------------------------------------------------------------------------------------------------
# Jitted functions (module level so the partials above only bind static settings)
# ------------------------------------------------------------------------------------------------
def toward_anchor(coef: float, mask: dict[str, bool], anchor: Params) -> optax.GradientTransformation:
    """Coupled L2-Init: g <- g + coef * (theta - theta_0) on the masked parameters (before Adam's moments)."""
    def update(grads, state, params):
        return {k: grads[k] + coef * (params[k] - anchor[k]) if mask[k] else grads[k] for k in grads}, state
    return optax.GradientTransformation(lambda params: optax.EmptyState(), update)


def _update(params, opt_state, batch, order, lr, clip_range, *, tx, decay, mask, anchor, post, n_epochs, batch_size,
            ent_coef, vf_coef, nets, act, normalize_advantage, target_kl):
    """``n_epochs`` x (rollout / batch_size) minibatch steps in one ``lax.scan``; returns per-step stats and
    whether each step's loss was computed (SB3 stops at the first step whose approx KL > 1.5 target_kl). After
    each step the ``post`` transforms (per-step remedies, ``Learner.add_step_transform``) act, in order."""
    grad_fn = jax.value_and_grad(ppo_loss, has_aux=True)

    def step(carry, idx):
        params, opt_state, stopped = carry
        mb = {k: v[idx] for k, v in batch.items()}
        (loss, aux), grads = grad_fn(params, mb, clip_range, ent_coef, vf_coef, nets, act, normalize_advantage)
        new_opt_state = tx.update(grads, opt_state, params)
        updates, new_opt_state = new_opt_state
        # decoupled (AdamW) decay first, as torch does: theta <- theta * (1 - lr * coef) - lr * adam_update
        # (L2-Init: theta <- theta - lr * coef * (theta - theta_0) - lr * adam_update)
        if anchor is None:
            shrunk = {k: params[k] * (1.0 - lr * decay) if decay and mask[k] else params[k] for k in params}
        else:
            shrunk = {k: params[k] - lr * decay * (params[k] - anchor[k]) if decay and mask[k] else params[k]
                      for k in params}
        new_params = {k: shrunk[k] - lr * updates[k] for k in params}
        for transform in post:
            new_params = {**new_params, **transform(new_params, jnp)}
        computed = jnp.logical_not(stopped)
        if target_kl is not None:
            stop = stopped | (aux[4] > 1.5 * target_kl)
            new_params = jax.tree.map(lambda new, old: jnp.where(stop, old, new), new_params, params)
            new_opt_state = jax.tree.map(lambda new, old: jnp.where(stop, old, new), new_opt_state, opt_state)
            stopped = stop
        return (new_params, new_opt_state, stopped), (*aux, loss, computed)

    minibatches = order.reshape(-1, batch_size)
    (params, opt_state, _), stats = jax.lax.scan(step, (params, opt_state, jnp.asarray(False)), minibatches)
    return params, opt_state, stats


def _hidden(params, obs, *, nets, act):
    """(pre, post) hidden activations of the policy and of the value network."""
    return mlp_forward(params, nets[0], obs, act)[1], mlp_forward(params, nets[1], obs, act)[1]


def _grad_norm(params, batch, *, nets, act, ent_coef, vf_coef, normalize_advantage, clip_range):
    """Global norm of the PPO loss gradient with the rollout policy = the current one (ratio 1: the clip is
    inactive, so the learner's own ``clip_range`` is passed only to keep the loss the one ``ppo_loss``)."""
    mean, _ = mlp_forward(params, nets[0], batch["observations"], act)
    old = jax.lax.stop_gradient(gaussian_log_prob(batch["actions"], mean, params["log_std"]))
    grads = jax.grad(lambda p: ppo_loss(p, {**batch, "old_log_prob": old}, clip_range, ent_coef, vf_coef, nets, act,
                                        normalize_advantage)[0])(params)
    return optax.global_norm(grads)
