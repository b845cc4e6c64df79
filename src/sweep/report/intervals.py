"""Interval-estimate figures (rliable's layout, Agarwal et al. 2021): per measure, one row per agent sorted by
it, the point estimate as a tick and its 95% CI as a bar, PPO's value as a vertical reference line, one panel per
arm (training wind x --by values) side by side on a shared x axis.

Each row is drawn as rliable's ``plot_utils.plot_interval_estimates`` draws one (``_row``; tests/test_report.py
compares the two). That function itself is not called: its rows are shared by all its panels (one order for
every arm, where a reader wants each arm's own ranking), it needs every agent in every panel and has no
reference line.
"""
from __future__ import annotations

import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import pyplot as plt

from sweep import metrics
from sweep.report import figures, stats, style

HEIGHT = 0.6           # bar height in rows (rliable's interval_height)
ROW_INCHES = 0.17      # height of one agent's row
LABEL_WIDTH = 26       # characters per line of an agent's label


@dataclass(frozen=True)
class Measure:
    """A per-run column aggregated over seeds: by its mean with a 95% Student-t CI (``mean``) or by rliable's IQM
    with a 95% stratified-bootstrap CI (``iqm``), drawn times ``scale``. A ``percent`` measure lies in [0, 100],
    and its CI is cut there (a t-interval over few bimodal seeds can reach past both ends), a ``nonnegative`` one's
    at 0; a ``lower_is_better`` measure (a distance) sorts its best, lowest row to the top."""
    column: str
    title: str
    statistic: str
    scale: float = 1.0
    percent: bool = False
    lower_is_better: bool = False
    nonnegative: bool = False


# File stem interval_<name> -> the measure: the leaderboard's primary measure, the final and best policy's success
# at the end of the run, the IQM final training reward, the re-learning AUC (drawn only for runs that have it).
MEASURES = {
    "keeps_hovering": Measure("keeps_hovering", "Keeps hovering (%): share of late evaluations at ≥ 50% success",
                              "mean", 100.0, True),
    "success_final": Measure(metrics.eval_key("final", "success_rate"), "Final policy's success (%)", "mean", 100.0,
                             True),
    "success_best": Measure(metrics.eval_key("best", "success_rate"), "Best policy's success (%)", "mean", 100.0,
                            True),
    "final_reward": Measure("final_reward", "IQM final training reward", "iqm"),
    "relearning": Measure("relearning", "Re-learning AUC (%): mean eval success within the segments after the first",
                          "mean", 100.0, True),   # runs evaluated in two segments or more (relearning.py)
    "relearning_distance": Measure("relearning_distance", "Re-learning distance (m): mean final distance to the "
                                   "target of the evaluations within the segments after the first (lower is "
                                   "better)", "mean", lower_is_better=True, nonnegative=True),   # logged in training
}
STATISTIC = {"mean": "mean over seeds, bar: 95% Student-t CI", "iqm": "IQM over seeds, bar: 95% bootstrap CI"}


def estimate(values, statistic: str) -> tuple[float, float, float, int]:
    """(point, CI low, CI high, n) of the finite ``values``; a degenerate CI (one seed) is the point itself."""
    x = np.asarray(values, dtype=float)
    n = int(np.isfinite(x).sum())
    if statistic == "mean":
        point, half, _ = stats.mean_t_ci(x)
        lo, hi = point - half, point + half
    else:
        point, lo, hi = stats.iqm_ci(x)
    if np.isfinite(point) and not np.isfinite(lo):
        lo = hi = point
    return point, lo, hi, n


