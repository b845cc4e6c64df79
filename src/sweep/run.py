"""One job of a sweep: validate -> seed -> env + learner + hooks -> train (sweep.training.loop) -> evaluate -> track.

``run(cfg, out_dir)`` is the orchestration; ``run_job(cfg)`` is what ``python -m sweep`` calls for each
Hydra job (it records the job's status and turns errors into one line and an exit code).
"""
from __future__ import annotations

import logging
import os
import socket
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.logger import CSVOutputFormat, Logger
from stable_baselines3.common.utils import set_random_seed
from threadpoolctl import threadpool_limits

from sweep.agents import build_learner
from sweep import metrics, portable
from sweep.checkpoint import JobRecord, job_key, load_checkpoint
from sweep.config import (ConfigError, agent_identity, algorithm_of, drop_unused_algorithm_blocks, one_line, settings,
                          switch_off_unrun_remedy_settings, validate)
from sweep.envs.factory import make_env, vehicle_schedule, wind_schedule
from sweep.evaluate import evaluate, flight_conditions
from sweep.status import read_status, write_status
from sweep.training.hooks import Hooks, build_hooks
from sweep.training.loop import Training, train
from sweep.tracking import (PROJECT_ROOT, MlflowWriter, TrackedRun, checkpoint_dir_of_run, flatten, last_logged_step,
                            tracking_uri)

log = logging.getLogger("sweep")


def job_tags(cfg: DictConfig) -> dict[str, str]:
    name, label = agent_identity(cfg.agent)
    tags = {"agent": name, "agent_label": label, "wind": cfg.wind.name,
            "vehicle": cfg.vehicle.name, "seed": str(cfg.seed), "backend": cfg.env.backend,
            "learner": cfg.agent.learner, "sweep": "single", "job": "0", "portable": str(bool(cfg.train.portable)).lower(),
            "cpu_model": portable.cpu_model(), "cpu_flags": portable.cpu_flags_hash()}
    if HydraConfig.initialized():
        hc = HydraConfig.get()
        if hc.mode == RunMode.MULTIRUN:
            tags["sweep"], tags["job"] = str(Path(hc.sweep.dir).resolve()), str(hc.job.num)
        tags["overrides"] = " ".join(hc.overrides.task)
    vehicle = "" if cfg.vehicle.name == "nominal" else f"-{cfg.vehicle.name}"
    tags["run_name"] = f"{tags['agent']}-{tags['wind']}{vehicle}-s{tags['seed']}"
    return tags


def own_job_record(cfg: DictConfig, uri: str) -> JobRecord:
    """The config's own checkpoint directory for the store at ``uri``: ``<train.checkpoint_dir>/<job key>``."""
    root = Path(cfg.train.checkpoint_dir) if cfg.train.checkpoint_dir else PROJECT_ROOT / "checkpoints"
    return JobRecord(root / job_key(cfg, uri))


def job_record(cfg: DictConfig) -> JobRecord:
    """The checkpoint directory of this job: ``resume`` names one, else the config's own."""
    uri = tracking_uri(cfg.tracking.uri)
    own = own_job_record(cfg, uri)
    resume = str(cfg.resume)
    if resume in ("auto", "never"):
        return own
    path = Path(resume)
    if (path / "job.json").exists():
        return JobRecord(path)
    checkpoint_dir = (read_status(path) or {}).get("checkpoint_dir")
    if checkpoint_dir:
        return JobRecord(Path(checkpoint_dir))
    try:
        return JobRecord(checkpoint_dir_of_run(uri, resume))
    except Exception as err:  # noqa: BLE001
        raise ConfigError(f"resume={resume!r}: must be auto, never, a job output dir or an MLflow run id "
                          f"of this store with a checkpoint ({type(err).__name__})") from None


def run(cfg: DictConfig, out_dir: Path) -> str:
    """Train and evaluate one agent/wind/seed (continuing its checkpoint if any); returns the MLflow run id."""
    hooks = validated_hooks(cfg)
    out_dir.mkdir(parents=True, exist_ok=True)
    limit_threads(cfg)
    set_random_seed(cfg.seed)
    tags = job_tags(cfg)

    record = job_record(cfg)
    with record.hold(waiting=lambda: log.info("[%s] the same job runs in another process (listed twice in this "
                                              "sweep?): waiting for it, then reporting its run", tags["run_name"])):
        return train_and_track(cfg, out_dir, hooks, tags, record)


