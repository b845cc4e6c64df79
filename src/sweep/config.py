"""The config schema, in one place for the run and beside each hook for its own block.

``SweepConfig`` mirrors conf/ (conf/config.yaml, one agent YAML, one wind YAML, one vehicle YAML): the YAML files
hold the values and their comments, the dataclasses below the types (an ``Enum`` for a choice) and, in each field's
``check``, the range a type cannot say. The schema is registered in Hydra's ConfigStore as ``sweep_schema``
(``compose(config_name="sweep_schema")`` gives it, every value ``???``). It is not in conf/config.yaml's defaults
list: Hydra reports a schema error at composition in several lines with exit code 1, and a sweep must instead name
the first bad key in one line and exit 2 before anything is trained or tracked. So ``validate(cfg)`` merges the
composed config into the schema and raises ``ConfigError``: ``train.total_timesteps=-5: must be an integer > 0``.

Hook blocks (an agent's remedies ``agent.<name>`` from conf/remedy/, and ``hooks.<name>`` from conf/hooks/) are
checked against the ``Settings`` dataclass their class declares beside itself (a ``HookSettings`` subclass built
with the helpers below), and then by the class's own ``check_config`` for rules across keys (RECOM wants a
constant LR schedule): a new remedy brings its schema along and touches nothing here. A block whose class
declares no schema is a config error.
"""
from __future__ import annotations

import dataclasses
import math
import typing
from pathlib import Path
from dataclasses import dataclass, field, fields, is_dataclass
from enum import Enum
from typing import Any, Callable, Dict, List, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf, open_dict


class ConfigError(ValueError):
    """An invalid configuration value (message: key=value: what is allowed)."""


# ---- choices ---------------------------------------------------------------------------------------------------
def choice(name: str, *values: str) -> type[Enum]:
    return Enum(name, {v: v for v in values})


Observation = choice("Observation", "quaternion", "euler")
TimeLimit = choice("TimeLimit", "truncate", "terminate")
ActionReference = choice("ActionReference", "zero", "hover")
AfterList = choice("AfterList", "repeat", "hold")
Activation = choice("Activation", "tanh", "relu")
LRSchedule = choice("LRSchedule", "constant", "linear", "cosine")
EvalPolicy = choice("EvalPolicy", "final", "best", "both")
EvalCondition = choice("EvalCondition", "fixed", "current", "all")


# ---- ranges ----------------------------------------------------------------------------------------------------
def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def key(check: Callable[[Any], bool] | None = None, allowed: str = "", default: Any = MISSING) -> Any:
    """A schema field: ``check`` (on the typed value) and the text naming what is allowed."""
    return field(default=default, metadata={"check": check, "allowed": allowed})


def at_least(low: float, what: str = "an integer", unit: str = "") -> Any:
    return key(lambda v: v >= low, f"{what} >= {low:g}{unit}")


def positive_int(unit: str = "") -> Any:
    return key(lambda v: v > 0, f"an integer > 0{unit}")


def positive(unit: str = "") -> Any:
    return key(lambda v: _finite(v) and v > 0, f"a number > 0{unit}")


def non_negative(unit: str = "") -> Any:
    return key(lambda v: _finite(v) and v >= 0, f"a number >= 0{unit}")


def unit_interval(unit: str = "") -> Any:
    return key(lambda v: _finite(v) and 0 <= v <= 1, f"a number in [0, 1]{unit}")


def non_empty(what: str) -> Any:
    return key(lambda v: len(v) > 0, what)


def vector3() -> Any:
    return key(lambda v: len(v) == 3 and all(_finite(s) for s in v) and any(s != 0 for s in v),
               "a non-zero 3-vector [x, y, z]")




# ---- the tree (conf/config.yaml top to bottom) --------------------------------------------------------------------
@dataclass
class Reward:
    w_p: float = non_negative()
    w_v: float = non_negative()
    w_a: float = non_negative()
    alive_bonus: float = non_negative()
    crash_reward: Optional[float] = key(lambda v: v is None or _finite(v), "a number or null (no replacement)")
    power: int = key(lambda v: v in (1, 2), "1 (norms, Eqs. 3-4) or 2 (squared norms)")
    w_q: float = non_negative(" (attitude cost on 1 - q_w^2)")
    action_reference: ActionReference = MISSING


@dataclass
class ObservationScale:
    velocity: float = positive()
    body_rate: float = positive()


@dataclass
class Observe:
    rotor_speeds: bool = MISSING
    action_history: int = at_least(0, unit=" (actions; 0: none)")
    critic_rotor_speeds: bool = MISSING
    critic_condition: bool = MISSING


@dataclass
class Start:
    tilt_deg: float = key(lambda v: _finite(v) and 0 <= v <= 180, "a number in [0, 180] (degrees)")
    velocity: float = key(lambda v: _finite(v) and 0 <= v < 100,
                          "a number in [0, 100) (m/s; 100 leaves RotorPy's safe region at once)")
    body_rate: float = key(lambda v: _finite(v) and 0 <= v < 100,
                           "a number in [0, 100) (rad/s; 100 leaves RotorPy's safe region at once)")


