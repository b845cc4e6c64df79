"""The hover success criterion on synthetic flights (sweep.evaluate.hover_success)."""
from __future__ import annotations

import numpy as np

from sweep.evaluate import hover_success

R, HOLD = 0.1, 5


def flight(tail_point, before=(1.5, -1.0, 0.5), steps=20):
    """A flight far away for ``steps - HOLD`` states, then ``HOLD`` states at ``tail_point``."""
    return np.array([before] * (steps - HOLD) + [tail_point] * HOLD, dtype=float)


def test_inside_the_ball_for_the_whole_hold_is_a_success():
    assert hover_success(flight((0.03, -0.02, 0.05)), False, R, HOLD)


def test_outside_the_ball_is_a_failure():
    assert not hover_success(flight((0.2, 0.0, 0.0)), False, R, HOLD)
    assert not hover_success(flight((0.06, 0.06, 0.06)), False, R, HOLD)  # each axis inside, norm 0.104 outside


def test_exactly_on_the_boundary_counts_as_inside():
    assert hover_success(flight((R, 0.0, 0.0)), False, R, HOLD)
    assert hover_success(flight((0.0, 0.0, -R)), False, R, HOLD)


def test_leaving_the_ball_during_the_hold_is_a_failure():
    pos = flight((0.0, 0.0, 0.0))
    pos[-2] = (0.0, 0.15, 0.0)
    assert not hover_success(pos, False, R, HOLD)


def test_only_the_final_hold_matters():
    pos = flight((0.0, 0.0, 0.0))
    pos[-HOLD - 1] = (3.0, 3.0, 3.0)  # just before the hold window
    assert hover_success(pos, False, R, HOLD)


def test_a_crashed_flight_is_never_a_success():
    assert not hover_success(flight((0.0, 0.0, 0.0)), True, R, HOLD)


def test_empty_flight_is_a_failure():
    assert not hover_success(np.zeros((0, 3)), False, R, HOLD)
