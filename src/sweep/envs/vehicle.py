"""Crazyflie parameters, read from RotorPy (``rotorpy.vehicles.crazyflie_params``), not retyped.

Only the motor time constant is overridden: RotorPy 3.0.0 ships tau_m = 0.072 s, the paper's
Table II uses 0.05 s (config ``env.motor_time_constant``).
"""
from __future__ import annotations

import copy

import numpy as np
from rotorpy.vehicles.crazyflie_params import quad_params as _CRAZYFLIE

GRAVITY = 9.81  # m/s^2, RotorPy's Multirotor.g


def crazyflie_params(motor_time_constant: float | None = 0.05) -> dict:
    params = copy.deepcopy(_CRAZYFLIE)
    if motor_time_constant is not None:
        params["tau_m"] = float(motor_time_constant)
    return params


def hover_rotor_speed(params: dict) -> float:
    """Rotor speed (rad/s) whose total thrust equals the weight: m g = 4 k_eta w^2."""
    return float(np.sqrt(params["mass"] * GRAVITY / (params["num_rotors"] * params["k_eta"])))
