"""Column-width figures (PNG + PDF): training curves per wind condition and the evaluation flights."""
from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import pyplot as plt
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter

from sweep import metrics
from sweep.metrics import Curve
from sweep.report import load, stats, style
from sweep.report.highlight import Highlight


# File stem (figure <stem>_<wind>) -> its panels, top to bottom (sweep.metrics.CURVES). A figure is written for a
# wind condition when some run of it has the first panel's metric; a lower panel is drawn when some run has its metric.
CURVES = metrics.FIGURES
# What a figure's panels measure, before the notes of the panels drawn (below the legend).
NOTES = {"dormant": "Policy network, its hidden layers pooled."}
# conf/config.yaml's plasticity thresholds: the labels' values for runs that did not log the param (older stores)
THRESHOLDS = {"dormant_tau": 0.025, "saturation": 0.99, "dead_fraction": 0.99, "signed_mean_tau": 0.1}
BAND = "mean over n seeds; band: 95% bootstrap CI"
PANEL_STEP = {True: 1.4, False: 1.15}  # inches per panel below the first: up to 3 panels (True), more (False)
POSITION_COLUMNS = 4  # conditions side by side in eval_position_axes


def save(fig, out: Path, stem: str) -> list[Path]:
    """``stem``.png and .pdf (style.formats: only the PNG with --draft); the PDF without a creation date, so that
    re-making a report from the same runs writes the same bytes (a committed report changes only where its numbers
    do)."""
    paths = [out / f"{stem}.{suffix}" for suffix in style.formats]
    for p in paths:
        fig.savefig(p, bbox_inches="tight", pad_inches=0.02,
                    metadata={"CreationDate": None} if p.suffix == ".pdf" else None)
    plt.close(fig)
    return paths


def panel_inches(ax) -> float:
    """A panel's width in inches, as laid out so far."""
    return ax.get_position().width * ax.figure.get_figwidth()


def timestep_axis(ax, x_max: float) -> None:
    """Timesteps in k or M, about one label per half inch of the panel (six at most), so narrow panels stay legible."""
    scale, unit = (1e6, "M") if x_max >= 1e6 else (1e3, "k") if x_max >= 1e3 else (1.0, "")
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v / scale:g}"))
    ax.xaxis.set_major_locator(MaxNLocator(int(min(6, max(2, panel_inches(ax) / 0.5)))))
    ax.set_xlabel(f"Timesteps ({unit})" if unit else "Timesteps")


def wind_changes(speeds: list, segment: float, x_max: float) -> list[tuple[float, float, float | str]]:
    """(start, end, label) of each constant stretch within [0, x_max], the labels repeating every len(speeds)
    segments as WindSchedule.speed_at has it: wind speeds, or the conditions' labels (load.segment_labels)."""
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


def mark_wind(ax, spans, speeds: bool = True) -> None:
    """Dotted vertical line at each wind change, the speed (m/s) written above each stretch (if ``speeds``); with
    conditions' labels (load.segment_labels) the label instead, every other stretch on a grey band."""
    if len(spans) < 2:
        return
    left, right = ax.get_xlim()
    conditions = any(isinstance(s, str) for _, _, s in spans)   # labelled conditions: every other one shaded
    for i, (start, end, speed) in enumerate(spans):
        if conditions and i % 2:
            ax.axvspan(start, end, color="0.93", zorder=0, linewidth=0)
        if start > 0:
            ax.axvline(start, color="0.45", linestyle=":", linewidth=0.7, zorder=0)
        if not speeds:
            continue
        if end - start < 0.04 * (right - left):  # a sliver (e.g. the last rollout past a change): no label
            continue
        ax.text((max(start, left) + end) / 2, 1.01, speed if isinstance(speed, str) else f"{speed:.1f}",
                transform=ax.get_xaxis_transform(), ha="center", va="bottom", fontsize=7, color="0.3")
    if speeds and not any(isinstance(s, str) for _, _, s in spans):
        ax.text(1.0, 1.01, " m/s", transform=ax.transAxes, ha="left", va="bottom", fontsize=7, color="0.3")


def has_data(curve: Curve, hist: pd.DataFrame) -> bool:
    """Some run logged the metric (a sparse one at >= 2 steps: one final evaluation is no curve)."""
    if hist.empty:
        return False
    return not curve.sparse or int(hist.groupby("run_id")["step"].nunique().max()) >= 2


