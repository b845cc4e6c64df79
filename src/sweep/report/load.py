"""Read one experiment of the MLflow store back into pandas (the only module that reads the store).

* ``runs``: one row per FINISHED run: run_id, agent, its legend label, learner, wind, seed, sweep, the wind schedule and
  eval params, the end-of-run evaluations (metrics.EVAL_KEYS: the final policy's ``eval/*``, the best kept policies'
  ``eval_best/*`` and ``eval_best_eval/*``; NaN where the run did not evaluate that policy), the names of its
  metrics (``logged``) and one column per ``--by`` param. Of several runs of one agent, learner, ``--by`` values,
  wind and seed only the newest is kept.
* ``asked``: what the sweeps asked for and did not get (``read_runs``): runs that did not finish and jobs of a
  Hydra multirun that failed before their run existed, without a finished run of the same cell.
* ``histories``: long table (run_id, key, step, value) of the metric histories the report plots.
* ``trajectories``: the ``eval_trajectories.npz`` artifact of one run (or a best policy's, ``eval_best_…``).
"""
from __future__ import annotations

import difflib
import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
from hydra.utils import get_class  # noqa: E402
from mlflow.exceptions import MlflowException  # noqa: E402
from mlflow.tracking import MlflowClient  # noqa: E402

from sweep import metrics  # noqa: E402
from sweep.config import TWIN_SUFFIX  # noqa: E402
from sweep.status import read_status  # noqa: E402

# What a run logged and the report reads: sweep.metrics (one registry of keys, labels, figures and tables).
NA = "n/a"  # value of a --by param that does not apply to a run (or that the run did not log)
LEARNER = "agent.learner"  # the param naming a run's learner (conf/learner/); its tag is ``learner``
OLD_LEARNER = "sb3"        # the learner of runs logged before agent.learner existed (SB3 was the only one)
# Labels of the paper's agents in stores logged before an agent's YAML had a `label:` (tag agent_label).
OLD_LABELS = {"ppo": "PPO", "l2": "L2 + PPO", "recom_l2": "RECOM + L2 PPO"}
PARAM_KEYS = {"wind.segment_steps": "segment_steps", "wind.speeds": "speeds", "wind.directions": "directions",
              "wind.gusts": "gusts",
              "vehicle.segments": "vehicle_segments", "train.total_timesteps": "total_timesteps",
              "eval.wind_speed": "eval_wind_speed", "eval.success_radius": "success_radius",
              "eval.policy": "eval_policy", "eval.condition": "eval_condition",  # None in stores logged before it existed (final policy only)
              # the thresholds of the plasticity readings, for the dormant figure's labels (None where not logged)
              "plasticity.tau": "dormant_tau", "plasticity.saturation": "saturation",
              "plasticity.dead_fraction": "dead_fraction", "plasticity.signed_mean_tau": "signed_mean_tau"}


class ReportError(Exception):
    """A problem the user must fix; reported as one line, exit code 1."""


def by_value(params: dict[str, str], key: str) -> str:
    """The run's logged value of ``key``; NA if the run lacks it or an enclosing component is disabled
    (an ``enabled`` param above the key is false, e.g. ``agent.l2.coef`` of a run with ``agent.l2.enabled=False``)."""
    parts = key.split(".")
    for i in range(1, len(parts)):
        flag = ".".join(parts[:i]) + ".enabled"
        if flag != key and str(params.get(flag, "True")).lower() == "false":
            return NA
    return params.get(key, NA)


def check_keys(by: list[str], available: set[str]) -> None:
    """One-line error for a --by key that no run logged, naming a few params that exist."""
    for key in by:
        if key in ("agent", "wind", "seed"):
            raise ReportError(f"--by {key}: conditions always differ in agent and wind and aggregate over seeds; "
                              "--by takes other logged params, e.g. agent.l2.coef")
        if key not in available:
            names = sorted(available)
            hints = (difflib.get_close_matches(key, names, n=4, cutoff=0.6)
                     or [n for n in names if n.startswith("agent.")][:4] or names[:4])
            raise ReportError(f"unknown --by key {key!r}: no run logged that param "
                              f"(params are flattened config names, e.g. {', '.join(hints)})")


