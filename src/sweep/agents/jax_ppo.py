"""``JaxPPO``: SB3's PPO, compiled. The update runs in JAX, the rollout in numba (``sweep.agents.rollout``).

Same algorithm, hyperparameters and logged names as ``stable_baselines3.PPO`` with ``MlpPolicy``
(tests/test_jax_learner.py holds them together):

* networks: separate policy and value MLPs (``net_arch``, tanh or ReLU), a linear action head, a linear
  value head and a state-independent ``log_std`` (starting at 0); parameters carry SB3's ``state_dict``
  names and torch's (out, in) layout. Initial weights are those SB3's ``ActorCriticPolicy`` draws for
  the same seed (orthogonal, gains sqrt(2) / 0.01 / 1, zero biases): built once with torch and copied.
* rollout: SB3's ``collect_rollouts`` (Gaussian actions, clipped only for the env, timeout bootstrap,
  GAE(lambda)), compiled for the hover env.
* update, one jitted call per rollout: ``n_epochs`` epochs over minibatches of ``batch_size`` drawn
  with ``np.random.permutation`` (SB3's order and RNG), in a ``lax.scan``; per minibatch the advantages
  are normalised (Bessel-corrected std, as torch), the loss is the clipped surrogate + ``vf_coef`` x the
  unclipped value MSE + ``ent_coef`` x the entropy loss, the gradient is clipped to a global norm of
  ``max_grad_norm`` and Adam (torch's defaults, ``eps`` from the config) takes the step.
* the learning rate is an argument of that call, read from ``lr_schedule`` before every update as SB3
  does, so RECOM's ``AdaptiveLR`` drives it unchanged; L2 (``use_l2``) is the same coupled
  (Adam ``weight_decay``) or decoupled (AdamW) decay on the same parameters.

It subclasses SB3's ``OnPolicyAlgorithm``, so ``learn()``, the logger, ``rollout/*`` and ``time/*``
metrics, the episode buffer and every callback hook are SB3's own. One difference: callbacks'
``on_step`` runs once per compiled chunk of steps (a chunk ends where an episode ends, or at the end of
the rollout), with ``locals["infos"]`` of the chunk's last step, so every finished episode is seen.

Only the fast backend can be stepped from the compiled rollout (``env.backend=fast``).
"""
from __future__ import annotations

import os
from pathlib import Path

# One CPU thread (as torch: train.torch_threads; see _jax_cpu_client_on_one_thread), and compiled programs cached across runs (~3 s per job).
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(Path.home() / ".cache" / "sweep" / "jax"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

import math  # noqa: E402
from functools import partial  # noqa: E402
from typing import Any  # noqa: E402

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
from sweep.plasticity.l2 import penalized  # noqa: E402

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

TORCH_ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}
Params = dict[str, jax.Array]


# ------------------------------------------------------------------------------------------------
# The networks and the PPO loss, in SB3's terms (parameter names = ActorCriticPolicy.state_dict keys)
# ------------------------------------------------------------------------------------------------
def layer_names(prefix: str, n_hidden: int, head: str) -> list[str]:
    """SB3 names of one network's Linear layers: ``<prefix>.0``, ``<prefix>.2``, ..., then the head."""
    return [f"{prefix}.{2 * i}" for i in range(n_hidden)] + [head]


def mlp_forward(params: Params, names: list[str], x: jax.Array, act) -> tuple[jax.Array, list[jax.Array]]:
    """(output, hidden activations) of an SB3 MLP + head: Linear (x W^T + b) and ``act`` between layers."""
    hidden = []
    for name in names[:-1]:
        x = act(x @ params[f"{name}.weight"].T + params[f"{name}.bias"])
        hidden.append(x)
    head = names[-1]
    return x @ params[f"{head}.weight"].T + params[f"{head}.bias"], hidden


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


