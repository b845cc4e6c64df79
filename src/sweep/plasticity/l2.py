"""L2 regularization for PPO (paper Sec. III-E): decay toward 0, or toward theta_0 (``anchor``, L2-Init).

``coupled``: Adam(weight_decay=coef) adds coef*theta to the gradient, i.e. the gradient of an explicit
penalty (coef/2)*||theta||^2 on the loss, before Adam's normalisation. ``decoupled``: AdamW (weight
decay applied outside Adam's moments). ``params`` chooses the penalized networks (policy = actor MLP +
action head, value = critic MLP + value head, log_std = the Gaussian's log std) and ``biases`` whether
bias vectors are included; everything else sits in a second param group with weight_decay 0.
Adam's eps, betas and kernel (fused) are copied from SB3's optimizer, so the only difference from plain PPO is L2.

``anchor=init`` (``sweep.plasticity.l2_init``) pulls toward the initial parameters theta_0 instead of 0: the
penalty (coef/2)*||theta - theta_0||^2, coupled (g += coef*(theta - theta_0)) or decoupled
(theta -= lr*coef*(theta - theta_0) before Adam's step, as AdamW orders it).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, List

import torch
from hydra.utils import get_class
from stable_baselines3.common.policies import ActorCriticPolicy

from sweep.agents.networks import GROUPS
from sweep.config import (MISSING, ConfigError, HookSettings, algorithm_of, choice, non_empty, non_negative,
                          remedy_blocks, runs)
from sweep.training.hooks import Hook


ParamGroup = choice("ParamGroup", *GROUPS)   # the words a remedy's ``params`` setting takes
DecayMode = choice("DecayMode", "coupled", "decoupled")


def params_key() -> Any:
    return non_empty(f"a non-empty subset of [{', '.join(ParamGroup.__members__)}]")


def penalized(name: str, params: list[str], biases: bool, groups: dict[str, tuple[str, ...]] = GROUPS) -> bool:
    """Whether L2 acts on parameter ``name``: it belongs to one of the ``params`` groups (``groups``: the learner's
    prefixes of each; PPO's are ``GROUPS``) and is not a bias unless ``biases``."""
    if not biases and name.endswith("bias"):
        return False
    return any(name.startswith(prefix) for group in params for prefix in groups.get(group, ()))


class AnchoredAdam(torch.optim.Adam):
    """Adam whose param groups may carry ``anchors`` (theta_0), ``anchor_coef`` and ``anchor_mode``: L2 toward
    the anchors, coupled (added to the gradient before the moments) or decoupled (applied to the parameters
    before Adam's step)."""

    @torch.no_grad()
    def step(self, closure=None):
        for group in self.param_groups:
            coef = group.get("anchor_coef", 0.0)
            for p, p0 in zip(group["params"], group.get("anchors", ())) if coef else ():
                if group["anchor_mode"] == "coupled":
                    if p.grad is not None:
                        p.grad.add_(p - p0, alpha=coef)
                else:
                    p.sub_(p - p0, alpha=group["lr"] * coef)
        return super().step(closure)


def l2_optimizer(policy: ActorCriticPolicy, coef: float, mode: str = "decoupled",
                 params: tuple[str, ...] = ("policy", "value"), biases: bool = True,
                 anchors: dict[str, torch.Tensor] | None = None) -> torch.optim.Optimizer:
    """A copy of ``policy.optimizer`` (same lr, betas, eps, kernel) with weight decay on the chosen parameters, toward 0
    or, given ``anchors`` (name -> theta_0), toward them."""
    return l2_copy(policy.optimizer, policy.named_parameters(), coef, mode,
                   lambda name: penalized(name, list(params), biases), anchors)


def l2_copy(optimizer: torch.optim.Optimizer, named_parameters, coef: float, mode: str, decayed,
            anchors: dict[str, torch.Tensor] | None = None) -> torch.optim.Optimizer:
    """A copy of the Adam ``optimizer`` of ``named_parameters`` (same lr, betas, eps, kernel; a fresh state) with weight
    decay on the parameters whose name ``decayed(name)`` accepts, toward 0 or, given ``anchors`` (name -> theta_0),
    toward them."""
    old = optimizer.param_groups[0]
    decay, rest, names = [], [], []
    for name, p in named_parameters:
        if decayed(name):
            decay.append(p)
            names.append(name)
        else:
            rest.append(p)
    kwargs = {"lr": old["lr"], "betas": old["betas"], "eps": old["eps"], "fused": old.get("fused")}
    if anchors is not None:
        group = {"params": decay, "anchors": [anchors[n].detach().clone() for n in names], "anchor_coef": coef,
                 "anchor_mode": mode}
        new = AnchoredAdam([group, {"params": rest}], **kwargs)
    else:
        cls = torch.optim.Adam if mode == "coupled" else torch.optim.AdamW
        new = cls([{"params": decay, "weight_decay": coef}, {"params": rest, "weight_decay": 0.0}], **kwargs)
    return new


@dataclass
class WeightDecaySettings(HookSettings):   # conf/remedy/l2.yaml, l2_init.yaml
    coef: float = non_negative()
    mode: DecayMode = MISSING
    params: List[ParamGroup] = params_key()
    biases: bool = MISSING


class L2Regularization(Hook):
    """Switches the learner's L2 on when training starts (SB3: ``l2_optimizer``; JAX: the same decay in
    its optax chain, ``sweep.agents.jax_ppo``)."""

    Settings = WeightDecaySettings
    anchor = "zero"

    @classmethod
    def check_config(cls, where: str, settings: dict, cfg: dict) -> None:
        """One weight decay per run: L2 and L2-Init both set the optimizer's decay; ``log_std`` only where there is
        one (PPO's parameter, SAC's head; TD3's actor is deterministic)."""
        if "log_std" in settings["params"] and algorithm_of(cfg["agent"]) == "td3":
            raise ConfigError(f"{where}.params={settings['params']!r}: must leave out log_std with TD3 (a deterministic "
                              "actor: no log_std)")
        others = [f"agent.{k}" for k, v in remedy_blocks(cfg["agent"]).items() if runs(v) and f"agent.{k}" != where
                  and issubclass(get_class(v["_target_"]), L2Regularization)]
        if others:
            raise ConfigError(f"{where}.enabled=True and {others[0]}.enabled=True: must be one of them (both set the "
                              "optimizer's weight decay; L2 pulls toward 0, L2-Init toward theta_0)")

    def __init__(self, coef: float = 1e-3, mode: str = "decoupled", params=("policy", "value"), biases: bool = True):
        self.coef, self.mode, self.params, self.biases = float(coef), mode, tuple(params), bool(biases)

    def setup(self, learner, training) -> None:
        learner.use_l2(self.coef, self.mode, self.params, self.biases, anchor=self.anchor)