@dataclass
class Curriculum:
    start_bound_from: Optional[float] = key(lambda v: v is None or (_finite(v) and v >= 0),
                                            "a number >= 0 (m) or null (no curriculum)")
    steps: int = positive_int(" (env steps)")


@dataclass
class CurriculumFactors:
    w_p: float = positive(" (x per stage; 1: held)")
    w_v: float = positive(" (x per stage; 1: held)")
    w_a: float = positive(" (x per stage; 1: held)")
    w_q: float = positive(" (x per stage; 1: held)")


def _limit() -> Any:
    return key(lambda v: v is None or (_finite(v) and v >= 0), "a number >= 0 or null (no limit)", default=None)


@dataclass
class CurriculumLimits:
    w_p: Optional[float] = _limit()
    w_v: Optional[float] = _limit()
    w_a: Optional[float] = _limit()
    w_q: Optional[float] = _limit()


@dataclass
class RewardCurriculum:
    every: Optional[int] = key(lambda v: v is None or v > 0, "an integer > 0 (env steps) or null (no curriculum)",
                               default=None)
    factor: CurriculumFactors = field(default_factory=CurriculumFactors)
    limit: CurriculumLimits = field(default_factory=CurriculumLimits)
    recompute_replay: bool = MISSING


@dataclass
class Target:
    """A block built by hydra.utils.instantiate from its ``_target_``."""
    _target_: str = MISSING


@dataclass
class Factory(Target):
    """A class (or its from_config) that the code calls later: conf/learner/, conf/backend/."""
    _partial_: bool = key(lambda v: v is True, "true (the code calls the class with its arguments later)")


@dataclass
class Env:
    backend: str = MISSING   # a key of backends: checked in _cross_rules
    backends: Dict[str, Factory] = field(default_factory=dict)
    n_envs: int = positive_int()
    sim_rate: float = positive(" (Hz)")
    episode_seconds: float = positive(" (s)")
    start_bound: float = non_negative(" (m)")
    world_bound: float = positive(" (m)")
    terminate_radius: Optional[float] = key(lambda v: v is None or (_finite(v) and v > 0),
                                            "a number > 0 (m) or null (no such bound)")
    motor_time_constant: float = positive(" (s)")
    observation: Observation = MISSING
    observation_scale: ObservationScale = field(default_factory=ObservationScale)
    observe: Observe = field(default_factory=Observe)
    start: Start = field(default_factory=Start)
    curriculum: Curriculum = field(default_factory=Curriculum)
    reward_curriculum: RewardCurriculum = field(default_factory=RewardCurriculum)
    reward_scale: float = positive()
    time_limit: TimeLimit = MISSING
    reward: Reward = field(default_factory=Reward)


@dataclass
class Train:
    total_timesteps: int = positive_int()
    progress_every_s: float = positive()
    torch_threads: int = positive_int()
    checkpoint_every: int = positive_int(" (timesteps)")
    checkpoint_dir: Optional[str] = MISSING
    portable: bool = MISSING


@dataclass
class Probe:
    steps: int = at_least(0, unit=" (0: no probe)")
    batch_size: int = positive_int()
    lr: float = positive()
    observations: int = positive_int()
    fresh: bool = MISSING


@dataclass
class Plasticity:
    every_rollouts: int = positive_int()
    tau: float = unit_interval()
    batch_size: int = positive_int()
    saturation: float = unit_interval()
    extra_taus: List[float] = key(lambda v: all(_finite(t) and 0 <= t <= 1 for t in v), "a list of numbers in [0, 1]")
    dead_fraction: float = unit_interval()
    signed_mean_tau: float = unit_interval()
    activation: Activation = MISSING
    probe: Probe = field(default_factory=Probe)
    srank_delta: float = unit_interval()


@dataclass
class Eval:
    policy: EvalPolicy = MISSING
    episodes: int = key(lambda v: v >= 1, "an integer >= 1")
    every_timesteps: int = at_least(0, unit=" (0: only at the end)")
    condition: EvalCondition = MISSING
    wind_speed: float = non_negative(" (m/s)")
    direction: List[float] = vector3()
    gust: float = non_negative(" (Dryden sigma, RotorPy's sig_wind)")
    mass: float = key(lambda v: _finite(v) and v > 0, "a number > 0 (factor on RotorPy's mass and inertia)")
    rotor_efficiency: List[float] = key(lambda v: _efficiencies_ok(v), "4 numbers in (0, 1] (each rotor's share of its thrust)")
    seed: int = at_least(0)
    success_radius: float = positive(" (m)")
    success_hold_s: float = non_negative(" (s)")


@dataclass
class Tracking:
    experiment: str = key(lambda v: v.strip() != "", "a non-empty string")
    uri: Optional[str] = MISSING
    log_model: bool = MISSING
    flush_every_s: float = non_negative(" (s; 0 writes every logger dump at once)")


def _vector3_ok(v: Any) -> bool:
    return isinstance(v, list) and len(v) == 3 and all(_finite(s) for s in v) and any(s != 0 for s in v)


def _efficiencies_ok(v: Any) -> bool:
    return len(v) == 4 and all(_finite(e) and 0 < e <= 1 for e in v)


