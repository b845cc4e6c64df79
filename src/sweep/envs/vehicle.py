"""Crazyflie parameters, read from RotorPy (``rotorpy.vehicles.crazyflie_params``), not retyped, and the vehicle
schedule (``conf/vehicle/``): what changes about the vehicle segment by segment.

Only the motor time constant is overridden: RotorPy 3.0.0 ships tau_m = 0.072 s, the paper's
Table II uses 0.05 s (config ``env.motor_time_constant``).

A ``VehicleSegment`` scales the vehicle for its segment:

* ``mass``: a payload as a factor on RotorPy's mass *and* inertia (a payload at the centre of mass, spread as the
  airframe is, a choice: README "Conditions"); thrust-to-weight 1.95 nominal, 1.50 at 1.3, 1.30 at 1.5;
* ``rotor_efficiency``: per rotor, the share of RotorPy's thrust it makes, ``k_eta * eta_i * w_i^2`` (a
  degraded motor or a chipped propeller; rotor drag, yaw moment and translational lift are RotorPy's unchanged).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from rotorpy.vehicles.crazyflie_params import quad_params as _CRAZYFLIE

from sweep.envs.schedule import segment_index

GRAVITY = 9.81  # m/s^2, RotorPy's Multirotor.g
INERTIA_KEYS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


def crazyflie_params(motor_time_constant: float | None = 0.05) -> dict:
    params = copy.deepcopy(_CRAZYFLIE)
    if motor_time_constant is not None:
        params["tau_m"] = float(motor_time_constant)
    return params


def hover_rotor_speed(params: dict) -> float:
    """Rotor speed (rad/s) whose total thrust equals the weight: m g = 4 k_eta w^2."""
    return float(np.sqrt(params["mass"] * GRAVITY / (params["num_rotors"] * params["k_eta"])))


@dataclass(frozen=True)
class VehicleSegment:
    """The vehicle of one segment: a mass (and inertia) factor and each rotor's thrust efficiency."""
    mass: float = 1.0
    rotor_efficiency: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mass) and self.mass > 0):
            raise ValueError(f"vehicle mass factor {self.mass!r}: must be a number > 0")
        if len(self.rotor_efficiency) != 4 or not all(0 < e <= 1 for e in self.rotor_efficiency):
            raise ValueError(f"rotor_efficiency {list(self.rotor_efficiency)!r}: must be 4 numbers in (0, 1]")

    @classmethod
    def of(cls, block) -> "VehicleSegment":
        """From a mapping with ``mass`` and ``rotor_efficiency`` (a ``vehicle.segments`` entry, an ``eval`` block,
        a Gymnasium keyword), either left out meaning RotorPy's value."""
        return cls(float(block.get("mass", 1.0)), tuple(float(e) for e in block.get("rotor_efficiency", (1.0,) * 4)))

    @property
    def nominal(self) -> bool:
        return self.mass == 1.0 and all(e == 1.0 for e in self.rotor_efficiency)


NOMINAL = VehicleSegment()


def thrust_to_weight(params: dict, segment: VehicleSegment) -> float:
    """Total thrust at full rotor speed over the weight of the segment's vehicle (1.95 for RotorPy's Crazyflie)."""
    thrust = params["k_eta"] * params["rotor_speed_max"] ** 2 * sum(segment.rotor_efficiency)
    return float(thrust / (params["mass"] * segment.mass * GRAVITY))


def scaled_params(params: dict, segment: VehicleSegment) -> dict:
    """RotorPy params with the segment's mass factor applied to the mass and every inertia entry (the rotor
    efficiency is not a RotorPy parameter: the backends apply it to the thrust)."""
    out = copy.deepcopy(params)
    out["mass"] = params["mass"] * segment.mass
    for k in INERTIA_KEYS:
        out[k] = params[k] * segment.mass
    return out


@dataclass
class VehicleSchedule:
    segments: Sequence[VehicleSegment] = (NOMINAL,)
    segment_steps: int = 2_000_000
    after_list: str = "repeat"     # repeat | hold
    name: str = "nominal"
    _distinct: int = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.segments = [s if isinstance(s, VehicleSegment) else VehicleSegment.of(s) for s in self.segments]
        self._distinct = len(set(self.segments))

    @property
    def varies(self) -> bool:
        """More than one distinct vehicle in the list."""
        return self._distinct > 1

    def index(self, global_step):
        return segment_index(global_step, self.segment_steps, len(self.segments), self.after_list)

    def at(self, global_step: int) -> VehicleSegment:
        """The vehicle in force at ``global_step``."""
        return self.segments[self.index(global_step)]