class JaxPPO(OnPolicyAlgorithm):
    """PPO with SB3's semantics; see the module docstring. Keyword arguments are SB3 PPO's."""

    def __init__(self, env: VecEnv, *, learning_rate: float = 3e-4, n_steps: int = 2048, batch_size: int = 64,
                 n_epochs: int = 10, gamma: float = 0.99, gae_lambda: float = 0.95, clip_range: float = 0.2,
                 ent_coef: float = 0.0, vf_coef: float = 0.5, max_grad_norm: float = 0.5,
                 normalize_advantage: bool = True, net_arch: tuple[int, ...] = (64, 64), activation: str = "tanh",
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
        self.net_arch, self.activation, self.adam_eps = tuple(int(h) for h in net_arch), activation, float(adam_eps)
        self.l2_spec: dict[str, Any] | None = None
        self._setup_model()

    @classmethod
    def from_config(cls, env: VecEnv, ppo: dict, net_arch: list[int], activation: str, adam_eps: float,
                    seed: int) -> "JaxPPO":
        return cls(env, **ppo, net_arch=net_arch, activation=activation, adam_eps=adam_eps, seed=seed)

    # ---- construction ---------------------------------------------------------------------------
    def torch_policy(self) -> ActorCriticPolicy:
        """An SB3 ``ActorCriticPolicy`` of this architecture (its parameters are SB3's initial draw)."""
        arch = list(self.net_arch)
        return ActorCriticPolicy(self.observation_space, self.action_space, self.lr_schedule,
                                 net_arch={"pi": arch, "vf": arch},
                                 activation_fn=TORCH_ACTIVATIONS[self.activation],
                                 optimizer_kwargs={"eps": self.adam_eps})

    def _setup_model(self) -> None:
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)  # as SB3 PPO: the same seed draws the same initial weights
        self.rollout_buffer = RolloutBuffer(self.n_steps, self.observation_space, self.action_space, device="cpu",
                                            gamma=self.gamma, gae_lambda=self.gae_lambda, n_envs=self.n_envs)
        self.policy = None  # no torch policy; ``to_sb3`` builds one
        self.clip_range_schedule = FloatSchedule(self.clip_range)
        n_hidden = len(self.net_arch)
        self._nets = (layer_names("mlp_extractor.policy_net", n_hidden, "action_net"),
                      layer_names("mlp_extractor.value_net", n_hidden, "value_net"))
        self._act = ACTIVATIONS[self.activation]
        self.params: Params = {k: jnp.asarray(v.numpy()) for k, v in self.torch_policy().state_dict().items()}
        self.noise_rng = np.random.default_rng(self.seed)
        self._build_optimizer()

    def _build_optimizer(self) -> None:
        """Adam (torch's betas, ``adam_eps``) after SB3's global-norm clip, with L2 if ``use_l2`` set it."""
        l2 = self.l2_spec or {"coef": 0.0, "mode": "coupled", "params": (), "biases": True}
        mask = {k: bool(l2["coef"]) and penalized(k, list(l2["params"]), l2["biases"]) for k in self.params}
        self.l2_decayed = sorted(k for k, on in mask.items() if on)
        coupled = l2["coef"] if l2["mode"] == "coupled" else 0.0
        decoupled = l2["coef"] if l2["mode"] == "decoupled" else 0.0
        transforms = [optax.clip_by_global_norm(self.max_grad_norm)]
        if coupled:  # torch Adam(weight_decay): g <- g + coef * theta, before the moments
            transforms.append(optax.add_decayed_weights(coupled, mask=mask))
        transforms.append(optax.scale_by_adam(b1=0.9, b2=0.999, eps=self.adam_eps))
        self._tx = optax.chain(*transforms)
        self.opt_state = self._tx.init(self.params)
        self._update = jax.jit(partial(
            _update, tx=self._tx, decay=decoupled, mask=mask, n_epochs=self.n_epochs, batch_size=self.batch_size,
            ent_coef=float(self.ent_coef), vf_coef=float(self.vf_coef), nets=self._nets, act=self._act,
            normalize_advantage=self.normalize_advantage))
        self._activations = jax.jit(partial(_hidden, nets=self._nets, act=self._act))
        self._grad_norm = jax.jit(partial(_grad_norm, nets=self._nets, act=self._act, ent_coef=float(self.ent_coef),
                                          vf_coef=float(self.vf_coef), normalize_advantage=self.normalize_advantage))
        self._export_weights()

    def use_l2(self, coef: float, mode: str = "coupled", params=("policy", "value"), biases: bool = True) -> None:
        """L2 regularization (``sweep.plasticity.l2``): rebuilds the optimizer with the decay."""
        self.l2_spec = {"coef": float(coef), "mode": mode, "params": tuple(params), "biases": bool(biases)}
        self._build_optimizer()

    def _export_weights(self) -> None:
        """numba's copy of the networks: per layer (in, out) float32 weights, biases, and log_std."""
        host = {k: np.array(v, dtype=np.float32) for k, v in self.params.items()}  # writable copies

        def layers(names):
            return (tuple(np.ascontiguousarray(host[f"{n}.weight"].T) for n in names),
                    tuple(np.ascontiguousarray(host[f"{n}.bias"]) for n in names))
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
        wind = env.wind.velocities(env.global_step + n * np.arange(n_rollout_steps))
        args = env.kernel_args
        t = 0
        while t < n_rollout_steps:
            t_next = rollout.fly(t, n_rollout_steps, obs, episode_starts, dones, noise, wind, *self._pi, *self._vf,
                                 self._log_std, self._relu, self.gamma, buf.observations, buf.actions, buf.rewards,
                                 buf.episode_starts, buf.values, buf.log_probs, *args)
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
        rollout.values_of(obs, *self._vf, self._relu, last_values)
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
        lr = float(self.lr_schedule(self._current_progress_remaining))
        self.logger.record("train/learning_rate", lr)
        clip_range = float(self.clip_range_schedule(self._current_progress_remaining))
        batch = self.rollout_batch()
        values = batch.pop("values")
        size = len(batch["advantages"])
        order = np.stack([np.random.permutation(size) for _ in range(self.n_epochs)])  # SB3's draws
        self.params, self.opt_state, stats = self._update(self.params, self.opt_state, batch, order, lr, clip_range)
        self._export_weights()
        self._n_updates += self.n_epochs
        pg, vf, ent, clip_frac, kl, loss = (np.asarray(s) for s in stats)
        per_epoch = size // self.batch_size
        self.logger.record("train/entropy_loss", float(ent.mean()))
        self.logger.record("train/policy_gradient_loss", float(pg.mean()))
        self.logger.record("train/value_loss", float(vf.mean()))
        self.logger.record("train/approx_kl", float(kl[-per_epoch:].mean()))  # SB3: the last epoch's
        self.logger.record("train/clip_fraction", float(clip_frac.mean()))
        self.logger.record("train/loss", float(loss[-1]))  # SB3: the last minibatch's
        self.logger.record("train/explained_variance", explained_variance(values, batch["returns"]))
        self.logger.record("train/std", float(np.exp(self._log_std).mean()))
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/clip_range", clip_range)

    # ---- what the rest of the project asks of a learner -------------------------------------------
    def predict(self, observation, state=None, episode_start=None, deterministic: bool = False):
        obs = np.ascontiguousarray(np.atleast_2d(observation), dtype=np.float32)
        mean = np.empty((len(obs), self.action_space.shape[0]), np.float32)
        rollout.actions_of(obs, *self._pi, self._relu, mean)
        if not deterministic:
            mean = mean + np.exp(self._log_std) * self.noise_rng.standard_normal(mean.shape, dtype=np.float32)
        return np.clip(mean, -1.0, 1.0), state

    def parameter_arrays(self) -> dict[str, np.ndarray]:
        return {k: np.array(v) for k, v in self.params.items()}  # copies

    def hidden_activations(self, obs: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Hidden-layer activations of the policy and of the value network on ``obs``."""
        pi_hidden, vf_hidden = self._activations(self.params, np.asarray(obs, np.float32))
        return [np.asarray(h) for h in pi_hidden], [np.asarray(h) for h in vf_hidden]

    def loss_grad_norm(self, obs, actions, advantages, returns) -> float:
        """Norm of the PPO loss gradient at the current parameters (ratio 1), before clipping."""
        batch = {"observations": obs, "actions": actions, "advantages": advantages, "returns": returns}
        return float(self._grad_norm(self.params, {k: np.asarray(v, np.float32) for k, v in batch.items()}))

    def learner_state(self) -> dict[str, Any]:
        return {"params": self.parameter_arrays(), "opt_state": jax.tree.map(np.asarray, self.opt_state),
                "noise_rng": self.noise_rng.bit_generator.state}

    def load_learner_state(self, state: dict[str, Any], optimizer: bool = True) -> None:
        self.params = {k: jnp.asarray(v) for k, v in state["params"].items()}
        self._export_weights()
        if optimizer:
            self.opt_state = jax.tree.map(jnp.asarray, state["opt_state"])
            self.noise_rng.bit_generator.state = state["noise_rng"]

    def to_sb3(self) -> PPO:
        """An SB3 ``PPO`` with this learner's weights (``PPO.load``-able once saved)."""
        arch = list(self.net_arch)
        model = PPO("MlpPolicy", self.env, learning_rate=self.learning_rate, n_steps=self.n_steps,
                    batch_size=self.batch_size, n_epochs=self.n_epochs, gamma=self.gamma, gae_lambda=self.gae_lambda,
                    clip_range=self.clip_range, ent_coef=self.ent_coef, vf_coef=self.vf_coef,
                    max_grad_norm=self.max_grad_norm, device="cpu",
                    policy_kwargs={"net_arch": {"pi": arch, "vf": arch},
                                   "activation_fn": TORCH_ACTIVATIONS[self.activation],
                                   "optimizer_kwargs": {"eps": self.adam_eps}})
        model.policy.load_state_dict({k: torch.as_tensor(v) for k, v in self.parameter_arrays().items()})
        model.num_timesteps = self.num_timesteps
        return model

    def save(self, path, exclude=None, include=None) -> None:
        """Saved as an SB3 PPO zip, so ``stable_baselines3.PPO.load`` reads a JAX run's model too."""
        self.to_sb3().save(path)


# ------------------------------------------------------------------------------------------------
# Jitted functions (module level so the partials above only bind static settings)
# ------------------------------------------------------------------------------------------------
def _update(params, opt_state, batch, order, lr, clip_range, *, tx, decay, mask, n_epochs, batch_size,
            ent_coef, vf_coef, nets, act, normalize_advantage):
    """``n_epochs`` x (rollout / batch_size) minibatch steps in one ``lax.scan``; returns per-step stats."""
    grad_fn = jax.value_and_grad(ppo_loss, has_aux=True)

    def step(carry, idx):
        params, opt_state = carry
        mb = {k: v[idx] for k, v in batch.items()}
        (loss, aux), grads = grad_fn(params, mb, clip_range, ent_coef, vf_coef, nets, act, normalize_advantage)
        updates, opt_state = tx.update(grads, opt_state, params)
        # decoupled (AdamW) decay first, as torch does: theta <- theta * (1 - lr * coef) - lr * adam_update
        shrunk = {k: params[k] * (1.0 - lr * decay) if decay and mask[k] else params[k] for k in params}
        return ({k: shrunk[k] - lr * updates[k] for k in params}, opt_state), (*aux, loss)

    minibatches = order.reshape(-1, batch_size)
    (params, opt_state), stats = jax.lax.scan(step, (params, opt_state), minibatches)
    return params, opt_state, stats


def _hidden(params, obs, *, nets, act):
    """Hidden activations of the policy and of the value network."""
    return mlp_forward(params, nets[0], obs, act)[1], mlp_forward(params, nets[1], obs, act)[1]


def _grad_norm(params, batch, *, nets, act, ent_coef, vf_coef, normalize_advantage):
    """Global norm of the PPO loss gradient with the rollout policy = the current one (ratio 1)."""
    mean, _ = mlp_forward(params, nets[0], batch["observations"], act)
    old = jax.lax.stop_gradient(gaussian_log_prob(batch["actions"], mean, params["log_std"]))
    grads = jax.grad(lambda p: ppo_loss(p, {**batch, "old_log_prob": old}, 0.2, ent_coef, vf_coef, nets, act,
                                        normalize_advantage)[0])(params)
    return optax.global_norm(grads)