@dataclass
class Wind:
    name: str = MISSING
    speeds: List[float] = key(lambda v: len(v) > 0 and all(_finite(s) and s >= 0 for s in v),
                              "a non-empty list of speeds >= 0 (m/s)")
    segment_steps: int = positive_int()
    after_list: AfterList = MISSING
    direction: List[float] = vector3()
    directions: Optional[List[List[float]]] = key(lambda v: v is None or (len(v) > 0 and all(map(_vector3_ok, v))),
                                                  "null or a list of non-zero 3-vectors [x, y, z], one per speed")
    gusts: Optional[List[float]] = key(lambda v: v is None or (len(v) > 0 and all(_finite(g) and g >= 0 for g in v)),
                                       "null or a list of Dryden sigmas >= 0 (RotorPy's sig_wind), one per speed")
    gust_altitude: float = positive(" (m)")


@dataclass
class VehicleSegment:
    mass: float = key(lambda v: _finite(v) and v > 0, "a number > 0 (factor on RotorPy's mass and inertia)")
    rotor_efficiency: List[float] = key(_efficiencies_ok, "4 numbers in (0, 1] (each rotor's share of its thrust)")


@dataclass
class Vehicle:
    name: str = MISSING
    segments: List[VehicleSegment] = non_empty("a non-empty list of {mass, rotor_efficiency} segments")
    segment_steps: int = positive_int()
    after_list: AfterList = MISSING


@dataclass
class PPO:
    """SB3 PPO's arguments (agent.ppo), and the two controls."""
    learning_rate: float = positive()
    n_steps: int = at_least(2)
    batch_size: int = at_least(2)
    n_epochs: int = positive_int()
    gamma: float = unit_interval()
    gae_lambda: float = unit_interval()
    clip_range: float = positive()
    ent_coef: float = non_negative()
    vf_coef: float = non_negative()
    max_grad_norm: float = positive()
    target_kl: Optional[float] = key(lambda v: v is None or (_finite(v) and v > 0), "a number > 0 or null (off)")
    lr_schedule: LRSchedule = MISSING
    lr_floor: float = non_negative()
    lr_decay_timesteps: Optional[int] = key(lambda v: v is None or v > 0, "an integer > 0 or null (the whole run)")


def _auto_or_positive(v: Any) -> bool:
    return v == "auto" or (isinstance(v, (int, float)) and not isinstance(v, bool) and _finite(v) and v > 0)


@dataclass
class OffPolicy:
    """SB3's SAC/TD3 arguments common to both (agent.sac, agent.td3), the round and the LR-decay controls."""
    learning_rate: float = positive()
    buffer_size: int = positive_int(" (transitions)")
    learning_starts: int = at_least(0, unit=" (env steps of uniform random actions before the first update)")
    batch_size: int = positive_int()
    tau: float = key(lambda v: _finite(v) and 0 < v <= 1, "a number in (0, 1] (Polyak coefficient)")
    gamma: float = unit_interval()
    train_freq: int = positive_int(" (env steps per env between two updates)")
    gradient_steps: int = key(lambda v: v == -1 or v >= 0, "an integer >= 0, or -1 (as many as the env steps collected)")
    round_steps: int = positive_int(" (env steps between two log lines and hook calls)")
    action_noise_std: Optional[float] = key(lambda v: v is None or (_finite(v) and v > 0),
                                            "a number > 0 (Gaussian exploration noise) or null (none)")
    lr_schedule: LRSchedule = MISSING
    lr_floor: float = non_negative()
    lr_decay_timesteps: Optional[int] = key(lambda v: v is None or v > 0, "an integer > 0 or null (the whole run)")


@dataclass
class SAC(OffPolicy):
    """SB3 SAC's own arguments (agent.sac)."""
    ent_coef: Any = key(_auto_or_positive, "auto (learned, init 1) or a number > 0 (fixed)")
    target_entropy: Any = key(lambda v: v == "auto" or (isinstance(v, (int, float)) and not isinstance(v, bool)
                                                         and _finite(v)), "auto (-dim(A)) or a number")
    target_update_interval: int = positive_int(" (gradient steps)")


@dataclass
class TD3(OffPolicy):
    """SB3 TD3's own arguments (agent.td3)."""
    policy_delay: int = positive_int(" (critic steps per actor step)")
    target_policy_noise: float = non_negative()
    target_noise_clip: float = non_negative()


ALGORITHMS = ("ppo", "sac", "td3")   # an agent's algorithm is the one of these blocks it has


@dataclass
class Policy:
    net_arch: List[int] = key(lambda v: len(v) > 0 and all(h > 0 for h in v), "a non-empty list of layer widths > 0")
    activation: Activation = MISSING
    layer_norm: bool = MISSING
    adam_eps: float = positive()


@dataclass
class HookSettings(Target):
    """The settings schema of a hook or remedy block (an ``agent.<name>`` block or a ``hooks.<name>`` block): its
    class declares a subclass of this as ``Settings``, one field per argument of its ``__init__``, beside the class
    (e.g. ``sweep.plasticity.redo.ReDo.Settings``). ``enabled`` (default true) switches the block off."""
    enabled: bool = key(lambda v: isinstance(v, bool), "true|false", default=True)