def agent_label(agent: str, tags: dict[str, str], params: dict[str, str]) -> str:
    """The run's legend label: its tag ``agent_label``, else its param ``agent.label`` (the agent's YAML
    ``label:``), else (older stores) OLD_LABELS, else the agent's name."""
    return tags.get("agent_label") or params.get("agent.label") or OLD_LABELS.get(agent, agent)


def final_evaluated(params: dict[str, str]) -> bool:
    """Whether the run evaluated its final policy at the end (eval.policy final or both; stores logged before
    eval.policy existed always did). With eval.policy=best the latest ``eval/*`` value, if any, comes from an
    evaluation during training (eval.every_timesteps), of an earlier policy."""
    return params.get("eval.policy", "final") in ("final", "both")


def tracking_uri() -> str:
    """``$MLFLOW_TRACKING_URI`` if set, else the project's store (resolved exactly as the jobs resolve it)."""
    from sweep.tracking import tracking_uri as resolve  # noqa: PLC0415 - heavy import (SB3), only when needed

    return resolve(None)


def client_for(uri: str) -> MlflowClient:
    if uri.startswith("sqlite:///") and not Path(uri[len("sqlite:///"):]).exists():
        raise ReportError(f"no MLflow store at {uri} (run a sweep first)")
    return MlflowClient(tracking_uri=uri)


def pick_experiment(client: MlflowClient, name: str | None) -> tuple[str, str]:
    """(experiment id, name): the named one, else the experiment whose latest run started last."""
    if name is not None:
        exp = client.get_experiment_by_name(name)
        if exp is None:
            known = ", ".join(sorted(e.name for e in client.search_experiments())) or "none"
            raise ReportError(f"unknown experiment {name!r} (experiments in the store: {known})")
        return exp.experiment_id, exp.name
    latest = []
    for exp in client.search_experiments():
        runs = client.search_runs([exp.experiment_id], max_results=1, order_by=["attributes.start_time DESC"])
        if runs:
            latest.append((runs[0].info.start_time, exp.experiment_id, exp.name))
    if not latest:
        raise ReportError("the MLflow store has no runs (run a sweep first, e.g. python -m sweep -m experiment=demo)")
    _, exp_id, exp_name = max(latest)
    return exp_id, exp_name


def _all_runs(client: MlflowClient, exp_id: str) -> list:
    runs, token = [], None
    while True:
        page = client.search_runs([exp_id], max_results=1000, page_token=token)
        runs.extend(page)
        token = page.token
        if not token:
            return runs


def matches_sweep(tag: str, sweep: str | None) -> bool:
    """``sweep`` is an existing directory (exact match of the resolved path) or a substring of the tag."""
    if sweep is None:
        return True
    if Path(sweep).is_dir():
        return tag == str(Path(sweep).resolve())
    return sweep in tag


def learner_of(tags: dict[str, str], params: dict[str, str]) -> str:
    """The run's learner: its tag ``learner``, else its param agent.learner, else (older stores) OLD_LEARNER."""
    return tags.get("learner") or params.get(LEARNER) or OLD_LEARNER


@dataclass
class Loaded:
    """What ``read_runs`` read: ``runs`` (the finished runs, one per cell), ``notes`` about runs left out, and
    ``asked``: one row per cell that a sweep asked for and that has no finished run (columns CELL, the --by
    keys, ``what``: the run or job that did not finish and how it ended)."""
    runs: pd.DataFrame
    notes: list[str]
    asked: pd.DataFrame = field(default_factory=pd.DataFrame)


CELL = ["agent", "learner", "wind", "seed"]  # with the --by values: what the report keeps one run of


