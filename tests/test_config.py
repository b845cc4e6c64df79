"""Every config composes; invalid values fail before training with one line naming key and value."""
from __future__ import annotations

import itertools
import re
from pathlib import Path

import pytest
import yaml
from hydra.utils import get_class
from mlflow.tracking import MlflowClient

from conftest import CONF, compose_cfg, new_store, run_cli
from sweep.training.hooks import build_hooks
from sweep.config import ConfigError, validate

AGENTS = sorted(p.stem for p in (CONF / "agent").glob("*.yaml"))
WINDS = sorted(p.stem for p in (CONF / "wind").glob("*.yaml"))
EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))


# conf/hooks/default.yaml, in order (the checkpointer, which runs last, moved to the end)
DEFAULT_HOOKS = ["NonFiniteGuard", "PlasticityDiagnostics", "EnvMonitor", "PlasticityProbe", "PeriodicEvaluation",
                 "BestPolicies", "ProgressLine", "Checkpointer"]
REMEDY_BLOCKS = {p.stem: yaml.safe_load(p.read_text()) for p in sorted((CONF / "remedy").glob("*.yaml"))}


def remedies_of(cfg) -> list[str]:
    """The classes of the remedies an agent composes and leaves enabled, in config order (read from its YAML blocks,
    so a new agent or remedy needs no table here)."""
    return [get_class(b._target_).__name__ for b in cfg.agent.values()
            if hasattr(b, "get") and "_target_" in b and b.get("enabled", True)]


def test_groups_exist():
    assert {"none", "paper"} <= set(WINDS)
    assert {"paper", "demo", "smoke", "remedies"} <= set(EXPERIMENTS)
    assert {"ppo", "l2", "recom_l2", "reset_all"} <= set(AGENTS)
    for agent in AGENTS:   # each agent names itself and has a legend label
        cfg = compose_cfg([f"agent={agent}"])
        assert cfg.agent.name == agent and cfg.agent.label.strip()
    # the paper's agents compose what the paper says (and PPO carries no remedy at all)
    assert remedies_of(compose_cfg(["agent=ppo"])) == []
    assert remedies_of(compose_cfg(["agent=recom_l2"])) == ["L2Regularization", "Recom"]


VEHICLES = sorted(p.stem for p in (CONF / "vehicle").glob("*.yaml"))
LEARNERS = ["sb3", "jax"]
OWN_LEARNERS = {a: [k for k in LEARNERS if k in compose_cfg([f"agent={a}"]).agent.learners] for a in AGENTS}