def train_and_track(cfg: DictConfig, out_dir: Path, hooks: Hooks, tags: dict[str, str], record: JobRecord) -> str:
    """``run`` once the job is held: skip it if finished, else train (continuing its checkpoint), evaluate, track."""
    previous = {} if str(cfg.resume) == "never" else record.read()
    if previous.get("status") == "FINISHED":
        log.info("[%s] already complete (MLflow run %s); not retrained", tags["run_name"], previous["run_id"])
        return previous["run_id"]
    state = load_checkpoint(record.checkpoint) if previous else None

    env = make_env(cfg.env, cfg.env.n_envs, wind_schedule(cfg.wind), cfg.seed, learning=True,
                   vehicle=vehicle_schedule(cfg.vehicle))
    model = build_learner(cfg.agent, env, cfg.seed, cfg.train.total_timesteps)
    run_id = previous.get("run_id") if previous else None
    params = {**flatten(settings(cfg)), "hooks": ",".join(h.name for h in hooks),   # the hooks that ran, in order
              "hook_classes": ",".join(f"{h.name}={type(h).__module__}.{type(h).__qualname__}" for h in hooks)}
    with TrackedRun(cfg.tracking, params, {**tags, "checkpoint_dir": str(record.dir)}, run_id=run_id) as tracked:
        record.write(run_id=tracked.run_id, status="RUNNING", uri=tracked.uri, pid=os.getpid(), host=socket.gethostname())
        write_status(out_dir, "RUNNING", run_id=tracked.run_id, checkpoint_dir=str(record.dir))
        log.info("[%s] MLflow run %s in %s%s", tags["run_name"], tracked.run_id, tracked.uri,
                 f" (resumed at {state['num_timesteps']:,} timesteps)" if state else "")
        OmegaConf.save(cfg, out_dir / "config.yaml", resolve=True)
        tracked.log_artifact(out_dir / "config.yaml")
        writer = MlflowWriter(tracked, after_step=last_logged_step(tracked) if run_id else -1,
                              flush_every_s=cfg.tracking.flush_every_s)
        logger = Logger(str(out_dir), [CSVOutputFormat(str(out_dir / "progress.csv")), writer])
        training = Training(model, env, hooks, cfg.train.total_timesteps, logger, label=tags["run_name"],
                            checkpoint_path=record.checkpoint, flush=writer.flush)
        try:
            train(training, resume=state)   # a checkpoint taken at the end: restored for the evaluation only
        finally:
            writer.flush()  # what was logged before a failure is kept too
        evaluate_policies(model, cfg, tracked, out_dir, tags["run_name"], hooks)
    record.write(status="FINISHED")
    return tracked.run_id


def validated_hooks(cfg: DictConfig) -> Hooks:
    """Everything that can be wrong with a config, before anything runs (a ConfigError, one line): the schema, the
    process's float mode, and the hook list; returns the run's hooks (``sweep.training.hooks.build_hooks``)."""
    validate(cfg)
    for name in switch_off_unrun_remedy_settings(cfg):
        log.info("agent %s does not compose remedy %s: its agent.%s.* settings are not used", cfg.agent.name, name, name)
    for name in drop_unused_algorithm_blocks(cfg):
        log.info("agent %s runs %s: the agent.%s.* settings are not used", cfg.agent.name, algorithm_of(cfg.agent), name)
    try:
        portable.check(cfg.train.portable)
    except ValueError as err:
        raise ConfigError(str(err)) from None
    try:
        return build_hooks(cfg)
    except (ValueError, TypeError, InstantiationException) as err:   # a bad order, argument or class
        raise ConfigError(f"hooks: {one_line(err)}") from None


def limit_threads(cfg: DictConfig) -> None:
    """One thread per run for torch and NumPy's BLAS (``train.torch_threads``)."""
    torch.set_num_threads(cfg.train.torch_threads)
    # NumPy's BLAS too (diagnostics' SVD): its idle threads spin and take the core from the next update
    threadpool_limits(cfg.train.torch_threads)
    # No argument checks in torch.distributions: a NaN update then surfaces as train/loss=nan, which
    # NonFiniteGuard reports, instead of a ValueError deep inside SB3's next minibatch.
    torch.distributions.Distribution.set_default_validate_args(False)


