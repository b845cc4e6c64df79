"""The interface every simulator backend implements."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from sweep.envs.vehicle import VehicleSegment


class Vehicles(NamedTuple):
    """A backend's state arrays (the same objects, not copies), as compiled code takes them."""
    x: np.ndarray             # (N,3) world position
    v: np.ndarray             # (N,3) world velocity
    q: np.ndarray             # (N,4) attitude quaternion (i, j, k, w), body to world
    w: np.ndarray             # (N,3) body rates
    rotor_speeds: np.ndarray  # (N,R) rad/s


class Backend:
    """N vehicles with RotorPy's state layout, advanced by one fixed step ``dt``.

    State arrays (float64, owned by the backend, writable by the task on reset):
      x (N,3) world position, v (N,3) world velocity, q (N,4) attitude quaternion scalar-last
      (i, j, k, w) body-to-world, w (N,3) body rates, rotor_speeds (N,4) rad/s.
    """

    def __init__(self, n: int, params: dict, dt: float) -> None:
        self.n = int(n)
        self.params = params
        self.dt = float(dt)
        self.x = np.zeros((n, 3))
        self.v = np.zeros((n, 3))
        self.q = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (n, 1))
        self.w = np.zeros((n, 3))
        self.rotor_speeds = np.zeros((n, params["num_rotors"]))

    @property
    def vehicles(self) -> Vehicles:
        return Vehicles(self.x, self.v, self.q, self.w, self.rotor_speeds)

    def set_vehicle(self, vehicle: VehicleSegment) -> None:
        """Fly ``vehicle`` (a mass factor and rotor efficiencies on ``params``) from the next step on."""
        raise NotImplementedError

    def step(self, cmd_rotor_speeds: np.ndarray, wind: np.ndarray) -> None:
        """Advance all vehicles by ``dt`` under constant commanded rotor speeds (N,4) and wind (N,3)."""
        raise NotImplementedError

    def get_state(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k).copy() for k in ("x", "v", "q", "w", "rotor_speeds")}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        for k in ("x", "v", "q", "w", "rotor_speeds"):
            getattr(self, k)[...] = state[k]
