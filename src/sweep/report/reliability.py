"""The reliability table (docs/reliability.md): per row of settings, how many seeds learn the hover, how soon, how fast
on the clock, and whether they keep it.

A seed *hovers* at an evaluation when its success there (``eval/success_rate``: the share of the evaluation flights
within ``eval.success_radius`` of the origin for the last ``eval.success_hold_s``; logged every
``eval.every_timesteps`` and at the end) is at least a threshold: 50% and 90%. A row is the runs of one agent, learner,
training wind and ``--by`` values (``load.read_runs``); per row, over its seeds:

* ``reached``: the share of seeds with an evaluation at or above the threshold at or before each budget (300k, 1M, 3M
  env steps), with its Wilson 95% interval. An evaluation counts at the step it was scheduled for (``eval.every_timesteps``
  multiples: a learner evaluates after the update that passes it, e.g. at 1,001,472 for 1M on rollouts of 2048). A
  seed whose run ended before the budget without reaching it is censored: the share is over the others, and the cell
  then shows the lower bound k of all seeds and how many ran short ("≥ 2/16, 14 ran < 3M");
* ``median steps`` and ``median wall s`` to the first such evaluation, over the seeds that reach it (wall: the metric's
  MLflow timestamp minus the run's start, so set-up, compilation and the evaluations themselves count);
* ``at end``: the share whose last evaluation is at or above the threshold.

The figure (``hovering.png``): the share of seeds hovering (>= 50%) at each evaluation step, one curve per row with its
Wilson band; a seed counts from its first evaluation to its last.

    python -m sweep.report.reliability --experiment reliability --by env.observe.action_history,env.curriculum.start_bound_from
"""
from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import pyplot as plt

from sweep.report import load, style
from sweep.report.stats import wilson
from sweep.report.tables import markdown

THRESHOLDS = (0.5, 0.9)
BUDGETS = (300_000, 1_000_000, 3_000_000)
SUCCESS = "eval/success_rate"


def steps_label(n: int) -> str:
    return f"{n / 1e6:g}M" if n >= 1_000_000 else f"{n / 1e3:g}k"


EVERY = "eval.every_timesteps"


