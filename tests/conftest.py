"""Shared test helpers: Hydra composition of the real configs and a temporary MLflow store."""
from __future__ import annotations

import sweep  # noqa: F401  (first: the test process's float mode, train.portable, before NumPy is imported)

import atexit
import functools
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

torch.set_num_threads(1)  # one thread per process, as every run (`make test` runs a test process per core)

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"

# Tiny but real: 2 rollouts of 512 steps on RotorPy's own integrator.
TINY = ["train.total_timesteps=1024", "agent.ppo.n_steps=512", "eval.episodes=2", "train.progress_every_s=1000"]


# `make test` runs a test process per core and gives each whole modules from one queue (pytest-xdist's --dist
# loadscope; --no-loadscope-reorder keeps this order instead of xdist's, most tests first). The modules that took
# longest are queued first, so that the last module left is a short one: measured 12-07 in `make test`'s slowest
# durations, xdist's own order ran test_report.py (~5 min, most of it its trained store) last, on one core, while
# the other core sat idle. The rest keep the collection's (alphabetical) order.
LONGEST_FIRST = ["test_report", "test_reliability", "test_config", "test_reference_history", "test_offpolicy_resume",
                 "test_recipes", "test_multirun", "test_remedies", "test_run_options", "test_plasticity"]


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.stem, len(LONGEST_FIRST)))   # stable: each module's own order kept


def compose_cfg(overrides: list[str] | None = None):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=overrides or [])


def backend(name: str):
    """The simulator class ``env.backend=<name>`` builds (conf/backend/<name>.yaml, by its _target_)."""
    from hydra.utils import instantiate

    return instantiate(compose_cfg().env.backends[name])


@pytest.fixture(autouse=True)
def checkpoint_dir(tmp_path, monkeypatch) -> Path:
    """Checkpoints of test runs go to the test's temp dir, never to <project root>/checkpoints."""
    path = tmp_path / "checkpoints"
    monkeypatch.setenv("SWEEP_CHECKPOINT_DIR", str(path))
    return path


@pytest.fixture(autouse=True)
def in_tmp_dir(tmp_path, monkeypatch) -> Path:
    """Each test runs in its temp dir: what a run writes relative to the working directory (MLflow's ./mlruns
    artifacts of a SQLite store, Hydra's outputs/) stays there, never in the project root."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.fixture(autouse=True)
def sb3_logdir(tmp_path, monkeypatch) -> Path:
    """SB3's own ``learn()`` (the reference in equivalence tests) makes a log folder even when it writes nothing:
    ``$SB3_LOGDIR``, else a new ``/tmp/SB3-<time>`` per call. It goes to the test's temp dir."""
    path = tmp_path / "sb3"
    monkeypatch.setenv("SB3_LOGDIR", str(path))
    return path


@functools.cache
def _empty_store() -> Path:
    """An empty store that MLflow itself made (created and migrated), once per test process."""
    from mlflow.tracking import MlflowClient

    folder = Path(tempfile.mkdtemp(prefix="sweep-empty-store-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    MlflowClient(f"sqlite:///{folder / 'mlflow.db'}").search_experiments()
    return folder / "mlflow.db"


def new_store(path: Path) -> str:
    """The URI of an empty MLflow store at ``path``: a copy of ``_empty_store()``. A new SQLite store runs MLflow's
    schema migrations (~1.3 s, measured 12-08: a quarter of test_tracking.py's time); the copy is the same file. The
    tests of a store's first creation (concurrent jobs on a fresh store) don't use it."""
    shutil.copyfile(_empty_store(), path)
    return f"sqlite:///{path}"


@pytest.fixture
def store(tmp_path, monkeypatch) -> str:
    uri = new_store(tmp_path / "mlflow.db")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    return uri


def run_cli(args: list[str], uri: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "MLFLOW_TRACKING_URI": uri, "HYDRA_FULL_ERROR": "0"}
    return subprocess.run([sys.executable, "-m", "sweep", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)


def train_with(model, hooks=(), timesteps: int = 1024, logger=None):
    """Train ``model`` from 0 to ``timesteps`` in the project's loop with ``hooks`` (Hook objects, in order);
    returns the ``Training`` (its logger: one without outputs unless given)."""
    from sweep.training.hooks import Hooks
    from sweep.training.loop import Training, train

    kwargs = {"logger": logger} if logger is not None else {}
    training = Training(model, model.env, Hooks(list(hooks)), timesteps, **kwargs)
    train(training)
    return training
