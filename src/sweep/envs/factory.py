"""The hover env of an ``env`` config (conf/config.yaml ``env:``), for training and for evaluation, and the
schedules of the ``wind`` and ``vehicle`` configs (conf/wind/, conf/vehicle/)."""
from __future__ import annotations

from hydra.utils import instantiate
from omegaconf import DictConfig

from sweep.envs.hover import HoverVecEnv
from sweep.envs.reward import HoverReward, RewardCurriculum
from sweep.envs.vehicle import VehicleSchedule, VehicleSegment
from sweep.envs.wind import WindSchedule


def make_env(env_cfg: DictConfig, n_envs: int, wind: WindSchedule, seed: int, learning: bool = False,
             vehicle: VehicleSchedule | None = None) -> HoverVecEnv:
    """The hover env of ``env_cfg`` with ``n_envs`` vehicles on the backend ``env.backend`` names among
    ``env.backends``, under ``wind`` and ``vehicle`` (None: nominal); the reward it returns is scaled by
    ``env.reward_scale``, its starts follow ``env.start`` and ``env.curriculum``, its weights
    ``env.reward_curriculum``, and it ends episodes beyond
    ``env.terminate_radius``, only for a learner
    (``learning=True``): evaluations score every agent on the same starts (+-``env.start_bound``, level, at rest) and
    bounds, with ``env.reward`` (so an evaluation's return is in the reward's units; success is not)."""
    return HoverVecEnv(
        n_envs=n_envs, backend=instantiate(env_cfg.backends[env_cfg.backend]), wind=wind, vehicle=vehicle,
        reward=HoverReward(**env_cfg.reward),
        sim_rate=env_cfg.sim_rate, episode_seconds=env_cfg.episode_seconds, start_bound=env_cfg.start_bound,
        world_bound=env_cfg.world_bound, motor_time_constant=env_cfg.motor_time_constant,
        terminate_radius=env_cfg.get("terminate_radius") if learning else None,
        observation=env_cfg.observation, time_limit=env_cfg.time_limit,
        observation_scale=dict(env_cfg.observation_scale), reward_scale=env_cfg.reward_scale if learning else 1.0,
        observe=dict(env_cfg.get("observe") or {}),
        start=dict(env_cfg.start) if learning and env_cfg.get("start") else None,
        curriculum=dict(env_cfg.curriculum) if learning and env_cfg.get("curriculum") else None,
        reward_curriculum=reward_curriculum(env_cfg.get("reward_curriculum")) if learning else None, seed=seed)


def reward_curriculum(cfg: DictConfig | None) -> RewardCurriculum | None:
    """The ``env.reward_curriculum`` block's schedule (None when absent or off: the weights stay)."""
    if cfg is None or cfg.get("every") is None:
        return None
    return RewardCurriculum(every=int(cfg.every), factor=dict(cfg.factor), limit=dict(cfg.limit),
                            recompute_replay=bool(cfg.recompute_replay))


def wind_schedule(wind_cfg: DictConfig) -> WindSchedule:
    """The training wind of a ``wind`` config (conf/wind/*.yaml)."""
    directions = wind_cfg.get("directions")
    return WindSchedule(speeds=list(wind_cfg.speeds), segment_steps=wind_cfg.segment_steps,
                        after_list=wind_cfg.after_list, direction=list(wind_cfg.direction), name=wind_cfg.name,
                        directions=None if directions is None else [list(d) for d in directions],
                        gusts=None if wind_cfg.get("gusts") is None else list(wind_cfg.gusts),
                        gust_altitude=wind_cfg.get("gust_altitude", 2.0))


def vehicle_schedule(vehicle_cfg: DictConfig) -> VehicleSchedule:
    """The training vehicle of a ``vehicle`` config (conf/vehicle/*.yaml)."""
    return VehicleSchedule(segments=[VehicleSegment.of(s) for s in vehicle_cfg.segments],
                           segment_steps=vehicle_cfg.segment_steps, after_list=vehicle_cfg.after_list,
                           name=vehicle_cfg.name)