@dataclass
class Agent:
    name: str = MISSING
    label: str = MISSING
    learner: str = MISSING   # a key of learners: checked in _cross_rules
    learners: Dict[str, Factory] = field(default_factory=dict)
    algorithm: str = key(lambda v: v in ALGORITHMS, "|".join(ALGORITHMS), default="ppo")
    ppo: Optional[PPO] = None   # the block of agent.algorithm: its hyperparameters (another's: unused_algorithm_blocks)
    sac: Optional[SAC] = None
    td3: Optional[TD3] = None
    policy: Policy = field(default_factory=Policy)
    twin: Optional[str] = key(lambda v: v in (None, "fresh"), "fresh (twin=fresh, conf/twin/) or absent", default=None)
    # and the agent's remedies: any other key holding a block with a _target_ (conf/remedy/), checked against the
    # ``Settings`` of the class it names (``validate``)


@dataclass
class SweepConfig:
    agent: Agent = field(default_factory=Agent)
    wind: Wind = field(default_factory=Wind)
    vehicle: Vehicle = field(default_factory=Vehicle)
    seed: int = at_least(0)
    resume: Any = key(lambda v: isinstance(v, (str, int)) and not isinstance(v, bool),   # run.job_record resolves it
                      "auto, never, a job output dir or an MLflow run id")
    env: Env = field(default_factory=Env)
    train: Train = field(default_factory=Train)
    plasticity: Plasticity = field(default_factory=Plasticity)
    eval: Eval = field(default_factory=Eval)
    tracking: Tracking = field(default_factory=Tracking)
    hooks: Dict[str, Any] = field(default_factory=dict, metadata={
        "check": lambda v: all(isinstance(h, dict) and "_target_" in h for h in v.values()),
        "allowed": "a block of named hooks, each with a _target_ (conf/hooks/)"})


ConfigStore.instance().store(name="sweep_schema", node=SweepConfig)

# Which class builds a learner / backend, and the hooks (whose settings are interpolations of documented keys):
# wiring, not a setting of the run (agent.learner and env.backend, the names, are). Left out of the logged MLflow
# params; a job's resume key has the hooks' names and classes (sweep.checkpoint.job_key).
WIRING = (("agent", "learners"), ("env", "backends"), (None, "hooks"))


# Env blocks added after runs were archived, and when a block means "as before" (the job runs what it ran before the
# block existed): such a block stays out of the job's resume key, so adding it moved no key (sweep.checkpoint.job_key).
ENV_AS_BEFORE: dict[str, Callable[[dict], bool]] = {
    "observe": lambda b: not any(b.get(k) for k in ("rotor_speeds", "action_history", "critic_rotor_speeds",
                                                     "critic_condition")),
    "start": lambda b: not any(b.get(k) for k in ("tilt_deg", "velocity", "body_rate")),
    "curriculum": lambda b: b.get("start_bound_from") is None,
    "reward_curriculum": lambda b: b.get("every") is None,
}
# Env keys added since, with the value that means "as before": dropped when they hold it. Top-level keys under "",
# a block's keys under its name.
ENV_KEYS_AS_BEFORE: dict[str, dict[str, Any]] = {
    "": {"terminate_radius": None},
    "reward": {"power": 1, "w_q": 0.0, "action_reference": "zero"},
}


def drop_as_before(env: dict) -> dict:
    """Remove from a resolved ``env`` block (the run's, or a hook's copy of it) the ENV_AS_BEFORE blocks and the
    ENV_KEYS_AS_BEFORE keys that mean "as before"; returns it."""
    for name, unchanged in ENV_AS_BEFORE.items():
        if isinstance(env.get(name), dict) and unchanged(env[name]):
            env.pop(name)
    for block, defaults in ENV_KEYS_AS_BEFORE.items():
        keys = env if not block else env.get(block)
        for name, value in defaults.items() if isinstance(keys, dict) else ():
            if name in keys and keys[name] == value:
                keys.pop(name)
    return env


def settings(cfg: DictConfig) -> dict:
    """The resolved config as plain containers, without the WIRING blocks."""
    container = OmegaConf.to_container(cfg, resolve=True)
    for group, name in WIRING:
        (container if group is None else container.get(group, {})).pop(name, None)
    return container


# ---- validation ------------------------------------------------------------------------------------------------
def _hints(cls: type) -> dict[str, Any]:
    """Field types; a class declared elsewhere (a hook's ``Settings``) is read in its own module's names."""
    return typing.get_type_hints(cls)


def _what(typ: Any) -> str:
    """What a type allows, as the error message says it."""
    if typing.get_origin(typ) is typing.Union:
        inner = [a for a in typing.get_args(typ) if a is not type(None)][0]
        return f"{_what(inner)} or null"
    if typing.get_origin(typ) is list:
        return f"a list whose items are each {_what(typing.get_args(typ)[0])}"
    if is_dataclass(typ):
        return "a block with keys " + ", ".join(f.name for f in fields(typ))
    if isinstance(typ, type) and issubclass(typ, Enum):
        return "|".join(typ.__members__)
    return {int: "an integer", float: "a number", bool: "true|false", str: "a string"}.get(typ, str(typ))