def evaluate_policies(model, cfg: DictConfig, tracked: TrackedRun, out_dir: Path, name: str, hooks: Hooks) -> None:
    """``eval.policy``: the final policy, and/or the best ones the ``best_policies`` hook kept."""
    if cfg.eval.policy in ("final", "both"):
        scores = evaluate_and_store(model, cfg, tracked, out_dir, "final")
        log.info("[%s] done: %s", name, ", ".join(f"{k}={v:.3g}" for k, v in scores.items()))
    if cfg.eval.policy in ("best", "both") and "best_policies" in hooks:
        final = model.parameter_arrays()
        for reading, kept in hooks["best_policies"].kept.items():
            model.write_parameters(kept["params"])
            policy = metrics.KEPT[reading]
            scores = evaluate_and_store(model, cfg, tracked, out_dir, policy,
                                        {"source_step": kept["step"], "source_score": kept["score"]}, kept["step"])
            log.info("[%s] %s (from %s steps): %s", name, metrics.POLICIES[policy], f"{kept['step']:,}",
                     ", ".join(f"{k}={v:.3g}" for k, v in scores.items()))
        model.write_parameters(final)


def evaluate_and_store(model, cfg: DictConfig, tracked: TrackedRun, out_dir: Path, policy: str,
                       extra: dict[str, float] | None = None, trained_to: int | None = None) -> dict[str, float]:
    """The evaluation protocol on the learner's current policy, scored as ``policy`` (a ``metrics.POLICIES``
    key): metrics under its prefix at the final step, the flights as ``eval<suffix>_trajectories.npz`` and the
    model as ``model<suffix>.zip`` (run artifacts; suffix "" for the final policy, else "_best", "_best_eval").
    ``trained_to``: the timestep the policy was kept at (a kept policy flies ``eval.condition=current`` under the
    condition it was kept under; None: the learner's)."""
    step = model.num_timesteps if trained_to is None else trained_to
    conditions = flight_conditions(cfg.eval, cfg.wind, cfg.vehicle, step, cfg.train.total_timesteps)
    values, flights = evaluate(model, cfg.eval, cfg.env, conditions)
    scores = {metrics.eval_key(policy, k): float(v) for k, v in {**values, **(extra or {})}.items()}
    suffix = "" if policy == "final" else f"_{policy}"
    tracked.log_metrics(scores, model.num_timesteps)
    np.savez_compressed(out_dir / f"eval{suffix}_trajectories.npz", **flights)
    tracked.log_artifact(out_dir / f"eval{suffix}_trajectories.npz")
    if cfg.tracking.log_model:
        model.save(out_dir / f"model{suffix}.zip")
        tracked.log_artifact(out_dir / f"model{suffix}.zip")
    return scores


def run_job(cfg: DictConfig) -> str | None:
    """Entry point of one Hydra job: run it, record status.json, report errors in one line."""
    multirun = HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN
    out_dir = Path(HydraConfig.get().runtime.output_dir) if HydraConfig.initialized() else Path(tempfile.mkdtemp())
    overrides = list(HydraConfig.get().overrides.task) if HydraConfig.initialized() else []
    try:
        run_id = run(cfg, out_dir)
    except ConfigError as err:
        print(f"sweep: invalid config: {err}", file=sys.stderr)
        write_status(out_dir, "INVALID", reason=str(err), overrides=overrides)
        if not multirun:
            sys.exit(2)
        return None
    except Exception as err:  # noqa: BLE001 - every failure is recorded; the sweep goes on
        log.exception("job failed")
        print(f"sweep: job failed: {type(err).__name__}: {err}  (log in {out_dir})", file=sys.stderr)
        write_status(out_dir, "FAILED", reason=f"{type(err).__name__}: {err}", overrides=overrides)
        if not multirun:
            sys.exit(1)
        return None
    write_status(out_dir, "FINISHED", run_id=run_id, overrides=overrides)
    return run_id
