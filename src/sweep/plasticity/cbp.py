"""Continual backpropagation (Dohare et al. 2024, "Loss of plasticity in deep continual learning", Nature).

Each hidden unit i carries a contribution utility and an age. After every update, on the most recent
observations,

    u_i <- eta * u_i + (1 - eta) * E_x|h_i(x)| * sum_k |w_out[k, i]|      (running average, decay eta)
    a_i <- a_i + (minibatch steps of the update)

Units older than the maturity threshold are eligible; per layer, rho x (eligible units) x (minibatch
steps) replacements accrue (fractions carry over) and that many lowest-utility eligible units are
replaced: fresh incoming weights from the layer's init, zero bias, zero outgoing weights, utility and
age reset. rho and the maturity are in minibatch (SGD) steps, as in Dohare et al.; the utility is
measured once per PPO update (so eta decays per update). Adam's state is not reset by default (Dohare
et al.'s code does not, on purpose). Combined with L2 as ``agent=cbp_l2``, Dohare's recommendation.
Logs ``remedy/cbp/replaced_units`` per event and ``remedy/cbp/eligible_units``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List

import numpy as np

from sweep.agents.learner import Learner
from sweep.config import MISSING, HookSettings, at_least, positive_int, unit_interval
from sweep.plasticity.remedy import NETWORKS, NetworkName, Remedy, UnitSurgery, networks_key


@dataclass
class CBPSettings(HookSettings):   # conf/remedy/cbp.yaml
    replacement_rate: float = unit_interval(" (per eligible unit and minibatch step)")
    maturity: int = at_least(0, unit=" (minibatch steps)")
    decay: float = unit_interval()
    networks: List[NetworkName] = networks_key()
    batch_size: int = positive_int()
    reset_adam: bool = MISSING


class ContinualBackprop(Remedy):
    Settings = CBPSettings
    name = "cbp"
    reads_activations = True

    def __init__(self, replacement_rate: float = 1e-4, maturity: int = 10_000, decay: float = 0.99,
                 networks=NETWORKS, batch_size: int = 256, reset_adam: bool = False) -> None:
        super().__init__(every_updates=1, batch_size=batch_size)
        self.rate, self.maturity, self.decay = float(replacement_rate), int(maturity), float(decay)
        self.networks, self.reset_adam = tuple(networks), bool(reset_adam)
        self.utility: dict[str, np.ndarray] = {}   # "<network>/<k>" -> per unit
        self.age: dict[str, np.ndarray] = {}
        self.pending: dict[str, float] = {}        # accrued fractional replacements

    def extra_state(self) -> dict:
        return {"utility": {k: v.copy() for k, v in self.utility.items()},
                "age": {k: v.copy() for k, v in self.age.items()}, "pending": dict(self.pending)}

    def load_extra_state(self, state: dict) -> None:
        self.utility, self.age, self.pending = dict(state["utility"]), dict(state["age"]), dict(state["pending"])

    def act(self, learner: Learner, observations: np.ndarray | None) -> dict[str, float]:
        activations = learner.hidden_activations(observations)
        steps = learner.minibatches_per_update
        surgery = UnitSurgery(learner)
        params = surgery.params
        replaced = eligible_total = 0
        for net in learner.networks:
            if net.role not in self.networks:
                continue
            for k, layer in enumerate(activations[net.name]):
                key = f"{net.name}/{k}"
                width = layer.post.shape[1]
                outgoing = sum(np.abs(params[f"{r}.weight"]).sum(axis=0) for r in net.readers(k))  # before this event's writes
                now = np.abs(layer.post).mean(axis=0) * outgoing
                u = self.utility.setdefault(key, np.zeros(width))
                a = self.age.setdefault(key, np.zeros(width, np.int64))
                u[:] = self.decay * u + (1.0 - self.decay) * now
                a += steps
                eligible = np.flatnonzero(a > self.maturity)
                eligible_total += len(eligible)
                self.pending[key] = self.pending.get(key, 0.0) + self.rate * len(eligible) * steps
                n = min(int(self.pending[key]), len(eligible))
                self.pending[key] -= int(self.pending[key])
                if n == 0:
                    continue
                worst = eligible[np.argsort(u[eligible], kind="stable")[:n]]
                units = np.zeros(width, bool)
                units[worst] = True
                replaced += surgery.reinitialize(net, k, units)
                u[units], a[units] = 0.0, 0
        surgery.commit(self.reset_adam)
        return {"replaced_units": replaced, "eligible_units": eligible_total}