def read_runs(client: MlflowClient, exp_id: str, sweep: str | None = None, by: list[str] = (),
              experiment: str | None = None) -> Loaded:
    """The experiment's runs (those of ``sweep`` if given). Of several finished runs of one cell (agent, learner,
    ``by`` values, wind, seed) only the one that started last is kept: runs of two learners are two cells.

    ``asked`` holds the cells the sweeps asked for and did not get: a run that did not finish (FAILED, KILLED,
    RUNNING: still running or killed) and a job of a Hydra multirun that ended INVALID or FAILED before its run
    existed (its status.json in the directory the runs' ``sweep`` tag names, ``unrun_jobs``), where no finished
    run of the same cell exists. ``experiment``: the experiment's name (a multirun job of another one is not
    counted)."""
    rows, unfinished, notes, available, sweeps, run_ids = [], [], [], set(), set(), set()
    for run in _all_runs(client, exp_id):
        tags, params, logged = run.data.tags, run.data.params, run.data.metrics
        if not matches_sweep(tags.get("sweep", ""), sweep):
            continue
        available.update(params)
        sweeps.add(tags.get("sweep", ""))
        run_ids.add(run.info.run_id)
        name = tags.get("run_name", run.info.run_id[:8])
        agent, learner = tags.get("agent", "?"), learner_of(tags, params)
        cell = {"agent": agent, "learner": learner,
                "wind": metrics.condition_arm(tags),  # the wind, and the vehicle where not RotorPy's (conf/vehicle/)
                "seed": int(tags.get("seed", -1)),
                **{key: learner if key == LEARNER else by_value(params, key) for key in by}}
        if run.info.status != "FINISHED":
            notes.append(f"left out run {name} ({run.info.status})")
            unfinished.append({**cell, "what": f"run {name} {run.info.status}", "start_time": run.info.start_time})
            continue
        row = {"run_id": run.info.run_id, "agent": agent, "label": agent_label(agent, tags, params),
               "wind": cell["wind"], "seed": cell["seed"], "sweep": tags.get("sweep", ""), "run_name": name,
               "start_time": run.info.start_time,
               "wall_minutes": (run.info.end_time - run.info.start_time) / 60000 if run.info.end_time else np.nan,
               # what the numbers were made on (runs before train.portable existed: native, CPU unknown)
               "cpu_model": (f"{tags['cpu_model']} (flags {tags.get('cpu_flags', '?')})" if "cpu_model" in tags
                             else "unknown CPU"),
               "float_mode": "portable" if tags.get("portable") == "true" else "native"}
        row.update({short: params.get(key) for key, short in PARAM_KEYS.items()})
        row.update({key: logged.get(key, np.nan) for key in metrics.EVAL_KEYS})
        if not final_evaluated(params):  # its latest eval/* is an in-training evaluation, not the final policy's
            row.update({metrics.eval_key("final", f.name): np.nan for f in metrics.EVAL_FIELDS})
        row.update({key: cell[key] for key in by})
        row["learner"], row["logged"] = learner, frozenset(logged)
        row["hook_classes"] = params.get("hook_classes")   # the hooks it ran (their curves: hook_curves)
        rows.append(row)
    if available:
        check_keys(list(by), available)
    key = CELL + [k for k in by if k != LEARNER]
    asked = pd.DataFrame(unfinished + unrun_jobs(sweeps, run_ids, experiment, by),
                         columns=[*key, "what", "start_time"])
    df = pd.DataFrame(rows)
    if not df.empty:
        df["segment_steps"] = pd.to_numeric(df["segment_steps"], errors="coerce")
        df["speeds"] = df["speeds"].map(lambda s: json.loads(s) if isinstance(s, str) else [])
        df["segment_labels"] = [segment_labels(r["speeds"], r.get("directions"), r.get("vehicle_segments"),
                                               r.get("gusts")) for _, r in df.iterrows()]
        df = df.sort_values(["agent", "wind", "seed", "start_time"])
        dupes = df.duplicated(key, keep="last")
        if dupes.any():
            what = "/".join(["agent", *[k for k in by if k != LEARNER], "learner", "wind", "seed"])
            notes.append(f"{int(dupes.sum())} older duplicate run(s) of the same {what} left out "
                         "(use --sweep to pick one sweep)")
            df = df[~dupes]
        done = set(df[key].itertuples(index=False, name=None))
        asked = asked[np.array([c not in done for c in asked[key].itertuples(index=False, name=None)], dtype=bool)]
    asked = asked.sort_values("start_time", na_position="first").drop_duplicates(key, keep="last")
    return Loaded(df.reset_index(drop=True), notes, asked.drop(columns="start_time").reset_index(drop=True))


def load_runs(client: MlflowClient, exp_id: str, sweep: str | None = None,
              by: list[str] = ()) -> tuple[pd.DataFrame, list[str]]:
    """(finished runs as a DataFrame, notes about runs left out): ``read_runs`` without what is missing."""
    loaded = read_runs(client, exp_id, sweep, by)
    return loaded.runs, loaded.notes