def _scalar_ok(value: Any, typ: Any) -> bool:
    """The value's own Python type fits: no conversion (OmegaConf would read 'no' as false and '5' as 5)."""
    if typ is Any:
        return True
    if isinstance(typ, type) and issubclass(typ, Enum):
        return isinstance(value, str) and value in typ.__members__
    if typ is bool:
        return isinstance(value, bool)
    if typ is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if typ is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    return isinstance(value, typ)


def _fail(key: str, value: Any, allowed: str) -> ConfigError:
    return ConfigError(f"{key}={value!r}: must be {allowed}")


def _check(value: Any, typ: Any, key: str, meta: Any = None) -> None:
    """Raise ConfigError at the first value under ``key`` that the schema type ``typ`` (and the field's range
    check in ``meta``) does not allow, depth first in the schema's order."""
    allowed = (meta or {}).get("allowed") or _what(typ)
    if value == "???":
        raise ConfigError(f"{key}: missing; must be {allowed}")
    origin = typing.get_origin(typ)
    if origin is typing.Union:
        if value is None:
            return
        typ = [a for a in typing.get_args(typ) if a is not type(None)][0]
        origin = typing.get_origin(typ)
    if is_dataclass(typ):
        if not isinstance(value, dict):
            raise _fail(key, value, _what(typ))
        names, hints = [f.name for f in fields(typ)], _hints(typ)
        for name in value:
            if name not in names:
                raise ConfigError(f"{key}.{name}: not a config key (allowed under {key}: {', '.join(names)})")
        for f in fields(typ):
            if f.name not in value and f.default is not dataclasses.MISSING and f.default != MISSING:
                continue   # a schema default (e.g. HookSettings.enabled, true): the class's own default applies
            if f.name not in value:
                raise ConfigError(f"{key}.{f.name}: missing; must be {f.metadata.get('allowed') or _what(hints[f.name])}")
            _check(value[f.name], hints[f.name], f"{key}.{f.name}", f.metadata)
        return
    if origin is dict:
        if not isinstance(value, dict):
            raise _fail(key, value, "a block of named entries")
        for name, item in value.items():
            _check(item, typing.get_args(typ)[1], f"{key}.{name}")
        check = (meta or {}).get("check")
        if check is not None and not check(value):
            raise _fail(key, value, allowed)
        return
    if origin is list:
        item_type = typing.get_args(typ)[0]
        if not isinstance(value, list):
            raise _fail(key, value, allowed)
        if is_dataclass(item_type) or typing.get_origin(item_type) is list:
            for i, item in enumerate(value):
                _check(item, item_type, f"{key}[{i}]")
        elif not all(_scalar_ok(v, item_type) for v in value):
            raise _fail(key, value, allowed)
    elif not _scalar_ok(value, typ):
        raise _fail(key, value, allowed)
    check = (meta or {}).get("check")
    if check is not None and not check(value):
        raise _fail(key, value, allowed)


def one_line(err: BaseException) -> str:
    """An error's whole message on one line (Hydra's instantiation errors put the cause on the lines below)."""
    return " ".join(line.strip() for line in str(err).splitlines() if line.strip())


def component_class(block: dict, where: str) -> type:
    """The class a block's ``_target_`` names (ConfigError if it cannot be imported)."""
    from hydra.utils import get_class

    target = block.get("_target_")
    if not isinstance(target, str) or not target.strip():
        raise ConfigError(f"{where}._target_={target!r}: must be the dotted path of a class")
    try:
        return get_class(target)
    except Exception as err:  # noqa: BLE001 - an import error of the user's module, or no such class
        raise ConfigError(f"{where}._target_={target!r}: cannot be imported ({one_line(err.__cause__ or err)})") from None


def remedy_blocks(agent: dict) -> dict[str, dict]:
    """The agent's remedy blocks, in config order: every ``agent.<name>`` block with a ``_target_`` (plain dicts of
    the resolved config; the one rule the schema, the hook builder and the job key share)."""
    known = {f.name for f in fields(Agent)}
    return {k: v for k, v in agent.items() if k not in known and isinstance(v, dict) and "_target_" in v}


def runs(block: dict) -> bool:
    """Whether a remedy or hook block runs: ``enabled`` (``HookSettings``, default true) is not false."""
    return block.get("enabled", True) is not False


def components(plain: dict) -> list[tuple[str, dict]]:
    """Every hook block of a resolved config, by where it sits: the agent's remedies (``remedy_blocks``), then
    ``hooks.<name>``."""
    agent = [(f"agent.{k}", v) for k, v in remedy_blocks(plain.get("agent", {})).items()]
    return agent + [(f"hooks.{k}", v) for k, v in (plain.get("hooks") or {}).items() if isinstance(v, dict)]


REMEDY_GROUP = Path(__file__).resolve().parents[2] / "conf" / "remedy"   # the remedies an agent may compose


def unrun_remedy_settings(agent: dict) -> dict[str, dict]:
    """``agent.<name>`` blocks without a ``_target_`` where ``name`` is a remedy of conf/remedy/ the agent does not
    compose: settings given to every agent of a sweep (``++agent.recom.interval=512`` with ``agent=ppo,recom_l2``)
    that this one does not run. Checked against that remedy's schema (``validate``; ``enabled=true`` there is an
    error: composing a remedy is ``+remedy@agent.<name>=<name>``), never built, marked ``enabled: false`` by
    ``switch_off_unrun_remedy_settings`` (the report reads them as not applying) and left out of the job key."""
    known = {f.name for f in fields(Agent)}
    return {k: v for k, v in agent.items() if k not in known and isinstance(v, dict) and "_target_" not in v
            and (REMEDY_GROUP / f"{k}.yaml").exists()}