def thresholds(sub: pd.DataFrame) -> dict[str, str]:
    """The plasticity thresholds the runs of ``sub`` logged, as text for labels: one value, or all values joined
    by '/' where runs differ; THRESHOLDS' value where no run logged the param. ``dead_fraction`` as a percentage."""
    text = {}
    for name, default in THRESHOLDS.items():
        logged = pd.to_numeric(sub[name], errors="coerce") if name in sub else pd.Series(dtype=float)
        values = sorted(set(logged.dropna())) or [default]
        if name == "dead_fraction":
            text[name] = "/".join(f"{100 * v:g}" for v in values) + "%"
        else:
            text[name] = "/".join(f"{v:g}" for v in values)
    return text


def curve_figure(runs: pd.DataFrame, histories: pd.DataFrame, wind: str, stem: str, conds,
                 highlight: Highlight, out: Path) -> list[Path]:
    """Figure <stem>_<wind>: per condition the mean over seeds with a 95% bootstrap band; a row of panels per
    Curve, a column per panel of ``conds.panels`` (small multiples of the --by values, shared axes); the agents
    ``highlight`` does not colour thin and grey, without band or legend entry."""
    sub = runs[runs["wind"] == wind]
    mine = histories[histories["run_id"].isin(sub["run_id"])]
    rows = [(c, mine[mine["key"] == c.key]) for c in CURVES[stem]]
    if not has_data(*rows[0]):
        return []
    rows = [r for r in rows if has_data(*r)]
    panels = conds.panels(sub["condition"])
    x_max = max(float(h["step"].max()) for _, h in rows)
    step = PANEL_STEP[len(rows) <= 3]
    fig, axes = plt.subplots(len(rows), len(panels), sharex=True, sharey="row", squeeze=False,
                             figsize=(style.figure_width(len(panels)), 2.3 + step * (len(rows) - 1)))
    spans = wind_changes(sub.iloc[0]["segment_labels"], sub.iloc[0]["segment_steps"], x_max)
    values = thresholds(sub)
    seeds = {}
    for j, (title, shown) in enumerate(panels):
        for i, (curve, hist) in enumerate(rows):
            ax = axes[i, j]
            seeds.update(_panel(ax, curve, hist, sub[sub["condition"].isin(shown)], conds, highlight, wind))
            if j == 0:
                ax.set_ylabel(curve.ylabel.format(**values))
            ax.set_xlim(0, x_max * (1.05 if len(stats.common_grid(hist)) == 1 or curve.sparse else 1.0))
            mark_wind(ax, spans, speeds=i == 0)
        _panel_title(axes[0, j], title, spans)
        timestep_axis(axes[-1, j], x_max)
    if len(rows) > 1:
        fig.align_ylabels(axes[:, 0])
    same = len(set(seeds.values())) == 1  # seeds per condition: in the title if the same for all
    n = {}  # else in each legend entry, per panel where a series' conditions differ ("n=3/2")
    for cond, k in seeds.items():
        n.setdefault(conds.series(cond), set()).add(k)
    if max(seeds.values()) == 1:
        title = "one seed per condition" if conds.by and not conds.split else "one seed per agent"
    else:
        title = f"mean over {max(seeds.values())} seeds; band: 95% bootstrap CI" if same else BAND
    notes = [NOTES.get(stem, "")] + [curve.note.format(**values) for curve, _ in rows]
    _legend(fig, axes, wind, panels, conds, highlight, title, notes if any(notes[1:]) else [],
            (lambda label: label) if same else (lambda label: f"{label} (n={'/'.join(map(str, sorted(n[label])))})"))
    return save(fig, out, f"{stem}_{wind}")


def _panel_title(ax, title: str, spans) -> None:
    """A small-multiple panel's title (its --by values), above the wind speeds if the panel shows them; one value per
    line where the panel is too narrow for the title on one line."""
    if title:
        if len(title) * 0.055 > panel_inches(ax):   # ~0.055 in per character at the figures' 7 pt
            title = title.replace(", ", ",\n")
        ax.set_title(title, pad=13 if len(spans) >= 2 else 4)


