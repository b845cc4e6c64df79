"""Column-width figures (PNG + PDF): training curves per wind condition and the evaluation flights."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import pyplot as plt
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter, MaxNLocator, NullFormatter

from sweep.report import stats, style

CURVES = {  # file stem -> (metric, y label, scale, log y)
    "reward": ("rollout/ep_rew_mean", "Mean episode reward", 1.0, False),
    "dormant": ("plasticity/dormant_ratio", "Dormant units, policy net (%)", 100.0, False),
    "learning_rate": ("train/learning_rate", "Learning rate", 1.0, True),
}
BAND = "mean over seeds; band: 95% bootstrap CI"


def save(fig, out: Path, stem: str) -> list[Path]:
    paths = [out / f"{stem}.png", out / f"{stem}.pdf"]
    for p in paths:
        fig.savefig(p, bbox_inches="tight", pad_inches=0.02)
    plt.close(fig)
    return paths


def timestep_axis(ax, x_max: float) -> None:
    scale, unit = (1e6, "M") if x_max >= 1e6 else (1e3, "k") if x_max >= 1e3 else (1.0, "")
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v / scale:g}"))
    ax.xaxis.set_major_locator(MaxNLocator(6))
    ax.set_xlabel(f"Timesteps ({unit})" if unit else "Timesteps")


def wind_changes(speeds: list[float], segment: float, x_max: float) -> list[tuple[float, float, float]]:
    """(start, end, speed) of each constant-wind stretch within [0, x_max], as WindSchedule.speed_at has it."""
    if not speeds or not np.isfinite(segment) or segment <= 0:
        return []
    spans, k = [], 0
    while k * segment < x_max and k < 1000:
        speed = speeds[k % len(speeds)]
        if spans and spans[-1][2] == speed:
            spans[-1] = (spans[-1][0], min((k + 1) * segment, x_max), speed)
        else:
            spans.append((k * segment, min((k + 1) * segment, x_max), speed))
        k += 1
    return spans


def mark_wind(ax, spans) -> None:
    """Dotted vertical line at each wind change, the speed (m/s) written above each stretch."""
    if len(spans) < 2:
        return
    left, right = ax.get_xlim()
    for start, end, speed in spans:
        if start > 0:
            ax.axvline(start, color="0.45", linestyle=":", linewidth=0.7, zorder=0)
        if end - start < 0.04 * (right - left):  # a sliver (e.g. the last rollout past a change): no label
            continue
        ax.text((max(start, left) + end) / 2, 1.01, f"{speed:.1f}", transform=ax.get_xaxis_transform(), ha="center",
                va="bottom", fontsize=7, color="0.3")
    ax.text(1.0, 1.01, " m/s", transform=ax.transAxes, ha="left", va="bottom", fontsize=7, color="0.3")


def curve_figure(runs: pd.DataFrame, histories: pd.DataFrame, wind: str, stem: str, colors: dict,
                 out: Path) -> list[Path]:
    key, ylabel, scale, logy = CURVES[stem]
    sub = runs[runs["wind"] == wind]
    hist = histories[(histories["key"] == key) & histories["run_id"].isin(sub["run_id"])]
    if hist.empty:
        return []
    grid = stats.common_grid(hist)  # a single point if every run logged ``key`` once
    fig, ax = plt.subplots(figsize=(style.COLUMN_WIDTH, 2.3))
    seeds = []
    for agent in style.ordered(sub["agent"]):
        matrix = stats.aligned(hist, key, sub.loc[sub["agent"] == agent, "run_id"], grid) * scale
        if not len(matrix):
            continue
        mean, lo, hi, _ = stats.mean_band(matrix)
        ax.plot(grid, mean, color=colors[agent], linestyle=style.dashes(agent), linewidth=1.2,
                marker="o" if len(grid) == 1 else None, markersize=3,
                label=f"{style.label(agent)} (n={len(matrix)})")
        ax.fill_between(grid, lo, hi, color=colors[agent], alpha=0.2, linewidth=0)
        seeds.append(len(matrix))
    first = sub.iloc[0]
    ax.set_xlim(0, grid[-1] * (1.05 if len(grid) == 1 else 1.0))
    mark_wind(ax, wind_changes(first["speeds"], first["segment_steps"], grid[-1]))
    timestep_axis(ax, grid[-1])
    ax.set_ylabel(ylabel)
    if logy:
        ax.set_yscale("log")
        ax.yaxis.set_minor_formatter(NullFormatter())  # decade labels only: narrow and legible
    if stem == "dormant":  # a percentage: from 0, at least 0-1% so an all-zero curve is not centred on 0
        ax.set_ylim(0, max(1.0, ax.get_ylim()[1]))
    ax.grid(True)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=3, frameon=False, handlelength=1.5,
              columnspacing=1.0, title=BAND if max(seeds) > 1 else "one seed per agent")
    return save(fig, out, f"{stem}_{wind}")


def eval_runs(runs: pd.DataFrame) -> tuple[str, pd.DataFrame]:
    """Per agent, the best-return seed among runs trained with wind 'paper' (else the first condition present)."""
    wind = "paper" if "paper" in set(runs["wind"]) else sorted(runs["wind"].unique())[0]
    sub = runs[runs["wind"] == wind].sort_values("eval/return", ascending=False, na_position="last")
    return wind, sub.drop_duplicates("agent").set_index("agent")


def flights_3d(trajs: dict, picked: pd.DataFrame, wind: str, colors: dict, out: Path) -> list[Path]:
    agents = [a for a in style.ordered(trajs) if a in trajs]
    cols = min(len(agents), 2)
    rows = int(np.ceil(len(agents) / cols))
    spare = rows * cols > len(agents)  # the legend goes into the empty panel, else below the panels
    legend_h = 0.05 if spare else 0.6  # inches below the panels for the legend
    fig = plt.figure(figsize=(style.COLUMN_WIDTH, 1.75 * rows + 0.1 + legend_h))
    bound = max(float(np.nanmax(np.abs(t["positions"]))) for t in trajs.values())
    bound = min(np.ceil(bound), 4.0)
    for i, agent in enumerate(agents):
        t, run = trajs[agent], picked.loc[agent]
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        for pos, crashed in zip(t["positions"], t["crashed"]):
            ax.plot(pos[:, 0], pos[:, 1], pos[:, 2], color=colors[agent], linewidth=0.7, alpha=0.8)
            ax.scatter(*pos[0], color=colors[agent], s=6, marker="o", depthshade=False)
            if crashed:
                end = pos[~np.isnan(pos[:, 0])][-1]
                ax.scatter(*end, color="k", s=10, marker="x", depthshade=False, linewidths=0.8)
        ax.scatter(0, 0, 0, color="k", marker="*", s=30, depthshade=False)
        ax.set(xlim=(-bound, bound), ylim=(-bound, bound), zlim=(-bound, bound))
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(MaxNLocator(3))
            axis.set_tick_params(pad=-3, labelsize=6)
            axis.labelpad = -9
        ax.set_xlabel("x (m)", fontsize=7)
        ax.set_ylabel("y (m)", fontsize=7)
        ax.set_zlabel("z (m)", fontsize=7)
        ax.set_title(f"{style.label(agent)}, seed {run['seed']}\nsuccess {100 * np.mean(t['success']):.0f}%",
                     fontsize=7, pad=-2)
        ax.view_init(elev=22, azim=-60)
    wind_vec = next(iter(trajs.values()))["wind"]
    handles = [Line2D([], [], color="0.3", marker="o", linestyle="-", markersize=3, label="start"),
               Line2D([], [], color="k", marker="*", linestyle="", markersize=6, label="target"),
               Line2D([], [], color="k", marker="x", linestyle="", markersize=4, label="crash")]
    title = (f"Evaluation wind {np.linalg.norm(wind_vec):g} m/s along {_direction(wind_vec)}\n"
             f"agents trained with wind '{wind}'\nbest-return seed per agent")
    if spare:
        fig.legend(handles=handles, loc="center", ncol=1, frameon=False, title=title,
                   bbox_to_anchor=(0.75, 0.5 / rows))
    else:
        fig.legend(handles=handles, loc="lower center", ncol=3, frameon=False, bbox_to_anchor=(0.5, 0.0),
                   title=title.replace("'\nbest", "', best"))
    fig.subplots_adjust(left=0.02, right=0.95, top=0.93, bottom=legend_h / fig.get_figheight(), wspace=0.15,
                        hspace=0.25)
    return save(fig, out, "eval_flights_3d")


def _direction(v: np.ndarray) -> str:
    v = np.asarray(v, dtype=float)
    if not np.any(v):
        return "-"
    axis = int(np.argmax(np.abs(v)))
    return ("+" if v[axis] > 0 else "-") + "xyz"[axis] if np.count_nonzero(v) == 1 else str(np.round(v, 2))


def position_axes(trajs: dict, picked: pd.DataFrame, wind: str, colors: dict, radius: float, out: Path) -> list[Path]:
    agents = [a for a in style.ordered(trajs) if a in trajs]
    fig, axes = plt.subplots(3, len(agents), figsize=(style.COLUMN_WIDTH, 3.4), sharex=True, sharey="row",
                             squeeze=False)
    for j, agent in enumerate(agents):
        t = trajs[agent]
        time = np.arange(t["positions"].shape[1]) * float(t["dt"])
        axes[0, j].set_xlim(0, time[-1])
        for i in range(3):
            ax = axes[i, j]
            if np.isfinite(radius):
                ax.axhspan(-radius, radius, color="0.85", linewidth=0, zorder=0)
            ax.axhline(0, color="0.5", linewidth=0.5, zorder=0)
            for pos in t["positions"]:
                ax.plot(time, pos[:, i], color=colors[agent], linewidth=0.6, alpha=0.8)
            if j == 0:
                ax.set_ylabel(f"{'xyz'[i]} (m)")
            ax.yaxis.set_major_locator(MaxNLocator(4))
        axes[0, j].set_title(f"{style.label(agent)}\nseed {picked.loc[agent, 'seed']}", fontsize=7)
        axes[-1, j].set_xlabel("Time (s)")
        axes[-1, j].xaxis.set_major_locator(MaxNLocator(3, steps=[1, 2, 5]))  # no label on the right edge
    note = f"\ngrey band: success radius ±{radius:g} m" if np.isfinite(radius) else ""
    fig.suptitle(f"Evaluation flights, agents trained with wind '{wind}', best-return seed{note}", fontsize=7,
                 y=0.995)
    fig.tight_layout(pad=0.3, h_pad=0.3, w_pad=0.3)
    return save(fig, out, "eval_position_axes")