def on_schedule(histories: pd.DataFrame, runs: pd.DataFrame) -> pd.DataFrame:
    """``histories`` with each evaluation at the step it was scheduled for: the multiple of its run's
    ``eval.every_timesteps`` it was taken after (a run without one: as logged)."""
    every = pd.to_numeric(histories["run_id"].map(runs.set_index("run_id")[EVERY]), errors="coerce")
    use = every.notna() & (every > 0)
    step = histories["step"].where(~use, (histories["step"] // every.where(use, 1)) * every.where(use, 1))
    return histories.assign(step=step.astype(np.int64))


def per_seed(runs: pd.DataFrame, histories: pd.DataFrame) -> pd.DataFrame:
    """One row per run: its row key, the last (scheduled) step it evaluated at, and per threshold the first step and
    wall second at which it hovered (NaN: never) and whether its last evaluation hovers."""
    out = []
    for _, run in runs.iterrows():
        h = histories[histories["run_id"] == run["run_id"]].sort_values("step")
        row = {"run_id": run["run_id"], "row": run["row"], "seed": run["seed"],
               "last_step": h["step"].max() if len(h) else np.nan}
        for t in THRESHOLDS:
            hit = h[h["value"] >= t - 1e-9]
            row[f"first_step_{t:g}"] = hit["step"].iloc[0] if len(hit) else np.nan
            row[f"first_wall_{t:g}"] = (hit["ts"].iloc[0] - run["start_time"]) / 1000 if len(hit) else np.nan
            row[f"end_{t:g}"] = bool(len(h) and h["value"].iloc[-1] >= t - 1e-9)
        out.append(row)
    return pd.DataFrame(out)


def table(seeds: pd.DataFrame, rows: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(numbers, display): per row and threshold, the shares reached within each budget [Wilson CI] (n), the median
    steps and wall seconds to the first hovering evaluation, the share hovering at the end."""
    numbers, display = [], []
    for name in rows:
        g = seeds[seeds["row"] == name]
        for t in THRESHOLDS:
            num = {"row": name, "threshold": t, "seeds": len(g)}
            shown = {"Row": name, "Success ≥": f"{t:.0%}", "Seeds": len(g)}
            for budget in BUDGETS:
                label = steps_label(budget)
                reached = g[f"first_step_{t:g}"] <= budget
                counted = reached | (g["last_step"] >= budget)   # censored: ended before the budget without it
                k, n, short = int(reached.sum()), int(counted.sum()), int((~counted).sum())
                share, lo, hi = wilson(k, n)
                num.update({f"reached_{label}": share, f"reached_{label}_low": lo, f"reached_{label}_high": hi,
                            f"n_{label}": n, f"censored_{label}": short})
                shown[f"within {label}"] = (f"{k}/{n} [{lo:.0%}, {hi:.0%}]" if not short else
                                            f"≥ {k}/{len(g)}, {short} ran < {label}")
            steps, wall = g[f"first_step_{t:g}"].dropna(), g[f"first_wall_{t:g}"].dropna()
            end = wilson(int(g[f"end_{t:g}"].sum()), len(g))
            num.update({"median_steps": steps.median() if len(steps) else np.nan,
                        "median_wall_s": wall.median() if len(wall) else np.nan,
                        "at_end": end[0], "at_end_low": end[1], "at_end_high": end[2]})
            shown["median steps to first"] = f"{steps.median() / 1e3:.0f}k" if len(steps) else "–"
            shown["median wall s to first"] = f"{wall.median():.0f}" if len(wall) else "–"
            shown["hovering at end"] = f"{int(g[f'end_{t:g}'].sum())}/{len(g)} [{end[1]:.0%}, {end[2]:.0%}]"
            numbers.append(num)
            display.append(shown)
    return pd.DataFrame(numbers), pd.DataFrame(display)


def share_curve(histories: pd.DataFrame, runs: pd.DataFrame, threshold: float = 0.5
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(steps, share hovering, Wilson low, high) of ``runs`` at every step any of them evaluated at; a seed counts at
    the steps from its first evaluation to its last, hovering at the last evaluation at or before the step."""
    h = histories[histories["run_id"].isin(runs["run_id"])]
    steps = np.array(sorted(h["step"].unique()))
    shares, lows, highs = [], [], []
    for s in steps:
        k = n = 0
        for _, g in h.groupby("run_id"):
            done = g[g["step"] <= s]
            if len(done) and g["step"].max() >= s:
                n += 1
                k += bool(done["value"].iloc[-1] >= threshold - 1e-9)
        share, lo, hi = wilson(k, n)
        shares.append(share), lows.append(lo), highs.append(hi)
    return steps, np.array(shares), np.array(lows), np.array(highs)


def figure(histories: pd.DataFrame, runs: pd.DataFrame, rows: list[str], out: Path) -> Path:
    style.apply()
    labels = {name: textwrap.fill(f"{name} (n={int((runs['row'] == name).sum())})", 120, subsequent_indent="    ")
              for name in rows}   # below the axes, one per line however long the rows' names are
    lines = sum(label.count("\n") + 1 for label in labels.values())
    fig, ax = plt.subplots(figsize=(7.5, 3.6 + 0.16 * lines), layout="constrained")
    colours = plt.get_cmap("tab10" if len(rows) <= 10 else "tab20")
    for i, name in enumerate(rows):
        steps, share, lo, hi = share_curve(histories, runs[runs["row"] == name])
        colour = colours(i % colours.N)
        ax.plot(steps, 100 * share, color=colour, label=labels[name], lw=1.6)
        ax.fill_between(steps, 100 * lo, 100 * hi, color=colour, alpha=0.15, lw=0)
    ax.set_xlabel("env steps")
    ax.set_ylabel("seeds hovering (eval success ≥ 50%), %")
    ax.set_ylim(-2, 102)
    ax.grid(alpha=0.3)
    fig.legend(fontsize=6, loc="outside lower center", frameon=False, ncol=1)
    ax.set_title("Share of seeds hovering, with Wilson 95% bands", fontsize=10)
    path = out / "hovering.png"
    fig.savefig(path, dpi=150)
    plt.close(fig)
    return path


def row_names(runs: pd.DataFrame, by: list[str]) -> pd.Series:
    """A row's name: the agent's label, its learner and wind, and the --by values that differ between the runs
    (``key=value``, the key's last part)."""
    differ = [k for k in by if runs[k].nunique() > 1]

    def name(r) -> str:
        settings = ", ".join(f"{k.split('.', 1)[-1]}={r[k]}" for k in differ)   # env.observe.x -> observe.x
        return f"{r['label']} [{r['learner']}, {r['wind']}]" + (f" {settings}" if settings else "")
    return runs.apply(name, axis=1)


def seed_list(text: str) -> list[int]:
    """``--seeds`` "0-15,100": the seeds it names (ranges inclusive)."""
    seeds: list[int] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        low, _, high = part.partition("-")
        seeds.extend(range(int(low), int(high or low) + 1))
    return seeds


def report(experiment: str, by: list[str], out: Path, sweep: str | None = None, seeds: list[int] | None = None) -> str:
    client = load.client_for(load.tracking_uri())
    exp_id, exp_name = load.pick_experiment(client, experiment)
    loaded = load.read_runs(client, exp_id, sweep, [*by, EVERY] if EVERY not in by else by, experiment=exp_name)
    runs = loaded.runs
    if seeds is not None:   # e.g. a pilot's seeds, or the seeds held out from it
        runs = runs[runs["seed"].astype(int).isin(seeds)]
    if runs.empty:
        raise load.ReportError(f"experiment {exp_name!r}: no finished runs" + (" of those seeds" if seeds else ""))
    runs = runs.assign(row=row_names(runs, by))
    rows = list(dict.fromkeys(runs.sort_values(["agent", "learner", "wind", *by])["row"]))
    histories = on_schedule(load.load_histories(client, runs, [SUCCESS], timestamps=True), runs)
    seeds = per_seed(runs, histories)
    numbers, display = table(seeds, rows)
    out.mkdir(parents=True, exist_ok=True)
    numbers.to_csv(out / "reliability.csv", index=False)
    seeds.to_csv(out / "reliability_seeds.csv", index=False)
    text = markdown(display)
    (out / "reliability.md").write_text(text)
    figure(histories, runs, rows, out)
    notes = "".join(f"note: {n}\n" for n in loaded.notes)
    return f"{notes}experiment {exp_name!r}: {len(runs)} finished runs, {len(rows)} rows -> {out}\n\n{text}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sweep.report.reliability", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--experiment", required=True, help="MLflow experiment")
    parser.add_argument("--by", metavar="KEY[,KEY...]", type=lambda s: [k for k in s.split(",") if k], default=[],
                        help="logged params that, with agent, learner and wind, make a row")
    parser.add_argument("--sweep", help="only runs of this sweep (its directory, or a substring of the 'sweep' tag)")
    parser.add_argument("--seeds", type=seed_list, metavar="LIST", help="only these seeds, e.g. 0-15 or 100,101")
    parser.add_argument("--out", help="output folder (default: reports/<experiment>/reliability/)")
    args = parser.parse_args(argv)
    out = Path(args.out) if args.out else Path("reports") / args.experiment / "reliability"
    try:
        print(report(args.experiment, args.by, out, args.sweep, args.seeds))
    except load.ReportError as err:
        print(f"sweep.report.reliability: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