def _legend(fig, axes, wind: str, panels: list, conds, highlight: Highlight, title: str, notes: list[str],
            name=lambda label: label) -> None:
    """One legend below the panels for the coloured series (in ranking order, as many columns as fit the figure's
    width), then the notes and the greyed agents, left-aligned with the panels."""
    entries = {}
    for ax in axes.flat:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, handle)
    drawn = list(dict.fromkeys(c for _, shown in panels for c in shown))  # the conditions of the panels
    ranked = highlight.ranked(wind, drawn)
    order = list(dict.fromkeys(conds.series(c) for c in ranked if conds.series(c) in entries))
    handles = [entries[label] for label in order]
    labels = [textwrap.fill(name(label), 56, subsequent_indent="  ") for label in order]
    left, right = axes[-1, 0].get_position(), axes[-1, -1].get_position()
    drop = 0.39 if axes.shape[0] > 1 or axes[-1, 0].get_xlabel() else 0.3
    anchor = ((left.x0 + right.x1) / 2, left.y0 - drop / fig.get_figheight())
    bottom = anchor[1] * fig.bbox.height  # of the legend, in display units (none drawn: below the axis labels)
    for ncol in range(min(len(handles), 6 if axes.shape[1] > 1 else 3), 0, -1):  # as many columns as fit
        legend = fig.legend(handles, labels, loc="upper center", bbox_to_anchor=anchor, ncol=ncol, frameon=False,
                            handlelength=2.5, columnspacing=1.0, title=title)
        box = legend.get_window_extent(fig.canvas.get_renderer())
        bottom = box.y0
        if (box.x0 >= fig.bbox.x0 and box.x1 <= fig.bbox.x1) or ncol == 1:
            break
        legend.remove()
    grey = sorted({conds.labels[conds.agent(c)] for c in drawn if not highlight.is_coloured(wind, conds.agent(c))},
                  key=str.casefold)
    if grey:
        notes = [*notes, f"Grey, without band: {', '.join(grey)} (not among the top {highlight.top} of a "
                         "panel)."]
    if any(notes):  # below the legend, left-aligned with the panels (figure coordinates: savefig's tight bbox
        top = bottom / fig.bbox.height - 0.04 / fig.get_figheight()  # moves them)
        width = 60 if axes.shape[1] == 1 else 125
        fig.text(left.x0, top, textwrap.fill(" ".join(n for n in notes if n), width), ha="left", va="top",
                 color="0.25")


def performance_profile(runs: pd.DataFrame, late: pd.DataFrame, wind: str, conds, highlight: Highlight,
                        out: Path) -> list[Path]:
    """Figure performance_profile_<wind> (rliable's performance profile): per condition, the share of its runs whose
    mean evaluation success in the second half of training (stats.late_evaluations) exceeds each level, with
    a 95% bootstrap band over runs, a panel per panel of ``conds.panels``; written when runs of the wind
    evaluated during training."""
    sub = runs[runs["wind"] == wind].merge(late, on="run_id")
    if sub.empty:
        return []
    taus = np.linspace(0.0, 1.0, 101)
    panels = conds.panels(sub["condition"])
    fig, axes = plt.subplots(1, len(panels), sharey="row", squeeze=False,
                             figsize=(style.figure_width(len(panels)), 2.3))
    n = {}
    for j, (title, shown) in enumerate(panels):
        ax = axes[0, j]
        alpha = band_alpha(shown, conds, highlight, wind, 0.15)
        for cond in _back_to_front(shown, conds, highlight, wind):
            scores = sub.loc[sub["condition"] == cond, "late_success"]
            n[cond] = len(scores)
            point, lo, hi = stats.performance_profile(scores, taus)
            _series(ax, 100 * taus, 100 * point, 100 * lo, 100 * hi, cond, conds,
                    highlight.is_coloured(wind, conds.agent(cond)), alpha, drawstyle="steps-post")
        ax.set_xlabel("Success level τ (%)")
        ax.set_xlim(0, 100)
        ax.set_ylim(-3, 103)
        _panel_title(ax, title, [])
    axes[0, 0].set_ylabel("Runs whose mean late\nsuccess exceeds τ (%)")
    runs_text = f"{max(n.values())} runs each" if len(set(n.values())) == 1 else "runs: " + ", ".join(map(str, n.values()))
    title = textwrap.fill(f"late = second half of training; {runs_text}; band: 95% bootstrap CI",
                          60 if len(panels) == 1 else 125)
    _legend(fig, axes, wind, panels, conds, highlight, title, [])
    return save(fig, out, f"performance_profile_{wind}")


SEGMENT_MEASURES = {"auc": ("Eval success AUC\nin segment (%)", "Δ AUC"),   # tables.segment_scores' column prefixes
                    "end": ("Eval success at\nsegment end (%)", "Δ end success")}


