"""Study archives: the finished runs of an experiment as small files that travel with the repository.

A long study (docs/remedies_study.md: ~13 to ~31 h on two cores) outlives one machine, and the MLflow store it
writes stays outside the work tree. ``export`` writes each FINISHED run of an experiment as one ``.npz``:
params, tags, start and end times, the artifacts named by ``--artifacts`` (default: the config and the
final policy's evaluation flights, which the report draws) and every metric's history, thinned to at most ``--max-points`` points per key (the first,
the last and evenly spaced ones between; a key with fewer points, such as ``eval/*``, is kept whole).
``import`` re-creates those runs, FINISHED, in another store (tag ``archived_from`` = the exported run id,
so importing twice adds nothing) and writes each run's ``job.json`` FINISHED where the run's own config
puts its checkpoint, so the same sweep command against that store with ``resume=auto`` skips them and runs
only what is missing.

    python -m sweep.archive export --experiment remedies --out docs/remedies_study/runs
    python -m sweep.archive import docs/remedies_study/runs          # into $MLFLOW_TRACKING_URI
    python -m sweep.archive export --experiment remedies --where wind=none --artifacts 'config.yaml,eval_*,model*' --out ...

What thinning changes: ``sweep.report`` draws curves on a 200-point grid and takes a curve's final value as
the mean over its last 10% of timesteps; from a 20M-step run thinned to 400 points per key that mean is over
~40 logged values instead of ~1,000 (measured on 20 pilot runs of docs/remedies_study.md: evaluations and the
leaderboard's primary measure unchanged, final rewards within 0.4%, the final approx KL within 14%).
"""
from __future__ import annotations

import argparse
import io
import json
import sys
from fnmatch import fnmatch
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from sweep.checkpoint import JobRecord
from sweep.run import own_job_record
from sweep.tracking import (RunRecord, archived_run_ids, parse_where, read_finished_runs, tracking_uri,
                            write_finished_run)

MAX_POINTS = 400
CONFIG = "config.yaml"
ARTIFACTS = (CONFIG, "eval_trajectories.npz")  # ~90 KB of a 20M-step run's ~360 KB: models and the best
                                               # policies' flights stay in the store unless asked for


def thin(steps: np.ndarray, *columns: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, ...]:
    """At most ``max_points`` rows: the first, the last and evenly spaced ones between (all if fewer)."""
    n = len(steps)
    if n <= max_points:
        return (steps, *columns)
    keep = np.unique(np.round(np.linspace(0, n - 1, max_points)).astype(int))
    return (steps[keep], *(c[keep] for c in columns))


def file_name(record: RunRecord) -> str:
    return f"{record.tags.get('run_name', 'run')}-{record.tags.get('learner', '')}-{record.run_id[:8]}.npz"


def save(record: RunRecord, path: Path, max_points: int = MAX_POINTS) -> None:
    """One run as a compressed ``.npz``: ``meta`` (JSON), ``m<i>_step/_value/_time`` per metric, ``a<i>`` per
    artifact (bytes)."""
    keys, paths = sorted(record.metrics), sorted(record.artifacts)
    meta = {"run_id": record.run_id, "experiment": record.experiment, "start_time": record.start_time,
            "end_time": record.end_time, "params": record.params, "tags": record.tags, "metrics": keys,
            "artifacts": paths, "max_points": max_points}
    arrays = {"meta": np.array(json.dumps(meta))}
    for i, key in enumerate(keys):
        steps, values, times = thin(*record.metrics[key], max_points=max_points)
        arrays |= {f"m{i}_step": steps, f"m{i}_value": values, f"m{i}_time": times}
    for i, name in enumerate(paths):
        arrays[f"a{i}"] = np.frombuffer(record.artifacts[name], dtype=np.uint8)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(buffer.getvalue())
    tmp.replace(path)


def load_meta(path: Path) -> dict:
    """The run's ``meta`` record only (np.load reads an .npz member when asked for it)."""
    with np.load(path, allow_pickle=False) as data:
        return json.loads(str(data["meta"]))


def load(path: Path) -> RunRecord:
    with np.load(path, allow_pickle=False) as data:
        meta = json.loads(str(data["meta"]))
        record = RunRecord(meta["run_id"], meta["experiment"], meta["start_time"], meta["end_time"],
                           meta["params"], meta["tags"])
        for i, key in enumerate(meta["metrics"]):
            record.metrics[key] = (data[f"m{i}_step"], data[f"m{i}_value"], data[f"m{i}_time"])
        for i, name in enumerate(meta["artifacts"]):
            record.artifacts[name] = data[f"a{i}"].tobytes()
    return record


