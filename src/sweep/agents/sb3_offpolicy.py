"""``SB3SAC`` and ``SB3TD3``: Stable-Baselines3's SAC and TD3, unchanged, implementing the project's ``Learner`` contract.

The off-policy references (``agent=sac`` / ``agent=td3`` with ``agent.learner=sb3``): SB3's classes with
``MlpPolicy``, their own init (torch's ``nn.Linear`` default), losses, target networks and exploration; the loop drives
them a turn at a time (``sweep.agents.offpolicy``). This module is the only place that reaches into their policies and
optimizers.

Networks, by name (``networks``: the trained ones; remedies pick them by role, ``policy`` or ``value``):

* ``actor`` (role policy): SAC's ``actor.latent_pi`` MLP with the ``actor.mu`` and ``actor.log_std`` heads; TD3's
  ``actor.mu`` MLP (its last Linear the head, then tanh);
* ``critic_0``, ``critic_1`` (role value): ``critic.qf0`` and ``critic.qf1``, Q(s, a) on concat(s, a);
* their targets (``critic_target.*``, TD3's ``actor_target.*``) are not trained and not in ``parameter_arrays``:
  they follow by Polyak averaging, and ``reset_targets`` makes them copies of the networks (a reset's).
* SAC's entropy coefficient (``ent_coef: auto``): the parameter ``log_ent_coef``, with an optimizer of its own.

Optimizers, by name: ``actor``, ``critic`` (both critics) and SAC's ``ent_coef``; one learning rate drives them all, as
in SB3 (``set_learning_rate``; RECOM sets it). ``agent.policy.layer_norm`` puts a LayerNorm between each hidden Linear
and its activation in the actor and the critics (and their targets): ``LayerNormSACPolicy``, ``LayerNormTD3Policy``.
An asymmetric actor-critic (``env.observe.critic_*``: the env appends columns only the critics see) builds the actor
(and TD3's target actor) on the leading ``actor_columns``: the ``Asymmetric*Policy`` classes.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import torch
import torch.nn.functional as F
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.sac.policies import SACPolicy
from stable_baselines3.td3.policies import TD3Policy

from sweep.agents.learner import Hidden
from sweep.agents.networks import ActorColumns, Network, actor_columns, adam_kwargs, remedy_rng, with_layer_norm
from sweep.agents.offpolicy import RoundwiseLearning
from sweep.agents.sb3 import ACTIVATIONS, hidden_of
from sweep.plasticity.l2 import l2_copy, penalized
from sweep.training.records import Samples

TARGETS = ("critic_target.", "actor_target.")
GROUPS = {"policy": ("actor.",), "value": ("critic.",), "log_std": ("actor.log_std.",)}   # L2's params words


def target_of(name: str) -> str:
    """The target network's name of a trained parameter (``critic.qf0.0.weight`` -> ``critic_target.qf0.0.weight``)."""
    head, rest = name.split(".", 1)
    return f"{head}_target.{rest}"


def off_policy_networks(algorithm: str, n_hidden: int, layer_norm: bool = False) -> tuple[Network, ...]:
    """(actor, critic_0, critic_1) of SB3's SAC or TD3 ``MlpPolicy``: Sequential indices Linear[, LayerNorm], act."""
    step = 3 if layer_norm else 2

    def layers(prefix: str) -> tuple[tuple[str, ...], tuple[str | None, ...], str]:
        hidden = tuple(f"{prefix}.{step * i}" for i in range(n_hidden))
        norms = tuple(f"{prefix}.{step * i + 1}" if layer_norm else None for i in range(n_hidden))
        return hidden, norms, f"{prefix}.{step * n_hidden}"

    if algorithm == "sac":
        hidden, norms, _ = layers("actor.latent_pi")
        actor = Network("actor", hidden, norms, "actor.mu", 1.0, role="policy", init="uniform",
                        extra_heads=("actor.log_std",))
    else:
        actor = Network("actor", *layers("actor.mu"), 1.0, role="policy", init="uniform")
    critics = tuple(Network(f"critic_{k}", *layers(f"critic.qf{k}"), 1.0, role="value", init="uniform")
                    for k in range(2))
    return (actor, *critics)