def segment_scores(numbers: pd.DataFrame, conds, shown, out: Path, reference: str = "reset_all",
                   name: str = "segment_scores", runs_shown: str = "", diff_label: str = "",
                   measure: str = "auc") -> list[Path]:
    """Figure segment_scores (tables.segment_scores' numbers), small multiples with one column per arm (training
    wind and vehicle: one change of condition each): per segment of the schedule, each agent's eval-success AUC
    (top row; ``measure="end"``: the success of the segment's last evaluation, as segment_scores_end draws it) and
    its difference to ``reference`` on that segment (bottom row, where the reference ran), agents side
    by side at each segment with 95% CIs as bars, each agent's points joined by a line across the segments, axes
    shared so the changes compare at a glance. With more than highlight.MAX_COLOURED agents in an arm only those
    ``shown`` colours there (its top by the primary measure, PPO, the reference, --highlight) are in colour and in
    the legend; the rest are thin grey, no bars. ``name``: the file stem; ``runs_shown``: which runs, in the title;
    ``diff_label``: the bottom row's label (relearning.write_learned draws the seeds that learned segment 0 and
    their gain over their own segment 0, columns auc_vs_first, as segment_scores_learned)."""
    if numbers.empty:
        return []
    winds = sorted(numbers["wind"].unique(), key=lambda w: (w != "paper", w))
    diff = f"{measure}_vs_{reference}"
    y_label, diff_name = SEGMENT_MEASURES[measure]
    has_diff = numbers[diff].notna().any()
    fig, axes = plt.subplots(2 if has_diff else 1, len(winds), sharex=True, sharey="row", squeeze=False,
                             layout="constrained",
                             figsize=(style.figure_width(len(winds)), 4.2 if has_diff else 2.6))
    handles, grey = {}, {}
    for col, wind in enumerate(winds):
        sub = numbers[numbers["wind"] == wind]
        present = shown.ranked(wind, [c for c in conds.order if c in set(sub["condition"])])
        width = 0.8 / max(len(present), 1)
        for i, cond in enumerate(present):
            rows = sub[sub["condition"] == cond].sort_values("segment")
            x = rows["segment"].to_numpy() + (i - (len(present) - 1) / 2) * width
            coloured = shown.is_coloured(wind, conds.agent(cond))
            colour = conds.color(cond) if coloured else "0.75"
            look = (dict(color=colour, ls=conds.dash(cond), marker="o", ms=3, lw=0.8, elinewidth=0.9, capsize=1.5,
                         zorder=3) if coloured else dict(color=colour, marker="o", ms=2, lw=0.5, zorder=1))
            series = [(axes[0, col], 100 * rows[f"{measure}_mean"].to_numpy(),
                       100 * rows[f"{measure}_ci95"].fillna(0).to_numpy())]
            if has_diff and rows[diff].notna().any():
                d, lo, hi = (100 * rows[c].to_numpy() for c in (diff, f"{diff}_low", f"{diff}_high"))
                series.append((axes[1, col], d, [np.nan_to_num(d - lo), np.nan_to_num(hi - d)]))
            for ax, y, err in series:
                if coloured:
                    ax.errorbar(x, y, yerr=err, label=conds.series(cond), **look)
                else:
                    ax.plot(x, y, label=conds.series(cond), **look)
            if coloured:
                handles.setdefault(cond, Line2D([], [], color=colour, ls=conds.dash(cond), marker="o", ms=3, lw=0.8,
                                                label=conds.series(cond)))
            else:
                grey.setdefault(cond, conds.series(cond))
        axes[0, col].set_title(style.arm_title(wind), fontsize="small")
        if has_diff:
            axes[1, col].axhline(0.0, color="0.4", lw=0.8, ls=":")
        axes[-1, col].set_xlabel("Segment (each wind.segment_steps)")
        axes[-1, col].xaxis.set_major_locator(MaxNLocator(integer=True))
    axes[0, 0].set_ylabel(y_label)
    axes[0, 0].set_ylim(-3, 103)
    if has_diff:   # once every column is drawn: set on the first, the shared row's limits would stop at its data
        low, high = axes[1, 0].get_ylim()   # a difference of two shares lies in [-100, 100] points
        axes[1, 0].set_ylim(max(low, -103), min(high, 103))
        axes[1, 0].set_ylabel(diff_label or f"{diff_name} vs {reference}\n(points)")
    fig.suptitle(textwrap.fill("Learning per segment: mean over " + (runs_shown or "seeds") + ", bars 95% CI",
                               70 * len(winds)), fontsize="small")
    grey = [label for cond, label in grey.items() if cond not in handles]   # grey in every arm
    note = textwrap.fill("grey, no bars: " + ", ".join(grey), 100 * len(winds)) if grey else None
    ordered = [handles[c] for c in conds.order if c in handles]
    fig.legend(handles=ordered, fontsize="x-small", ncol=2 * len(winds), frameon=False, loc="outside lower center",
               title=note, title_fontsize="xx-small")
    return save(fig, out, name)


