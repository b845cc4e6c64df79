"""``SB3PPO``: Stable-Baselines3's PPO, unchanged, implementing the project's ``Learner`` contract.

The reference learner (``agent.learner=sb3``): SB3 PPO with ``MlpPolicy`` as the paper used it
(Sec. III-E: SB3 defaults, 64x64 tanh, Adam, batch 64). The contract's methods
(``sweep.agents.learner.Learner``) are what remedies, diagnostics and checkpoints call, on this learner and
on ``JaxPPO`` alike; this module is the only place that reaches into SB3's policy and optimizer.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import torch
import torch.nn.functional as F
from stable_baselines3 import PPO
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.vec_env import VecEnv

from sweep.agents.learner import Hidden
from sweep.agents.networks import actor_columns, actor_critic, adam_kwargs, policy_class, remedy_rng
from sweep.agents.onpolicy import StepwiseLearning
from sweep.plasticity.l2 import l2_optimizer
from sweep.training.records import Samples, UpdateRecord

ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}


class SB3PPO(StepwiseLearning, PPO):
    @classmethod
    def from_config(cls, env: VecEnv, ppo: dict, net_arch: list[int], activation: str, adam_eps: float,
                    seed: int, layer_norm: bool = False) -> "SB3PPO":
        policy_kwargs = {"net_arch": {"pi": list(net_arch), "vf": list(net_arch)},
                         "activation_fn": ACTIVATIONS[activation],
                         "optimizer_class": torch.optim.Adam, "optimizer_kwargs": adam_kwargs(adam_eps)}
        columns = actor_columns(env)
        if columns is not None:   # an asymmetric actor-critic (env.observe.critic_*)
            policy_kwargs["actor_columns"] = columns
        model = cls(policy_class(layer_norm, columns is not None), env, policy_kwargs=policy_kwargs, seed=seed,
                    device="cpu", verbose=0, **ppo)
        model.networks = actor_critic(len(net_arch), layer_norm)
        model.rng = remedy_rng(seed)
        model._initial = model.parameter_arrays()
        model.step_transforms = []
        return model

    def _excluded_save_params(self) -> list[str]:
        """Not in model.zip: the per-step remedies (the hooks hold them; a saved policy loads without them)."""
        return [*super()._excluded_save_params(), "step_transforms", "_named", "_named_of"]

    @property
    def minibatches_per_update(self) -> int:
        return self.n_epochs * -(-self.n_steps * self.n_envs // self.batch_size)

    # ---- one update, as a record ---------------------------------------------------------------------
    def _train_record(self) -> UpdateRecord:
        """SB3's ``PPO.train()``, unchanged; what it logs is caught by a logger of its own and returned."""
        caught = Logger(folder=None, output_formats=[])
        own, self._logger = getattr(self, "_logger", None), caught   # None: a learner not yet given one
        epochs_before = self._n_updates
        try:
            self.train()
        finally:
            if own is not None:
                self._logger = own
        v = caught.name_to_value
        return UpdateRecord(
            index=self._updates, timesteps=int(self.num_timesteps), learning_rate=float(v["train/learning_rate"]),
            clip_range=float(v["train/clip_range"]), policy_gradient_loss=float(v["train/policy_gradient_loss"]),
            value_loss=float(v["train/value_loss"]), entropy_loss=float(v["train/entropy_loss"]), loss=float(v["train/loss"]),
            approx_kl=float(v["train/approx_kl"]), clip_fraction=float(v["train/clip_fraction"]),
            explained_variance=float(v["train/explained_variance"]), epochs=self._n_updates - epochs_before,
            n_updates=int(self._n_updates), std=float(v["train/std"]) if "train/std" in v else None,
            vf_coef=float(self.vf_coef), ent_coef=float(self.ent_coef))

    # ---- parameters ----------------------------------------------------------------------------------
    def parameter_arrays(self) -> dict[str, np.ndarray]:
        return {k: v.detach().numpy().copy() for k, v in self.policy.state_dict().items()}

    def write_parameters(self, arrays: Mapping[str, np.ndarray]) -> None:
        params = dict(self.policy.named_parameters())
        with torch.no_grad():
            for name, value in arrays.items():
                params[name].copy_(torch.as_tensor(np.asarray(value, np.float32)))

    def initial_parameters(self) -> dict[str, np.ndarray]:
        return {k: v.copy() for k, v in self._initial.items()}

    def use_l2(self, coef: float, mode: str = "decoupled", params=("policy", "value"), biases: bool = True,
               anchor: str = "zero") -> None:
        anchors = {k: torch.as_tensor(v) for k, v in self._initial.items()} if anchor == "init" else None
        self.policy.optimizer = l2_optimizer(self.policy, coef, mode, tuple(params), biases, anchors)
        names = {id(p): n for n, p in self.policy.named_parameters()}
        self.l2_decayed = sorted(names[id(p)] for p in self.policy.optimizer.param_groups[0]["params"])
        self._hook_optimizer()

    # ---- per-step remedies ---------------------------------------------------------------------------
    def add_step_transform(self, transform) -> None:
        """``transform(params, torch)`` after every optimizer step from now on (a step hook on SB3's optimizer)."""
        self.step_transforms.append(transform)
        self._hook_optimizer()

    def _hook_optimizer(self) -> None:
        """Hook the transforms onto the optimizer in force (once each: L2 builds a new one)."""
        optimizer = self.policy.optimizer
        if self.step_transforms and not getattr(optimizer, "_sweep_transforms", False):
            optimizer.register_step_post_hook(lambda opt, args, kwargs: self._after_step())
            optimizer._sweep_transforms = True

    @torch.no_grad()
    def _after_step(self) -> None:
        if getattr(self, "_named_of", None) is not self.policy:   # parameters are written in place: look them up once
            self._named, self._named_of = dict(self.policy.named_parameters()), self.policy
        for transform in self.step_transforms:
            new = transform(self._named, torch)
            if new:
                torch._foreach_copy_([self._named[k] for k in new], list(new.values()))

    # ---- optimizer -----------------------------------------------------------------------------------
    def optimizer_moments(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        state = self.policy.optimizer.state
        out = {}
        for name, p in self.policy.named_parameters():
            s = state.get(p, {})
            zeros = np.zeros(tuple(p.shape), np.float32)
            out[name] = (s["exp_avg"].numpy().copy() if "exp_avg" in s else zeros,
                         s["exp_avg_sq"].numpy().copy() if "exp_avg_sq" in s else zeros.copy())
        return out

    def reset_optimizer_state(self) -> None:
        """torch's Adam creates a parameter's state (step 0, zero moments) at its first step after this."""
        self.policy.optimizer.state.clear()

    def reset_optimizer(self, masks: Mapping[str, np.ndarray]) -> None:
        params = dict(self.policy.named_parameters())
        with torch.no_grad():
            for name, mask in masks.items():
                s = self.policy.optimizer.state.get(params[name], {})
                keep = torch.as_tensor(~np.asarray(mask, bool))
                for key in ("exp_avg", "exp_avg_sq"):
                    if key in s:
                        s[key].mul_(keep)

    # ---- activations and gradients -------------------------------------------------------------------
    def hidden_activations(self, obs: np.ndarray) -> dict[str, list[Hidden]]:
        """Per network, each hidden layer's (input of the activation, its output) on ``obs``."""
        policy = self.policy
        with torch.no_grad():
            features = policy.extract_features(torch.as_tensor(obs, dtype=torch.float32))
            pi, vf = features if isinstance(features, tuple) else (features, features)   # a tuple: asymmetric
            return {"policy": hidden_of(policy.mlp_extractor.policy_net, pi),
                    "value": hidden_of(policy.mlp_extractor.value_net, vf)}

    def loss_grad_norm(self, samples: Samples) -> float:
        """Norm of the PPO loss gradient at the current parameters (ratio 1, so no clipping), as SB3 computes it."""
        t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
        obs, actions = t(samples.observations), t(samples.actions)
        advantages, returns = t(samples.advantages).flatten(), t(samples.returns).flatten()
        values, log_prob, entropy = self.policy.evaluate_actions(obs, actions)
        if self.normalize_advantage and len(advantages) > 1:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        ratio = torch.exp(log_prob - log_prob.detach())
        loss = (-(advantages * ratio).mean() + self.vf_coef * F.mse_loss(returns, values.flatten())
                - self.ent_coef * (entropy.mean() if entropy is not None else -log_prob.mean()))
        grads = torch.autograd.grad(loss, [p for p in self.policy.parameters() if p.requires_grad], allow_unused=True)
        squares = float(sum((g ** 2).sum() for g in grads if g is not None))   # a float32 value
        return float(np.sqrt(np.float32(squares)))   # exactly rounded, as XLA's; torch.sqrt is MKL's (adam_kwargs)

    # ---- checkpoints ---------------------------------------------------------------------------------
    def learner_state(self) -> dict[str, Any]:
        return {"policy": self.policy.state_dict(), "optimizer": self.policy.optimizer.state_dict(),
                "rng": self.rng.bit_generator.state}

    def load_learner_state(self, state: dict[str, Any]) -> None:
        """Parameters, Adam's moments and the remedy generator from ``state``. Adam's kernel stays the one this
        code builds (``adam_kwargs``): torch would take a checkpoint's ``fused`` too, and one written before the
        fused Adam would bring back MKL's square root for the rest of the run."""
        optimizer = self.policy.optimizer
        fused = [group.get("fused") for group in optimizer.param_groups]
        self.policy.load_state_dict(state["policy"])
        optimizer.load_state_dict(state["optimizer"])
        for group, kernel in zip(optimizer.param_groups, fused):
            group["fused"] = kernel
        if "rng" in state:
            self.rng.bit_generator.state = state["rng"]


def hidden_of(mlp: torch.nn.Sequential, x: torch.Tensor, head: bool = False) -> list[Hidden]:
    """(pre, post) of every hidden activation module of an SB3 MLP (Linear[, LayerNorm], act, ...); with ``head``, its
    last Linear (and a Tanh after it) are the output, not a hidden layer (SAC/TD3's critics, TD3's actor)."""
    modules = list(mlp)
    end = max(i for i, m in enumerate(modules) if isinstance(m, torch.nn.Linear)) if head else len(modules)
    out = []
    for i, module in enumerate(modules):
        pre = x
        x = module(x)
        if i < end and not isinstance(module, (torch.nn.Linear, torch.nn.LayerNorm)):
            out.append(Hidden(pre.numpy(), x.numpy()))
    return out