def _normed_optimizer(policy, module: torch.nn.Module, lr_schedule) -> torch.optim.Optimizer:
    return policy.optimizer_class(module.parameters(), lr=lr_schedule(1), **policy.optimizer_kwargs)


class LayerNormSACPolicy(SACPolicy):
    """SB3's SAC ``MlpPolicy`` with Linear -> LayerNorm -> activation in the actor and the critics (``_build`` then the
    norms inserted, the target copied, the optimizers built over the new parameters). SB3 draws only the Linears, so
    a seed gives the Linear weights of the plain policy; ``SAC.load`` rebuilds it from the zip."""

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        self.actor.latent_pi = with_layer_norm(self.actor.latent_pi, head=False)
        _norm_critics(self.critic, self.critic_target)
        self.actor.optimizer = _normed_optimizer(self, self.actor, lr_schedule)
        self.critic.optimizer = _normed_optimizer(self, self.critic, lr_schedule)


class LayerNormTD3Policy(TD3Policy):
    """SB3's TD3 ``MlpPolicy`` with LayerNorm, as ``LayerNormSACPolicy``; the actor's output layer left alone."""

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        self.actor.mu = with_layer_norm(self.actor.mu, head=True)
        self.actor_target.mu = with_layer_norm(self.actor_target.mu, head=True)
        self.actor_target.load_state_dict(self.actor.state_dict())
        _norm_critics(self.critic, self.critic_target)
        self.actor.optimizer = _normed_optimizer(self, self.actor, lr_schedule)
        self.critic.optimizer = _normed_optimizer(self, self.critic, lr_schedule)


class _ActorReadsLeadingColumns:
    """An SB3 off-policy policy whose actor (and target actor) reads the leading ``actor_columns`` of the observation;
    the critics read all of it (their own ``FlattenExtractor``, SAC's and TD3's default)."""

    def __init__(self, *args, actor_columns: int, **kwargs) -> None:
        self.actor_columns = int(actor_columns)   # read by make_actor, inside the policy's __init__
        kwargs["share_features_extractor"] = False   # a shared one would give the critics the actor's columns
        super().__init__(*args, **kwargs)

    def _get_constructor_parameters(self) -> dict:
        return {**super()._get_constructor_parameters(), "actor_columns": self.actor_columns}

    def make_actor(self, features_extractor=None):
        return super().make_actor(ActorColumns(self.observation_space, self.actor_columns))


class AsymmetricSACPolicy(_ActorReadsLeadingColumns, SACPolicy):
    pass


class AsymmetricLayerNormSACPolicy(_ActorReadsLeadingColumns, LayerNormSACPolicy):
    pass


class AsymmetricTD3Policy(_ActorReadsLeadingColumns, TD3Policy):
    pass


class AsymmetricLayerNormTD3Policy(_ActorReadsLeadingColumns, LayerNormTD3Policy):
    pass


def _norm_critics(critic, target) -> None:
    for module in (critic, target):
        module.q_networks = [with_layer_norm(q, head=True) for q in module.q_networks]
        for k, q in enumerate(module.q_networks):
            module.add_module(f"qf{k}", q)
    target.load_state_dict(critic.state_dict())


