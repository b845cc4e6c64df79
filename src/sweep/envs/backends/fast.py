"""Vectorised RotorPy multirotor model: all N vehicles in one compiled pass, fixed-step RK4.

The physics is RotorPy 3.0.0's ``Multirotor._s_dot_fn`` / ``compute_body_wrench`` with ``aero=True``
and ``control_abstraction='cmd_motor_speeds'``, term by term:

* rotor thrust ``k_eta eta_i w_i^2`` along body z (``eta_i`` the rotor's efficiency, 1 in RotorPy's model:
  ``sweep.envs.vehicle.VehicleSegment``), plus translational lift ``k_h (u_x^2 + u_y^2)`` on the
  local airspeed ``u_i`` of each rotor hub, ``u_i = R^T (v - wind) + omega x r_i``;
* rotor drag (H force) ``-w_i diag(k_d, k_d, k_z) u_i`` at each hub, parasitic drag
  ``-|v_b| diag(c_Dx, c_Dy, c_Dz) v_b`` at the CoM (``v_b = R^T (v - wind)``);
* moments ``sum_i r_i x (T_i + H_i)``, yaw ``dir_i k_m w_i^2`` and flapping ``-k_flap w_i (u_i x e_z)``;
* ``v_dot = (m g_vec + R F_b) / m``, ``omega_dot = I^-1 (M_b - omega x I omega)``,
  ``q_dot = 0.5 G(q)^T omega`` on the unnormalised quaternion (as RotorPy: no penalty term), while the
  rotation matrix comes from the normalised quaternion (scipy's ``Rotation.from_quat`` normalises);
* first-order motors ``w_dot = (clip(cmd, min, max) - w) / tau_m``.

One step = one classical RK4 step of length ``dt`` with the wind held constant, then quaternion
renormalisation and the rotor-speed clip of ``Multirotor.step`` (motor noise must be zero; ground
contact is not modelled, as in the hover task's ``enable_ground=False``).

The step is one numba-compiled loop over vehicles (``step_vehicles``); the compiled rollout
(``sweep.agents.rollout``) calls the same function. Its inputs are two named tuples: ``Vehicles`` (the
backend's state arrays, stepped in place) and ``Physics`` (the model's constants, read from RotorPy's params).
"""
from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from sweep.envs.backends.base import Backend, Vehicles
from sweep.envs.vehicle import GRAVITY, NOMINAL, VehicleSegment, scaled_params


class Physics(NamedTuple):
    """Everything the derivative and the step need: the step length and the vehicle's constants."""
    dt: float
    rotor_geometry: np.ndarray  # (R,3) rotor hub positions in the body frame
    rotor_dir: np.ndarray       # (R,) yaw moment sign of each rotor
    inertia: np.ndarray         # (3,3)
    inv_inertia: np.ndarray     # (3,3)
    c_d: np.ndarray             # (3,) parasitic drag c_Dx, c_Dy, c_Dz
    mass: float
    k_eta: float
    thrust_coef: np.ndarray     # (R,) k_eta * eta_i: each rotor's thrust per squared speed
    k_m: float
    k_d: float
    k_z: float
    k_h: float
    k_flap: float
    inv_tau_m: float            # 1 / motor time constant
    speed_min: float            # rotor speed bounds (rad/s)
    speed_max: float


def physics(params: dict, dt: float, vehicle: VehicleSegment = NOMINAL) -> Physics:
    """``Physics`` of a RotorPy params dict (same defaults as RotorPy) with ``vehicle``'s mass factor and rotor
    efficiencies applied (``NOMINAL``: RotorPy's vehicle, bit for bit)."""
    params = scaled_params(params, vehicle)
    if float(params.get("motor_noise_std", 0.0)) != 0.0:
        raise ValueError("FastBackend is deterministic: params['motor_noise_std'] must be 0")
    inertia = np.array([[params["Ixx"], params["Ixy"], params["Ixz"]],
                        [params["Ixy"], params["Iyy"], params["Iyz"]],
                        [params["Ixz"], params["Iyz"], params["Izz"]]], dtype=np.float64)
    rotor_geometry = np.array([params["rotor_pos"][k] for k in params["rotor_pos"]], dtype=np.float64)
    assert rotor_geometry.shape == (int(params["num_rotors"]), 3)
    return Physics(
        dt=float(dt),
        rotor_geometry=rotor_geometry,
        rotor_dir=np.asarray(params["rotor_directions"], dtype=np.float64),
        inertia=inertia,
        inv_inertia=np.linalg.inv(inertia),
        c_d=np.array([params.get("c_Dx", 0.0), params.get("c_Dy", 0.0), params.get("c_Dz", 0.0)], dtype=np.float64),
        mass=float(params["mass"]),
        k_eta=float(params["k_eta"]),
        thrust_coef=float(params["k_eta"]) * np.asarray(vehicle.rotor_efficiency, dtype=np.float64),
        k_m=float(params["k_m"]),
        k_d=float(params.get("k_d", 0.0)),
        k_z=float(params.get("k_z", 0.0)),
        k_h=float(params.get("k_h", 0.0)),
        k_flap=float(params.get("k_flap", 0.0)),
        inv_tau_m=1.0 / float(params["tau_m"]),
        speed_min=float(params["rotor_speed_min"]),
        speed_max=float(params["rotor_speed_max"]),
    )


