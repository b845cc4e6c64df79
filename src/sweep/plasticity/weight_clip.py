"""Weight clipping (Elsayed, Lan, Lyle & Mahmood 2024, "Weight clipping for deep continual and reinforcement
learning", RLC 2024): after every optimizer step, each weight and bias of the chosen networks is clipped,

    theta_l <- clip(theta_l, -kappa * s_l, kappa * s_l),    s_l = 1 / sqrt(fan_in of layer l)

s_l is the bound of the layer's initialisation distribution as the authors take it (torch's default ``nn.Linear``
init, Kaiming-uniform, U(-1/sqrt(fan_in), 1/sqrt(fan_in)), for the weights and the biases of a layer alike). It is
not this project's init: SB3 draws orthogonal weights (gain sqrt(2) in the hidden layers, 0.01 and 1 in the heads),
whose hidden weights reach past 1/sqrt(fan_in); kappa = 2 clips about a sixth of the 64 x 64 layer's initial weights
at the first step. The output layers are clipped only with ``heads`` (the authors' ``clip_last_layer``): a clipped
value head bounds |V| by about 8 kappa (64 tanh units x kappa/8 + the bias), against discounted returns of about -150
to -450 here, and PPO then learns no value at all (explained variance 0; docs/calibration.md#weight-clip measures kappa and heads).
LayerNorm's scale and shift and ``log_std`` are not clipped (the authors' networks have no LayerNorm; a scale
initialised at 1 would be cut to kappa/sqrt(64) at once).

A per-step remedy (``Learner.add_step_transform``): the clip runs inside every update, after each Adam step, on
both learners, so the final policy is within the bounds too. Every ``log_every_updates`` updates it logs
``remedy/weight_clip/at_bound``: the share of the clipped parameters' entries that sit at their bound.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, List, Mapping

import numpy as np

from sweep.agents.learner import Learner
from sweep.config import MISSING, HookSettings, positive
from sweep.metrics import Curve
from sweep.plasticity.remedy import NETWORKS, NetworkName, Remedy, every_updates_key, networks_key

AT_CLIP_BOUND = "remedy/weight_clip/at_bound"


@dataclass
class WeightClipSettings(HookSettings):   # conf/remedy/weight_clip.yaml
    kappa: float = positive(" (times each layer's init bound 1/sqrt(fan_in))")
    networks: List[NetworkName] = networks_key()
    heads: bool = MISSING
    log_every_updates: int = every_updates_key()


def init_bounds(learner: Learner, networks: tuple[str, ...], heads: bool = True) -> dict[str, float]:
    """s_l = 1/sqrt(fan_in) for the weight and the bias of every Linear layer of ``networks``: the hidden layers, and
    the output layers (action and value head) if ``heads``."""
    shapes = {k: v.shape for k, v in learner.initial_parameters().items()}
    bounds = {}
    for net in learner.networks:
        if net.role in networks:
            for layer in net.linears if heads else net.hidden:
                s = 1.0 / math.sqrt(shapes[f"{layer}.weight"][1])
                bounds[f"{layer}.weight"] = bounds[f"{layer}.bias"] = s
    return bounds


class WeightClip(Remedy):
    Settings = WeightClipSettings
    name = "weight_clip"
    curves = (Curve(AT_CLIP_BOUND, "Weights at the\nclip bound (%)", "weight_clip", 100.0, percent=True,
                    final="final_weights_at_bound", title="Final at clip bound (%)"),)

    def __init__(self, kappa: float = 2.0, networks=NETWORKS, heads: bool = False, log_every_updates: int = 1) -> None:
        super().__init__(every_updates=log_every_updates)   # act() only logs: the clip acts at every step
        self.kappa, self.networks, self.heads = float(kappa), tuple(networks), bool(heads)
        self.bounds: dict[str, float] = {}

    def setup(self, learner: Learner, training) -> None:
        self.bounds = {k: self.kappa * s for k, s in init_bounds(learner, self.networks, self.heads).items()}
        learner.add_step_transform(self.clip)

    def clip(self, params: Mapping[str, Any], xp: Any) -> dict[str, Any]:
        """The step transform: every clipped parameter of those just stepped within +-kappa s_l (``xp``: torch or
        jax.numpy)."""
        return {name: xp.clip(params[name], -bound, bound) for name, bound in self.bounds.items() if name in params}

    def act(self, learner: Learner, observations: np.ndarray | None) -> dict[str, float]:
        theta = learner.parameter_arrays()
        at = sum(int((np.abs(theta[k]) >= np.float32(b)).sum()) for k, b in self.bounds.items())
        return {"at_bound": at / sum(theta[k].size for k in self.bounds)}