def log_axis(axis) -> None:
    """A log scale labelled as plain numbers (0.02, 0.05, 0.1), minor ticks unlabelled. The labels sit at 1-9 of each
    decade when the drawn data span less than 0.3 decades, at 1, 2, 3, 5 below 0.6, at 1, 2, 5 below one, at 1, 3
    below two, at the decades otherwise. Call it after drawing. Matplotlib's default labels the minor ticks of an axis
    spanning less than a decade in scientific notation, and those labels overlap (the payload's probe panels,
    0.013-0.11)."""
    lo, hi = axis.get_data_interval()
    if axis.axis_name == "x":
        axis.axes.set_xscale("log")
    else:
        axis.axes.set_yscale("log")
    decades = np.log10(hi / lo) if lo > 0 and np.isfinite(hi) else np.inf
    subs = next(s for most, s in ((0.3, range(1, 10)), (0.6, (1, 2, 3, 5)), (1, (1, 2, 5)), (2, (1, 3)),
                                  (np.inf, (1,))) if decades < most)   # 2 to 6 labels, none crowded
    axis.set_major_locator(LogLocator(base=10, subs=[float(s) for s in subs]))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def readings_scatter(per_run: pd.DataFrame, readings: dict, titles: dict, conds, shown, out: Path) -> list[Path]:
    """Figure readings_<wind> (relearning.reading_correlation's data, one file per wind): one panel per reading
    (``readings``: column -> relearning.Reading, its axis label, scale and log axis), each run a point at its
    reading and its re-learning AUC; filled if it learned segment 0 (``learned_first`` 1), hollow if not. Agents
    that ``shown`` colours in this wind are in their colour, the rest grey. ``titles[(wind, column)]``: the panel's
    title (the report puts Spearman's ρ there), so the reader sees which runs make a correlation."""
    written = []
    for wind, sub in per_run.groupby("wind"):
        present = [c for c in readings if c in sub and sub[c].notna().any()]
        if not present:
            continue
        cols = min(len(present), 3)
        rows = -(-len(present) // cols)
        fig, axes = plt.subplots(rows, cols, sharey=True, squeeze=False, layout="constrained",
                                 figsize=(style.figure_width(cols), 2.1 * rows + 0.6))
        handles = {}
        order = _back_to_front([c for c in conds.order if c in set(sub["condition"])], conds, shown, wind)
        for ax, column in zip(axes.flat, present):
            axis, scale, log = readings[column].axis, readings[column].scale, readings[column].log
            for cond in order:
                runs = sub[(sub["condition"] == cond) & sub[column].notna()]
                coloured = shown.is_coloured(wind, conds.agent(cond))
                colour = conds.color(cond) if coloured else style.GREY
                for learned, face in ((True, colour), (False, "none")):
                    pick = runs[(runs["learned_first"] == 1.0) == learned]
                    ax.scatter(scale * pick[column], 100 * pick["relearning"], s=14 if coloured else 8,
                               facecolors=face, edgecolors=colour, linewidths=0.7, zorder=3 if coloured else 1,
                               label=f"{conds.series(cond)} ({'learned' if learned else 'not learned'})")
                if coloured:
                    handles.setdefault(cond, Line2D([], [], color=colour, marker="o", lw=0, ms=4,
                                                    label=conds.series(cond)))
            if log:
                log_axis(ax.xaxis)
            ax.set_xlabel(axis, fontsize="small")
            ax.set_title(titles.get((wind, column), ""), fontsize="x-small")
        for ax in axes.flat[len(present):]:
            ax.set_visible(False)
        for ax in axes[:, 0]:
            ax.set_ylabel("Re-learning AUC (%)")
        ordered = [handles[c] for c in conds.order if c in handles]
        ordered += [Line2D([], [], color="0.3", marker="o", lw=0, ms=4, label="learned segment 0"),
                    Line2D([], [], color="0.3", marker="o", mfc="none", lw=0, ms=4, label="did not learn it"),
                    Line2D([], [], color=style.GREY, marker="o", lw=0, ms=3, label="other agents")]
        fig.legend(handles=ordered, fontsize="x-small", ncol=min(len(ordered), 5), frameon=False,
                   loc="outside lower center")
        fig.suptitle(textwrap.fill(f"{style.arm_title(wind)}: each run's plasticity reading at the changes against "
                                   "its re-learning (reset_all left out); higher reading = less plastic, so a "
                                   "predictor slopes down", 110), fontsize="small")
        written += save(fig, out, f"readings_{wind}")
    return written


def transfer_gap(seeds: pd.DataFrame, numbers: pd.DataFrame, out: Path) -> list[Path]:
    """Figure transfer_gap (``sweep.report.transfer``): one panel per change, its three cells side by side (A on A,
    A on B: the same policies, joined per seed; B on B: fresh networks), each seed a dot, the mean with its 95%
    Student-t CI in black; the title gives the gap on the seeds that hover under A."""
    changes = list(numbers["change"])
    if not changes:
        return []
    cols = min(len(changes), 3)
    rows = -(-len(changes) // cols)
    fig, axes = plt.subplots(rows, cols, sharey=True, squeeze=False, layout="constrained",
                             figsize=(style.figure_width(cols), 2.0 * rows + 0.4))
    cells = ["A on A", "A on B", "B on B"]
    for ax, row in zip(axes.flat, numbers.itertuples()):
        sub = seeds[seeds["change"] == row.change]
        wide = sub.pivot_table(index="seed", columns="cell", values="success")
        hovers = wide.get("A on A", pd.Series(dtype=float)) >= stats.HOVER
        for seed, values in wide.iterrows():   # the same policy under A and under B, joined
            colour = style.PALETTE[0] if hovers.get(seed, False) else style.GREY
            ax.plot([0, 1], [100 * values.get("A on A", np.nan), 100 * values.get("A on B", np.nan)], color=colour,
                    lw=0.7, marker="o", ms=2.5, zorder=2)
        b = sub[sub["cell"] == "B on B"]
        jitter = np.linspace(-0.12, 0.12, max(len(b), 1))[: len(b)]
        ax.plot(2 + jitter, 100 * b["success"], color=style.PALETTE[1], lw=0, marker="o", ms=2.5, zorder=2)
        for x, cell in enumerate(cells):
            key = cell.replace(" ", "_")
            mean, half = getattr(row, f"{key}_success"), getattr(row, f"{key}_success_ci95")
            ax.errorbar(x + 0.25, 100 * mean, yerr=100 * (0.0 if np.isnan(half) else half), color="black",
                        marker="_", ms=8, lw=0, elinewidth=1.0, capsize=2, zorder=3)
        ax.set_xticks(range(3), cells, fontsize="x-small")
        ax.set_xlim(-0.4, 2.6)
        ax.set_ylim(-5, 105)
        gap = ("" if row.gap_hovering_n == 0 else
               f"\ngap {100 * row.gap_hovering_success:.0f} ± {100 * np.nan_to_num(row.gap_hovering_success_ci95):.0f}"
               f" pp (n={row.gap_hovering_n})")
        ax.set_title(f"{row.change}\n{row.A} → {row.B}{gap}", fontsize="small")
    for ax in axes.flat[len(changes):]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel("Success (%)")
    fig.suptitle("Transfer gap: a policy kept under A, flown under B, against a fresh network trained under B\n"
                 "lines: one seed's policy (coloured: it hovers under A); black: mean, 95% t CI", fontsize="small")
    return save(fig, out, "transfer_gap")


def band_alpha(shown: list[str], conds, highlight: Highlight, wind: str, alpha: float) -> float:
    """A band's opacity: ``alpha`` for up to 3 coloured series in a panel, half of it for more (overlapping bands
    would wash into one colour)."""
    coloured = sum(highlight.is_coloured(wind, conds.agent(c)) for c in shown)
    return alpha if coloured <= 3 else alpha / 2


def _series(ax, x, y, lo, hi, cond: str, conds, coloured: bool, alpha: float, **line) -> None:
    """One condition's line: in its colour, with its legend label and its band (where it has one), or thin and
    grey without band or label (``line``: the plot's own keywords, e.g. drawstyle, marker, linewidth)."""
    step = {"step": "post"} if line.get("drawstyle") == "steps-post" else {}
    if not coloured:
        ax.plot(x, y, color=style.GREY, **{**line, "linewidth": 0.6, "markersize": 1.5}, zorder=1)
        return
    ax.plot(x, y, color=conds.color(cond), linestyle=conds.dash(cond), markersize=3, label=conds.series(cond),
            zorder=3, **line)
    if np.isfinite(lo).any():
        ax.fill_between(x, lo, hi, color=conds.color(cond), alpha=alpha, linewidth=0, zorder=2, **step)


def _back_to_front(shown: list[str], conds, highlight: Highlight, wind: str) -> list[str]:
    """The grey conditions first (drawn below), then the coloured ones by rank, best last (drawn on top)."""
    grey = [c for c in shown if not highlight.is_coloured(wind, conds.agent(c))]
    return grey + highlight.ranked(wind, [c for c in shown if c not in grey])[::-1]


def _panel(ax, curve: Curve, hist: pd.DataFrame, sub: pd.DataFrame, conds, highlight: Highlight,
           wind: str) -> dict[str, int]:
    """Draw one Curve for each condition of ``sub`` (a coloured one with its band, a greyed one thin without);
    returns condition -> seeds drawn."""
    grid = np.unique(hist["step"].to_numpy(dtype=float)) if curve.sparse else stats.common_grid(hist)
    seeds = {}
    present = [c for c in conds.order if c in set(sub["condition"])]
    alpha = band_alpha(present, conds, highlight, wind, 0.2)
    for cond in _back_to_front(present, conds, highlight, wind):
        matrix = stats.aligned(hist, curve.key, sub.loc[sub["condition"] == cond, "run_id"], grid) * curve.scale
        if not len(matrix):
            continue
        mean, lo, hi, _ = stats.mean_band(matrix)
        _series(ax, grid, mean, lo, hi, cond, conds, highlight.is_coloured(wind, conds.agent(cond)), alpha,
                linewidth=1.2, marker="o" if len(grid) == 1 or curve.sparse else None)
        seeds[cond] = len(matrix)
    if curve.logy:
        log_axis(ax.yaxis)
    if curve.percent:  # from just below 0: a curve at 0 shows above the axis line
        top = max(1.0, ax.get_ylim()[1])
        ax.set_ylim(-0.03 * top, top)
        if seeds and (hist["value"] == 0).all():  # coinciding curves: say that every one of them is at 0
            ax.text(0.5, 0.5, f"0 throughout for every {'condition' if conds.by and not conds.split else 'agent'}",
                    ha="center", va="center", transform=ax.transAxes, color="0.3",
                    bbox={"facecolor": "white", "edgecolor": "none"})
    if curve.ylim:
        ax.set_ylim(*curve.ylim)
    ax.grid(True)
    return seeds


# How the flight figures name the policy they show (metrics.POLICIES keys).
POLICY_NAMES = {"final": "final policy", "best": "best policy (by training reward)"}


def eval_runs(runs: pd.DataFrame) -> tuple[str, pd.DataFrame, str]:
    """(wind, per condition the best-return seed among runs trained with wind 'paper' (else the first wind
    present), the policy whose flights to draw): the final policy's (eval/return); the best policy's
    (eval_best/return) only where no run of that wind evaluated its final policy (every run eval.policy=best)."""
    wind = "paper" if "paper" in set(runs["wind"]) else sorted(runs["wind"].unique())[0]
    sub = runs[runs["wind"] == wind]
    final, best = metrics.eval_key("final", "return"), metrics.eval_key("best", "return")
    policy = "final" if sub[final].notna().any() or not sub[best].notna().any() else "best"
    sub = sub.sort_values(metrics.eval_key(policy, "return"), ascending=False, na_position="last")
    return wind, sub.drop_duplicates("condition").set_index("condition"), policy


def _title(cond: str, conds, width: int) -> str:
    """A condition's label for a narrow panel: its agent's label wrapped to ``width`` characters, then each --by
    value on a line of its own."""
    agent = conds.labels[conds.table.loc[cond, "agent"]]
    values = cond[len(agent) + 2:-1].split(", ") if cond != agent else []  # cond = "agent (k=v, k=v)"
    return "\n".join([textwrap.fill(agent, width), *values])


def flights_3d(trajs: dict, picked: pd.DataFrame, wind: str, conds, out: Path, policy: str = "final") -> list[Path]:
    shown = [c for c in conds.order if c in trajs]
    cols = min(len(shown), 2)
    rows = int(np.ceil(len(shown) / cols))
    spare = rows * cols > len(shown)  # the legend goes into the empty panel, else below the panels
    legend_h = 0.05 if spare else 0.6  # inches below the panels for the legend
    titles = {c: textwrap.fill(f"{c}, seed {picked.loc[c, 'seed']}", 28)
              + f"\nsuccess {100 * np.mean(trajs[c]['success']):.0f}%" for c in shown}
    extra = max(t.count("\n") for t in titles.values()) - 1  # title lines beyond two (long --by labels)
    fig = plt.figure(figsize=(style.COLUMN_WIDTH, (1.75 + 0.12 * extra) * rows + 0.1 + legend_h))
    bound = max(float(np.nanmax(np.abs(t["positions"]))) for t in trajs.values())
    bound = min(np.ceil(bound), 4.0)
    for i, cond in enumerate(shown):
        t = trajs[cond]
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        for pos, crashed in zip(t["positions"], t["crashed"]):
            ax.plot(pos[:, 0], pos[:, 1], pos[:, 2], color=conds.color(cond), linewidth=0.7, alpha=0.8)
            ax.scatter(*pos[0], color=conds.color(cond), s=6, marker="o", depthshade=False)
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
        ax.set_title(titles[cond], fontsize=7, pad=-2)
        ax.view_init(elev=22, azim=-60)
    wind_vec = next(iter(trajs.values()))["wind"]
    handles = [Line2D([], [], color="0.3", marker="o", linestyle="-", markersize=3, label="start"),
               Line2D([], [], color="k", marker="*", linestyle="", markersize=6, label="target"),
               Line2D([], [], color="k", marker="x", linestyle="", markersize=4, label="crash")]
    air = f"Evaluation wind {np.linalg.norm(wind_vec):g} m/s along {_direction(wind_vec)}"
    trained = f"agents trained with wind '{wind}'"
    seed = f"best-return seed per {'condition' if conds.by else 'agent'}"
    if spare:  # in the empty panel, half the width: a line each
        fig.legend(handles=handles, loc="center", ncol=1, frameon=False, bbox_to_anchor=(0.75, 0.5 / rows),
                   title="\n".join([air, trained, seed, POLICY_NAMES[policy]]))
    else:
        fig.legend(handles=handles, loc="lower center", ncol=3, frameon=False, bbox_to_anchor=(0.5, 0.0),
                   title=f"{air}, {POLICY_NAMES[policy]}\n{trained}, {seed}")
    fig.subplots_adjust(left=0.02, right=0.95, top=0.93, bottom=legend_h / fig.get_figheight(), wspace=0.15,
                        hspace=0.25 + 0.1 * extra)
    return save(fig, out, "eval_flights_3d")


def _direction(v: np.ndarray) -> str:
    v = np.asarray(v, dtype=float)
    if not np.any(v):
        return "-"
    axis = int(np.argmax(np.abs(v)))
    return ("+" if v[axis] > 0 else "-") + "xyz"[axis] if np.count_nonzero(v) == 1 else str(np.round(v, 2))


def position_axes(trajs: dict, picked: pd.DataFrame, wind: str, conds, radius: float, out: Path,
                  policy: str = "final") -> list[Path]:
    """x, y, z against time, a column per condition; at most POSITION_COLUMNS columns side by side, further
    conditions in blocks below (the same y scales throughout)."""
    shown = [c for c in conds.order if c in trajs]
    cols = min(len(shown), POSITION_COLUMNS)
    blocks = [shown[i:i + cols] for i in range(0, len(shown), cols)]
    fig = plt.figure(figsize=(style.COLUMN_WIDTH, 0.3 + 3.1 * len(blocks)), layout="constrained")
    fig.get_layout_engine().set(w_pad=0.02, h_pad=0.02, hspace=0.02, wspace=0.02)
    title_size = 7 if cols <= 3 else 6  # narrow columns
    grids = []
    for sub, block in zip(fig.subfigures(len(blocks), 1, squeeze=False)[:, 0], blocks):
        axes = sub.subplots(3, cols, sharex=True, sharey="row", squeeze=False)
        grids.append(axes)
        for ax in axes[:, len(block):].flat:  # the last block's empty columns
            ax.set_visible(False)
        for j, cond in enumerate(block):
            t = trajs[cond]
            time = np.arange(t["positions"].shape[1]) * float(t["dt"])
            axes[0, j].set_xlim(0, time[-1])
            for i in range(3):
                ax = axes[i, j]
                if np.isfinite(radius):
                    ax.axhspan(-radius, radius, color="0.85", linewidth=0, zorder=0)
                ax.axhline(0, color="0.5", linewidth=0.5, zorder=0)
                for pos in t["positions"]:
                    ax.plot(time, pos[:, i], color=conds.color(cond), linewidth=0.6, alpha=0.8)
                if j == 0:
                    ax.set_ylabel(f"{'xyz'[i]} (m)")
                ax.yaxis.set_major_locator(MaxNLocator(4))
            title = _title(cond, conds, 24 if cols <= 2 else 16 if cols == 3 else 13)
            axes[0, j].set_title(f"{title}\nseed {picked.loc[cond, 'seed']}", fontsize=title_size)
            axes[-1, j].set_xlabel("Time (s)")
            axes[-1, j].xaxis.set_major_locator(MaxNLocator(3, steps=[1, 2, 5]))  # no label on the right edge
    for i in range(3):  # one y scale per axis across the blocks
        lows, highs = zip(*(axes[i, 0].get_ylim() for axes in grids))
        for axes in grids:
            axes[i, 0].set_ylim(min(lows), max(highs))
    note = f"\ngrey band: success radius ±{radius:g} m" if np.isfinite(radius) else ""
    fig.suptitle(f"Evaluation flights, agents trained with wind '{wind}',\nbest-return seed, {POLICY_NAMES[policy]}"
                 f"{note}", fontsize=7)
    return save(fig, out, "eval_position_axes")