def switch_off_unrun_remedy_settings(cfg: DictConfig) -> list[str]:
    """Mark (in place) the ``unrun_remedy_settings`` of the agent ``enabled: false``; returns their names."""
    names = list(unrun_remedy_settings(OmegaConf.to_container(cfg.agent, resolve=True)))
    for name in names:
        with open_dict(cfg.agent[name]):
            cfg.agent[name].enabled = False
    return names


def _check_unrun(name: str, block: dict) -> None:
    import yaml

    if block.get("enabled") is True:
        raise ConfigError(f"agent.{name}.enabled=True: agent settings alone do not compose a remedy; must be "
                          f"composed: +remedy@agent.{name}={name} (or an agent whose defaults list it)")
    check_component(f"agent.{name}", {**yaml.safe_load((REMEDY_GROUP / f"{name}.yaml").read_text()), **block})


def check_component(where: str, block: dict) -> type:
    """Check one hook block against the ``Settings`` schema its class declares; returns the class."""
    cls = component_class(block, where)
    schema = getattr(cls, "Settings", None)
    if not (isinstance(schema, type) and is_dataclass(schema) and issubclass(schema, HookSettings)):
        raise ConfigError(f"{where}: {block['_target_']} declares no settings schema: it needs a `Settings` dataclass "
                          "(a subclass of sweep.config.HookSettings, one field per argument; README 'Add a remedy')")
    _check({"enabled": True, **block}, schema, where)
    return cls


def validate(cfg: DictConfig) -> None:
    """Raise ConfigError naming the first invalid key, its value and what is allowed."""
    plain = OmegaConf.to_container(cfg, resolve=True)
    plain.pop("hydra", None)
    blocks = components(plain)
    for where, _ in blocks:   # the agent's remedy blocks are checked against their classes' schemas below
        if where.startswith("agent."):
            plain["agent"].pop(where.split(".", 1)[1])
    for name, block in unrun_remedy_settings(plain.get("agent", {})).items():
        _check_unrun(name, block)
        plain["agent"].pop(name)
    agent_hints = _hints(Agent)
    for name in unused_algorithm_blocks(plain.get("agent", {})):
        _check_partial(plain["agent"].pop(name), typing.get_args(agent_hints[name])[0], f"agent.{name}")
    hints = _hints(SweepConfig)
    for name in plain:
        if name not in hints:
            raise ConfigError(f"{name}: not a config key (top level: {', '.join(hints)})")
    for f in fields(SweepConfig):
        if f.name not in plain:
            raise ConfigError(f"{f.name}: missing")
        _check(plain[f.name], hints[f.name], f.name, f.metadata)
    classes = [(where, block, check_component(where, block)) for where, block in blocks]
    _cross_rules(OmegaConf.merge(OmegaConf.structured(SweepConfig), plain))
    whole = OmegaConf.to_container(cfg, resolve=True)
    _twin_rules(whole["agent"])
    algorithm = algorithm_of(whole["agent"])
    for where, block, cls in classes:   # what a hook asks of the rest of the run (e.g. RECOM: a constant LR schedule)
        if runs(block):
            works = getattr(cls, "algorithms", ALGORITHMS)
            if algorithm not in works:
                raise ConfigError(f"{where}: {cls.__name__} works with agent.algorithm={'|'.join(works)}, not with "
                                  f"agent {whole['agent']['name']}'s {algorithm}")
            cls.check_config(where, block, whole)


TWIN_SUFFIX, TWIN_LABEL = "_fresh", " (fresh)"   # twin=fresh: the agent's name and label as the twin's runs log them


def agent_identity(agent) -> tuple[str, str]:
    """The run's agent name and label (its MLflow tags ``agent`` and ``agent_label``): the agent's own, or with
    twin=fresh its fresh twin's, ``<name>_fresh`` and ``<label> (fresh)``."""
    if agent.get("twin") is None:
        return agent["name"], agent["label"]
    return agent["name"] + TWIN_SUFFIX, agent["label"] + TWIN_LABEL


def _twin_rules(agent: dict) -> None:
    """twin=fresh needs an agent that keeps its networks across changes (PPO's twin is agent=reset_all) and the
    reset that makes the twin fresh switched on."""
    if agent.get("twin") is None:
        return
    if agent["name"] in ("ppo", "reset_all"):
        raise ConfigError(f"twin=fresh with agent={agent['name']}: PPO's fresh twin is agent=reset_all (the plasticity "
                          "study's reference); twin=fresh composes with any other agent")
    if "reset_all" not in agent or not runs(agent["reset_all"]):
        what = "agent.reset_all.enabled=false" if "reset_all" in agent else "no agent.reset_all block"
        raise ConfigError(f"{what} with agent.twin=fresh: the twin needs the reset_all remedy on (it draws the twin's "
                          "fresh networks at every change); use twin=fresh")


