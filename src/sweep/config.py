"""Validation of a composed config, in one place, before anything is trained or tracked.

Each rule names a key, what is allowed, and a check. ``validate(cfg)`` raises ``ConfigError`` with a
one-line message for the first broken rule: ``train.total_timesteps=-5: must be an integer > 0``.
"""
from __future__ import annotations

import math
from typing import Any, Callable

from omegaconf import DictConfig, OmegaConf


class ConfigError(ValueError):
    """An invalid configuration value (message: key=value: what is allowed)."""


_MISSING = object()


def _get(cfg: DictConfig, key: str) -> Any:
    value = OmegaConf.select(cfg, key, default=_MISSING)
    return OmegaConf.to_object(value) if OmegaConf.is_config(value) else value


def _backend_names() -> list[str]:
    from sweep.envs.backends import BACKENDS

    return list(BACKENDS)


def _learner_names() -> list[str]:
    from sweep.agents import LEARNERS

    return list(LEARNERS)


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def positive_int(v: Any) -> bool:
    return _is_int(v) and v > 0


def positive(v: Any) -> bool:
    return _is_num(v) and v > 0


def non_negative(v: Any) -> bool:
    return _is_num(v) and v >= 0


def unit_interval(v: Any) -> bool:
    return _is_num(v) and 0 <= v <= 1


def speeds_list(v: Any) -> bool:
    return isinstance(v, list) and len(v) > 0 and all(non_negative(s) for s in v)


def vector3(v: Any) -> bool:
    return isinstance(v, list) and len(v) == 3 and all(_is_num(s) for s in v) and any(s != 0 for s in v)


def param_groups_list(v: Any) -> bool:
    return isinstance(v, list) and len(v) > 0 and set(v) <= {"policy", "value", "log_std"}


def networks_list(v: Any) -> bool:
    return isinstance(v, list) and len(v) > 0 and set(v) <= {"policy", "value"}


def one_of(*allowed: str) -> Callable[[Any], bool]:
    return lambda v: v in allowed


