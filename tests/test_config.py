"""Every config composes; invalid values fail before training with one line naming key and value."""
from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from conftest import CONF, ROOT, compose_cfg, run_cli
from sweep.agents import build_remedies
from sweep.config import ConfigError, validate

AGENTS = sorted(p.stem for p in (CONF / "agent").glob("*.yaml"))
WINDS = sorted(p.stem for p in (CONF / "wind").glob("*.yaml"))
EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))


def test_groups_exist():
    assert {"ppo", "l2", "recom_l2"} <= set(AGENTS)
    assert {"none", "paper"} <= set(WINDS)
    assert {"paper", "demo", "smoke"} <= set(EXPERIMENTS)


@pytest.mark.parametrize("agent,wind,experiment", list(itertools.product(AGENTS, WINDS, [None, *EXPERIMENTS])))
def test_every_config_composes_and_validates(agent, wind, experiment):
    overrides = [f"agent={agent}", f"wind={wind}"] + ([f"experiment={experiment}"] if experiment else [])
    cfg = compose_cfg(overrides)
    validate(cfg)
    assert cfg.agent.name == agent and cfg.wind.name == wind
    remedies = build_remedies(cfg.agent)
    assert len(remedies) == {"ppo": 0, "l2": 1, "recom_l2": 2}.get(agent, len(remedies))


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
]


@pytest.mark.parametrize("override,expected", INVALID)
def test_invalid_value_is_named(override, expected):
    with pytest.raises(ConfigError) as err:
        validate(compose_cfg(override.split()))
    message = str(err.value)
    assert message.startswith(expected) and "must be" in message and "\n" not in message


def test_cli_invalid_value_one_line_no_run(tmp_path: Path):
    uri = f"sqlite:///{tmp_path / 'x.db'}"
    proc = run_cli(["train.total_timesteps=-5", f"hydra.run.dir={tmp_path / 'out'}"], uri, ROOT)
    assert proc.returncode == 2
    errors = [line for line in proc.stderr.splitlines() if line.startswith("sweep:")]
    assert errors == ["sweep: invalid config: train.total_timesteps=-5: must be an integer > 0"]
    assert "Traceback" not in proc.stderr
    client = MlflowClient(uri)
    assert client.search_runs([e.experiment_id for e in client.search_experiments()]) == []


def test_cli_unknown_group_option_lists_valid_ones(tmp_path: Path):
    proc = run_cli(["agent=nope", f"hydra.run.dir={tmp_path / 'out'}"], f"sqlite:///{tmp_path / 'x.db'}", ROOT)
    assert proc.returncode != 0
    assert "Could not find 'agent/nope'" in proc.stderr and "ppo" in proc.stderr and "recom_l2" in proc.stderr


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