def validate_section(cfg: DictConfig, name: str) -> None:
    """Raise ConfigError at the first invalid key of the top-level block ``name`` alone: e.g. the ``eval`` of a
    finished run re-evaluated (``sweep.reevaluate``), whose config may predate keys added elsewhere since."""
    spec = {f.name: f for f in fields(SweepConfig)}[name]
    _check(OmegaConf.to_container(cfg[name], resolve=True), _hints(SweepConfig)[name], name, spec.metadata)


def _vehicle_rules(c: DictConfig) -> None:
    """Every vehicle flown can lift itself (thrust-to-weight > 1 at full rotor speed), and ``vehicle.name=nominal``
    is RotorPy's vehicle (the tag the report and ``--where vehicle=`` split runs by)."""
    from sweep.envs.vehicle import VehicleSegment, crazyflie_params, thrust_to_weight  # noqa: PLC0415 (RotorPy)

    params = crazyflie_params(c.env.motor_time_constant)
    flown = [(f"vehicle.segments[{i}]", s) for i, s in enumerate(c.vehicle.segments)] + [("eval", c.eval)]
    for where, s in flown:
        segment = VehicleSegment.of(s)
        ratio = thrust_to_weight(params, segment)
        if ratio <= 1.0:
            raise ConfigError(f"{where}: mass={segment.mass:g}, rotor_efficiency={list(segment.rotor_efficiency)}: "
                              f"thrust-to-weight {ratio:.2f}; must be > 1 (the vehicle cannot lift itself)")
        if where != "eval" and c.vehicle.name == "nominal" and not segment.nominal:
            raise ConfigError(f"vehicle.name='nominal' with {where} mass={segment.mass:g}, rotor_efficiency="
                              f"{list(segment.rotor_efficiency)}: must be another name (nominal means RotorPy's vehicle)")


def learner_algorithm(target: str) -> str:
    """The algorithm of the learner a ``conf/learner/`` block builds (its class's ``algorithm``)."""
    from hydra.utils import get_method

    try:
        built = get_method(target)
    except Exception as err:  # noqa: BLE001 - the user's target: one line
        raise ConfigError(f"agent.learners: _target_={target!r} cannot be imported ({one_line(err)})") from None
    return getattr(getattr(built, "__self__", built), "algorithm", "ppo")


def algorithm_of(agent: Any) -> str:
    """The agent's algorithm (``agent.algorithm``; PPO's agents leave it at its default, ppo)."""
    return agent.get("algorithm", "ppo") or "ppo"


def unused_algorithm_blocks(agent: dict) -> list[str]:
    """Blocks of another algorithm than the agent's (``agent.ppo`` settings of a PPO experiment, e.g. smoke's
    ``n_steps``, composed with ``agent=sac``): checked against that algorithm's schema key by key (``validate``),
    never used, dropped from the config before the run is logged or keyed (``drop_unused_algorithm_blocks``)."""
    own = algorithm_of(agent)
    return [name for name in ALGORITHMS if name != own and agent.get(name) is not None]


def drop_unused_algorithm_blocks(cfg: DictConfig) -> list[str]:
    """Remove (in place) the ``unused_algorithm_blocks`` of the agent; returns their names."""
    names = unused_algorithm_blocks(OmegaConf.to_container(cfg.agent, resolve=True))
    for name in names:
        with open_dict(cfg.agent):
            del cfg.agent[name]
    return names


def _check_partial(value: Any, typ: type, where: str) -> None:
    """The keys given of a schema block, each checked (missing keys allowed)."""
    if not isinstance(value, dict):
        raise _fail(where, value, _what(typ))
    spec, hints = {f.name: f for f in fields(typ)}, _hints(typ)
    for name, item in value.items():
        if name not in spec:
            raise ConfigError(f"{where}.{name}: not a config key (allowed under {where}: {', '.join(spec)})")
        _check(item, hints[name], f"{where}.{name}", spec[name].metadata)


def _off_policy_rules(c: DictConfig, algorithm: str) -> None:
    h = c.agent[algorithm]
    if c.agent.learner == "jax" and c.env.backend != "fast":
        raise ConfigError(f"env.backend={c.env.backend!r}: must be fast with agent.learner=jax (its compiled "
                          "collect steps the fast backend)")
    if h.batch_size > h.buffer_size:
        raise ConfigError(f"agent.{algorithm}.batch_size={h.batch_size}: must be <= agent.{algorithm}.buffer_size="
                          f"{h.buffer_size}")
    if algorithm == "sac" and h.target_update_interval > 1 and 0 <= h.gradient_steps < h.target_update_interval:
        raise ConfigError(f"agent.sac.target_update_interval={h.target_update_interval}: must be 1, or <= agent.sac."
                          f"gradient_steps={h.gradient_steps} (SB3 counts it within one update's gradient steps, from 0 "
                          "each time: with fewer steps per update the targets move at every step)")
    if h.round_steps < h.train_freq * c.env.n_envs:
        raise ConfigError(f"agent.{algorithm}.round_steps={h.round_steps}: must be >= one turn, agent.{algorithm}."
                          f"train_freq x env.n_envs = {h.train_freq * c.env.n_envs} env steps")


