"""The hover task as a Gymnasium environment (``sweep.envs.gym``): gymnasium's env checker, the conditions as
keyword arguments, and the same transitions as the env the studies train on."""
from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from sweep.envs import HoverVecEnv, VehicleSchedule, VehicleSegment, WindSchedule

KWARGS = dict(wind_speeds=[3.0, 3.0], wind_directions=[[1, 0, 0], [-1, 0, 0]], segment_steps=120,
              vehicle_segments=[{"mass": 1.0}, {"mass": 1.3, "rotor_efficiency": [0.7, 1, 1, 1]}])


def test_passes_gymnasiums_env_checker():
    env = gymnasium.make("sweep.envs:CrazyflieHover-v0", **KWARGS)
    check_env(env.unwrapped, skip_render_check=True)


def test_steps_as_the_studies_env_with_the_conditions_on_its_own_clock():
    """The same seed and actions give the same observations and rewards as ``HoverVecEnv`` with one vehicle; the
    condition changes at step 120 and the clock runs on across an episode's end."""
    env = gymnasium.make("sweep.envs:CrazyflieHover-v0", **KWARGS, episode_seconds=1.0)
    vec = HoverVecEnv(n_envs=1, seed=7, episode_seconds=1.0,
                      wind=WindSchedule([3.0, 3.0], segment_steps=120, directions=KWARGS["wind_directions"]),
                      vehicle=VehicleSchedule([VehicleSegment(1.0), VehicleSegment(1.3, (0.7, 1.0, 1.0, 1.0))],
                                              segment_steps=120))
    obs, info = env.reset(seed=7)
    np.testing.assert_array_equal(obs, vec.reset()[0])
    assert info["condition"].wind == (3.0, 0.0, 0.0)
    rng = np.random.default_rng(0)
    for t in range(100):   # the first episode (100 steps at 100 Hz): same transitions
        action = rng.uniform(-0.1, 0.1, size=4).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        vec_obs, vec_reward, done, infos = vec.step(action[None])
        np.testing.assert_array_equal(obs, infos[0]["terminal_observation"] if done[0] else vec_obs[0])
        assert reward == pytest.approx(float(vec_reward[0]), abs=0)
        if terminated or truncated:
            break
    assert truncated or terminated
    env.reset()
    for _ in range(30):
        *_, info = env.step(np.zeros(4, np.float32))
    assert info["condition"].wind == (-3.0, 0.0, 0.0) and info["condition"].mass == 1.3


def test_a_bad_backend_is_named():
    with pytest.raises(ValueError, match="backend='gpu': must be one of fast|rotorpy"):
        gymnasium.make("sweep.envs:CrazyflieHover-v0", backend="gpu")
