"""MLflow: the store, one run per job, and SB3's logger bridged into it. The only module that writes MLflow.

* Store: ``tracking.uri`` if set, else ``$MLFLOW_TRACKING_URI``, else ``sqlite:///<project root>/mlflow.db``
  (absolute), which a bare ``mlflow ui`` started in the project root opens.
* The store's schema is created once in the parent process (``SweepCallback``, a Hydra callback that
  runs before the launcher starts jobs): several processes creating a fresh SQLite store race. A SQLite
  store is switched to write-ahead logging there, so a reader (``mlflow ui``, a report, a ``sqlite3`` shell)
  never makes a job's write fail with "database is locked".
* ``MlflowWriter`` is an SB3 ``KVWriter``: logger dumps are written in ``log_batch``es (every
  ``tracking.flush_every_s`` seconds) with step = environment timesteps and SB3's own metric names
  (``rollout/ep_rew_mean``, ``train/loss``, ...).
* ``read_finished_runs`` / ``write_finished_run``: a finished run as a plain ``RunRecord`` and back, for the
  study archives of ``sweep.archive`` (a long study carried from one machine's store to another's).
* ``finished_runs`` / ``download_artifacts`` / ``add_to_finished_run``: a finished run's stored policies read and
  scores added to it, for ``sweep.reevaluate``.
"""
from __future__ import annotations

import json
import logging
import math
import numbers
import os
import sqlite3
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.logger import KVWriter

os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
os.environ.setdefault("MLFLOW_ENABLE_ASYNC_TRACE_LOGGING", "false")
os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
import mlflow  # noqa: E402
from mlflow.entities import Metric, Param, RunTag  # noqa: E402
from mlflow.tracking import MlflowClient  # noqa: E402
from sweep.metrics import TAG_DEFAULTS  # noqa: E402

log = logging.getLogger(__name__)

PROJECT_ROOT = Path(__file__).resolve().parents[2]
BATCH_LIMIT = 1000  # MLflow accepts at most 1000 metrics / 100 params per log_batch


