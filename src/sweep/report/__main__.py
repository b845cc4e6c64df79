"""CLI: build every figure and table of one experiment; errors are one line on stderr and exit code 1."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def build(experiment: str | None, sweep: str | None, out: str | None) -> Path:
    from mlflow.exceptions import MlflowException

    from sweep.report import figures, load, stats, style, tables

    uri = load.tracking_uri()
    try:
        client = load.client_for(uri)
        exp_id, exp_name = load.pick_experiment(client, experiment)
        runs, notes = load.load_runs(client, exp_id, sweep)
    except MlflowException as err:
        raise load.ReportError(f"cannot read the MLflow store {uri}: {str(err).splitlines()[0]}") from err
    for note in notes:
        print(f"sweep.report: note: {note}")
    if runs.empty:
        where = f" of sweep {sweep!r}" if sweep else ""
        raise load.ReportError(f"experiment {exp_name!r}{where} has no finished runs in {uri}")

    out_dir = Path(out) if out else Path("reports") / exp_name
    out_dir.mkdir(parents=True, exist_ok=True)
    print(f"sweep.report: experiment {exp_name!r}: {len(runs)} finished runs from {uri}")
    for missing in missing_conditions(runs):
        print(f"sweep.report: missing: {missing}")

    histories = load.load_histories(client, runs["run_id"])
    for key in load.CURVE_KEYS:
        lacking = runs.loc[~runs["run_id"].isin(histories.loc[histories["key"] == key, "run_id"]), "run_name"]
        if len(lacking):
            print(f"sweep.report: missing: {key} history in {', '.join(lacking)}")
    style.apply()
    agents = style.ordered(runs["agent"])
    colors = style.palette(agents)
    written = []
    for wind in sorted(runs["wind"].unique()):
        for stem in figures.CURVES:
            written += figures.curve_figure(runs, histories, wind, stem, colors, out_dir)

    wind, picked = figures.eval_runs(runs)
    trajs = {}
    for agent, run in picked.iterrows():
        t = load.load_trajectories(client, run["run_id"])
        if t is None:
            print(f"sweep.report: missing: eval_trajectories.npz of {run['run_name']}")
        else:
            trajs[agent] = t
    if trajs:
        radius = float(picked["success_radius"].astype(float).iloc[0]) if picked["success_radius"].notna().any() \
            else np.nan
        written += figures.flights_3d(trajs, picked, wind, colors, out_dir)
        written += figures.position_axes(trajs, picked, wind, colors, radius, out_dir)

    written += tables.write_tables(runs, stats.per_run_curve_stats(histories), agents, out_dir)
    print(f"sweep.report: wrote {len(written)} files")
    return out_dir.resolve()


def missing_conditions(runs) -> list[str]:
    """Agent x wind cells of the paper's design (and of whatever else is present) without any run."""
    from sweep.report.style import KNOWN, ordered

    agents = ordered(set(runs["agent"]) | set(KNOWN))
    winds = sorted(set(runs["wind"]) | {"paper", "none"})
    present = set(zip(runs["agent"], runs["wind"]))
    return [f"agent={a} wind={w} (no finished runs)" for w in winds for a in agents if (a, w) not in present]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sweep.report", description=__doc__)
    parser.add_argument("--experiment", help="MLflow experiment (default: the one whose latest run started last)")
    parser.add_argument("--sweep", help="only runs of this sweep: its directory, or a substring of the 'sweep' tag")
    parser.add_argument("--out", help="output folder (default: reports/<experiment>/)")
    args = parser.parse_args(argv)
    from sweep.report.load import ReportError

    try:
        out = build(args.experiment, args.sweep, args.out)
    except ReportError as err:
        print(f"sweep.report: {err}", file=sys.stderr)
        return 1
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