class _OffPolicyContract(RoundwiseLearning):
    """The ``Learner`` contract on an SB3 SAC or TD3 (see the module docstring)."""

    algorithm = ""
    groups = GROUPS
    policies: dict[tuple[bool, bool], Any]   # (layer_norm, asymmetric) -> the SB3 policy class (or name)
    logged: tuple[str, ...]   # SB3's train/* keys of one train() call that a round averages

    @classmethod
    def from_config(cls, env: VecEnv, hyper: dict, net_arch: list[int], activation: str, adam_eps: float, seed: int,
                    layer_norm: bool = False):
        """The learner of ``agent.<algorithm>`` (SB3's arguments, ``round_steps``, ``action_noise_std``) and
        ``agent.policy``."""
        columns = actor_columns(env)
        kwargs = _build_kwargs(env, hyper, net_arch, activation, adam_eps, seed, cls.policies[layer_norm, columns is not None])
        if columns is not None:
            kwargs["policy_kwargs"]["actor_columns"] = columns
        model = cls(**kwargs)
        model._contract_setup(seed, len(net_arch), layer_norm, hyper.get("round_steps", 2048))
        return model

    def _train_stats(self, logged: dict[str, float]) -> dict[str, float]:
        return {k.split("/", 1)[1]: v for k, v in logged.items() if k in self.logged}

    def _contract_setup(self, seed: int, n_hidden: int, layer_norm: bool, round_steps: int) -> None:
        self.networks = off_policy_networks(self.algorithm, n_hidden, layer_norm)
        self.round_steps = int(round_steps)
        self.rng = remedy_rng(seed)
        self.step_transforms = []
        self._initial = self.parameter_arrays()

    def _excluded_save_params(self) -> list[str]:
        """Not in model.zip: the per-step remedies (the hooks hold them) and the contract's own fields."""
        return [*super()._excluded_save_params(), "step_transforms", "_named", "_named_of", "rng", "networks",
                "_initial"]

    # ---- parameters ----------------------------------------------------------------------------------
    def _trained(self) -> dict[str, torch.Tensor]:
        """Every trained parameter by name (targets excluded; SAC's ``log_ent_coef`` included)."""
        named = {n: p for n, p in self.policy.named_parameters() if not n.startswith(TARGETS)}
        if getattr(self, "log_ent_coef", None) is not None:
            named["log_ent_coef"] = self.log_ent_coef
        return named

    def parameter_arrays(self) -> dict[str, np.ndarray]:
        return {k: v.detach().numpy().copy() for k, v in self._trained().items()}

    def write_parameters(self, arrays: Mapping[str, np.ndarray]) -> None:
        params = self._trained()
        with torch.no_grad():
            for name, value in arrays.items():
                params[name].copy_(torch.as_tensor(np.asarray(value, np.float32)).reshape(params[name].shape))

    def initial_parameters(self) -> dict[str, np.ndarray]:
        return {k: v.copy() for k, v in self._initial.items()}

    def target_arrays(self) -> dict[str, np.ndarray]:
        return {k: v.detach().numpy().copy() for k, v in self.policy.state_dict().items() if k.startswith(TARGETS)}

    def reset_targets(self, names=None) -> None:
        """The target copies of the named parameters (None: every target network) become copies of them (as SB3
        builds the targets)."""
        if names is None:
            self.critic_target.load_state_dict(self.critic.state_dict())
            if hasattr(self, "actor_target"):
                self.actor_target.load_state_dict(self.actor.state_dict())
            return
        state, trained = self.policy.state_dict(), self._trained()
        with torch.no_grad():
            for name in names:
                target = target_of(name)
                if target in state:
                    state[target].copy_(trained[name])

    # ---- optimizers ----------------------------------------------------------------------------------
    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """The optimizers by name: ``actor``, ``critic`` (and SAC's ``ent_coef``)."""
        out = {"actor": self.actor.optimizer, "critic": self.critic.optimizer}
        if getattr(self, "ent_coef_optimizer", None) is not None:
            out["ent_coef"] = self.ent_coef_optimizer
        return out

    def optimizer_moments(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        states = [opt.state for opt in self.optimizers().values()]
        out = {}
        for name, p in self._trained().items():
            s = next((st[p] for st in states if p in st), {})
            zeros = np.zeros(tuple(p.shape), np.float32)
            out[name] = (s["exp_avg"].numpy().copy() if "exp_avg" in s else zeros,
                         s["exp_avg_sq"].numpy().copy() if "exp_avg_sq" in s else zeros.copy())
        return out

    def reset_optimizer_state(self) -> None:
        for opt in self.optimizers().values():
            opt.state.clear()

    def reset_optimizer(self, masks: Mapping[str, np.ndarray]) -> None:
        params, states = self._trained(), [opt.state for opt in self.optimizers().values()]
        with torch.no_grad():
            for name, mask in masks.items():
                s = next((st[params[name]] for st in states if params[name] in st), {})
                keep = torch.as_tensor(~np.asarray(mask, bool))
                for key in ("exp_avg", "exp_avg_sq"):
                    if key in s:
                        s[key].mul_(keep)

    def use_l2(self, coef: float, mode: str = "decoupled", params=("policy", "value"), biases: bool = True,
               anchor: str = "zero") -> None:
        """The actor's and the critics' optimizers with weight decay on the chosen groups (``GROUPS``: policy = the
        actor, value = the critics, log_std = SAC's log-std head), toward 0 or theta_0."""
        anchors = {k: torch.as_tensor(v) for k, v in self._initial.items()} if anchor == "init" else None
        decayed = lambda name: penalized(name, list(params), biases, GROUPS)  # noqa: E731
        named = self._trained()
        for owner in (self.actor, self.critic):
            prefix = "actor." if owner is self.actor else "critic."
            mine = [(n, p) for n, p in named.items() if n.startswith(prefix)]
            new = l2_copy(owner.optimizer, mine, coef, mode, decayed, anchors)
            new.state.update(owner.optimizer.state)   # Adam's moments and step counts carry over (none at set-up)
            owner.optimizer = new
        self.l2_decayed = sorted(n for n in named if decayed(n))
        self._hook_optimizer()

    def add_step_transform(self, transform) -> None:
        """``transform(params, torch)`` after every step of the actor's and the critics' optimizers from now on."""
        self.step_transforms.append(transform)
        self._hook_optimizer()

    def _hook_optimizer(self) -> None:
        for name in ("actor", "critic"):
            optimizer = self.optimizers()[name]
            if self.step_transforms and not getattr(optimizer, "_sweep_transforms", False):
                optimizer.register_step_post_hook(lambda opt, args, kwargs, owner=name: self._after_step(owner))
                optimizer._sweep_transforms = True

    @torch.no_grad()
    def _after_step(self, owner: str) -> None:
        """The transforms on the parameters of the optimizer that stepped (``owner``: actor or critic): SAC's actor
        loss holds the actor's weights in its graph while the critics step."""
        if getattr(self, "_named_of", None) is not self.policy:
            trained = self._trained()
            self._named = {o: {k: v for k, v in trained.items() if k.startswith(f"{o}.")} for o in ("actor", "critic")}
            self._named_of = self.policy
        named = self._named[owner]
        for transform in self.step_transforms:
            new = transform(named, torch)
            if new:
                torch._foreach_copy_([named[k] for k in new], list(new.values()))

    # ---- activations and gradients -------------------------------------------------------------------
    @torch.no_grad()
    def hidden_activations(self, obs: np.ndarray) -> dict[str, list[Hidden]]:
        """Per network, each hidden layer's (input of the activation, its output): the actor on ``obs``, the critics
        on ``obs`` and the actor's deterministic action there (the Q the actor's gradient reads)."""
        x = torch.as_tensor(np.asarray(obs, np.float32))
        actor_mlp = self.actor.latent_pi if self.algorithm == "sac" else self.actor.mu
        actions = torch.as_tensor(self.policy._predict(x, deterministic=True).numpy())
        xa = torch.cat([x, actions], dim=1)
        features = self.actor.extract_features(x, self.actor.features_extractor)   # an asymmetric actor's columns
        return {"actor": hidden_of(actor_mlp, features, head=self.algorithm != "sac"),
                **{f"critic_{k}": hidden_of(q, xa, head=True) for k, q in enumerate(self.critic.q_networks)}}

    def loss_grad_norm(self, samples: Samples) -> float:
        """Norm of the critics' TD loss gradient on ``samples`` (SB3's loss: 0.5 x the sum of the critics' MSE for
        SAC, their sum for TD3), the target from the target critics at the target policy's deterministic next action
        (no exploration noise, no entropy term: a reading that draws no random numbers)."""
        t = lambda a: torch.as_tensor(np.asarray(a, np.float32))  # noqa: E731
        obs, actions, next_obs = t(samples.observations), t(samples.actions), t(samples.next_observations)
        rewards, dones = t(samples.rewards).reshape(-1, 1), t(samples.dones).reshape(-1, 1)
        with torch.no_grad():
            target_actor = getattr(self, "actor_target", self.actor)
            next_actions = target_actor(next_obs, deterministic=True) if self.algorithm == "sac" else target_actor(next_obs)
            next_q = torch.min(torch.cat(self.critic_target(next_obs, next_actions), dim=1), dim=1, keepdim=True)[0]
            target = rewards + (1 - dones) * self.gamma * next_q
        qs = self.critic(obs, actions)
        loss = sum(F.mse_loss(q, target) for q in qs) * (0.5 if self.algorithm == "sac" else 1.0)
        params = [p for p in self.critic.parameters() if p.requires_grad]
        grads = torch.autograd.grad(loss, params, allow_unused=True)
        squares = float(sum((g ** 2).sum() for g in grads if g is not None))
        return float(np.sqrt(np.float32(squares)))

    # ---- checkpoints ---------------------------------------------------------------------------------
    def learner_state(self) -> dict[str, Any]:
        state = {"policy": self.policy.state_dict(), "rng": self.rng.bit_generator.state,
                 "optimizers": {k: opt.state_dict() for k, opt in self.optimizers().items()}}
        if getattr(self, "log_ent_coef", None) is not None:
            state["log_ent_coef"] = self.log_ent_coef.detach().clone()
        return state

    def load_learner_state(self, state: dict[str, Any]) -> None:
        """Parameters (targets too), every optimizer's state and the remedy generator; each Adam keeps the kernel this
        code built (see ``SB3PPO.load_learner_state``)."""
        self.policy.load_state_dict(state["policy"])
        if "log_ent_coef" in state:
            with torch.no_grad():
                self.log_ent_coef.copy_(state["log_ent_coef"])
        for name, optimizer in self.optimizers().items():
            fused = [group.get("fused") for group in optimizer.param_groups]
            optimizer.load_state_dict(state["optimizers"][name])
            for group, kernel in zip(optimizer.param_groups, fused):
                group["fused"] = kernel
        self.rng.bit_generator.state = state["rng"]


def _build_kwargs(env: VecEnv, hyper: dict, net_arch, activation: str, adam_eps: float, seed: int,
                  policy: Any = "MlpPolicy") -> dict:
    """SB3's constructor arguments from ``agent.<algorithm>`` (its own keys) and ``agent.policy``."""
    hyper = dict(hyper)
    hyper.pop("round_steps", None)
    noise_std = hyper.pop("action_noise_std", None)
    n_actions = env.action_space.shape[0]
    noise = NormalActionNoise(np.zeros(n_actions), np.full(n_actions, float(noise_std))) if noise_std else None
    policy_kwargs = {"net_arch": list(net_arch), "activation_fn": ACTIVATIONS[activation],
                     "optimizer_class": torch.optim.Adam, "optimizer_kwargs": adam_kwargs(adam_eps)}
    return {"policy": policy, "env": env, "policy_kwargs": policy_kwargs, "action_noise": noise, "seed": seed,
            "device": "cpu", "verbose": 0, **hyper}


class SB3SAC(_OffPolicyContract, SAC):
    algorithm = "sac"
    policies = {(False, False): "MlpPolicy", (True, False): LayerNormSACPolicy, (False, True): AsymmetricSACPolicy,
                (True, True): AsymmetricLayerNormSACPolicy}
    logged = ("train/ent_coef", "train/actor_loss", "train/critic_loss", "train/ent_coef_loss")


class SB3TD3(_OffPolicyContract, TD3):
    algorithm = "td3"
    policies = {(False, False): "MlpPolicy", (True, False): LayerNormTD3Policy, (False, True): AsymmetricTD3Policy,
                (True, True): AsymmetricLayerNormTD3Policy}
    logged = ("train/actor_loss", "train/critic_loss")

    def _train_counts(self, key: str, steps: int) -> int:
        """TD3's logged actor loss is the mean over the delayed steps of the call, one per ``policy_delay``."""
        if key != "actor_loss":
            return steps
        first = self._n_updates - steps + 1   # SB3 counts a step before its delay check
        return sum(1 for n in range(first, self._n_updates + 1) if n % self.policy_delay == 0)


__all__ = ["SB3SAC", "SB3TD3", "off_policy_networks"]
