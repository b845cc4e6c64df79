"""One job of a sweep: validate -> seed -> env + agent + callbacks -> learn -> evaluate -> track.

``run(cfg, out_dir)`` is the orchestration; ``run_job(cfg)`` is what ``python -m sweep`` calls for each
Hydra job (it records the job's status and turns errors into one line and an exit code).
"""
from __future__ import annotations

import logging
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.logger import CSVOutputFormat, Logger
from stable_baselines3.common.utils import set_random_seed

from sweep.agents import build_ppo, build_remedies
from sweep.config import ConfigError, validate
from sweep.envs import WindSchedule
from sweep.evaluate import evaluate, make_env
from sweep.monitor import EnvMonitor, ProgressLine
from sweep.plasticity.diagnostics import PlasticityDiagnostics
from sweep.status import write_status
from sweep.tracking import MlflowWriter, TrackedRun

log = logging.getLogger("sweep")


def job_tags(cfg: DictConfig) -> dict[str, str]:
    tags = {"agent": cfg.agent.name, "wind": cfg.wind.name, "seed": str(cfg.seed), "backend": cfg.env.backend,
            "sweep": "single", "job": "0"}
    if HydraConfig.initialized():
        hc = HydraConfig.get()
        if hc.mode == RunMode.MULTIRUN:
            tags["sweep"], tags["job"] = str(Path(hc.sweep.dir).resolve()), str(hc.job.num)
        tags["overrides"] = " ".join(hc.overrides.task)
    tags["run_name"] = f"{tags['agent']}-{tags['wind']}-s{tags['seed']}"
    return tags


def run(cfg: DictConfig, out_dir: Path) -> str:
    """Train and evaluate one agent/wind/seed; returns the MLflow run id."""
    validate(cfg)
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(cfg.train.torch_threads)
    set_random_seed(cfg.seed)
    tags = job_tags(cfg)

    wind = WindSchedule(speeds=list(cfg.wind.speeds), segment_steps=cfg.wind.segment_steps,
                        direction=list(cfg.wind.direction), name=cfg.wind.name)
    env = make_env(cfg.env, cfg.env.n_envs, wind, cfg.seed)
    model = build_ppo(cfg.agent, env, cfg.seed)
    callbacks = build_remedies(cfg.agent) + [
        PlasticityDiagnostics(**cfg.plasticity),
        EnvMonitor(),
        ProgressLine(tags["run_name"], cfg.train.total_timesteps, cfg.train.progress_every_s),
    ]
    with TrackedRun(cfg, tags) as tracked:
        log.info("[%s] MLflow run %s in %s", tags["run_name"], tracked.run_id, tracked.uri)
        config_path = out_dir / "config.yaml"
        OmegaConf.save(cfg, config_path, resolve=True)
        tracked.log_artifact(config_path)
        model.set_logger(Logger(str(out_dir), [CSVOutputFormat(str(out_dir / "progress.csv")), MlflowWriter(tracked)]))

        model.learn(total_timesteps=cfg.train.total_timesteps, callback=CallbackList(callbacks))

        metrics, flights = evaluate(model, cfg)
        tracked.log_metrics(metrics, model.num_timesteps)
        np.savez_compressed(out_dir / "eval_trajectories.npz", **flights)
        tracked.log_artifact(out_dir / "eval_trajectories.npz")
        if cfg.tracking.log_model:
            model.save(out_dir / "model.zip")
            tracked.log_artifact(out_dir / "model.zip")
        log.info("[%s] done: %s", tags["run_name"], ", ".join(f"{k}={v:.3g}" for k, v in metrics.items()))
        return tracked.run_id


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
        print(f"sweep: job failed: {type(err).__name__}: {err}  (traceback in {out_dir})", file=sys.stderr)
        write_status(out_dir, "FAILED", reason=f"{type(err).__name__}: {err}", overrides=overrides)
        if not multirun:
            sys.exit(1)
        return None
    write_status(out_dir, "FINISHED", run_id=run_id, overrides=overrides)
    return run_id
