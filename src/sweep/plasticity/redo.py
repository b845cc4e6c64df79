"""ReDo, recycling dormant neurons (Sokar et al. 2023, "The dormant neuron phenomenon in deep RL").

Every K updates, on the most recent observations, each hidden unit's score

    s_i = E_x |h_i(x)| / ( 1/H * sum_k E_x |h_k(x)| )              (Sokar et al., Def. 3.1)

is computed per layer; every unit with s_i <= tau gets fresh incoming weights from the layer's own
init and a zero bias, its outgoing weights are set to 0, and Adam's m and v of those weights are zeroed
(the ReDo authors' code does; Plasticine's does not, and we follow the authors). Output layers are never
reset. Logs ``remedy/redo/reset_units`` (both networks) and per layer ``remedy/redo/<network>_layer<k>``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List

import numpy as np

from sweep.agents.learner import Learner
from sweep.config import MISSING, HookSettings, positive_int, unit_interval
from sweep.plasticity.dormant import dormant_mask
from sweep.plasticity.remedy import NETWORKS, NetworkName, Remedy, UnitSurgery, every_updates_key, networks_key


@dataclass
class ReDoSettings(HookSettings):   # conf/remedy/redo.yaml
    every_updates: int = every_updates_key()
    tau: float = unit_interval()
    networks: List[NetworkName] = networks_key()
    batch_size: int = positive_int()
    reset_adam: bool = MISSING


class ReDo(Remedy):
    Settings = ReDoSettings
    name = "redo"
    reads_activations = True

    def __init__(self, every_updates: int = 100, tau: float = 0.1, networks=NETWORKS, batch_size: int = 1024,
                 reset_adam: bool = True) -> None:
        super().__init__(every_updates, batch_size)
        self.tau, self.networks, self.reset_adam = float(tau), tuple(networks), bool(reset_adam)

    def act(self, learner: Learner, observations: np.ndarray | None) -> dict[str, float]:
        activations = learner.hidden_activations(observations)
        surgery = UnitSurgery(learner)
        stats = {}
        for net in learner.networks:
            if net.role not in self.networks:
                continue
            for k, layer in enumerate(activations[net.name]):
                stats[f"{net.name}_layer{k}"] = surgery.reinitialize(net, k, dormant_mask(layer.post, self.tau))
        surgery.commit(self.reset_adam)
        return {"reset_units": sum(stats.values()), **stats}
