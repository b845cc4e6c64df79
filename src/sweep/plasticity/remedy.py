"""What every remedy that writes the networks shares: when it acts, and how it re-initialises units.

``Remedy`` is a hook (``sweep.training.hooks``) that acts after every ``every_updates``-th PPO update that
training continues from (``after_update``; not after the last), so both learners see the same sequence of
updates, rollouts and remedy events. Remedies that read activations get the ``batch_size`` most recent
observations of the rollout the update learned from. Each logs what it did under ``remedy/<name>/<what>``
(``name``: its key in the agent config). It talks to the learner only through ``sweep.agents.learner.Learner``.

``UnitSurgery`` re-initialises hidden units (ReDo, CBP): for unit i of hidden layer k, fresh incoming
weights (row i of the layer's weight, drawn from the layer's own init: ``networks.fresh_rows``), a zero bias (LayerNorm scale 1,
shift 0), and zero outgoing weights (column i of every layer that reads it: the next layer, or the heads), so the network's output is unchanged at
the moment of the reset; optionally Adam's moments of exactly those entries are zeroed.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from sweep.agents.learner import Learner
from sweep.agents.networks import Network, fresh_rows
from sweep.config import choice, non_empty, positive_int
from sweep.training.hooks import Hook
from sweep.training.records import RolloutRecord, UpdateRecord


NETWORKS = ("policy", "value")
# the words a remedy's settings use for what it acts on (its schema: ``Remedy.Settings`` and the subclasses' own)
NetworkName = choice("NetworkName", *NETWORKS)


def networks_key() -> Any:
    return non_empty(f"a non-empty subset of [{', '.join(NetworkName.__members__)}]")


def every_updates_key() -> Any:
    return positive_int(" (updates)")


class UnitSurgery:
    """Collects unit re-initialisations on a copy of the parameters; ``commit`` writes them in one go."""

    def __init__(self, learner: Learner) -> None:
        self.learner = learner
        self.params = learner.parameter_arrays()
        self.masks: dict[str, np.ndarray] = {}

    def _mask(self, name: str) -> np.ndarray:
        return self.masks.setdefault(name, np.zeros(self.params[name].shape, bool))

    def reinitialize(self, net: Network, k: int, units: np.ndarray) -> int:
        """Re-initialise the ``units`` (bool per unit) of ``net``'s hidden layer k; returns how many."""
        units = np.asarray(units, bool)
        if not units.any():
            return 0
        layer = net.hidden[k]
        weight = f"{layer}.weight"
        self.params[weight][units] = fresh_rows(net, layer, self.params[weight].shape, int(units.sum()), self.learner.rng)
        self.params[f"{layer}.bias"][units] = 0.0   # (a uniform init's bias too: the unit's output is then its weights')
        if net.norms[k]:
            self.params[f"{net.norms[k]}.weight"][units] = 1.0
            self.params[f"{net.norms[k]}.bias"][units] = 0.0
        incoming = [weight, f"{layer}.bias"] + ([f"{net.norms[k]}.weight", f"{net.norms[k]}.bias"] if net.norms[k] else [])
        for name in incoming:
            self._mask(name)[units] = True
        for out in net.readers(k):
            self.params[f"{out}.weight"][:, units] = 0.0
            self._mask(f"{out}.weight")[:, units] = True
        return int(units.sum())

    def commit(self, reset_adam: bool = True) -> None:
        if not self.masks:
            return
        self.learner.write_parameters({name: self.params[name] for name in self.masks})
        if reset_adam:
            self.learner.reset_optimizer(self.masks)


class Remedy(Hook):
    """Acts on the learner after every ``every_updates``-th update (see the module docstring)."""

    reads_activations = False

    def __init__(self, every_updates: int = 1, batch_size: int = 1024) -> None:
        self.every, self.batch_size = int(every_updates), int(batch_size)
        self.updates = 0    # updates this remedy has handled
        self.observations: np.ndarray | None = None

    # -- what a remedy implements --
    def act(self, learner: Learner, observations: np.ndarray | None) -> dict[str, float]:
        """Change the learner after an update; returns what to log under remedy/<name>/."""
        raise NotImplementedError

    def extra_state(self) -> dict:
        return {}

    def load_extra_state(self, state: dict) -> None:
        pass

    # -- checkpoints --
    def state_dict(self) -> dict:
        return {"updates": self.updates, **self.extra_state()}

    def load_state_dict(self, state: dict) -> None:
        self.updates = state["updates"]
        self.load_extra_state(state)

    # -- the loop's moments --
    def after_rollout(self, learner: Learner, rollout: RolloutRecord) -> dict[str, float]:
        if self.reads_activations:   # the rollout the coming update learns from, in time order
            self.observations = learner.recent_samples(self.batch_size).observations
        return {}

    def after_update(self, learner: Learner, update: UpdateRecord) -> dict[str, float]:
        self.updates += 1
        if self.updates % self.every:
            return {}
        return {f"remedy/{self.name}/{key}": float(value) for key, value in self.act(learner, self.observations).items()}