@numba.njit(cache=True, inline="always")
def rotation_matrix(q0, q1, q2, q3):
    """Body-to-world rotation matrix (row-major r00, r01, ..., r22) of the quaternion (i, j, k, w) = (q0, q1,
    q2, q3), normalised first (as scipy's ``Rotation.from_quat``)."""
    inv_n2 = 1.0 / (q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    xx, yy, zz = q0 * q0 * inv_n2, q1 * q1 * inv_n2, q2 * q2 * inv_n2
    xy, xz, yz = q0 * q1 * inv_n2, q0 * q2 * inv_n2, q1 * q2 * inv_n2
    xw, yw, zw = q0 * q3 * inv_n2, q1 * q3 * inv_n2, q2 * q3 * inv_n2
    return (1.0 - 2.0 * (yy + zz), 2.0 * (xy - zw), 2.0 * (xz + yw),
            2.0 * (xy + zw), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - xw),
            2.0 * (xz - yw), 2.0 * (yz + xw), 1.0 - 2.0 * (xx + yy))


@numba.njit(cache=True, inline="always")
def _deriv_one(s, cmd, wind, p, out):
    """One vehicle's state derivative into ``out``; ``s`` is x(3) v(3) q(4) w(3) rotor speeds(R)."""
    geo, rdir, inertia, inv_inertia, c_d = p.rotor_geometry, p.rotor_dir, p.inertia, p.inv_inertia, p.c_d
    # every field read once, here: a field read inside the rotor loop costs ~30% of the step's speed
    thrust, k_m, k_d, k_z, k_h, k_flap = p.thrust_coef, p.k_m, p.k_d, p.k_z, p.k_h, p.k_flap
    mass, inv_tau_m = p.mass, p.inv_tau_m
    nrot = geo.shape[0]
    q0, q1, q2, q3 = s[6], s[7], s[8], s[9]
    w0, w1, w2 = s[10], s[11], s[12]
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation_matrix(q0, q1, q2, q3)
    a0 = s[3] - wind[0]
    a1 = s[4] - wind[1]
    a2 = s[5] - wind[2]
    vb0 = r00 * a0 + r10 * a1 + r20 * a2
    vb1 = r01 * a0 + r11 * a1 + r21 * a2
    vb2 = r02 * a0 + r12 * a1 + r22 * a2

    f0 = 0.0
    f1 = 0.0
    f2 = 0.0
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for i in range(nrot):
        g0, g1, g2 = geo[i, 0], geo[i, 1], geo[i, 2]
        om = s[13 + i]
        u0 = vb0 + (w1 * g2 - w2 * g1)
        u1 = vb1 + (w2 * g0 - w0 * g2)
        u2 = vb2 + (w0 * g1 - w1 * g0)
        h0 = -om * k_d * u0
        h1 = -om * k_d * u1
        h2 = -om * k_z * u2 + thrust[i] * om * om + k_h * (u0 * u0 + u1 * u1)
        f0 += h0
        f1 += h1
        f2 += h2
        m0 += g1 * h2 - g2 * h1 - k_flap * om * u1
        m1 += g2 * h0 - g0 * h2 + k_flap * om * u0
        m2 += g0 * h1 - g1 * h0 + rdir[i] * k_m * om * om
        out[13 + i] = (cmd[i] - om) * inv_tau_m
    nb = (vb0 * vb0 + vb1 * vb1 + vb2 * vb2) ** 0.5
    f0 -= nb * c_d[0] * vb0
    f1 -= nb * c_d[1] * vb1
    f2 -= nb * c_d[2] * vb2

    out[0] = s[3]
    out[1] = s[4]
    out[2] = s[5]
    out[3] = (r00 * f0 + r01 * f1 + r02 * f2) / mass
    out[4] = (r10 * f0 + r11 * f1 + r12 * f2) / mass
    out[5] = (r20 * f0 + r21 * f1 + r22 * f2) / mass - GRAVITY
    out[6] = 0.5 * (q3 * w0 - q2 * w1 + q1 * w2)
    out[7] = 0.5 * (q2 * w0 + q3 * w1 - q0 * w2)
    out[8] = 0.5 * (-q1 * w0 + q0 * w1 + q3 * w2)
    out[9] = 0.5 * (-q0 * w0 - q1 * w1 - q2 * w2)
    iw0 = inertia[0, 0] * w0 + inertia[0, 1] * w1 + inertia[0, 2] * w2
    iw1 = inertia[1, 0] * w0 + inertia[1, 1] * w1 + inertia[1, 2] * w2
    iw2 = inertia[2, 0] * w0 + inertia[2, 1] * w1 + inertia[2, 2] * w2
    t0 = m0 - (w1 * iw2 - w2 * iw1)
    t1 = m1 - (w2 * iw0 - w0 * iw2)
    t2 = m2 - (w0 * iw1 - w1 * iw0)
    out[10] = inv_inertia[0, 0] * t0 + inv_inertia[0, 1] * t1 + inv_inertia[0, 2] * t2
    out[11] = inv_inertia[1, 0] * t0 + inv_inertia[1, 1] * t1 + inv_inertia[1, 2] * t2
    out[12] = inv_inertia[2, 0] * t0 + inv_inertia[2, 1] * t1 + inv_inertia[2, 2] * t2