def _reward_curriculum_rules(c: DictConfig) -> None:
    rc = c.env.reward_curriculum
    if rc.every is None:
        return
    for name, limit in rc.limit.items():
        if limit is None and rc.factor[name] > 1:
            raise ConfigError(f"env.reward_curriculum.limit.{name}=null: must be a number with "
                              f"env.reward_curriculum.factor.{name}={rc.factor[name]:g} > 1 (the weight would grow "
                              "without bound)")
        if limit is not None and limit < c.env.reward[name]:
            raise ConfigError(f"env.reward_curriculum.limit.{name}={limit:g}: must be >= env.reward.{name}="
                              f"{c.env.reward[name]:g} (the curriculum raises the weight up to it) or null")
    if c.eval.policy.value != "final":
        raise ConfigError(f"eval.policy={c.eval.policy.value}: must be final under env.reward_curriculum.every="
                          f"{rc.every} (the best policy is picked by its training return, whose weights change "
                          "each stage)")


def _cross_rules(c: DictConfig) -> None:
    """Rules across keys, which no field type says."""
    a = c.agent
    if c.wind.directions is not None and len(c.wind.directions) != len(c.wind.speeds):
        raise ConfigError(f"wind.directions: {len(c.wind.directions)} directions for {len(c.wind.speeds)} speeds: must "
                          "be one per speed (or null: wind.direction for every speed)")
    if c.wind.gusts is not None and len(c.wind.gusts) != len(c.wind.speeds):
        raise ConfigError(f"wind.gusts: {len(c.wind.gusts)} sigmas for {len(c.wind.speeds)} speeds: must be one per "
                          "speed (or null: no turbulence)")
    if (any(g > 0 for g in c.wind.gusts or []) or c.eval.gust > 0) and c.env.sim_rate < 20:
        raise ConfigError(f"env.sim_rate={c.env.sim_rate:g} with Dryden gusts: must be >= 20 Hz (RotorPy's filter "
                          "sub-steps above 0.05 s, which is not reproduced)")
    _vehicle_rules(c)
    if c.env.observe.rotor_speeds and c.env.observe.critic_rotor_speeds:
        raise ConfigError("env.observe.critic_rotor_speeds=true: must be false with env.observe.rotor_speeds=true (the "
                          "actor, and so the critic, already observes them)")
    if c.env.curriculum.start_bound_from is not None and c.env.curriculum.start_bound_from > c.env.start_bound:
        raise ConfigError(f"env.curriculum.start_bound_from={c.env.curriculum.start_bound_from:g}: must be <= "
                          f"env.start_bound={c.env.start_bound:g} (the curriculum widens the start box to it)")
    _reward_curriculum_rules(c)
    radius, farthest = c.env.terminate_radius, c.env.start_bound * math.sqrt(3)
    if radius is not None and radius <= farthest:
        raise ConfigError(f"env.terminate_radius={radius:g}: must be > {farthest:.3g} m, the farthest start "
                          f"(env.start_bound={c.env.start_bound:g} x sqrt 3); a start beyond it would end at once")
    if c.env.backend not in c.env.backends:
        raise ConfigError(f"env.backend={c.env.backend!r}: must be one of {'|'.join(c.env.backends)} (conf/backend/)")
    if a.learner not in a.learners:
        raise ConfigError(f"agent.learner={a.learner!r}: must be one of {'|'.join(a.learners)} (conf/learner/)")
    algorithm = a.algorithm
    built = learner_algorithm(a.learners[a.learner]["_target_"])
    if built != algorithm:
        raise ConfigError(f"agent.learners.{a.learner}._target_={a.learners[a.learner]['_target_']!r} builds {built}: "
                          f"must build agent.algorithm={algorithm} (conf/learner/)")
    if a[algorithm] is None:
        raise ConfigError(f"agent.{algorithm}: missing; must be the hyperparameters of agent.algorithm={algorithm} "
                          "(conf/agent/ppo.yaml, sac.yaml, td3.yaml hold them)")
    h = a[algorithm]
    if h.lr_decay_timesteps is not None and h.lr_schedule.value == "constant":
        raise ConfigError(f"agent.{algorithm}.lr_decay_timesteps={h.lr_decay_timesteps!r}: must be null with "
                          f"agent.{algorithm}.lr_schedule=constant (it is when a linear|cosine decay reaches lr_floor)")
    if algorithm != "ppo":
        _off_policy_rules(c, algorithm)
        return
    rollout, batch = a.ppo.n_steps * c.env.n_envs, a.ppo.batch_size
    if batch > rollout:
        raise ConfigError(f"agent.ppo.batch_size={batch!r}: must be <= the rollout size "
                          f"agent.ppo.n_steps x env.n_envs = {rollout}")
    if a.learner == "jax":
        if rollout % batch:
            raise ConfigError(f"agent.ppo.batch_size={batch!r}: must be a divisor of the rollout size "
                              f"agent.ppo.n_steps x env.n_envs = {rollout} with agent.learner=jax")
        if c.env.backend != "fast":
            raise ConfigError(f"env.backend={c.env.backend!r}: must be fast with agent.learner=jax (its compiled "
                              "rollout steps the fast backend)")
