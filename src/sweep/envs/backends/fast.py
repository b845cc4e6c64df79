"""Vectorised RotorPy multirotor model: all N vehicles in one pass, fixed-step RK4 (no per-vehicle loop).

The physics is RotorPy 3.0.0's ``Multirotor._s_dot_fn`` / ``compute_body_wrench`` with ``aero=True``
and ``control_abstraction='cmd_motor_speeds'``, term by term:

* rotor thrust ``k_eta w_i^2`` along body z, plus translational lift ``k_h (u_x^2 + u_y^2)`` on the
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

With numba installed the step runs as one compiled loop over vehicles (much faster at small N, where
NumPy's per-call overhead dominates); without it, the NumPy path below is used. Both compute the same
expressions; ``FastBackend(..., use_numba=False)`` forces NumPy.
"""
from __future__ import annotations

import numpy as np

from sweep.envs.backends.base import Backend

try:  # optional accelerator
    import numba as _numba
except ImportError:  # pragma: no cover - exercised when numba is absent
    _numba = None

GRAVITY = 9.81  # m/s^2, RotorPy's Multirotor.g


def _model_constants(params: dict) -> dict:
    """Everything the derivative needs, read from the RotorPy params dict (same defaults as RotorPy)."""
    if float(params.get("motor_noise_std", 0.0)) != 0.0:
        raise ValueError("FastBackend is deterministic: params['motor_noise_std'] must be 0")
    inertia = np.array([[params["Ixx"], params["Ixy"], params["Ixz"]],
                        [params["Ixy"], params["Iyy"], params["Iyz"]],
                        [params["Ixz"], params["Iyz"], params["Izz"]]], dtype=np.float64)
    rotor_geometry = np.array([params["rotor_pos"][k] for k in params["rotor_pos"]], dtype=np.float64)
    n_rot = int(params["num_rotors"])
    assert rotor_geometry.shape == (n_rot, 3)
    return dict(
        mass=float(params["mass"]),
        inertia=inertia,
        inv_inertia=np.linalg.inv(inertia),
        rotor_geometry=rotor_geometry,                                   # (R,3)
        rotor_dir=np.asarray(params["rotor_directions"], dtype=np.float64),  # (R,)
        k_eta=float(params["k_eta"]),
        k_m=float(params["k_m"]),
        k_d=float(params.get("k_d", 0.0)),
        k_z=float(params.get("k_z", 0.0)),
        k_h=float(params.get("k_h", 0.0)),
        k_flap=float(params.get("k_flap", 0.0)),
        c_d=np.array([params.get("c_Dx", 0.0), params.get("c_Dy", 0.0), params.get("c_Dz", 0.0)],
                     dtype=np.float64),
        tau_m=float(params["tau_m"]),
        speed_min=float(params["rotor_speed_min"]),
        speed_max=float(params["rotor_speed_max"]),
    )