def split_learners(runs: pd.DataFrame, by: list[str]) -> tuple[pd.DataFrame, list[str], str | None]:
    """(runs, by, note): where an agent has finished runs of more than one learner, ``by`` gains agent.learner (the
    runs' learner column) so that its SB3 and JAX runs are separate conditions, as with ``--by agent.learner``,
    and the note says so; else all three unchanged (the note None)."""
    if runs.empty or LEARNER in by:
        return runs, list(by), None
    learners = runs.groupby("agent")["learner"].nunique()
    mixed = sorted(learners.index[learners > 1])
    if not mixed:
        return runs, list(by), None
    note = (f"runs of {', '.join(mixed)} come from several learners ({', '.join(sorted(set(runs['learner'])))}): "
            f"kept apart as with --by {LEARNER}")
    return runs.assign(**{LEARNER: runs["learner"]}), [*by, LEARNER], note


def _flat(cfg, prefix: str = "") -> dict[str, str]:
    """``{"a.b": "value"}`` of a nested config, values as a run logs them (sweep.tracking.flatten)."""
    if isinstance(cfg, dict):
        return {k: v for key, value in cfg.items() for k, v in _flat(value, f"{prefix}{key}.").items()}
    return {prefix[:-1]: json.dumps(cfg) if isinstance(cfg, list) else str(cfg)}


def unrun_jobs(sweeps, run_ids: set[str], experiment: str | None, by: list[str] = ()) -> list[dict]:
    """The jobs of the multiruns ``sweeps`` (the runs' ``sweep`` tags: absolute paths of directories that exist)
    that ended INVALID or FAILED without a run among ``run_ids``: one cell each (as ``read_runs``), read from the
    job's ``.hydra/config.yaml`` (a job of another experiment than ``experiment``, or without that file, is
    skipped), ``what`` naming the job, its status and the reason in its status.json."""
    import yaml  # noqa: PLC0415 - only when a sweep directory is there to read

    out = []
    for sweep in sorted(s for s in sweeps if Path(s).is_absolute() and Path(s).is_dir()):  # not "single"
        for job in sorted((p for p in Path(sweep).iterdir() if (p / "status.json").is_file()),
                          key=lambda p: (len(p.name), p.name)):
            status = read_status(job) or {}
            if status.get("status") not in ("INVALID", "FAILED") or status.get("run_id") in run_ids:
                continue
            try:
                config = _flat(yaml.safe_load((job / ".hydra" / "config.yaml").read_text()) or {})
            except (OSError, yaml.YAMLError):
                continue
            if experiment is not None and config.get("tracking.experiment", experiment) != experiment:
                continue
            learner = config.get(LEARNER, OLD_LEARNER)
            tags = {"wind": config.get("wind.name", "?"), "vehicle": config.get("vehicle.name", "nominal")}
            seed = config.get("seed", "-1")
            reason = " ".join(str(status.get("reason", "")).split())
            twin = config.get("agent.twin") not in (None, "None", "null")   # twin=fresh: config.agent_identity's name
            out.append({"agent": config.get("agent.name", "?") + (TWIN_SUFFIX if twin else ""), "learner": learner,
                        "wind": metrics.condition_arm(tags),
                        "seed": int(seed) if seed.lstrip("-").isdigit() else -1,
                        **{key: learner if key == LEARNER else by_value(config, key) for key in by},
                        "what": f"job {job.name} of {sweep} {status['status']}" + (f": {reason}" if reason else ""),
                        "start_time": np.nan})
    return out


AXES = {(1, 0): "+x", (-1, 0): "−x", (0, 1): "+y", (0, -1): "−y"}


