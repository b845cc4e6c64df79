"""The transfer-gap table (issue 33 §2): does a policy that hovers under condition A do worse under condition B?

    python -m sweep.report.transfer --experiment transfer --change "paper speed=x3:x1p5" --change "flip=x3:mx3" ...

A change tests plasticity only if it has a gap. For each ``--change NAME=A:B`` (A and B are arms: a run's wind
tag, ``+<vehicle>`` where the vehicle is not nominal, ``sweep.metrics.condition_arm``):

* **A on A**: the runs trained under A alone, their stored policies flown under A;
* **A on B**: the same policies flown under B;
* **B on B**: the runs trained under B alone, flown under B.

Every cell is a re-evaluation, ``sweep.reevaluate --name on_<Y>`` (``reeval_name``) with Y's wind and vehicle as
the fixed ``eval.*`` condition and a start seed of its own, read from the run under ``on_<Y>/``: the same protocol
for the three, and none of them on the starts the kept policy was chosen on (the in-training evaluations fly
``eval.seed``'s starts; a policy kept for its score on them would look better there than anywhere else).

Per change, for the policy ``--policy`` (``best_eval``, the default: the policy kept at the highest in-training
eval return, i.e. the one that hovered best under its own condition; or ``final``, ``best``): success rate (%)
and position MSE (the per-axis MSEs summed, m²), seed mean ± 95% Student-t CI; the gap (success A on A − A on B,
MSE A on B − A on A: positive = worse under B), paired by seed, with its 95% Student-t CI, over all seeds and over the seeds whose policy hovers under A (success >= 50%:
a seed that never learned the hover has no gap to show). Written to ``<out>/transfer_gap.md`` and ``.csv``, and the
figure ``transfer_gap.png`` (``figures.transfer_gap``: one panel per change, each seed's three cells).
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from sweep import metrics
from sweep.report import figures, load, stats
from sweep.report.tables import markdown, plus_minus

FIELDS = ("success_rate", "mse_x", "mse_y", "mse_z")
HOVERS = stats.HOVER   # a policy hovers under a condition: success >= this (the leaderboard's threshold)


def reeval_name(arm: str) -> str:
    """The ``sweep.reevaluate --name`` of the flights under arm ``arm``: ``on_`` and the arm, ``_`` for others."""
    return "on_" + re.sub(r"[^0-9A-Za-z]", "_", arm)


def scores(client, exp_id: str, policy: str) -> pd.DataFrame:
    """One row per FINISHED run: run_id, arm, seed, and every logged eval field of ``policy`` (own and re-flown
    ``on_*/``) as ``<prefix>/<field>`` columns (the newest run of an agent, arm and seed)."""
    prefix = metrics.POLICIES[policy]
    rows = []
    for run in load._all_runs(client, exp_id):
        if run.info.status != "FINISHED":
            continue
        tags, logged = run.data.tags, run.data.metrics
        row = {"run_id": run.info.run_id, "agent": tags.get("agent", "?"), "arm": metrics.condition_arm(tags),
               "seed": int(tags.get("seed", -1)),
               "start_time": run.info.start_time}
        row.update({k: v for k, v in logged.items() if k.split("/")[-2:-1] == [prefix] and k.split("/")[-1] in FIELDS})
        rows.append(row)
    df = pd.DataFrame(rows)
    if df.empty:
        return df
    return df.sort_values("start_time").drop_duplicates(["agent", "arm", "seed"], keep="last").reset_index(drop=True)


def _measures(df: pd.DataFrame, where: str, prefix: str) -> pd.DataFrame:
    """seed -> success and MSE (summed over axes) read under ``<where><prefix>/``."""
    cols = {f: f"{where}{prefix}/{f}" for f in FIELDS}
    if not all(c in df for c in cols.values()):
        return pd.DataFrame(columns=["seed", "success", "mse"])
    out = pd.DataFrame({"seed": df["seed"], "success": df[cols["success_rate"]],
                        "mse": df[cols["mse_x"]] + df[cols["mse_y"]] + df[cols["mse_z"]]})
    return out.dropna()


CELLS = ("A on A", "A on B", "B on B")


def cells_of(df: pd.DataFrame, a: str, b: str, prefix: str) -> dict[str, pd.DataFrame]:
    """The three cells of change A -> B: cell -> (seed, success, mse)."""
    runs_a, runs_b = df[df["arm"] == a], df[df["arm"] == b]
    return {"A on A": _measures(runs_a, f"{reeval_name(a)}/", prefix),
            "A on B": _measures(runs_a, f"{reeval_name(b)}/", prefix),
            "B on B": _measures(runs_b, f"{reeval_name(b)}/", prefix)}


def per_seed(df: pd.DataFrame, changes: list[tuple[str, str, str]], policy: str) -> pd.DataFrame:
    """One row per change, cell and seed: its success and MSE (what the figure draws)."""
    prefix = metrics.POLICIES[policy]
    frames = [m.assign(change=name, cell=cell) for name, a, b in changes
              for cell, m in cells_of(df, a, b, prefix).items()]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=["change", "cell", "seed"])


def gap_table(df: pd.DataFrame, changes: list[tuple[str, str, str]], policy: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(numbers, display) of the transfer gap of each (name, A, B) in ``changes``."""
    prefix = metrics.POLICIES[policy]
    numbers, display = [], []
    for name, a, b in changes:
        cells = cells_of(df, a, b, prefix)
        row = {"change": name, "A": a, "B": b}
        shown = {"Change": name, "A → B": f"{a} → {b}"}
        for cell, m in cells.items():
            key = cell.replace(" ", "_")
            for measure, scale, digits in (("success", 100.0, 0), ("mse", 1.0, 3)):
                mean, half, n = stats.mean_t_ci(m[measure])
                row.update({f"{key}_{measure}": mean, f"{key}_{measure}_ci95": half, f"{key}_n": n})
            per_seed = ", ".join(f"{100 * v:.0f}" for v in m.sort_values("seed")["success"])
            shown[f"{cell}: success (%)"] = plus_minus(100 * row[f"{key}_success"], 100 * row[f"{key}_success_ci95"], 0) \
                + f" ({per_seed})"
            shown[f"{cell}: MSE (m²)"] = plus_minus(row[f"{key}_mse"], row[f"{key}_mse_ci95"], 3)
        paired = cells["A on A"].merge(cells["A on B"], on="seed", suffixes=("_aa", "_ab"))
        for measure, sign in (("success", 1.0), ("mse", -1.0)):   # a gap: success lost, MSE gained under B
            mean, half, n = stats.mean_t_ci(sign * (paired[f"{measure}_aa"] - paired[f"{measure}_ab"]))
            row.update({f"gap_{measure}": mean, f"gap_{measure}_ci95": half, "gap_n": n})
        hovering = paired[paired["success_aa"] >= HOVERS]   # the seeds whose policy hovers under A
        mean, half, n = stats.mean_t_ci(hovering["success_aa"] - hovering["success_ab"])
        row.update({"gap_hovering_success": mean, "gap_hovering_success_ci95": half, "gap_hovering_n": n})
        shown["Gap A on A − A on B: success (pp)"] = plus_minus(100 * row["gap_success"], 100 * row["gap_success_ci95"], 0)
        shown[f"Gap, seeds hovering under A (≥ {HOVERS:.0%}): success (pp)"] = (
            plus_minus(100 * mean, 100 * half, 0) + f" (n={n})" if n else "–")
        shown["Gap: MSE A on B − A on A (m²)"] = plus_minus(row["gap_mse"], row["gap_mse_ci95"], 3)
        numbers.append(row)
        display.append(shown)
    return pd.DataFrame(numbers), pd.DataFrame(display)


