"""Reference backends: RotorPy's own ``Multirotor`` (scipy ``solve_ivp``, or its state derivative under one RK4
step), one vehicle at a time.

A vehicle segment (``sweep.envs.vehicle``) reaches RotorPy as its params with the mass and inertia scaled, and,
for the rotor efficiencies (not a RotorPy parameter), as ``Multirotor.compute_body_wrench`` with each rotor's
thrust ``k_eta w_i^2`` scaled by ``eta_i``: RotorPy's wrench, minus ``(1 - eta_i) k_eta w_i^2`` along body z at
each hub (its force and its moment ``r_i x T_i``). Everything else is RotorPy's code.
"""
from __future__ import annotations

import numpy as np
from rotorpy.vehicles.multirotor import Multirotor

from sweep.envs.backends.base import Backend
from sweep.envs.vehicle import NOMINAL, VehicleSegment, scaled_params


class ConditionedMultirotor(Multirotor):
    """RotorPy's ``Multirotor`` (cmd_motor_speeds, aero) whose rotor i makes ``eta_i`` of its thrust."""

    def __init__(self, params: dict, rotor_efficiency=(1.0, 1.0, 1.0, 1.0)) -> None:
        super().__init__(params, control_abstraction="cmd_motor_speeds", aero=True)
        self.rotor_efficiency = np.asarray(rotor_efficiency, dtype=np.float64)

    def compute_body_wrench(self, body_rates, rotor_speeds, body_airspeed_vector):
        force, moment = super().compute_body_wrench(body_rates, rotor_speeds, body_airspeed_vector)
        if np.all(self.rotor_efficiency == 1.0):
            return force, moment
        lost = (1.0 - self.rotor_efficiency) * self.k_eta * rotor_speeds ** 2  # thrust each rotor does not make
        r = self.rotor_geometry
        force = force - np.array([0.0, 0.0, lost.sum()])
        moment = moment - np.array([np.sum(r[:, 1] * lost), -np.sum(r[:, 0] * lost), 0.0])
        return force, moment


class RotorPyBackend(Backend):
    def __init__(self, n: int, params: dict, dt: float) -> None:
        super().__init__(n, params, dt)
        self.set_vehicle(NOMINAL)

    def set_vehicle(self, vehicle: VehicleSegment) -> None:
        self.vehicle = ConditionedMultirotor(scaled_params(self.params, vehicle), vehicle.rotor_efficiency)

    def step(self, cmd_rotor_speeds: np.ndarray, wind: np.ndarray) -> None:
        for i in range(self.n):
            state = {"x": self.x[i], "v": self.v[i], "q": self.q[i], "w": self.w[i],
                     "wind": wind[i], "rotor_speeds": self.rotor_speeds[i]}
            new = self.vehicle.step(state, {"cmd_motor_speeds": cmd_rotor_speeds[i]}, self.dt)
            self.x[i], self.v[i], self.q[i] = new["x"], new["v"], new["q"]
            self.w[i], self.rotor_speeds[i] = new["w"], new["rotor_speeds"]


class RotorPyRK4Backend(RotorPyBackend):
    """Reference for fixed-step backends: RotorPy's own state derivative (``Multirotor._s_dot_fn``)
    integrated with one classical RK4 step per ``dt``, then the quaternion renormalisation and the
    rotor-speed clip of ``Multirotor.step``. One vehicle at a time (slow; for tests)."""

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