@numba.njit(cache=True)
def step_vehicles(vehicles: Vehicles, cmd, wind, p: Physics):
    """Advance every vehicle of ``vehicles`` (in place) by ``p.dt`` under commanded rotor speeds ``cmd`` (N,R)
    and wind ``wind`` (N,3)."""
    x, v, q, w, rs = vehicles
    dt, speed_min, speed_max = p.dt, p.speed_min, p.speed_max
    n = x.shape[0]
    nrot = rs.shape[1]
    dim = 13 + nrot
    s = np.empty(dim)  # one vehicle's state: x(3) v(3) q(4) w(3) rotor speeds(R)
    tmp = np.empty(dim)
    k = np.empty(dim)
    acc = np.empty(dim)
    cm = np.empty(nrot)
    for j in range(n):
        for a in range(3):
            s[a] = x[j, a]
            s[3 + a] = v[j, a]
            s[10 + a] = w[j, a]
        for a in range(4):
            s[6 + a] = q[j, a]
        for i in range(nrot):
            s[13 + i] = rs[j, i]
            cm[i] = min(max(cmd[j, i], speed_min), speed_max)
        wj = wind[j]
        _deriv_one(s, cm, wj, p, k)       # k1
        for a in range(dim):
            acc[a] = k[a]
            tmp[a] = s[a] + 0.5 * dt * k[a]
        _deriv_one(tmp, cm, wj, p, k)     # k2
        for a in range(dim):
            acc[a] += 2.0 * k[a]
            tmp[a] = s[a] + 0.5 * dt * k[a]
        _deriv_one(tmp, cm, wj, p, k)     # k3
        for a in range(dim):
            acc[a] += 2.0 * k[a]
            tmp[a] = s[a] + dt * k[a]
        _deriv_one(tmp, cm, wj, p, k)     # k4
        for a in range(dim):
            s[a] = s[a] + (dt / 6.0) * (acc[a] + k[a])
        nq = (s[6] * s[6] + s[7] * s[7] + s[8] * s[8] + s[9] * s[9]) ** 0.5
        for a in range(3):
            x[j, a] = s[a]
            v[j, a] = s[3 + a]
            w[j, a] = s[10 + a]
        for a in range(4):
            q[j, a] = s[6 + a] / nq
        for i in range(nrot):
            rs[j, i] = min(max(s[13 + i], speed_min), speed_max)


class FastBackend(Backend):
    """RotorPy's multirotor (aero=True) for N vehicles at once; fixed RK4, one step per ``dt``."""

    def __init__(self, n: int, params: dict, dt: float) -> None:
        super().__init__(n, params, dt)
        self.physics = physics(params, self.dt)

    def set_vehicle(self, vehicle: VehicleSegment) -> None:
        self.physics = physics(self.params, self.dt, vehicle)

    def step(self, cmd_rotor_speeds: np.ndarray, wind: np.ndarray) -> None:
        step_vehicles(self.vehicles, np.ascontiguousarray(cmd_rotor_speeds, dtype=np.float64),
                      np.ascontiguousarray(wind, dtype=np.float64), self.physics)
