"""Reference backend: RotorPy's own ``Multirotor.step`` (scipy ``solve_ivp``), one vehicle at a time."""
from __future__ import annotations

import numpy as np
from rotorpy.vehicles.multirotor import Multirotor

from sweep.envs.backends.base import Backend


class RotorPyBackend(Backend):
    def __init__(self, n: int, params: dict, dt: float) -> None:
        super().__init__(n, params, dt)
        self.vehicle = Multirotor(params, control_abstraction="cmd_motor_speeds", aero=True)

    def step(self, cmd_rotor_speeds: np.ndarray, wind: np.ndarray) -> None:
        for i in range(self.n):
            state = {"x": self.x[i], "v": self.v[i], "q": self.q[i], "w": self.w[i],
                     "wind": wind[i], "rotor_speeds": self.rotor_speeds[i]}
            new = self.vehicle.step(state, {"cmd_motor_speeds": cmd_rotor_speeds[i]}, self.dt)
            self.x[i], self.v[i], self.q[i] = new["x"], new["v"], new["q"]
            self.w[i], self.rotor_speeds[i] = new["w"], new["rotor_speeds"]
