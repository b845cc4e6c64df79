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


class RotorPyRK4Backend(Backend):
    """Reference for fixed-step backends: RotorPy's own state derivative (``Multirotor._s_dot_fn``)
    integrated with one classical RK4 step per ``dt``, then the quaternion renormalisation and the
    rotor-speed clip of ``Multirotor.step``. One vehicle at a time (slow; for tests)."""

    def __init__(self, n: int, params: dict, dt: float) -> None:
        super().__init__(n, params, dt)
        self.vehicle = Multirotor(params, control_abstraction="cmd_motor_speeds", aero=True)

    def step(self, cmd_rotor_speeds: np.ndarray, wind: np.ndarray) -> None:
        veh, h = self.vehicle, self.dt
        for i in range(self.n):
            state = {"x": self.x[i], "v": self.v[i], "q": self.q[i], "w": self.w[i],
                     "wind": wind[i], "rotor_speeds": self.rotor_speeds[i]}
            cmd = np.clip(veh.get_cmd_motor_speeds(state, {"cmd_motor_speeds": cmd_rotor_speeds[i]}),
                          veh.rotor_speed_min, veh.rotor_speed_max)
            s = Multirotor._pack_state(state)
            k1 = veh._s_dot_fn(0.0, s, cmd)
            k2 = veh._s_dot_fn(0.5 * h, s + 0.5 * h * k1, cmd)
            k3 = veh._s_dot_fn(0.5 * h, s + 0.5 * h * k2, cmd)
            k4 = veh._s_dot_fn(h, s + h * k3, cmd)
            new = Multirotor._unpack_state(s + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4))
            self.x[i], self.v[i], self.w[i] = new["x"], new["v"], new["w"]
            self.q[i] = new["q"] / np.linalg.norm(new["q"])
            self.rotor_speeds[i] = np.clip(new["rotor_speeds"], veh.rotor_speed_min, veh.rotor_speed_max)