def sqlite_path(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` store URI; None for any other store."""
    return Path(uri[len("sqlite:///"):]) if uri.startswith("sqlite:///") else None


def tracking_uri(uri: str | None = None) -> str:
    """The store every job of a sweep writes to (always absolute for SQLite)."""
    uri = uri or os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{PROJECT_ROOT / 'mlflow.db'}"
    path = sqlite_path(uri)
    if path is not None and not path.is_absolute():
        uri = f"sqlite:///{path.resolve()}"
    return uri


# MLflow 3 opens an experiment of unknown kind on its GenAI overview ("Traces"); this tag marks it as model
# training. The UI still lands on that overview unless the link asks for the runs table (``experiment_url``).
EXPERIMENT_KIND = {"mlflow.experimentKind": "custom_model_development"}
UI_ADDRESS = "http://127.0.0.1:5000"


def use_write_ahead_log(uri: str) -> None:
    """Put a SQLite store in WAL mode (persistent, in the file): readers no longer block the jobs' writes.

    In SQLite's default rollback-journal mode a reader's open transaction holds a lock that makes every
    write wait, and MLflow's write fails with "database is locked" after ~20 s (a study job was lost this
    way to a ``sqlite3`` read of its store). With WAL, readers and the one writer at a time do not block
    each other. Not for a store on a network file system (WAL needs shared memory; README: one machine).
    """
    path = sqlite_path(uri)
    if path is None:
        return
    try:
        con = sqlite3.connect(path, timeout=30)
        try:
            mode = con.execute("PRAGMA journal_mode=WAL").fetchone()[0]
        finally:
            con.close()
        if mode != "wal":
            log.warning("SQLite store %s stays in journal mode %s (not WAL)", uri, mode)
    except sqlite3.Error as err:  # a busy store keeps its mode; the jobs still run, as before
        log.warning("SQLite store %s not switched to WAL: %s", uri, err)


def ensure_store(uri: str, experiment: str) -> str:
    """Create the store's schema and the experiment if missing (tagged as model training); return its id."""
    client = MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name(experiment)
    if exp is None:
        try:
            exp_id = client.create_experiment(experiment, tags=EXPERIMENT_KIND)
        except mlflow.exceptions.MlflowException:  # created concurrently by another process
            exp_id = client.get_experiment_by_name(experiment).experiment_id
    else:
        exp_id = exp.experiment_id
        if exp.tags.get("mlflow.experimentKind") != EXPERIMENT_KIND["mlflow.experimentKind"]:
            client.set_experiment_tag(exp_id, *next(iter(EXPERIMENT_KIND.items())))
    return exp_id


def experiment_url(uri: str, experiment: str, address: str = UI_ADDRESS) -> str | None:
    """The MLflow UI's link to an experiment's Runs table (not its GenAI overview); None if it does not exist."""
    exp = MlflowClient(tracking_uri=uri).get_experiment_by_name(experiment)
    if exp is None:
        return None
    return f"{address}/#/experiments/{exp.experiment_id}?workflowType=machine_learning"


def ui_command(uri: str) -> str:
    """The command that opens this store in the MLflow UI (a bare ``mlflow ui`` for the project's default store)."""
    if uri == f"sqlite:///{PROJECT_ROOT / 'mlflow.db'}":
        return f"cd {PROJECT_ROOT} && mlflow ui"
    return f"mlflow ui --backend-store-uri {uri}"


def checkpoint_dir_of_run(uri: str, run_id: str) -> Path:
    """The checkpoint directory an MLflow run of this store was tagged with (for ``resume=<run id>``)."""
    return Path(MlflowClient(tracking_uri=uri).get_run(run_id).data.tags["checkpoint_dir"])


def experiment_names(uri: str) -> list[str]:
    """The store's experiments, newest first (MLflow's ``Default`` left out)."""
    exps = MlflowClient(tracking_uri=uri).search_experiments(order_by=["creation_time DESC"])
    return [e.name for e in exps if e.name != "Default"]


def flatten(cfg: Any, prefix: str = "") -> dict[str, str]:
    """Flattened ``{"a.b.c": "value"}`` of a resolved config, lists as their JSON text."""
    out: dict[str, str] = {}
    if isinstance(cfg, dict):
        for k, v in cfg.items():
            out.update(flatten(v, f"{prefix}{k}."))
    else:
        out[prefix[:-1]] = json.dumps(cfg) if isinstance(cfg, (list, tuple)) else str(cfg)
    return out


class TrackedRun:
    """One MLflow run per job, in the store and experiment of ``tracking`` (the config's ``tracking:``), with
    ``params`` (e.g. ``flatten`` of the resolved config) logged when the run is created. Use as a context
    manager: an exception ends the run FAILED."""

    def __init__(self, tracking: DictConfig, params: dict[str, str], tags: dict[str, str],
                 run_id: str | None = None) -> None:
        self.uri = tracking_uri(tracking.uri)
        self.client = MlflowClient(tracking_uri=self.uri)
        self.experiment_id = ensure_store(self.uri, tracking.experiment)
        if run_id is None:
            run = self.client.create_run(self.experiment_id, tags=tags, run_name=tags.get("run_name"))
            self.run_id = run.info.run_id
            items = [Param(k, v[:6000]) for k, v in params.items()]
            for i in range(0, len(items), 100):
                self.client.log_batch(self.run_id, params=items[i:i + 100])
        else:
            self.run_id = run_id
            self.client.update_run(run_id, status="RUNNING")

    def log_metrics(self, metrics: dict[str, float], step: int) -> None:
        self.log_metric_batches([(metrics, step)])

    def log_metric_batches(self, batches: list[tuple[dict[str, float], int]]) -> None:
        """Several (metrics, step) records in as few ``log_batch`` calls as MLflow allows."""
        ts = int(time.time() * 1000)
        items = [Metric(k, float(v), ts, int(step)) for metrics, step in batches for k, v in metrics.items()
                 if isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) and math.isfinite(float(v))]
        for i in range(0, len(items), BATCH_LIMIT):
            self.client.log_batch(self.run_id, metrics=items[i:i + BATCH_LIMIT])

    def set_tags(self, tags: dict[str, str]) -> None:
        self.client.log_batch(self.run_id, tags=[RunTag(k, str(v)[:5000]) for k, v in tags.items()])

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        self.client.log_artifact(self.run_id, str(path), artifact_path)

    def finish(self, status: str = "FINISHED") -> None:
        self.client.set_terminated(self.run_id, status=status)

    def __enter__(self) -> "TrackedRun":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.finish("FINISHED")
        else:
            reason = f"{exc_type.__name__}: {exc}"
            try:
                self.set_tags({"failure_reason": reason})
            finally:
                self.finish("KILLED" if exc_type is KeyboardInterrupt else "FAILED")
        return False


def last_logged_step(run: TrackedRun) -> int:
    """Largest step of the run's SB3 dumps so far (-1 if none): a resumed run logs only later steps."""
    history = run.client.get_metric_history(run.run_id, "time/total_timesteps")
    return max((m.step for m in history), default=-1)


@dataclass
class RunRecord:
    """One finished MLflow run as plain data: what ``sweep.report`` reads of it, and its small artifacts."""
    run_id: str
    experiment: str
    start_time: int  # ms since the epoch, as MLflow keeps it
    end_time: int
    params: dict[str, str]
    tags: dict[str, str]
    metrics: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)  # key: steps, values, ms
    artifacts: dict[str, bytes] = field(default_factory=dict)  # artifact path: content


ARCHIVED_FROM = "archived_from"  # tag of an imported run: the run id it was exported from


WHERE_TAGS = ("agent", "wind", "vehicle", "seed")  # what a ``where`` key names in a run's tags; any other key, a param


def parse_where(items: list[str]) -> dict[str, str]:
    """``["wind=none", "env.n_envs=16"]`` -> {key: value}; ValueError naming a malformed or repeated item. A value
    matches the logged string exactly (``agent.ppo.learning_rate=0.0003``, not ``3e-4``)."""
    where: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--where {item!r}: expected KEY=VALUE, e.g. wind=none or env.n_envs=16")
        if key in where:
            raise ValueError(f"--where {key}: given twice ({where[key]!r}, {value!r}); a run has one value per key")
        where[key] = value
    return where


def run_matches(params: dict[str, str], tags: dict[str, str], where: dict[str, str]) -> bool:
    """Whether a run has every ``where`` value: tag ``agent``/``wind``/``vehicle``/``seed`` (a run without the vehicle
    tag flew the nominal one), else the flattened config param."""
    return all((tags.get(key, TAG_DEFAULTS.get(key)) if key in WHERE_TAGS else params.get(key)) == value
               for key, value in where.items())


def read_finished_runs(uri: str, experiment: str, skip: set[str] = frozenset(),
                       artifacts=lambda path: True, where: dict[str, str] | None = None) -> list[RunRecord]:
    """The FINISHED runs of ``experiment`` (oldest first) that match ``where`` (``run_matches``), with every
    metric's history and the artifacts whose path ``artifacts(path)`` accepts. Left out: the runs in ``skip``, by
    run id or, for a run imported from an archive, by the run id it was exported from (its ``archived_from`` tag)."""
    client = MlflowClient(tracking_uri=uri)
    out = []
    for run in _finished(client, uri, experiment, where or {}):
        if run.info.run_id in skip or run.data.tags.get(ARCHIVED_FROM) in skip:
            continue
        record = RunRecord(run.info.run_id, experiment, run.info.start_time, run.info.end_time,
                           dict(run.data.params), dict(run.data.tags))
        for key in run.data.metrics:
            hist = sorted(client.get_metric_history(run.info.run_id, key), key=lambda m: (m.step, m.timestamp))
            record.metrics[key] = (np.array([m.step for m in hist], dtype=np.int64),
                                   np.array([m.value for m in hist], dtype=np.float64),
                                   np.array([m.timestamp for m in hist], dtype=np.int64))
        with tempfile.TemporaryDirectory() as tmp:
            for path in _artifact_files(client, run.info.run_id):
                if artifacts(path):
                    record.artifacts[path] = Path(client.download_artifacts(run.info.run_id, path, tmp)).read_bytes()
        out.append(record)
    return out


def _artifact_files(client: MlflowClient, run_id: str, path: str | None = None) -> list[str]:
    files = []
    for item in client.list_artifacts(run_id, path):
        files += _artifact_files(client, run_id, item.path) if item.is_dir else [item.path]
    return files


def archived_run_ids(uri: str, experiment: str) -> dict[str, str]:
    """{exported run id: run id here} of the runs of ``experiment`` that ``write_finished_run`` created."""
    client = MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name(experiment)
    if exp is None:
        return {}
    runs = client.search_runs([exp.experiment_id], max_results=50000)
    return {r.data.tags[ARCHIVED_FROM]: r.info.run_id for r in runs if ARCHIVED_FROM in r.data.tags}


def write_finished_run(uri: str, record: RunRecord, experiment: str | None = None) -> str:
    """Create ``record`` as a FINISHED run of ``experiment`` (default: its own) in the store at ``uri``, with its
    start and end times, params, tags (plus ``archived_from``), metric histories and artifacts; its new run id."""
    client = MlflowClient(tracking_uri=uri)
    exp_id = ensure_store(uri, experiment or record.experiment)
    tags = {**record.tags, ARCHIVED_FROM: record.run_id}
    run_id = client.create_run(exp_id, start_time=record.start_time, tags=tags,
                               run_name=tags.get("mlflow.runName") or tags.get("run_name")).info.run_id
    params = [Param(k, v) for k, v in record.params.items()]
    for i in range(0, len(params), 100):
        client.log_batch(run_id, params=params[i:i + 100])
    items = [Metric(key, float(v), int(t), int(s)) for key, (steps, values, times) in record.metrics.items()
             for s, v, t in zip(steps, values, times)]
    for i in range(0, len(items), BATCH_LIMIT):
        client.log_batch(run_id, metrics=items[i:i + BATCH_LIMIT])
    with tempfile.TemporaryDirectory() as tmp:
        for path, content in record.artifacts.items():
            local = Path(tmp) / path
            local.parent.mkdir(parents=True, exist_ok=True)
            local.write_bytes(content)
            client.log_artifact(run_id, str(local), str(Path(path).parent) if Path(path).parent != Path(".") else None)
    client.set_terminated(run_id, status="FINISHED", end_time=record.end_time)
    return run_id


def finished_runs(uri: str, experiment: str, where: dict[str, str] | None = None
                  ) -> list[tuple[str, dict[str, str], dict[str, str]]]:
    """(run id, params, tags) of the FINISHED runs of ``experiment`` that match ``where``, oldest first."""
    return [(r.info.run_id, dict(r.data.params), dict(r.data.tags))
            for r in _finished(MlflowClient(tracking_uri=uri), uri, experiment, where or {})]


def _finished(client: MlflowClient, uri: str, experiment: str, where: dict[str, str]) -> list:
    """The FINISHED runs (MLflow ``Run``s) of ``experiment`` matching ``where``, oldest first; ValueError for an
    unknown experiment or a ``where`` key that no FINISHED run has (a typo would otherwise select nothing)."""
    exp = client.get_experiment_by_name(experiment)
    if exp is None:
        raise ValueError(f"no experiment {experiment!r} in {uri}; it has: {', '.join(experiment_names(uri)) or 'none'}")
    runs = client.search_runs([exp.experiment_id], "attributes.status = 'FINISHED'", max_results=50000,
                              order_by=["attributes.start_time ASC"])
    known = set(WHERE_TAGS).union(*(r.data.params for r in runs))
    for key in where:
        if key not in known:
            raise ValueError(f"--where {key}: no FINISHED run of {experiment!r} has that tag or param "
                             "(agent, wind, seed or a flattened config name, e.g. env.n_envs)")
    return [r for r in runs if run_matches(r.data.params, r.data.tags, where)]


def download_artifacts(uri: str, run_id: str, paths: list[str], dst: Path) -> dict[str, Path]:
    """Those of the artifact ``paths`` the run has, downloaded into ``dst``: {path: local file} (one listing)."""
    client = MlflowClient(tracking_uri=uri)
    present = set(_artifact_files(client, run_id))
    return {path: Path(client.download_artifacts(run_id, path, str(dst))) for path in paths if path in present}


def add_to_finished_run(uri: str, run_id: str, metrics: dict[str, float], tags: dict[str, str],
                        step_of: str) -> None:
    """Log ``metrics`` to a finished run at the step of its latest ``step_of`` metric (0 if none) and set ``tags``;
    the run keeps its status and times (a later reading of the run, e.g. ``sweep.reevaluate``)."""
    client = MlflowClient(tracking_uri=uri)
    step = max((m.step for m in client.get_metric_history(run_id, step_of)), default=0)
    now = int(time.time() * 1000)
    client.log_batch(run_id, metrics=[Metric(k, float(v), now, step) for k, v in metrics.items()],
                     tags=[RunTag(k, v) for k, v in tags.items()])


class MlflowWriter(KVWriter):
    """SB3 logger output into MLflow, step = environment timesteps, in batches.

    Dumps are buffered and written with one ``log_batch`` when ``flush_every_s`` seconds have passed since
    the last write (a write costs ~25 ms on SQLite, about half a JAX learner's rollout), when a batch is
    full, and on ``flush()``: before every checkpoint, at the end and on failure (see ``sweep.run``), so
    what a checkpoint covers is always in the store.

    ``after_step``: dumps at or before this step are dropped (a resumed run re-plays the steps between
    its checkpoint and the crash, which the first attempt already logged).
    """

    def __init__(self, run: TrackedRun, after_step: int = -1, flush_every_s: float = 10.0) -> None:
        self.run, self.after_step, self.flush_every_s = run, int(after_step), float(flush_every_s)
        self.pending: list[tuple[dict[str, float], int]] = []
        self.last_flush = time.monotonic()

    def write(self, key_values: dict[str, Any], key_excluded: dict[str, Any], step: int = 0) -> None:
        if step <= self.after_step:
            return
        metrics = {k: v for k, v in key_values.items()
                   if not (key_excluded.get(k) and "mlflow" in key_excluded[k])}
        metrics.pop("time/iterations", None)
        self.pending.append((metrics, step))
        if time.monotonic() - self.last_flush >= self.flush_every_s or \
                sum(len(m) for m, _ in self.pending) >= BATCH_LIMIT:
            self.flush()

    def flush(self) -> None:
        if self.pending:
            self.run.log_metric_batches(self.pending)
            self.pending = []
        self.last_flush = time.monotonic()

    def close(self) -> None:
        self.flush()


class SweepCallback(Callback):
    """Hydra callback (parent process): create the store before jobs start; say where results are."""

    started: float | None = None  # the multirun's start, epoch seconds (report_sweep's `since`)

    def _prepare(self, config: DictConfig) -> None:
        uri = tracking_uri(config.tracking.uri)
        ensure_store(uri, config.tracking.experiment)
        use_write_ahead_log(uri)  # once, here, before any job opens the store

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._prepare(config)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self.started = time.time() - 1.0  # jobs of this sweep write their dirs after this
        self._prepare(config)
        try:
            from sweep.plan import announce

            params = config.hydra.sweeper.get("params")
            params = OmegaConf.to_container(params, resolve=False) if params else {}
            print(announce(config, list(config.hydra.overrides.task), {k: str(v) for k, v in params.items()},
                           config.hydra.launcher.get("n_jobs", -1)), flush=True)
        except Exception as err:  # noqa: BLE001 - an estimate must never stop a sweep
            log.debug("no time estimate: %s", err)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        from sweep.status import report_sweep

        uri = tracking_uri(config.tracking.uri)
        report_sweep(Path(config.hydra.sweep.dir), uri, ui_command(uri), experiment_url(uri, config.tracking.experiment),
                     since=self.started)

    def on_run_end(self, config: DictConfig, **kwargs: Any) -> None:
        uri = tracking_uri(config.tracking.uri)
        print(f"sweep: runs in the MLflow UI ({ui_command(uri)}): {experiment_url(uri, config.tracking.experiment)}")