def all_pairs() -> list[tuple]:
    """(agent, experiment or None, wind, vehicle, learner): every agent with every experiment (and with none), the
    other three groups cycling with the two indices so that any two groups meet in every pair of their values
    (all-pairs testing: 196 compositions instead of the 5,880 of the full product, whose runtime bought only
    combinations of three or more values; test_the_composition_tests_meet_every_pair_of_values checks the claim)."""
    return [(agent, experiment, WINDS[(i + j) % len(WINDS)], VEHICLES[(i + 2 * j) % len(VEHICLES)],
             OWN_LEARNERS[agent][(i // 2 + j) % len(OWN_LEARNERS[agent])])
            for i, agent in enumerate(AGENTS) for j, experiment in enumerate([None, *EXPERIMENTS])]


@pytest.mark.parametrize("agent,experiment,wind,vehicle,learner", all_pairs())
def test_every_config_composes_and_validates(agent, experiment, wind, vehicle, learner):
    overrides = [f"agent={agent}", f"wind={wind}", f"vehicle={vehicle}", f"agent.learner={learner}"]
    cfg = compose_cfg(overrides + ([f"experiment={experiment}"] if experiment else []))
    validate(cfg)
    assert (cfg.agent.name, cfg.wind.name, cfg.vehicle.name, cfg.agent.learner) == (agent, wind, vehicle, learner)
    assert [type(h).__name__ for h in build_hooks(cfg)] == remedies_of(cfg) + DEFAULT_HOOKS


def test_the_composition_tests_meet_every_pair_of_values():
    assert {"nominal", "payload", "motor"} <= set(VEHICLES) and {"none", "paper", "flip"} <= set(WINDS)
    groups = [AGENTS, [None, *EXPERIMENTS], WINDS, VEHICLES, LEARNERS]
    combos = all_pairs()
    for a, b in itertools.combinations(range(len(groups)), 2):
        pairs = set(itertools.product(groups[a], groups[b]))
        if (a, b) == (0, 4):   # an agent meets the learners it has (agent.learners)
            pairs = {(agent, learner) for agent, learner in pairs if learner in OWN_LEARNERS[agent]}
        assert {(c[a], c[b]) for c in combos} == pairs, (a, b)


def test_paper_wind_and_experiment():
    cfg = compose_cfg(["wind=paper", "experiment=paper"])
    assert list(cfg.wind.speeds) == [3.0, 2.0, 2.5, 1.5, 2.5]
    assert cfg.wind.segment_steps == 2_000_000
    assert cfg.train.total_timesteps == 20_000_000
    assert cfg.agent.ppo.n_steps == 2048 and cfg.agent.ppo.batch_size == 64 and cfg.agent.ppo.n_epochs == 10


INVALID = [
    ("train.total_timesteps=0", "train.total_timesteps=0"),
    ("train.total_timesteps=-5", "train.total_timesteps=-5"),
    ("wind.speeds=[]", "wind.speeds=[]"),
    ("wind.speeds=[3.0,-1.0]", "wind.speeds=[3.0, -1.0]"),
    ("wind.segment_steps=0", "wind.segment_steps=0"),
    ("wind.direction=[0,0,0]", "wind.direction=[0, 0, 0]"),
    ("env.n_envs=0", "env.n_envs=0"),
    ("env.backend=gpu", "env.backend='gpu'"),
    ("env.observation=rpy", "env.observation='rpy'"),
    ("eval.episodes=0", "eval.episodes=0"),
    ("plasticity.tau=1.5", "plasticity.tau=1.5"),
    ("plasticity.tau=-0.1", "plasticity.tau=-0.1"),
    ("plasticity.every_rollouts=0", "plasticity.every_rollouts=0"),
    ("agent=recom_l2 agent.recom.interval=0", "agent.recom.interval=0"),
    ("agent=recom_l2 agent.recom.window=0", "agent.recom.window=0"),
    ("agent=recom_l2 agent.recom.lr_min=0.01", "agent.recom.lr_min=0.01 > agent.recom.lr_max"),
    ("agent=recom_l2 agent.recom.previous=foo", "agent.recom.previous='foo'"),
    ("agent=l2 agent.l2.coef=-1", "agent.l2.coef=-1"),
    ("agent=l2 agent.l2.params=[critic]", "agent.l2.params=['critic']"),
    ("agent.ppo.learning_rate=0", "agent.ppo.learning_rate=0"),
    ("agent.ppo.batch_size=4096", "agent.ppo.batch_size=4096"),
    ("seed=-1", "seed=-1"),
    # types and choices the schema (sweep.config.SweepConfig) says
    ("env.n_envs=1.5", "env.n_envs=1.5: must be an integer > 0"),
    ("agent.policy.layer_norm=maybe", "agent.policy.layer_norm='maybe': must be true|false"),
    ("agent.learner=torch", "agent.learner='torch': must be one of sb3|jax"),
    ("eval.policy=worst", "eval.policy='worst': must be final|best|both"),
    ("wind.after_list=loop", "wind.after_list='loop': must be repeat|hold"),
    ("agent.ppo.target_kl=-1", "agent.ppo.target_kl=-1: must be a number > 0 or null (off)"),
    ("agent.ppo.lr_decay_timesteps=0", "agent.ppo.lr_decay_timesteps=0: must be an integer > 0 or null"),
    ("agent.ppo.lr_decay_timesteps=1000", "agent.ppo.lr_decay_timesteps=1000: must be null with "
                                          "agent.ppo.lr_schedule=constant"),
    # no conversion: OmegaConf would read 'no' as false and '0.001' as a number, the run would not
    ("agent.policy.layer_norm=no", "agent.policy.layer_norm='no': must be true|false"),
    ("agent.ppo.learning_rate='0.001'", "agent.ppo.learning_rate='0.001': must be a number > 0"),
    ("agent.label=5", "agent.label=5: must be a string"),
    ("env.observation_scale=5", "env.observation_scale=5: must be a block with keys velocity, body_rate"),
    ("agent.learners.sb3._partial_=false", "agent.learners.sb3._partial_=False: must be true"),
    # conditions (conf/wind/, conf/vehicle/, eval.condition)
    ("vehicle.segments=[]", "vehicle.segments=[]: must be a non-empty list"),
    ("vehicle=payload vehicle.segments.1.mass=0", "vehicle.segments[1].mass=0: must be a number > 0"),
    ("vehicle=motor vehicle.segments.1.rotor_efficiency=[1.2,1,1,1]", "vehicle.segments[1].rotor_efficiency=[1.2, 1, 1, 1]: "
                                                                       "must be 4 numbers in (0, 1]"),
    ("vehicle=motor vehicle.segments.1.rotor_efficiency=[0,1,1,1]", "vehicle.segments[1].rotor_efficiency=[0, 1, 1, 1]"),
    ("vehicle=motor vehicle.segments.1.rotor_efficiency=[1,1,1]", "vehicle.segments[1].rotor_efficiency=[1, 1, 1]"),
    ("wind=flip wind.directions=[[1,0],[-1,0,0]]", "wind.directions=[[1, 0], [-1, 0, 0]]: must be null or a list of non-zero"),
    ("wind=rotate wind.speeds=[3.0]", "wind.directions: 4 directions for 1 speeds: must be one per speed"),
    ("eval.mass=-1", "eval.mass=-1: must be a number > 0"),
    ("vehicle=payload vehicle.segments.1.mass=2.0", "vehicle.segments[1]: mass=2, rotor_efficiency=[1.0, 1.0, 1.0, 1.0]: "
                                                    "thrust-to-weight 0.98; must be > 1"),
    ("eval.rotor_efficiency=[0.1,0.1,0.1,0.1]", "eval: mass=1, rotor_efficiency=[0.1, 0.1, 0.1, 0.1]: thrust-to-weight"),
    ("vehicle.segments.0.mass=1.5", "vehicle.name='nominal' with vehicle.segments[0] mass=1.5"),
    ("eval.condition=last", "eval.condition='last': must be fixed|current|all"),
    # the JAX learner's own rules
    ("agent.learner=jax env.backend=rotorpy", "env.backend='rotorpy': must be fast with agent.learner=jax"),
    ("agent.learner=jax agent.ppo.n_steps=100", "agent.ppo.batch_size=64: must be a divisor of the rollout size"),
]


@pytest.mark.parametrize("override,expected", INVALID)
def test_invalid_value_is_named(override, expected):
    with pytest.raises(ConfigError) as err:
        validate(compose_cfg(override.split()))
    message = str(err.value)
    assert message.startswith(expected) and "must be" in message and "\n" not in message


def test_cli_invalid_value_one_line_no_run(tmp_path: Path):
    uri = new_store(tmp_path / "x.db")
    proc = run_cli(["train.total_timesteps=-5", f"hydra.run.dir={tmp_path / 'out'}"], uri, tmp_path)
    assert proc.returncode == 2
    errors = [line for line in proc.stderr.splitlines() if line.startswith("sweep:")]
    assert errors == ["sweep: invalid config: train.total_timesteps=-5: must be an integer > 0"]
    assert "Traceback" not in proc.stderr
    client = MlflowClient(uri)
    assert client.search_runs([e.experiment_id for e in client.search_experiments()]) == []


def test_cli_unknown_group_option_lists_valid_ones(tmp_path: Path):
    proc = run_cli(["agent=nope", f"hydra.run.dir={tmp_path / 'out'}"], f"sqlite:///{tmp_path / 'x.db'}", tmp_path)
    assert proc.returncode != 0
    assert "Could not find 'agent/nope'" in proc.stderr and "ppo" in proc.stderr and "recom_l2" in proc.stderr


def test_every_remedy_setting_is_documented_beside_it():
    """A remedy's settings are documented where they are set (conf/remedy/<name>.yaml: a comment on each key's line)
    and typed in its class's schema; the README's configuration reference covers the run's own keys (below), so a new
    remedy needs no README row."""
    for path in sorted((CONF / "remedy").glob("*.yaml")):
        lines = [line for line in path.read_text().splitlines() if line and not line.startswith((" ", "#"))]
        undocumented = [line.split(":")[0] for line in lines if not line.startswith("_target_") and "#" not in line]
        assert not undocumented, (path.name, undocumented)
        assert path.read_text().startswith("# "), path.name   # what the remedy is, and its paper


def test_every_config_key_is_in_the_readme():
    """The README's configuration reference names every key a user can set (a key in a grouped row, e.g.
    `env.reward.w_p`, `w_v`, `w_a` or `agent.ppo.*`, counts)."""
    from omegaconf import OmegaConf

    readme = (CONF.parent / "README.md").read_text()
    cfg = OmegaConf.to_container(compose_cfg(), resolve=False)
    keys = []

    def walk(node, prefix):
        for k, v in node.items():
            if isinstance(v, dict) and not k.startswith("_"):
                walk(v, f"{prefix}{k}.")
            elif not k.startswith("_") and k != "name":
                keys.append(f"{prefix}{k}")

    walk(cfg, "")
    rows = [line for line in readme.splitlines() if line.startswith("| `")]
    missing = []
    for key in keys:
        parent, leaf = key.rsplit(".", 1) if "." in key else ("", key)
        documented = any(f"`{key}`" in r or (parent and f"`{parent}.*`" in r)
                         or (parent and f"`{parent}." in r and (f"`{leaf}`" in r or f".{leaf}`" in r)) for r in rows)
        if not documented:
            missing.append(key)
    assert not missing, f"config keys missing from the README's configuration reference: {missing}"


def test_a_missing_key_is_one_line():
    with pytest.raises(ConfigError, match=r"^agent\.recom\.gain: missing; must be a number >= 0"):
        validate(compose_cfg(["agent=recom_l2", "~agent.recom.gain"]))


def hook_blocks() -> list[tuple[str, dict]]:
    """Every hook block conf/ holds: each conf/remedy/ YAML and each block of conf/hooks/ (as written, unresolved)."""
    hooks = [(f"hooks/{p.stem}", block) for p in sorted((CONF / "hooks").glob("*.yaml"))
             for name, block in yaml.safe_load(p.read_text()).items() if name != "defaults"]
    return [(f"remedy/{k}", v) for k, v in REMEDY_BLOCKS.items()] + hooks


@pytest.mark.parametrize("where,block", hook_blocks(), ids=[w for w, _ in hook_blocks()])
def test_every_hook_block_has_its_schema_beside_its_class(where, block):
    """Each class a conf/ block builds declares ``Settings`` (a HookSettings dataclass) whose fields are the block's
    keys and the arguments of its __init__, so every setting is typed and ranged (validate checks it)."""
    import inspect
    from dataclasses import fields, is_dataclass

    from sweep.config import HookSettings

    cls = get_class(block["_target_"])
    assert is_dataclass(cls.Settings) and issubclass(cls.Settings, HookSettings), where
    schema = {f.name for f in fields(cls.Settings)} - {"_target_", "enabled"}
    assert schema == set(block) - {"_target_", "enabled"}, where
    arguments = {name for name, p in inspect.signature(cls).parameters.items()
                 if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}   # object's (*args, **kwargs): none
    assert schema == arguments, where


@pytest.mark.parametrize("override, expected", [
    # a block whose class declares no schema, or that cannot be imported: one line naming it
    ("+agent.odd._target_=collections.OrderedDict", "agent.odd: collections.OrderedDict declares no settings schema"),
    ("+agent.odd._target_=my_lab.Nope", "agent.odd._target_='my_lab.Nope': cannot be imported (No module named"),
    ("+hooks.odd._target_=collections.OrderedDict", "hooks.odd: collections.OrderedDict declares no settings schema"),
    # a key the schema does not know, and a value out of range, in an agent's remedy and in a hook
    ("agent=redo +agent.redo.kappa=1", "agent.redo.kappa: not a config key (allowed under agent.redo: _target_, enabled"),
    ("agent=redo agent.redo.networks=[critic]", "agent.redo.networks=['critic']: must be a non-empty subset of [policy, value]"),
    ("agent=redo agent.redo.enabled=maybe", "agent.redo.enabled='maybe': must be true|false"),
    ("+hooks.probe.stepz=3", "hooks.probe.stepz: not a config key"),
    ("hooks.checkpointer.every=0", "hooks.checkpointer.every=0: must be an integer > 0"),
    # a remedy's own rules across keys (check_config)
    ("agent=l2 +remedy@agent.l2_init=l2_init", "agent.l2.enabled=True and agent.l2_init.enabled=True: must be one"),
    ("agent=recom_l2 agent.ppo.lr_schedule=linear", "agent.ppo.lr_schedule='linear': must be constant with "
                                                    "agent.recom.enabled=True"),
])
def test_a_hook_block_is_checked_by_its_own_schema(override, expected):
    with pytest.raises(ConfigError) as err:
        validate(compose_cfg(override.split()))
    assert str(err.value).startswith(expected) and "\n" not in str(err.value), str(err.value)


def test_a_remedy_setting_given_to_every_agent_of_a_sweep_is_checked_and_dropped_where_the_agent_lacks_it():
    """`python -m sweep -m agent=ppo,recom_l2 ++agent.recom.interval=512`: PPO gets a recom block without a _target_;
    it is checked against RECOM's schema (a typo or a bad value is an error), not run, switched off, and not in the job
    key: PPO given two such values is one job (a sweep that lists it twice runs it once: test_run_options)."""
    from sweep.checkpoint import job_key
    from omegaconf import OmegaConf

    from sweep.config import switch_off_unrun_remedy_settings, unrun_remedy_settings

    cfg = compose_cfg(["agent=ppo", "++agent.recom.interval=512"])
    validate(cfg)
    assert list(unrun_remedy_settings(OmegaConf.to_container(cfg.agent))) == ["recom"] and remedies_of(cfg) == []
    assert [type(h).__name__ for h in build_hooks(cfg)] == DEFAULT_HOOKS
    assert job_key(cfg, "sqlite:///x.db") == job_key(compose_cfg(["agent=ppo", "++agent.recom.interval=1024"]),
                                                     "sqlite:///x.db") == job_key(compose_cfg(["agent=ppo"]), "sqlite:///x.db")
    assert switch_off_unrun_remedy_settings(cfg) == ["recom"] and cfg.agent.recom.enabled is False
    for override, message in (("++agent.recom.interval=0", "agent.recom.interval=0: must be an integer > 0"),
                              ("++agent.recom.intervall=5", "agent.recom.intervall: not a config key"),
                              ("++agent.recomm.interval=5", "agent.recomm: not a config key"),
                              ("++agent.recom.enabled=true", "agent.recom.enabled=True: agent settings alone do not "
                                                             "compose a remedy; must be composed: +remedy@agent.recom=recom")):
        with pytest.raises(ConfigError, match="^" + re.escape(message)):
            validate(compose_cfg(["agent=ppo", override]))


def test_a_switched_off_remedy_is_not_checked_by_its_rules_and_does_not_run():
    cfg = compose_cfg(["agent=l2", "+remedy@agent.l2_init=l2_init", "agent.l2_init.enabled=false"])
    validate(cfg)
    assert remedies_of(cfg) == ["L2Regularization"]
    assert [type(h).__name__ for h in build_hooks(cfg)] == ["L2Regularization"] + DEFAULT_HOOKS


def test_a_key_outside_the_schema_is_named():
    with pytest.raises(ConfigError, match=r"^env\.zzz: not a config key"):
        validate(compose_cfg(["+env.zzz=1"]))


def test_the_schema_is_in_hydras_config_store_and_types_every_key():
    """compose(config_name="sweep_schema") gives the schema (every value ???); a composed config merged into it
    keeps its values, typed: choices become the schema's Enums."""
    from enum import Enum

    from omegaconf import OmegaConf

    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        empty = compose(config_name="sweep_schema")
    assert OmegaConf.is_missing(empty.env, "backend") and OmegaConf.is_missing(empty.agent, "learner") and empty.agent.ppo is None and empty.agent.algorithm == "ppo"
    for node in (empty.agent.learners, empty.env.backends, empty.hooks):  # Dict nodes: Hydra's struct flag would refuse new keys
        OmegaConf.set_struct(node, False)
    typed = OmegaConf.merge(empty, OmegaConf.to_container(compose_cfg(["agent=ppo"]), resolve=True))
    assert isinstance(typed.agent.ppo.lr_schedule, Enum) and typed.agent.ppo.lr_schedule.value == "constant"
    assert typed.agent.ppo.gamma == 0.99 and typed.env.n_envs == 1


# The resume key of `agent=recom_l2` (train.checkpoint_dir=null, store sqlite:///x.db). It hashes the resolved
# settings, so any new or renamed config key changes it, and a sweep started before the change is then not
# resumed by resume=auto (its runs start over). Update it only for such a change, and say so in the commit.
JOB_KEY = "718c5c1647fcd682"   # issue 53: only enabled remedies enter the key (each without its `enabled` flag); the
                                # key of an archived run's stored config is the same as the new composition's


def test_the_resume_key_changes_only_with_the_settings():
    from sweep.checkpoint import job_key

    base = ["agent=recom_l2", "train.checkpoint_dir=null"]
    assert job_key(compose_cfg(base), "sqlite:///x.db") == JOB_KEY, "resume keys changed: see the comment at JOB_KEY"
    assert job_key(compose_cfg(base + ["resume=never", "train.progress_every_s=5"]), "sqlite:///x.db") == JOB_KEY
    # the wiring (which class builds a learner / backend) is not a setting; the choice of one is
    rewired = base + ["agent.learners.sb3._target_=my_lab.MyPPO.from_config"]
    assert job_key(compose_cfg(rewired), "sqlite:///x.db") == JOB_KEY
    assert job_key(compose_cfg(base + ["agent.learner=jax"]), "sqlite:///x.db") != JOB_KEY
    # a hook's settings are interpolations of keys already in the key; another hook list is another job
    assert job_key(compose_cfg(base + ["hooks.progress.every_s=5"]), "sqlite:///x.db") == JOB_KEY
    assert job_key(compose_cfg(base + ["~hooks.probe"]), "sqlite:///x.db") != JOB_KEY
    assert job_key(compose_cfg(base), "sqlite:///y.db") != JOB_KEY
    # a remedy the job composes but does not run is not in it; one it runs is
    assert job_key(compose_cfg(base + ["+remedy@agent.redo=redo", "agent.redo.enabled=false"]), "sqlite:///x.db") == JOB_KEY
    assert job_key(compose_cfg(base + ["+remedy@agent.redo=redo"]), "sqlite:///x.db") != JOB_KEY
    assert job_key(compose_cfg(base + ["agent.recom.enabled=false"]), "sqlite:///x.db") != JOB_KEY


def test_adding_a_remedy_or_a_hook_to_conf_moves_no_existing_job_key(tmp_path):
    """A new remedy (conf/remedy/ + an agent composing it) and a new hook (conf/hooks/) added to a copy of conf/: every
    agent that was there keeps its key, with the default hooks and with the paper's other settings."""
    import shutil

    from hydra import compose, initialize_config_dir

    from sweep.checkpoint import job_key

    shutil.copytree(CONF, tmp_path / "conf")
    (tmp_path / "conf" / "remedy" / "new_remedy.yaml").write_text("_target_: sweep.plasticity.redo.ReDo\nenabled: true\n"
                                                                "every_updates: 3\ntau: 0.2\nnetworks: [policy]\n"
                                                                "batch_size: 64\nreset_adam: false\n")
    (tmp_path / "conf" / "agent" / "new_agent.yaml").write_text("defaults:\n  - ppo\n  - /remedy@new_remedy: new_remedy\n"
                                                              "  - _self_\nname: new_agent\nlabel: New\n")
    (tmp_path / "conf" / "hooks" / "new_hook.yaml").write_text("new_hook:\n  _target_: sweep.monitor.EnvMonitor\n")

    def keys(conf):
        with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
            return {(a, w): job_key(compose(config_name="config", overrides=[f"agent={a}", f"wind={w}"]), "sqlite:///x.db")
                    for a in AGENTS for w in ("paper", "flip")}

    assert keys(tmp_path / "conf") == keys(CONF)
