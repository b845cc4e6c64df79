"""Per-job status files (``<job dir>/status.json``) and the end-of-sweep summary."""
from __future__ import annotations

import json
import sys
from pathlib import Path


def read_json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.exists() else {}


def update_json(path: Path, **fields) -> None:
    """Merge ``fields`` into the JSON record at ``path``, atomically (write a temp file, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps({**read_json(path), **fields}, indent=2))
    tmp.replace(path)


def write_status(job_dir: Path, status: str, **fields) -> None:
    """Record the job's status; fields of earlier writes (run id, checkpoint dir) are kept."""
    update_json(job_dir / "status.json", status=status, **fields)


def read_status(job_dir: Path) -> dict | None:
    return read_json(job_dir / "status.json") or None


def written_at(folder: Path) -> float:
    """The latest modification time of ``folder`` and the files in it (epoch seconds)."""
    return max([folder.stat().st_mtime, *(f.stat().st_mtime for f in folder.iterdir())])


def report_sweep(sweep_dir: Path, uri: str, ui: str, runs_url: str | None = None, since: float | None = None) -> None:
    """Print one line per failed job and where results are; exit 1 if any job did not finish.

    ``since``: the sweep's start (epoch seconds). Only job dirs that this sweep wrote (``.hydra`` or a file in it
    written after it: Hydra rewrites a resumed job's config files in the existing dir) are counted: a sweep
    re-invoked in the same dir with fewer jobs leaves the earlier invocation's extra job dirs, whose stale states
    (a killed job's RUNNING) would otherwise make a finished sweep exit 1.
    """
    jobs = sorted((p for p in sweep_dir.iterdir() if p.is_dir() and (p / ".hydra").exists()),
                  key=lambda p: (len(p.name), p.name)) if sweep_dir.exists() else []
    earlier = [p for p in jobs if since is not None and written_at(p / ".hydra") < since]
    jobs = [p for p in jobs if p not in earlier]
    statuses = [(job, read_status(job) or {"status": "UNKNOWN", "reason": "no status.json (job died?)"}) for job in jobs]
    bad = [(job, s) for job, s in statuses if s["status"] != "FINISHED"]
    print(f"sweep: {len(statuses) - len(bad)}/{len(statuses)} jobs finished; outputs in {sweep_dir}")
    if earlier:
        print(f"sweep: {len(earlier)} job dirs of an earlier sweep in this dir not counted "
              f"({', '.join(p.name for p in earlier)})")
    print(f"sweep: MLflow store {uri}; open it with: {ui}")
    if runs_url:
        print(f"sweep: then the runs table: {runs_url}")
    for job, s in bad:
        print(f"sweep: job {job.name} {s['status']} ({' '.join(s.get('overrides', []))}): {s.get('reason', '')}",
              file=sys.stderr)
    if bad:
        sys.exit(1)