def segment_labels(speeds: list[float], directions: str | None, vehicles: str | None, gusts: str | None = None) -> list:
    """What changes at each of the wind's segments, for the figures' bands: the speeds (m/s) when only the speed
    changes, else one short label per segment of the two lists' common period: the wind (speed and direction,
    e.g. '3 +x', its gusts' sigma 'σ100' or 'calm' where other segments have gusts) and the vehicle where not
    nominal ('m×1.3', 'η1 0.7')."""
    dirs = json.loads(directions) if isinstance(directions, str) and directions not in ("null", "None") else None
    segs = json.loads(vehicles) if isinstance(vehicles, str) else None
    sigmas = json.loads(gusts) if isinstance(gusts, str) and gusts not in ("null", "None") else None
    sigmas = sigmas if sigmas and any(sigmas) else None
    if dirs is None and sigmas is None and (
            not segs or len(segs) == 1 and segs[0]["mass"] == 1 and set(segs[0]["rotor_efficiency"]) == {1}):
        return list(speeds)
    segs = segs or [{"mass": 1.0, "rotor_efficiency": [1.0] * 4}]
    labels, wind_changes = [], dirs is not None or len(set(speeds)) > 1
    for k in range(int(np.lcm(len(speeds) or 1, len(segs)))):
        text = f"{speeds[k % len(speeds)]:g}" if speeds and wind_changes else ""
        if dirs is not None:
            d = dirs[k % len(dirs)]
            text += " " + AXES.get((int(np.sign(round(d[0], 6))), int(np.sign(round(d[1], 6)))), "") if not d[2] else " ↕"
        if sigmas is not None:
            g = sigmas[k % len(sigmas)]
            text += f" σ{g:g}" if g else " calm"
        seg = segs[k % len(segs)]
        if seg["mass"] != 1:
            text += f" m×{seg['mass']:g}"
        text += "".join(f" η{i + 1} {e:g}" for i, e in enumerate(seg["rotor_efficiency"]) if e != 1)
        labels.append(text.strip() or "nominal")
    return labels


def hook_curves(runs: pd.DataFrame) -> tuple[list[metrics.Curve], list[str]]:
    """The curves the runs' hooks declare beside their classes (``Hook.curves``; each run's param ``hook_classes``:
    ``name=module.Class,...``), and a note for a class this environment cannot import."""
    targets = sorted({item.split("=", 1)[1] for value in runs.get("hook_classes", pd.Series(dtype=object))
                      if isinstance(value, str) for item in value.split(",") if "=" in item})
    curves, notes = [], []
    for target in targets:
        try:
            curves += list(getattr(get_class(target), "curves", ()))
        except Exception as err:  # noqa: BLE001 - a hook of another code version or a module not on the path
            notes.append(f"hook class {target} cannot be imported here ({type(err).__name__}): its curves are not drawn")
    return curves, notes


def load_histories(client: MlflowClient, runs: pd.DataFrame, keys: list[str] | None = None,
                   timestamps: bool = False) -> pd.DataFrame:
    """Long table: run_id, key, step, value (sorted by step; a repeated step keeps its last value), and with
    ``timestamps`` the value's MLflow time ``ts`` (ms). ``keys``: the report's curves (``metrics``) by default."""
    keys = metrics.CURVE_KEYS + metrics.OPTIONAL_KEYS if keys is None else keys
    frames = []
    for run_id, logged in zip(runs["run_id"], runs["logged"]):
        for key in [k for k in keys if k in logged]:
            hist = client.get_metric_history(run_id, key)
            if hist:
                frames.append(pd.DataFrame({"run_id": run_id, "key": key, "step": [m.step for m in hist],
                                            "value": [m.value for m in hist], "ts": [m.timestamp for m in hist]}))
    if not frames:
        return pd.DataFrame(columns=["run_id", "key", "step", "value"])
    df = pd.concat(frames, ignore_index=True).sort_values(["run_id", "key", "step", "ts"])
    df = df.drop_duplicates(["run_id", "key", "step"], keep="last")
    return (df if timestamps else df.drop(columns="ts")).reset_index(drop=True)


def trajectories_name(policy: str = "final") -> str:
    """The artifact holding the evaluation flights of ``policy`` (a metrics.POLICIES key): eval_trajectories.npz,
    eval_best_trajectories.npz, eval_best_eval_trajectories.npz."""
    return f"eval{metrics.POLICIES[policy].removeprefix('eval')}_trajectories.npz"


def load_trajectories(client: MlflowClient, run_id: str, policy: str = "final") -> dict[str, np.ndarray] | None:
    """The run's evaluation flights of ``policy`` (``trajectories_name``) as a dict of arrays, or None if the run
    has none."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            path = client.download_artifacts(run_id, trajectories_name(policy), tmp)
        except (MlflowException, OSError):
            return None
        with np.load(path) as npz:
            return {k: npz[k] for k in npz.files}
