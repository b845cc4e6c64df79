"""The actor-critic networks both learners build, described once.

SB3's ``ActorCriticPolicy`` with ``MlpPolicy``: a policy MLP and a value MLP (``net_arch`` hidden units each,
tanh or ReLU), a linear action head, a linear value head and a state-independent ``log_std``. Parameters
carry SB3's ``state_dict`` names in torch's (out, in) layout. ``agent.policy.layer_norm`` puts a LayerNorm
between each hidden Linear and its activation (Lyle et al. 2024, "Normalization and effective learning
rates in reinforcement learning"): Linear -> LayerNorm -> activation.

Initialisation (SB3's ``ortho_init``): orthogonal weights with gain sqrt(2) in the hidden layers, 0.01 in
the action head, 1 in the value head; zero biases; LayerNorm scale 1 and shift 0; log_std 0.
``fresh_parameters`` draws from exactly that distribution with a NumPy generator, which is what a remedy
that re-initialises weights (ReDo, CBP, shrink-and-perturb) needs on either learner.

A hidden unit i of layer k owns row i of ``hidden[k].weight``, entry i of ``hidden[k].bias`` (and of the
LayerNorm's scale and shift): its *incoming* weights. Column i of the next layer's weight (the next hidden
layer, or the head) holds its *outgoing* weights.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, MlpExtractor

HIDDEN_GAIN = math.sqrt(2.0)
LAYER_NORM_EPS = 1e-5  # torch.nn.LayerNorm's default


def adam_kwargs(eps: float) -> dict:
    """torch Adam's arguments wherever the project builds one (SB3's policy optimizer, the SB3 policies of the JAX
    learner, the probe; the L2 optimizers copy them): ``eps`` and ``fused=True``. The fused
    kernel takes Adam's square root with the CPU's exactly rounded instruction. The default (loop) Adam calls
    MKL's vector math for it, whose portable branch (``MKL_CBWR=COMPATIBLE``) is not exactly rounded and gave
    different weights after the first update on an AMD EPYC and an Intel Xeon (README, "Determinism")."""
    return {"eps": float(eps), "fused": True}


INITS = ("orthogonal", "uniform")
# The words a remedy's ``params`` setting takes (L2, shrink-and-perturb) -> the parameter-name prefixes of PPO's
# groups (``Learner.groups``; the off-policy learners have their own: ``sweep.agents.sb3_offpolicy.GROUPS``)
GROUPS = {
    "policy": ("mlp_extractor.policy_net.", "action_net."),
    "value": ("mlp_extractor.value_net.", "value_net."),
    "log_std": ("log_std",),
}


@dataclass(frozen=True)
class Network:
    """One trained MLP of a learner: its hidden Linear layers (with their LayerNorms) and its head(s).

    ``role`` is what remedy settings name (``networks: [policy, value]``): PPO's ``policy`` and ``value`` networks;
    an off-policy learner's actor (role policy) and each of its critics (role value). ``init`` is the distribution
    its Linear layers are drawn from: ``orthogonal`` (SB3's ``ortho_init``: gain sqrt 2 in the hidden layers,
    ``head_gain`` in the head, zero biases) or ``uniform`` (torch's ``nn.Linear`` default, which SB3's SAC and TD3
    keep: weights and biases U(-1/sqrt(fan_in), 1/sqrt(fan_in))). ``extra_heads`` read the last hidden layer beside
    ``head`` (SAC's ``log_std``)."""

    name: str                        # policy | value | actor | critic_0 | critic_1
    hidden: tuple[str, ...]          # SB3 names of the hidden Linear layers
    norms: tuple[str | None, ...]    # the LayerNorm after each hidden layer (None: no LayerNorm)
    head: str                        # action_net | value_net | actor.mu | critic.qf0.4 ...
    head_gain: float
    role: str = ""                   # policy | value ("": the name)
    init: str = "orthogonal"         # orthogonal | uniform
    extra_heads: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not self.role:
            object.__setattr__(self, "role", self.name)
        if self.init not in INITS:
            raise ValueError(f"init {self.init!r}: one of {INITS}")

    def readers(self, k: int) -> tuple[str, ...]:
        """The layers that read hidden layer k's units."""
        return (self.hidden[k + 1],) if k + 1 < len(self.hidden) else (self.head, *self.extra_heads)

    def outgoing(self, k: int) -> str:
        """The (first) layer that reads hidden layer k's units."""
        return self.readers(k)[0]

    @property
    def linears(self) -> tuple[str, ...]:
        return (*self.hidden, self.head, *self.extra_heads)

    def gain(self, layer: str) -> float:
        """The orthogonal init's gain of ``layer`` (hidden: sqrt 2; a head: ``head_gain``)."""
        return HIDDEN_GAIN if layer in self.hidden else self.head_gain


def actor_critic(n_hidden: int, layer_norm: bool = False) -> tuple[Network, Network]:
    """(policy, value) network descriptions: SB3's Sequential indices, Linear[, LayerNorm], activation."""
    step = 3 if layer_norm else 2

    def net(name: str, prefix: str, head: str, gain: float) -> Network:
        hidden = tuple(f"{prefix}.{step * i}" for i in range(n_hidden))
        norms = tuple(f"{prefix}.{step * i + 1}" if layer_norm else None for i in range(n_hidden))
        return Network(name, hidden, norms, head, gain)

    return (net("policy", "mlp_extractor.policy_net", "action_net", 0.01),
            net("value", "mlp_extractor.value_net", "value_net", 1.0))


def orthogonal(shape: tuple[int, int], gain: float, rng: np.random.Generator) -> np.ndarray:
    """A draw of ``torch.nn.init.orthogonal_`` (Saxe et al. 2014) from a NumPy generator, float32."""
    rows, cols = shape
    flat = rng.standard_normal((rows, cols))
    if rows < cols:
        flat = flat.T
    q, r = np.linalg.qr(flat)
    q *= np.sign(np.diag(r))
    if rows < cols:
        q = q.T
    return (gain * q).astype(np.float32)


def uniform_fan_in(shape: tuple[int, ...], fan_in: int, rng: np.random.Generator) -> np.ndarray:
    """A draw of torch ``nn.Linear``'s default init (``kaiming_uniform_(a=sqrt 5)`` for the weight, the same bound for
    the bias): U(-1/sqrt(fan_in), 1/sqrt(fan_in)), float32."""
    bound = 1.0 / math.sqrt(fan_in)
    return rng.uniform(-bound, bound, shape).astype(np.float32)


def fresh_rows(net: Network, layer: str, shape: tuple[int, int], k: int, rng: np.random.Generator) -> np.ndarray:
    """k rows of a fresh draw of ``layer``'s init (a unit's incoming weights). Orthogonal: for a wide or square layer,
    k rows of a Haar-orthogonal matrix are a uniform k-frame, which is what an orthogonal (k, in) draw is; a tall layer
    is drawn whole and k of its rows kept. Uniform: k independent rows."""
    rows, cols = shape
    if net.init == "uniform":
        return uniform_fan_in((k, cols), cols, rng)
    if rows <= cols:
        return orthogonal((k, cols), net.gain(layer), rng)
    return orthogonal(shape, net.gain(layer), rng)[:k]


def fresh_parameters(shapes: dict[str, tuple[int, ...]], networks: tuple[Network, ...],
                     rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every parameter drawn anew from its initial distribution (see the module docstring and ``Network.init``);
    parameters of no network (log_std, SAC's log entropy coefficient) start at 0."""
    out = {name: np.zeros(shape, np.float32) for name, shape in shapes.items()}  # biases, LN shifts, log_std
    for net in networks:
        for k, layer in enumerate(net.hidden):
            if net.norms[k]:
                out[f"{net.norms[k]}.weight"] = np.ones(shapes[f"{net.norms[k]}.weight"], np.float32)
        for layer in net.linears:
            shape = shapes[f"{layer}.weight"]
            if net.init == "uniform":
                out[f"{layer}.weight"] = uniform_fan_in(shape, shape[1], rng)
                out[f"{layer}.bias"] = uniform_fan_in(shapes[f"{layer}.bias"], shape[1], rng)
            else:
                out[f"{layer}.weight"] = orthogonal(shape, net.gain(layer), rng)
    return out


def remedy_rng(seed: int) -> np.random.Generator:
    """The generator a learner hands its remedies: a stream of its own, apart from every global RNG."""
    return np.random.default_rng([int(seed), 0x5EED])


# ---- torch: SB3's policy with LayerNorm in the hidden layers -----------------------------------------------
def with_layer_norm(mlp: torch.nn.Sequential, head: bool = False) -> torch.nn.Sequential:
    """Linear -> LayerNorm -> activation for every hidden Linear; with ``head`` the last Linear is the output layer
    (SAC/TD3's critics, TD3's actor) and is left alone (PPO's MLPs and SAC's ``latent_pi`` have no head inside)."""
    last = max(i for i, m in enumerate(mlp) if isinstance(m, torch.nn.Linear))
    modules = []
    for i, module in enumerate(mlp):
        modules.append(module)
        if isinstance(module, torch.nn.Linear) and not (head and i == last):
            modules.append(torch.nn.LayerNorm(module.out_features, eps=LAYER_NORM_EPS))
    return torch.nn.Sequential(*modules)


class LayerNormMlpExtractor(MlpExtractor):
    """SB3's ``MlpExtractor`` with Linear -> LayerNorm -> activation in both networks."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.policy_net = with_layer_norm(self.policy_net)
        self.value_net = with_layer_norm(self.value_net)


class LayerNormActorCriticPolicy(ActorCriticPolicy):
    """``MlpPolicy`` with LayerNorm (``agent.policy.layer_norm=true``). SB3's orthogonal init touches only the
    Linear layers and LayerNorm draws no random numbers, so the same seed gives the same Linear weights."""

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = LayerNormMlpExtractor(self.features_dim, net_arch=self.net_arch,
                                                   activation_fn=self.activation_fn, device=self.device)


class ActorColumns(BaseFeaturesExtractor):
    """The leading ``columns`` of the observation: what the actor of an asymmetric actor-critic reads (the env appends
    the critic's own columns after them: ``HoverVecEnv.actor_columns``)."""

    def __init__(self, observation_space: spaces.Box, columns: int) -> None:
        super().__init__(observation_space, int(columns))
        self.columns = int(columns)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return observations[..., :self.columns]


class AsymmetricActorCriticPolicy(ActorCriticPolicy):
    """``MlpPolicy`` whose policy network reads the leading ``actor_columns`` of the observation and whose value network
    reads all of it (``env.observe.critic_*``). The same init: SB3's orthogonal draw, the policy MLP's first layer
    narrower."""

    layer_norm = False

    def __init__(self, *args, actor_columns: int, **kwargs) -> None:
        self.actor_columns = int(actor_columns)   # read by _build_mlp_extractor, inside ActorCriticPolicy.__init__
        kwargs["share_features_extractor"] = False
        super().__init__(*args, **kwargs)

    def _get_constructor_parameters(self) -> dict:
        return {**super()._get_constructor_parameters(), "actor_columns": self.actor_columns}

    def _build_mlp_extractor(self) -> None:
        self.pi_features_extractor = ActorColumns(self.observation_space, self.actor_columns)
        extractor = LayerNormMlpExtractor if self.layer_norm else MlpExtractor
        self.mlp_extractor = extractor(self.features_dim, net_arch=self.net_arch, activation_fn=self.activation_fn,
                                       device=self.device)
        self.mlp_extractor.policy_net = extractor(self.actor_columns, net_arch=self.net_arch,
                                                  activation_fn=self.activation_fn, device=self.device).policy_net


class AsymmetricLayerNormActorCriticPolicy(AsymmetricActorCriticPolicy):
    """``AsymmetricActorCriticPolicy`` with LayerNorm in both networks."""

    layer_norm = True


def policy_class(layer_norm: bool, asymmetric: bool = False):
    """The SB3 policy (class or name) of an actor-critic with or without LayerNorm, and with an actor that reads only
    the leading ``actor_columns`` (``asymmetric``; the class then takes ``actor_columns`` in its policy_kwargs)."""
    if asymmetric:
        return AsymmetricLayerNormActorCriticPolicy if layer_norm else AsymmetricActorCriticPolicy
    return LayerNormActorCriticPolicy if layer_norm else "MlpPolicy"


def actor_columns(env) -> int | None:
    """The observation columns an asymmetric actor reads (``HoverVecEnv.actor_columns``), or None when the actor reads
    them all (the critic sees nothing more)."""
    columns = getattr(env, "actor_columns", None)
    return None if columns is None or columns == env.observation_space.shape[0] else int(columns)