def parse_change(item: str) -> tuple[str, str, str]:
    name, sep, arms = item.rpartition("=")
    a, colon, b = arms.partition(":")
    if not sep or not colon or not name or not a or not b:
        raise ValueError(f"--change {item!r}: expected NAME=A:B, e.g. 'flip=x3:mx3' (A, B: wind[+vehicle] arms)")
    return name, a, b


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sweep.report.transfer", description=__doc__.split("\n\n")[0])
    parser.add_argument("--experiment", required=True)
    parser.add_argument("--change", action="append", required=True, metavar="NAME=A:B")
    parser.add_argument("--policy", default="best_eval", choices=list(metrics.POLICIES))
    parser.add_argument("--agent", help="the agent whose runs to read (needed when the experiment has several)")
    parser.add_argument("--out", type=Path, default=Path("."))
    parser.add_argument("--uri", help="MLflow store (default: $MLFLOW_TRACKING_URI, else <project root>/mlflow.db)")
    args = parser.parse_args(argv)
    try:
        changes = [parse_change(c) for c in args.change]
        uri = args.uri or load.tracking_uri()
        client = load.client_for(uri)
        exp_id, _ = load.pick_experiment(client, args.experiment)
        df = scores(client, exp_id, args.policy)
        agents = sorted(set(df["agent"])) if len(df) else []
        if args.agent is not None:
            if args.agent not in agents:
                raise ValueError(f"--agent {args.agent}: no FINISHED run of it (agents there: {', '.join(agents) or 'none'})")
            df = df[df["agent"] == args.agent]
        elif len(agents) > 1:
            raise ValueError(f"runs of several agents ({', '.join(agents)}): choose one with --agent")
        arms = set(df["arm"]) if len(df) else set()
        missing = sorted({arm for _, a, b in changes for arm in (a, b)} - arms)
        if missing:
            raise ValueError(f"no FINISHED run under {', '.join(missing)} in {args.experiment!r} (arms there: "
                             f"{', '.join(sorted(arms)) or 'none'})")
    except (ValueError, load.ReportError) as err:
        print(f"transfer: {err}", file=sys.stderr)
        return 1
    numbers, display = gap_table(df, changes, args.policy)
    args.out.mkdir(parents=True, exist_ok=True)
    numbers.to_csv(args.out / "transfer_gap.csv", index=False)
    text = (f"Transfer gap, {metrics.POLICIES[args.policy]} policy ({args.policy}), experiment {args.experiment!r}: "
            "A on A = runs trained under A alone, flown under A; A on B = the same policies flown under B; B on B = "
            "runs trained under B alone, flown under B (every cell re-flown by sweep.reevaluate on starts of its own "
            "seed, not those the kept policy was chosen on). Success rate and position MSE (summed over axes), seed mean ± 95% Student-t "
            "CI, per seed in parentheses (seed order); gap = success A on A − A on B and MSE A on B − A on A (positive: worse "
            "under B), paired by seed, 95% Student-t CI, over all "
            f"seeds and over the seeds whose policy hovers under A (success ≥ {HOVERS:.0%}).\n\n" + markdown(display))
    (args.out / "transfer_gap.md").write_text(text + "\n")
    figures.transfer_gap(per_seed(df, changes, args.policy), numbers, args.out)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
