"""The evaluation protocol: the success criterion and the scoring rule on hand-built flights, and evaluate()
on real flights of fixed policies."""
from __future__ import annotations

import numpy as np
import pytest

from sweep.evaluate import evaluate, flight_metrics, hover_success, scored_positions

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


# ---- the scoring rule: T post-step states, a crashed flight holds its exit position ----------------------------

def test_scored_positions_drop_the_start_and_hold_the_exit_position():
    nan = [np.nan] * 3
    flight = np.array([(9.0, 9, 9), (1.0, 0, 0), (2.0, 0, 0), (5.0, 0, 0), nan, nan])  # T = 5, ended at step 3
    np.testing.assert_array_equal(scored_positions(flight)[:, 0], [1.0, 2.0, 5.0, 5.0, 5.0])


def test_flight_metrics_by_hand():
    steady = np.array([(1.5, 1.5, 1.5)] + [(0.1, -0.2, 0.3)] * 5)
    m = flight_metrics(steady, False, radius=0.5, hold_steps=2)
    assert (m["mse_x"], m["mse_y"], m["mse_z"]) == pytest.approx((0.01, 0.04, 0.09))
    assert m["final_distance"] == pytest.approx(np.sqrt(0.14)) and m["success"] == 1.0
    nan = [np.nan] * 3
    crash = np.array([(0.0, 0, 1.0), (1.0, 0, 0), (2.0, 0, 0), (5.0, 0, 0), nan, nan])
    m = flight_metrics(crash, True, radius=0.5, hold_steps=2)
    assert m["mse_x"] == pytest.approx((1 + 4 + 25 + 25 + 25) / 5) and m["mse_z"] == 0.0  # start's z = 1 not scored
    assert m["final_distance"] == 5.0 and m["success"] == 0.0


@pytest.mark.parametrize("name,crash_rate,success", [("motors off", 1.0, 0.0), ("RotorPy SE3 controller", 0.0, 1.0)])
def test_evaluate_scores_real_flights_with_the_rule(monkeypatch, name, crash_rate, success):
    """evaluate() on real flights of fixed policies (no wind): every flight crashes / every flight hovers."""
    import sweep.evaluate
    from conftest import compose_cfg
    from sweep.fixed_policies import POLICIES, FixedPolicy

    built, original = {}, sweep.evaluate.make_env

    def make_env(*args, **kwargs):  # the fixed policy flies the env evaluate() builds (SE3 reads its state)
        env = original(*args, **kwargs)
        built["policy"] = FixedPolicy(env, POLICIES[name](env))
        return env

    class Policy:
        def predict(self, obs, deterministic=True):
            return built["policy"].predict(obs, deterministic)

    monkeypatch.setattr(sweep.evaluate, "make_env", make_env)
    cfg = compose_cfg(["eval.episodes=4", "eval.wind_speed=0.0"])
    metrics, flights = evaluate(Policy(), cfg.eval, cfg.env)
    assert metrics["crash_rate"] == crash_rate and metrics["success_rate"] == success
    scored = np.stack([scored_positions(p) for p in flights["positions"]])
    assert scored.shape == (4, 500, 3) and not np.isnan(scored).any()
    np.testing.assert_allclose(metrics["mse_z"], np.mean(scored[:, :, 2] ** 2))
    np.testing.assert_allclose(flights["mse"], np.mean(scored ** 2, axis=1))
    assert metrics["return"] == pytest.approx(flights["rewards"].sum(axis=1).mean())