def estimates(df: pd.DataFrame, measure: Measure, conds) -> pd.DataFrame:
    """One row per panel (arm: 'wind W' and the --by values) and condition with runs that have the measure:
    panel, condition, agent, label, point, low, high, n, cut; each panel's rows sorted by the point, best last;
    a percent measure's CI cut to [0, 100] (cut: whether it reached past either end)."""
    rows = []
    for wind in sorted(df["wind"].unique(), key=lambda w: (w != "paper", w)):
        dw = df[df["wind"] == wind]
        for title, shown in conds.panels(dw["condition"]):
            arm = style.arm_title(wind) + (f", {title}" if title else "")
            panel = []
            for cond in shown:
                point, lo, hi, n = estimate(dw.loc[dw["condition"] == cond, measure.column], measure.statistic)
                lo, hi = measure.scale * lo, measure.scale * hi
                floor = measure.percent or measure.nonnegative
                cut = (floor and lo < 0.0) or (measure.percent and hi > 100.0)
                lo = max(lo, 0.0) if floor else lo
                hi = min(hi, 100.0) if measure.percent else hi
                if n:
                    panel.append({"panel": arm, "condition": cond, "agent": conds.agent(cond),
                                  "label": conds.series(cond), "point": measure.scale * point,
                                  "low": lo, "high": hi, "n": n, "cut": cut})
            sign = -1.0 if measure.lower_is_better else 1.0   # the best last: drawn at the top
            rows += sorted(panel, key=lambda r: sign * r["point"])  # stable: ties keep the display order
    return pd.DataFrame(rows, columns=["panel", "condition", "agent", "label", "point", "low", "high", "n", "cut"])


def _row(ax, y: float, point: float, low: float, high: float, colour) -> None:
    """One agent's row as rliable's plot_interval_estimates draws it: the CI as a bar, the point as a tick."""
    ax.barh(y=y, width=high - low, height=HEIGHT, left=low, color=colour, alpha=0.75)
    ax.vlines(x=point, ymin=y - (7.5 * HEIGHT / 16), ymax=y + (6 * HEIGHT / 16), color="k", alpha=0.5)


def interval_figure(df: pd.DataFrame, name: str, conds, out: Path) -> list[Path]:
    """Figure interval_<name> (a MEASURES key) from the per-run table ``df`` (runs with their per-run columns);
    nothing when no run has the measure."""
    measure = MEASURES[name]
    if measure.column not in df:
        return []
    table = estimates(df, measure, conds)
    if table.empty:
        return []
    panels = list(dict.fromkeys(table["panel"]))
    rows = table.groupby("panel", sort=False).size().max()
    lines = max(len(textwrap.wrap(label, LABEL_WIDTH)) for label in table["label"])  # a row fits its label
    fig, axes = plt.subplots(1, len(panels), sharex=True, squeeze=False, layout="constrained",
                             figsize=(style.figure_width(len(panels)), 0.75 + ROW_INCHES * lines * rows))
    for ax, panel in zip(axes[0], panels):
        mine = table[table["panel"] == panel].reset_index(drop=True)
        ys = rows - len(mine) + np.arange(len(mine))  # the best row at the top of every panel
        for y, (_, r) in zip(ys, mine.iterrows()):
            _row(ax, y, r["point"], r["low"], r["high"], conds.color(r["condition"]))
        ppo = mine[mine["agent"] == "ppo"]
        if len(ppo):
            ax.axvline(ppo["point"].iloc[0], color="0.3", linestyle="--", linewidth=0.7, zorder=0)
        ax.set_yticks(ys, [textwrap.fill(label, LABEL_WIDTH) for label in mine["label"]])
        ax.set_ylim(-0.6, rows - 0.4)
        ax.tick_params(axis="y", length=0)
        ax.spines["left"].set_visible(False)
        ax.grid(True, axis="x")
        seeds = sorted(set(mine["n"]))
        ax.set_title(f"{panel} ({'/'.join(map(str, seeds))} seed{'s' if seeds != [1] else ''})")
    if measure.percent:
        axes[0, 0].set_xlim(-3, 103)
    reference = "; dashed line: PPO" if (table["agent"] == "ppo").any() else ""
    cut = (f" (cut to {'0–100' if measure.percent else 'above 0'})" if table["cut"].any()
           else "")  # said only where a CI reached past 0 or 100
    caption = f"{measure.title}; {STATISTIC[measure.statistic]}{cut}{reference}"
    fig.supxlabel(textwrap.fill(caption, 60 * len(panels)), fontsize=7)
    return figures.save(fig, out, f"interval_{name}")