def export(uri: str, experiment: str, out: Path, max_points: int = MAX_POINTS,
           artifacts: tuple[str, ...] = ARTIFACTS, where: dict[str, str] | None = None) -> list[Path]:
    """Write the experiment's FINISHED runs matching ``where`` (tracking.run_matches) not yet in ``out`` (by
    exported run id: a run imported from a file of ``out`` is that file's run) with the artifacts whose path
    matches one of the ``artifacts`` glob patterns; the files written."""
    done = {load_meta(p)["run_id"] for p in out.glob("*.npz")} if out.exists() else set()
    written = []
    for record in read_finished_runs(uri, experiment, skip=done, where=where,
                                     artifacts=lambda path: any(fnmatch(path, p) for p in artifacts)):
        path = out / file_name(record)
        save(record, path, max_points)
        written.append(path)
    return written


def job_record_of(record: RunRecord, uri: str) -> JobRecord | None:
    """Where ``resume=auto`` looks for this run's job in the store at ``uri``: the job key of the run's own
    config (its ``config.yaml`` artifact) under its ``train.checkpoint_dir``; None without a config."""
    if CONFIG not in record.artifacts:
        return None
    return own_job_record(OmegaConf.create(record.artifacts[CONFIG].decode()), uri)


def import_(paths: list[Path], uri: str, experiment: str | None = None) -> tuple[int, int]:
    """Create the archived runs in the store at ``uri`` (each once) and mark their jobs FINISHED for
    ``resume=auto``; (runs created, runs already there)."""
    created = present = 0
    existing: dict[str, dict[str, str]] = {}
    for path in paths:
        record = load(path)
        name = experiment or record.experiment
        if name not in existing:
            existing[name] = archived_run_ids(uri, name)
        run_id = existing[name].get(record.run_id)
        if run_id is None:
            run_id = existing[name][record.run_id] = write_finished_run(uri, record, name)
            created += 1
        else:
            present += 1
        job = job_record_of(record, uri)
        if job is not None and job.read().get("status") != "FINISHED":
            job.write(run_id=run_id, status="FINISHED", uri=uri, imported_from=str(path))
    return created, present


def archive_files(paths: list[str]) -> list[Path]:
    """The ``.npz`` files named, directories expanded (with their subdirectories, sorted)."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out += sorted(p.rglob("*.npz"))
        elif p.suffix == ".npz" and p.exists():
            out.append(p)
        else:
            raise FileNotFoundError(f"{p}: not an archive file (.npz) or a directory of them")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sweep.archive", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    ex = sub.add_parser("export", help="write the experiment's FINISHED runs not yet in --out")
    ex.add_argument("--experiment", required=True)
    ex.add_argument("--out", required=True, type=Path)
    ex.add_argument("--max-points", type=int, default=MAX_POINTS, help="per metric key (default %(default)s)")
    ex.add_argument("--artifacts", default=",".join(ARTIFACTS), type=lambda s: tuple(x for x in s.split(",") if x),
                    help="glob patterns of the artifacts to keep (default %(default)s; '*' keeps all, models too)")
    ex.add_argument("--where", action="append", default=[], metavar="KEY=VALUE",
                    help="only runs with this tag (agent, wind, seed) or param, e.g. wind=none; repeatable")
    im = sub.add_parser("import", help="create the archived runs in the store (each once)")
    im.add_argument("paths", nargs="+", help=".npz files or directories of them")
    im.add_argument("--experiment", help="import into this experiment (default: each run's own)")
    for p in (ex, im):
        p.add_argument("--uri", help="MLflow store (default: $MLFLOW_TRACKING_URI, else <project root>/mlflow.db)")
    args = parser.parse_args(argv)
    uri = tracking_uri(args.uri)
    try:
        if args.command == "export":
            if args.max_points < 2:
                raise ValueError(f"--max-points {args.max_points}: must be at least 2 (the first and the last point)")
            written = export(uri, args.experiment, args.out, args.max_points, args.artifacts,
                             parse_where(args.where))
            print(f"archive: {len(written)} run(s) of {args.experiment!r} written to {args.out}")
        else:
            created, present = import_(archive_files(args.paths), uri, args.experiment)
            print(f"archive: {created} run(s) imported into {uri}, {present} already there")
    except (ValueError, FileNotFoundError) as err:
        print(f"archive: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