# ------------------------------------------------------------------------------------------------
# NumPy path. State s is (N, 13 + R): x(3) v(3) q(4) w(3) rotor speeds(R).
# ------------------------------------------------------------------------------------------------
def _deriv_numpy(s: np.ndarray, cmd: np.ndarray, wind: np.ndarray, c: dict) -> np.ndarray:
    # component-wise on (N,) / (N,R) columns: np.cross / einsum on tiny axes cost more than the maths
    q0, q1, q2, q3 = s[:, 6], s[:, 7], s[:, 8], s[:, 9]
    w0, w1, w2 = s[:, 10], s[:, 11], s[:, 12]
    om = s[:, 13:]
    # rotation matrix of the normalised quaternion (i, j, k, w)
    inv_n2 = 2.0 / (q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    xx, yy, zz = q0 * q0 * inv_n2, q1 * q1 * inv_n2, q2 * q2 * inv_n2
    xy, xz, yz = q0 * q1 * inv_n2, q0 * q2 * inv_n2, q1 * q2 * inv_n2
    xw, yw, zw = q0 * q3 * inv_n2, q1 * q3 * inv_n2, q2 * q3 * inv_n2
    r00, r01, r02 = 1.0 - (yy + zz), xy - zw, xz + yw
    r10, r11, r12 = xy + zw, 1.0 - (xx + zz), yz - xw
    r20, r21, r22 = xz - yw, yz + xw, 1.0 - (xx + yy)
    # body airspeed v_b = R^T (v - wind)
    a0, a1, a2 = s[:, 3] - wind[:, 0], s[:, 4] - wind[:, 1], s[:, 5] - wind[:, 2]
    vb0 = r00 * a0 + r10 * a1 + r20 * a2
    vb1 = r01 * a0 + r11 * a1 + r21 * a2
    vb2 = r02 * a0 + r12 * a1 + r22 * a2
    # local airspeed per rotor u = v_b + omega x r_i, (N,R) per component
    g0, g1, g2 = c["geo0"], c["geo1"], c["geo2"]
    u0 = vb0[:, None] + (w1[:, None] * g2 - w2[:, None] * g1)
    u1 = vb1[:, None] + (w2[:, None] * g0 - w0[:, None] * g2)
    u2 = vb2[:, None] + (w0[:, None] * g1 - w1[:, None] * g0)
    # per-rotor body force: rotor drag H, thrust (+ translational lift) along z
    h0 = (-c["k_d"] * om) * u0
    h1 = (-c["k_d"] * om) * u1
    om2 = om * om
    h2 = (-c["k_z"] * om) * u2 + c["k_eta"] * om2
    if c["k_h"] != 0.0:
        h2 += c["k_h"] * (u0 * u0 + u1 * u1)
    f0, f1, f2 = h0.sum(axis=1), h1.sum(axis=1), h2.sum(axis=1)
    if c["has_parasitic"]:
        nb = np.sqrt(vb0 * vb0 + vb1 * vb1 + vb2 * vb2)
        f0 = f0 - nb * c["c_d"][0] * vb0
        f1 = f1 - nb * c["c_d"][1] * vb1
        f2 = f2 - nb * c["c_d"][2] * vb2
    # moments: r_i x (T_i + H_i), yaw, flapping -k_flap w_i (u_y, -u_x, 0)
    m0 = (g1 * h2 - g2 * h1).sum(axis=1)
    m1 = (g2 * h0 - g0 * h2).sum(axis=1)
    m2 = (g0 * h1 - g1 * h0).sum(axis=1) + om2 @ c["yaw_coeff"]
    if c["k_flap"] != 0.0:
        m0 = m0 - c["k_flap"] * (om * u1).sum(axis=1)
        m1 = m1 + c["k_flap"] * (om * u0).sum(axis=1)

    ds = np.empty_like(s)
    ds[:, 0:3] = s[:, 3:6]
    inv_m = 1.0 / c["mass"]
    ds[:, 3] = (r00 * f0 + r01 * f1 + r02 * f2) * inv_m
    ds[:, 4] = (r10 * f0 + r11 * f1 + r12 * f2) * inv_m
    ds[:, 5] = (r20 * f0 + r21 * f1 + r22 * f2) * inv_m - GRAVITY
    ds[:, 6] = 0.5 * (q3 * w0 - q2 * w1 + q1 * w2)
    ds[:, 7] = 0.5 * (q2 * w0 + q3 * w1 - q0 * w2)
    ds[:, 8] = 0.5 * (-q1 * w0 + q0 * w1 + q3 * w2)
    ds[:, 9] = 0.5 * (-q0 * w0 - q1 * w1 - q2 * w2)
    I, Ii = c["inertia"], c["inv_inertia"]
    iw0 = I[0, 0] * w0 + I[0, 1] * w1 + I[0, 2] * w2
    iw1 = I[1, 0] * w0 + I[1, 1] * w1 + I[1, 2] * w2
    iw2 = I[2, 0] * w0 + I[2, 1] * w1 + I[2, 2] * w2
    t0 = m0 - (w1 * iw2 - w2 * iw1)
    t1 = m1 - (w2 * iw0 - w0 * iw2)
    t2 = m2 - (w0 * iw1 - w1 * iw0)
    ds[:, 10] = Ii[0, 0] * t0 + Ii[0, 1] * t1 + Ii[0, 2] * t2
    ds[:, 11] = Ii[1, 0] * t0 + Ii[1, 1] * t1 + Ii[1, 2] * t2
    ds[:, 12] = Ii[2, 0] * t0 + Ii[2, 1] * t1 + Ii[2, 2] * t2
    ds[:, 13:] = (cmd - om) * (1.0 / c["tau_m"])
    return ds


def _step_numpy(s: np.ndarray, cmd: np.ndarray, wind: np.ndarray, dt: float, c: dict) -> np.ndarray:
    k1 = _deriv_numpy(s, cmd, wind, c)
    k2 = _deriv_numpy(s + (0.5 * dt) * k1, cmd, wind, c)
    k3 = _deriv_numpy(s + (0.5 * dt) * k2, cmd, wind, c)
    k4 = _deriv_numpy(s + dt * k3, cmd, wind, c)
    return s + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


# ------------------------------------------------------------------------------------------------
# numba path: the same expressions, one vehicle at a time inside a compiled loop.
# ------------------------------------------------------------------------------------------------
def _deriv_one(s, cmd, wind, geo, rdir, inertia, inv_inertia, c_d, scal, out):
    mass, k_eta, k_m, k_d, k_z, k_h, k_flap, inv_tau = (scal[0], scal[1], scal[2], scal[3], scal[4],
                                                         scal[5], scal[6], scal[7])
    nrot = geo.shape[0]
    q0, q1, q2, q3 = s[6], s[7], s[8], s[9]
    w0, w1, w2 = s[10], s[11], s[12]
    inv_n2 = 1.0 / (q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    xx, yy, zz = q0 * q0 * inv_n2, q1 * q1 * inv_n2, q2 * q2 * inv_n2
    xy, xz, yz = q0 * q1 * inv_n2, q0 * q2 * inv_n2, q1 * q2 * inv_n2
    xw, yw, zw = q0 * q3 * inv_n2, q1 * q3 * inv_n2, q2 * q3 * inv_n2
    r00 = 1.0 - 2.0 * (yy + zz)
    r01 = 2.0 * (xy - zw)
    r02 = 2.0 * (xz + yw)
    r10 = 2.0 * (xy + zw)
    r11 = 1.0 - 2.0 * (xx + zz)
    r12 = 2.0 * (yz - xw)
    r20 = 2.0 * (xz - yw)
    r21 = 2.0 * (yz + xw)
    r22 = 1.0 - 2.0 * (xx + yy)
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
        h2 = -om * k_z * u2 + k_eta * om * om + k_h * (u0 * u0 + u1 * u1)
        f0 += h0
        f1 += h1
        f2 += h2
        m0 += g1 * h2 - g2 * h1 - k_flap * om * u1
        m1 += g2 * h0 - g0 * h2 + k_flap * om * u0
        m2 += g0 * h1 - g1 * h0 + rdir[i] * k_m * om * om
        out[13 + i] = (cmd[i] - om) * inv_tau
    nb = (vb0 * vb0 + vb1 * vb1 + vb2 * vb2) ** 0.5
    f0 -= nb * c_d[0] * vb0
    f1 -= nb * c_d[1] * vb1
    f2 -= nb * c_d[2] * vb2

    out[0] = s[3]
    out[1] = s[4]
    out[2] = s[5]
    out[3] = (r00 * f0 + r01 * f1 + r02 * f2) / mass
    out[4] = (r10 * f0 + r11 * f1 + r12 * f2) / mass
    out[5] = (r20 * f0 + r21 * f1 + r22 * f2) / mass - 9.81
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


def _step_loop(x, v, q, w, rs, cmd, wind, dt, geo, rdir, inertia, inv_inertia, c_d, scal,
               speed_min, speed_max):
    n = x.shape[0]
    nrot = rs.shape[1]
    dim = 13 + nrot
    s = np.empty(dim)  # one vehicle's state, same layout as the NumPy path
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
        _deriv_one(s, cm, wj, geo, rdir, inertia, inv_inertia, c_d, scal, k)       # k1
        for a in range(dim):
            acc[a] = k[a]
            tmp[a] = s[a] + 0.5 * dt * k[a]
        _deriv_one(tmp, cm, wj, geo, rdir, inertia, inv_inertia, c_d, scal, k)     # k2
        for a in range(dim):
            acc[a] += 2.0 * k[a]
            tmp[a] = s[a] + 0.5 * dt * k[a]
        _deriv_one(tmp, cm, wj, geo, rdir, inertia, inv_inertia, c_d, scal, k)     # k3
        for a in range(dim):
            acc[a] += 2.0 * k[a]
            tmp[a] = s[a] + dt * k[a]
        _deriv_one(tmp, cm, wj, geo, rdir, inertia, inv_inertia, c_d, scal, k)     # k4
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


if _numba is not None:
    _deriv_one = _numba.njit(cache=True, fastmath=False, inline="always")(_deriv_one)
    _step_loop = _numba.njit(cache=True, fastmath=False)(_step_loop)


class FastBackend(Backend):
    """RotorPy's multirotor (aero=True) for N vehicles at once; fixed RK4, one step per ``dt``."""

    def __init__(self, n: int, params: dict, dt: float, use_numba: bool | None = None) -> None:
        super().__init__(n, params, dt)
        c = _model_constants(params)
        c["geo0"], c["geo1"], c["geo2"] = (np.ascontiguousarray(c["rotor_geometry"][:, a]) for a in range(3))
        c["yaw_coeff"] = c["rotor_dir"] * c["k_m"]
        c["has_parasitic"] = bool(np.any(c["c_d"] != 0.0))
        self._c = c
        self.use_numba = (_numba is not None) if use_numba is None else bool(use_numba)
        if self.use_numba and _numba is None:
            raise ImportError("FastBackend(use_numba=True) needs numba")
        self._scal = np.array([c["mass"], c["k_eta"], c["k_m"], c["k_d"], c["k_z"], c["k_h"],
                               c["k_flap"], 1.0 / c["tau_m"]])
        self._s = np.empty((self.n, 13 + c["rotor_geometry"].shape[0]))

    @property
    def kernel_args(self) -> tuple:
        """``_step_loop``'s arguments after (x, v, q, w, rotor_speeds, cmd, wind)."""
        c = self._c
        return (self.dt, c["rotor_geometry"], c["rotor_dir"], c["inertia"], c["inv_inertia"], c["c_d"], self._scal,
                c["speed_min"], c["speed_max"])

    def step(self, cmd_rotor_speeds: np.ndarray, wind: np.ndarray) -> None:
        c = self._c
        cmd = np.asarray(cmd_rotor_speeds, dtype=np.float64)
        wind = np.asarray(wind, dtype=np.float64)
        if self.use_numba:
            _step_loop(self.x, self.v, self.q, self.w, self.rotor_speeds,
                       np.ascontiguousarray(cmd), np.ascontiguousarray(wind), self.dt,
                       c["rotor_geometry"], c["rotor_dir"], c["inertia"], c["inv_inertia"], c["c_d"],
                       self._scal, c["speed_min"], c["speed_max"])
            return
        s = self._s
        s[:, 0:3] = self.x
        s[:, 3:6] = self.v
        s[:, 6:10] = self.q
        s[:, 10:13] = self.w
        s[:, 13:] = self.rotor_speeds
        cmd = np.clip(cmd, c["speed_min"], c["speed_max"])
        s = _step_numpy(s, cmd, wind, self.dt, c)
        self.x[...] = s[:, 0:3]
        self.v[...] = s[:, 3:6]
        q = s[:, 6:10]
        self.q[...] = q / np.sqrt(np.einsum("na,na->n", q, q))[:, None]
        self.w[...] = s[:, 10:13]
        np.clip(s[:, 13:], c["speed_min"], c["speed_max"], out=self.rotor_speeds)
