"""What one rollout and one update return: typed records, the only messages between a learner and the hooks.

PureJaxRL's update returns its metrics; here both learners do the same (``Learner.collect`` and
``Learner.update``, tests/test_learner.py), and a hook reads what it needs from the record instead of from a
logger. ``UpdateRecord.metrics()`` (PPO) and ``OffPolicyUpdate.metrics()`` (SAC, TD3) are what the loop logs under
``train/``: the names and values SB3's ``PPO.train`` / ``SAC.train`` / ``TD3.train`` log. Both records have what a hook
may read of any algorithm: ``index``, ``timesteps``, ``learning_rate``, ``n_updates``, ``loss`` (the NaN guard's) and
``mean_loss`` (RECOM's); the rest is the algorithm's own.
"""
from __future__ import annotations

import math

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


class Episode(NamedTuple):
    """One episode that finished in a rollout: its return (task units), length in steps, and whether it crashed."""

    ret: float
    length: int
    crashed: bool


class Samples(NamedTuple):
    """The most recent steps of a rollout or of the replay buffer (``Learner.recent_samples``): what diagnostics and
    remedies read. PPO fills the advantages and returns; an off-policy learner the rewards, next observations and
    dones (0 at a truncation, as SB3's replay samples)."""

    observations: np.ndarray
    actions: np.ndarray
    advantages: np.ndarray | None = None
    returns: np.ndarray | None = None
    rewards: np.ndarray | None = None
    next_observations: np.ndarray | None = None
    dones: np.ndarray | None = None


@dataclass(frozen=True)
class Condition:
    """The condition the vehicles flew under at the end of a rollout: the segment count on the run's clock
    (``sweep.envs.hover.segment_count``), the mean wind (world-frame m/s), its gusts' sigma, the vehicle's mass factor and each rotor's
    thrust efficiency (``sweep.envs.vehicle.VehicleSegment``)."""

    segment: int
    wind: tuple[float, float, float]
    mass: float = 1.0
    rotor_efficiency: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)
    gust: float = 0.0  # Dryden sigma of the turbulence on top of the wind (RotorPy's sig_wind; 0: calm)

    @property
    def wind_speed(self) -> float:
        return math.sqrt(sum(c * c for c in self.wind))

    def metrics(self) -> dict[str, float]:
        """The condition as ``env/*`` metrics: segment, wind speed and vector, gust sigma, mass factor, rotor
        efficiencies."""
        out = {"env/segment": float(self.segment), "env/wind_speed": self.wind_speed,
               **{f"env/wind_{a}": c for a, c in zip("xyz", self.wind)}, "env/gust_sigma": self.gust,
               "env/mass_factor": self.mass}
        out.update({f"env/rotor_efficiency_{i + 1}": e for i, e in enumerate(self.rotor_efficiency)})
        return out


@dataclass(frozen=True)
class RolloutRecord:
    """One rollout: the timesteps after it, the episodes it finished (in the order they ended), SB3's mean return
    of the last 100 finished episodes (``rollout/ep_rew_mean``; None before the first), and the condition at its end."""

    index: int
    timesteps: int
    episodes: tuple[Episode, ...]
    mean_recent_return: float | None
    condition: Condition | None   # None only inside an off-policy round
    ends_round: bool = True   # off-policy: False for the collects inside a round (no hooks, no log line, no episodes,
                              # no condition: the loop reads only this; the round's last collect has them all)


@dataclass(frozen=True)
class UpdateRecord:
    """One PPO update (all its epochs): the learning rate and clip range in force, the loss terms as means over
    the minibatches that ran, the total loss of the last minibatch (SB3's ``train/loss``), approx KL (the last
    epoch's mean), clip fraction, explained variance, the epochs run (fewer than ``n_epochs`` when
    ``target_kl`` stopped it), SB3's update counter (``train/n_updates``, epochs so far) and the policy's std."""

    index: int
    timesteps: int
    learning_rate: float
    clip_range: float
    policy_gradient_loss: float
    value_loss: float
    entropy_loss: float
    loss: float
    approx_kl: float
    clip_fraction: float
    explained_variance: float
    epochs: int
    n_updates: int
    std: float | None
    vf_coef: float
    ent_coef: float

    @property
    def mean_loss(self) -> float:
        """The mean total PPO loss over the update's minibatches: pg + vf_coef * value + ent_coef * entropy."""
        return float(self.policy_gradient_loss + self.vf_coef * self.value_loss + self.ent_coef * self.entropy_loss)

    def metrics(self) -> dict[str, float]:
        """SB3's ``train/*`` names and values."""
        out = {"train/entropy_loss": self.entropy_loss, "train/policy_gradient_loss": self.policy_gradient_loss,
               "train/value_loss": self.value_loss, "train/approx_kl": self.approx_kl,
               "train/clip_fraction": self.clip_fraction, "train/loss": self.loss,
               "train/explained_variance": self.explained_variance}
        if self.std is not None:
            out["train/std"] = self.std
        out.update({"train/n_updates": self.n_updates, "train/clip_range": self.clip_range,
                    "train/learning_rate": self.learning_rate})
        return out


@dataclass(frozen=True)
class OffPolicyUpdate:
    """The gradient steps of one round of an off-policy learner (SAC, TD3): the learning rate in force, the losses as
    means over the round's gradient steps (SB3 logs the means of one ``train()`` call; a round may hold several), the
    steps run (0 before ``learning_starts``: no losses), SB3's ``train/n_updates`` (gradient steps so far), SAC's
    entropy coefficient and its loss (``None`` for TD3, or with a fixed coefficient), and TD3's actor updates (the
    steps whose actor loss was computed: every ``policy_delay``-th)."""

    index: int
    timesteps: int
    learning_rate: float
    gradient_steps: int
    n_updates: int
    critic_loss: float | None = None
    actor_loss: float | None = None
    ent_coef: float | None = None
    ent_coef_loss: float | None = None

    @property
    def loss(self) -> float:
        """The critic's TD loss (its NaN is the first sign of a diverged learner; 0 before the first step): the NaN
        guard's reading."""
        return 0.0 if self.critic_loss is None else float(self.critic_loss)

    @property
    def mean_loss(self) -> float:
        """RECOM's loss L_t: the critic's mean TD loss (README: the actor's loss is -Q, whose scale follows the
        returns, not how well the networks fit)."""
        return float(self.critic_loss) if self.critic_loss is not None else math.nan

    def metrics(self) -> dict[str, float]:
        """SB3's ``train/*`` names and values (before the first gradient step: the learning rate and counter only)."""
        out: dict[str, float] = {}
        for key in ("ent_coef", "actor_loss", "critic_loss", "ent_coef_loss"):
            value = getattr(self, key)
            if value is not None:
                out[f"train/{key}"] = value
        out.update({"train/learning_rate": self.learning_rate, "train/n_updates": self.n_updates})
        return out