# (key, check, what is allowed). Keys absent from the config (e.g. agent.recom for ppo) are skipped.
RULES: list[tuple[str, Callable[[Any], bool], str]] = [
    ("seed", lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
    ("train.total_timesteps", positive_int, "an integer > 0"),
    ("train.progress_every_s", positive, "a number > 0"),
    ("train.torch_threads", positive_int, "an integer > 0"),
    ("train.checkpoint_every", positive_int, "an integer > 0 (timesteps)"),
    ("env.backend", lambda v: v in _backend_names(), "one of " + "|".join(sorted(_backend_names()))),
    ("env.n_envs", positive_int, "an integer > 0"),
    ("env.sim_rate", positive, "a number > 0 (Hz)"),
    ("env.episode_seconds", positive, "a number > 0 (s)"),
    ("env.start_bound", non_negative, "a number >= 0 (m)"),
    ("env.world_bound", positive, "a number > 0 (m)"),
    ("env.motor_time_constant", positive, "a number > 0 (s)"),
    ("env.observation", one_of("quaternion", "euler"), "quaternion|euler"),
    ("env.reward.w_p", non_negative, "a number >= 0"),
    ("env.reward.w_v", non_negative, "a number >= 0"),
    ("env.reward.w_a", non_negative, "a number >= 0"),
    ("env.reward.alive_bonus", non_negative, "a number >= 0"),
    ("env.reward.crash_reward", lambda v: v is None or _is_num(v), "a number or null (no replacement)"),
    ("env.time_limit", one_of("truncate", "terminate"), "truncate|terminate"),
    ("env.reward_scale", positive, "a number > 0"),
    ("env.observation_scale.velocity", positive, "a number > 0"),
    ("env.observation_scale.body_rate", positive, "a number > 0"),
    ("wind.speeds", speeds_list, "a non-empty list of speeds >= 0 (m/s)"),
    ("wind.segment_steps", positive_int, "an integer > 0"),
    ("wind.direction", vector3, "a non-zero 3-vector [x, y, z]"),
    ("wind.after_list", one_of("repeat", "hold"), "repeat|hold"),
    ("agent.learner", lambda v: v in _learner_names(), "one of " + "|".join(_learner_names())),
    ("agent.ppo.learning_rate", positive, "a number > 0"),
    ("agent.ppo.n_steps", lambda v: positive_int(v) and v >= 2, "an integer >= 2"),
    ("agent.ppo.batch_size", lambda v: positive_int(v) and v >= 2, "an integer >= 2"),
    ("agent.ppo.n_epochs", positive_int, "an integer > 0"),
    ("agent.ppo.gamma", unit_interval, "a number in [0, 1]"),
    ("agent.ppo.gae_lambda", unit_interval, "a number in [0, 1]"),
    ("agent.ppo.clip_range", positive, "a number > 0"),
    ("agent.ppo.ent_coef", non_negative, "a number >= 0"),
    ("agent.ppo.vf_coef", non_negative, "a number >= 0"),
    ("agent.ppo.max_grad_norm", positive, "a number > 0"),
    ("agent.policy.net_arch", lambda v: isinstance(v, list) and len(v) > 0 and all(positive_int(h) for h in v),
     "a non-empty list of layer widths > 0"),
    ("agent.policy.activation", one_of("tanh", "relu"), "tanh|relu"),
    ("agent.policy.adam_eps", positive, "a number > 0"),
    ("agent.policy.layer_norm", lambda v: isinstance(v, bool), "true|false"),
    ("agent.ppo.target_kl", lambda v: v is None or positive(v), "a number > 0 or null (off)"),
    ("agent.ppo.lr_schedule", one_of("constant", "linear", "cosine"), "constant|linear|cosine"),
    ("agent.ppo.lr_floor", non_negative, "a number >= 0"),
    ("agent.l2.coef", non_negative, "a number >= 0"),
    ("agent.l2.mode", one_of("coupled", "decoupled"), "coupled|decoupled"),
    ("agent.l2.params", param_groups_list, "a non-empty subset of [policy, value, log_std]"),
    ("agent.l2_init.coef", non_negative, "a number >= 0"),
    ("agent.l2_init.mode", one_of("coupled", "decoupled"), "coupled|decoupled"),
    ("agent.l2_init.params", param_groups_list, "a non-empty subset of [policy, value, log_std]"),
    ("agent.redo.every_updates", positive_int, "an integer > 0 (PPO updates)"),
    ("agent.redo.tau", unit_interval, "a number in [0, 1]"),
    ("agent.redo.networks", networks_list, "a non-empty subset of [policy, value]"),
    ("agent.redo.batch_size", positive_int, "an integer > 0"),
    ("agent.shrink_perturb.every_updates", positive_int, "an integer > 0 (PPO updates)"),
    ("agent.shrink_perturb.shrink", unit_interval, "a number in [0, 1]"),
    ("agent.shrink_perturb.perturb", non_negative, "a number >= 0"),
    ("agent.shrink_perturb.params", param_groups_list, "a non-empty subset of [policy, value, log_std]"),
    ("agent.cbp.replacement_rate", unit_interval, "a number in [0, 1] (per eligible unit and minibatch step)"),
    ("agent.cbp.maturity", lambda v: _is_int(v) and v >= 0, "an integer >= 0 (minibatch steps)"),
    ("agent.cbp.decay", unit_interval, "a number in [0, 1]"),
    ("agent.cbp.networks", networks_list, "a non-empty subset of [policy, value]"),
    ("agent.cbp.batch_size", positive_int, "an integer > 0"),
    ("agent.recom.interval", positive_int, "an integer > 0 (timesteps)"),
    ("agent.recom.window", positive_int, "an integer > 0 (episodes)"),
    ("agent.recom.gain", non_negative, "a number >= 0"),
    ("agent.recom.lr_min", positive, "a number > 0"),
    ("agent.recom.lr_max", positive, "a number > 0"),
    ("agent.recom.previous", one_of("last_update", "shifted"), "last_update|shifted"),
    ("agent.recom.gradient", one_of("absolute", "relative"), "absolute|relative"),
    ("agent.recom.reward", one_of("return", "per_step"), "return|per_step"),
    ("plasticity.every_rollouts", positive_int, "an integer > 0"),
    ("plasticity.tau", unit_interval, "a number in [0, 1]"),
    ("plasticity.batch_size", positive_int, "an integer > 0"),
    ("plasticity.saturation", unit_interval, "a number in [0, 1]"),
    ("plasticity.srank_delta", unit_interval, "a number in [0, 1]"),
    ("plasticity.extra_taus", lambda v: isinstance(v, list) and all(unit_interval(t) for t in v),
     "a list of numbers in [0, 1]"),
    ("plasticity.dead_fraction", unit_interval, "a number in [0, 1]"),
    ("plasticity.probe.steps", lambda v: _is_int(v) and v >= 0, "an integer >= 0 (0: no probe)"),
    ("plasticity.probe.batch_size", positive_int, "an integer > 0"),
    ("plasticity.probe.lr", positive, "a number > 0"),
    ("plasticity.probe.observations", positive_int, "an integer > 0"),
    ("plasticity.signed_mean_tau", unit_interval, "a number in [0, 1]"),
    ("eval.policy", one_of("final", "best", "both"), "final|best|both"),
    ("eval.episodes", positive_int, "an integer >= 1"),
    ("eval.every_timesteps", lambda v: _is_int(v) and v >= 0, "an integer >= 0 (0: only at the end)"),
    ("eval.wind_speed", non_negative, "a number >= 0 (m/s)"),
    ("eval.direction", vector3, "a non-zero 3-vector [x, y, z]"),
    ("eval.seed", lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
    ("eval.success_radius", positive, "a number > 0 (m)"),
    ("eval.success_hold_s", non_negative, "a number >= 0 (s)"),
    ("tracking.flush_every_s", non_negative, "a number >= 0 (s; 0 writes every logger dump at once)"),
    ("tracking.experiment", lambda v: isinstance(v, str) and v.strip() != "", "a non-empty string"),
]




def validate(cfg: DictConfig) -> None:
    """Raise ConfigError naming the first invalid key, its value and what is allowed."""
    for key, check, allowed in RULES:
        value = _get(cfg, key)
        if value is _MISSING:
            continue
        if not check(value):
            raise ConfigError(f"{key}={value!r}: must be {allowed}")
    lr_min, lr_max = _get(cfg, "agent.recom.lr_min"), _get(cfg, "agent.recom.lr_max")
    if lr_min is not _MISSING and lr_max is not _MISSING and lr_min > lr_max:
        raise ConfigError(f"agent.recom.lr_min={lr_min!r} > agent.recom.lr_max={lr_max!r}: must be lr_min <= lr_max")
    if _get(cfg, "agent.l2.enabled") is True and _get(cfg, "agent.l2_init.enabled") is True:
        raise ConfigError("agent.l2.enabled=True and agent.l2_init.enabled=True: must be one of them (both set the "
                          "optimizer's weight decay; L2 pulls toward 0, L2-Init toward theta_0)")
    if _get(cfg, "agent.recom.enabled") is True and _get(cfg, "agent.ppo.lr_schedule") not in (_MISSING, "constant"):
        raise ConfigError(f"agent.ppo.lr_schedule={_get(cfg, 'agent.ppo.lr_schedule')!r}: must be constant with "
                          "agent.recom.enabled=True (RECOM sets the learning rate itself)")
    rollout = _get(cfg, "agent.ppo.n_steps") * _get(cfg, "env.n_envs")
    batch = _get(cfg, "agent.ppo.batch_size")
    if batch > rollout:
        raise ConfigError(f"agent.ppo.batch_size={batch!r}: must be <= the rollout size "
                          f"agent.ppo.n_steps x env.n_envs = {rollout}")
    if _get(cfg, "agent.learner") == "jax":
        if rollout % batch:
            raise ConfigError(f"agent.ppo.batch_size={batch!r}: with agent.learner=jax must divide the rollout size "
                              f"agent.ppo.n_steps x env.n_envs = {rollout}")
        if _get(cfg, "env.backend") != "fast":
            raise ConfigError(f"env.backend={_get(cfg, 'env.backend')!r}: agent.learner=jax steps the env in its compiled "
                              f"rollout, which needs env.backend=fast")
