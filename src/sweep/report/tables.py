"""Table III (evaluation under wind), the per-condition summary and the reward per wind segment, as Markdown /
LaTeX / CSV."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from sweep import metrics
from sweep.metrics import CURVES, FINALS, PROBE, PROBE_FRESH, REWARD, TABLE3
from sweep.report import stats
from sweep.report.conditions import Conditions, baseline_of

# The policies scored at the end of a run (metrics.POLICIES) -> the suffix of their CSV columns. The tables show
# "final" and "best" side by side; "best_eval" (kept at the highest in-training eval return) is in the CSVs only.
SUFFIX = {"final": "", "best": "_best", "best_eval": "_best_eval"}
SHOWN = ("final", "best")

# the columns that name a run in the report's per-run files (segment_runs.csv, relearning_runs.csv)
IDENTITY = ["run_id", "run_name", "agent", "condition", "wind", "seed", "eval_condition"]


def plus_minus(mean: float, half: float, digits: int) -> str:
    if not np.isfinite(mean):
        return "–"
    return f"{mean:.{digits}f}" + (f" ± {half:.{digits}f}" if np.isfinite(half) else "")


def interval(point: float, lo: float, hi: float, digits: int) -> str:
    if not np.isfinite(point):
        return "–"
    return f"{point:.{digits}f}" + (f" [{lo:.{digits}f}, {hi:.{digits}f}]" if np.isfinite(lo) else "")


def markdown(df: pd.DataFrame) -> str:
    cells = [[str(c) for c in df.columns]] + [[str(v) for v in row] for row in df.itertuples(index=False)]
    lines = ["| " + " | ".join(c.replace("|", r"\|") for c in r) + " |" for r in cells]
    lines.insert(1, "|" + "|".join("---" for _ in df.columns) + "|")
    return "\n".join(lines) + "\n"


# LaTeX's special characters (an agent's label may have any, e.g. "Shrink & Perturb"), then the units.
TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{",
       "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def _tex(value) -> str:
    return "".join(TEX.get(ch, ch) for ch in str(value)).replace("±", r"$\pm$").replace("m²", r"m$^2$")


def latex(df: pd.DataFrame, caption: str, label_: str) -> str:
    body = df.map(_tex)
    body.columns = [_tex(c) for c in df.columns]
    return body.to_latex(index=False, column_format="l" * 2 + "c" * (len(df.columns) - 2),
                         caption=caption, label=label_, position="htbp")


def _ordered_groups(runs: pd.DataFrame, conds: Conditions):
    """(wind, condition, its runs) with wind 'paper' first, then the other winds, conditions in display order."""
    rank = {c: i for i, c in enumerate(conds.order)}
    groups = runs.groupby(["wind", "condition"], sort=False)
    for wind, cond in sorted(groups.groups, key=lambda k: (k[0] != "paper", k[0], rank[k[1]])):
        yield wind, cond, groups.get_group((wind, cond))


def _identity(conds: Conditions, cond: str, wind: str) -> dict:
    """The CSV columns that name a condition: agent, the --by values and the label (with --by), wind."""
    row = conds.table.loc[cond]
    return {"agent": row["agent"], **{k: row[k] for k in conds.by}, **({"condition": cond} if conds.by else {}),
            "wind": wind}


def top_seed(g: pd.DataFrame) -> pd.Series | None:
    """The run with the highest final training reward (lowest seed on a tie); None if no run has one."""
    ranked = g[np.isfinite(g["final_reward"])].sort_values(["final_reward", "seed"], ascending=[False, True])
    return ranked.iloc[0] if len(ranked) else None


def _key(policy: str, field: str) -> str:
    """The runs' column of ``field`` (e.g. success_rate) as ``policy`` was scored: eval/…, eval_best/…"""
    return metrics.eval_key(policy, field)


def _cell(mean: float, half: float, n: int, seeds: int, digits: int) -> str:
    """mean ± half, '(n=k)' appended where only k of the condition's seeds evaluated that policy; '–' for none."""
    text = plus_minus(mean, half, digits)
    return text + (f" (n={n})" if 0 < n < seeds else "")


def _round_steps(n: float) -> str:
    """Timesteps to three significant digits: 598k, 2.05k, 1.5M; '–' for NaN."""
    if not np.isfinite(n):
        return "–"
    return f"{n / 1e6:.3g}M" if n >= 999_500 else f"{n / 1e3:.3g}k" if n >= 1000 else f"{n:.0f}"


def source_step(g: pd.DataFrame, policy: str = "best") -> tuple[float, str]:
    """(mean over seeds of the timestep the kept ``policy`` came from, that mean as text, '(n=k)' as in _cell)."""
    steps = g[_key(policy, "source_step")].to_numpy(dtype=float)
    steps = steps[np.isfinite(steps)]
    mean = float(steps.mean()) if len(steps) else np.nan
    return mean, _round_steps(mean) + (f" (n={len(steps)})" if 0 < len(steps) < len(g) else "")


def table3(runs: pd.DataFrame, per_run: pd.DataFrame, conds: Conditions) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(numbers: one row per condition x wind with, per policy scored at the end (final, best, best_eval: SUFFIX),
    mean / ci95 / number of seeds per metric, the mean source step and score of the kept ones, and the top seed's
    final-policy values; display table: final and best side by side)."""
    df = runs.merge(per_run[["run_id", "final_reward"]], on="run_id", how="left")
    numbers, display = [], []
    for wind, cond, g in _ordered_groups(df, conds):
        num = {**_identity(conds, cond, wind), "n_seeds": len(g)}
        shown = {"Control policy": cond, "Training wind": wind, "Seeds": len(g)}
        for policy, suffix in SUFFIX.items():
            for f in TABLE3:
                mean, half, n = stats.mean_t_ci(g[_key(policy, f.name)] * f.scale)
                num[f"{f.name}{suffix}_mean"], num[f"{f.name}{suffix}_ci95"] = mean, half
            num[f"n_seeds{suffix or '_final'}"] = int(g[_key(policy, "success_rate")].notna().sum())
        for policy in ("best", "best_eval"):
            for field in metrics.SOURCE_FIELDS:
                num[f"{field}{SUFFIX[policy]}_mean"] = float(g[_key(policy, field)].mean())
        for f in TABLE3:
            for policy in SHOWN:
                suffix = SUFFIX[policy]
                shown[f"{f.title} {policy} {f.unit}"] = _cell(num[f"{f.name}{suffix}_mean"], num[f"{f.name}{suffix}_ci95"],
                                                              num[f"n_seeds{suffix or '_final'}"], len(g), f.digits)
        shown["Best taken at (step)"] = source_step(g)[1]
        top = top_seed(g)
        num["top_seed"] = int(top["seed"]) if top is not None else np.nan
        num["top_seed_final_reward"] = top["final_reward"] if top is not None else np.nan
        for f in TABLE3:
            num[f"top_seed_{f.name}"] = top[_key("final", f.name)] * f.scale if top is not None else np.nan
        shown["Top seed"] = num["top_seed"] if top is not None else "–"
        shown["Top seed: success final (%)"] = plus_minus(num["top_seed_success_rate"], np.nan, 0)
        shown["Top seed: MSE x/y/z final (m²)"] = (
            "–" if top is None or not np.isfinite(num["top_seed_mse_x"])
            else " / ".join(f"{num[f'top_seed_mse_{a}']:.2f}" for a in "xyz"))
        numbers.append(num)
        display.append(shown)
    return pd.DataFrame(numbers), pd.DataFrame(display)


def summary(runs: pd.DataFrame, per_run: pd.DataFrame, conds: Conditions,
            baseline: tuple[str, str] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per condition x wind: seeds, final reward / dormant / saturated / dead tanh / signed-mean≈0 share / weight
    norm (the mean over the seeds that logged it; NaN, shown '–', where none did), collapse, share of
    RECOM's LR updates at a bound, the end-of-run evaluations' success and crash rates of the final policy and of
    the best ones (the CSV: eval[_best|_best_eval]_{success,crash}_pct, with the mean step each best came from;
    shown: final and best), IQM [CI], P(improve over PPO) [CI], the mean wall time of a run, and with ``baseline`` = (KEY, VALUE) the IQM
    difference to the baseline condition [CI]."""
    df = runs.merge(per_run, on="run_id", how="left")
    numbers, display = [], []
    for wind, cond, g in _ordered_groups(df, conds):
        dw = df[df["wind"] == wind]
        present = conds.table.loc[[c for c in conds.order if c in set(dw["condition"])]]
        scores = lambda c: dw.loc[dw["condition"] == c, "final_reward"]  # noqa: E731
        ppo = baseline_of(present, cond, "agent", "ppo") if "ppo" in set(present["agent"]) else None
        iqm, iqm_lo, iqm_hi = stats.iqm_ci(g["final_reward"])
        poi = stats.poi_ci(g["final_reward"], scores(ppo)) if ppo is not None else (np.nan,) * 3
        num = {**_identity(conds, cond, wind), "n_seeds": len(g),
               **{column: g[column].mean() for column in FINALS},
               "collapse": g["collapse"].mean(), "lr_at_bound_pct": 100 * g["at_bound"].mean(),
               **{f"eval{SUFFIX[p]}_{what}_pct": 100 * g[_key(p, f"{what}_rate")].mean()
                  for p in SUFFIX for what in ("success", "crash")},
               "eval_best_source_step": source_step(g, "best")[0],
               "eval_best_eval_source_step": source_step(g, "best_eval")[0],
               "iqm_final_reward": iqm, "iqm_ci_low": iqm_lo, "iqm_ci_high": iqm_hi,
               "p_improve_over_ppo": poi[0], "p_improve_ci_low": poi[1], "p_improve_ci_high": poi[2],
               "wall_minutes": g["wall_minutes"].mean()}
        shown = {"Agent": cond, "Wind": wind, "Seeds": len(g),
                 **{c.title: _fixed(c.scale * num[c.final], c.digits) for c in CURVES if c.final},
                 "Collapse": f"{num['collapse']:.1f}",
                 "LR at bound (%)": _fixed(num["lr_at_bound_pct"], 0),
                 **{f"Eval {what} {p} (%)": _cell(num[f"eval{SUFFIX[p]}_{what}_pct"], np.nan,
                                                   int(g[_key(p, f"{what}_rate")].notna().sum()), len(g), 0)
                    for what in ("success", "crash") for p in SHOWN},
                 "Best taken at (step)": source_step(g, "best")[1],
                 "IQM final reward [95% CI]": interval(iqm, iqm_lo, iqm_hi, 1),
                 "P(> PPO) [95% CI]": interval(*poi, 2),
                 "Wall time per run (min)": _fixed(num["wall_minutes"], 1)}
        if baseline is not None:
            key, value = baseline
            base = baseline_of(present, cond, key, value)
            delta = stats.iqm_diff_ci(g["final_reward"], scores(base)) if base is not None else (np.nan,) * 3
            num.update({"baseline": base if base is not None else "", "delta_iqm": delta[0],
                        "delta_iqm_ci_low": delta[1], "delta_iqm_ci_high": delta[2]})
            shown[f"Δ IQM vs {key}={value} [95% CI]"] = interval(*delta, 1) if base is not None else ""
        numbers.append(num)
        display.append(shown)
    return pd.DataFrame(numbers), pd.DataFrame(display)


def _steps(n: int) -> str:
    return f"{n / 1e6:g}M" if n >= 1_000_000 else f"{n / 1e3:g}k" if n >= 1000 else str(n)


def segments(runs: pd.DataFrame, seg: pd.DataFrame, conds: Conditions) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(numbers: one row per condition x wind x wind segment with the seed mean / ci95 / n of the segment's mean
    training reward, display table: one row per condition x wind, one column per segment)."""
    df = runs[["run_id", "wind", "condition"]].merge(seg, on="run_id")
    numbers, display = [], []
    for wind, cond, g in _ordered_groups(df, conds):
        shown = {"Agent": cond, "Wind": wind, "Seeds": g["run_id"].nunique()}
        for (k, start, end, speed), s in g.groupby(["segment", "start", "end", "speed"]):
            mean, half, n = stats.mean_t_ci(s["reward"])
            numbers.append({**_identity(conds, cond, wind), "segment": k, "start": start, "end": end,
                            "speed": speed, "reward_mean": mean, "reward_ci95": half, "n_seeds": n})
            shown[f"{_steps(start)}–{_steps(end)} ({speed:g} m/s)"] = plus_minus(mean, half, 0)
        display.append(shown)
    return pd.DataFrame(numbers), pd.DataFrame(display)


def segment_scores(runs: pd.DataFrame, seg: pd.DataFrame, conds: Conditions, reference: str | None = "reset_all"
                   ) -> tuple[pd.DataFrame, dict[str, pd.DataFrame]]:
    """Per condition x wind x segment: the eval-success AUC and end-of-segment success (seed mean, 95% Student-t
    half-width, n; stats.segment_evaluations) and each one's difference to the ``reference`` agent's on the same
    segment, wind and --by values (95% percentile bootstrap resampling both agents' seeds; none with ``reference``
    None). Returns (numbers, displays: per measure "auc" and "end", one row per condition x wind, per segment
    'mean ± ci (Δ [lo, hi])' in %)."""
    df = runs[["run_id", "wind", "condition"]].merge(seg, on="run_id")
    refs = {c: baseline_of(conds.table, c, "agent", reference) for c in conds.order} if reference else {}
    numbers, display = [], {"auc": [], "end": []}
    for wind, cond, g in _ordered_groups(df, conds):
        shown = {m: {"Agent": cond, "Wind": wind, "Seeds": g["run_id"].nunique()} for m in display}
        ref = refs.get(cond)
        theirs = df[(df["wind"] == wind) & (df["condition"] == ref)] if ref is not None else df.iloc[0:0]
        for k, s in g.groupby("segment"):
            row = {**_identity(conds, cond, wind), "condition": cond, "segment": int(k), "start": int(s["start"].iloc[0]),
                   "end_step": int(s["end_step"].iloc[0]), "evals_per_run": float(s["n_evals"].mean())}
            other = theirs[theirs["segment"] == k]
            for m in ("auc", "end"):
                mean, half, n = stats.mean_t_ci(s[m])
                row.update({f"{m}_mean": mean, f"{m}_ci95": half, "n_seeds": n})
                if reference:
                    d, lo, hi = stats.mean_diff_ci(s[m], other[m]) if len(other) else (np.nan,) * 3
                    row.update({f"{m}_vs_{reference}": d, f"{m}_vs_{reference}_low": lo,
                                f"{m}_vs_{reference}_high": hi})
            numbers.append(row)
            for m in display:
                cell = plus_minus(100 * row[f"{m}_mean"], 100 * row[f"{m}_ci95"], 0)
                if reference and np.isfinite(row[f"{m}_vs_{reference}"]):
                    cell += " (Δ " + interval(100 * row[f"{m}_vs_{reference}"], 100 * row[f"{m}_vs_{reference}_low"],
                                              100 * row[f"{m}_vs_{reference}_high"], 0) + ")"
                shown[m][f"{k} ({_steps(row['start'])}–{_steps(row['end_step'])})"] = cell
        for m in display:
            display[m].append(shown[m])
    return pd.DataFrame(numbers), {m: pd.DataFrame(rows) for m, rows in display.items()}


def at_steps(runs: pd.DataFrame, histories: pd.DataFrame, conds: Conditions, key: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A metric logged at a few steps (e.g. the probe at every wind change): (numbers: one row per condition x wind
    x step with the seed mean / ci95 / n, display table: one row per condition x wind, one column per step)."""
    df = runs[["run_id", "wind", "condition"]].merge(histories[histories["key"] == key], on="run_id")
    numbers, display = [], []
    for wind, cond, g in _ordered_groups(df, conds):
        shown = {"Agent": cond, "Wind": wind, "Seeds": g["run_id"].nunique()}
        for step, s in g.groupby("step"):
            mean, half, n = stats.mean_t_ci(s["value"])
            numbers.append({**_identity(conds, cond, wind), "step": int(step), "mean": mean, "ci95": half, "n_seeds": n})
            shown[_round_steps(step)] = f"{mean:.3g}" + (f" ± {half:.2g}" if np.isfinite(half) else "")
        display.append(shown)
    return pd.DataFrame(numbers), pd.DataFrame(display)


def _per_seed(g: pd.DataFrame, column: str, scale: float = 100.0) -> str:
    return ", ".join("–" if not np.isfinite(v) else f"{scale * v:.0f}" for v in g.sort_values("seed")[column])


def leaderboard(runs: pd.DataFrame, per_run: pd.DataFrame, late: pd.DataFrame,
                conds: Conditions) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per condition x wind, sorted by the primary measure ``keeps_hovering`` (the share of evaluations in the
    second half of training at >= 50% success, stats.late_evaluations; ties by IQM final reward): that share
    (mean ± t CI over seeds, and per seed), P(> PPO) on it [95% CI], the IQM final reward [95% CI], the final
    and the best policy's end-of-run success (mean, per seed), the final readings of the summary and the mean wall
    time of a run (MLflow start to end: training, diagnostics and evaluation)."""
    df = runs.merge(per_run, on="run_id", how="left").merge(late, on="run_id", how="left")
    numbers, display = [], []
    for wind, cond, g in _ordered_groups(df, conds):
        dw = df[df["wind"] == wind]
        present = conds.table.loc[[c for c in conds.order if c in set(dw["condition"])]]
        ppo = baseline_of(present, cond, "agent", "ppo") if "ppo" in set(present["agent"]) else None
        keep, half, n = stats.mean_t_ci(g["keeps_hovering"])
        poi = (stats.poi_ci(g["keeps_hovering"], dw.loc[dw["condition"] == ppo, "keeps_hovering"])
               if ppo is not None else (np.nan,) * 3)
        iqm = stats.iqm_ci(g["final_reward"])
        learned = g["learned"] == 1.0
        kept, kept_half, _ = stats.mean_t_ci(g.loc[learned, "keeps_hovering"])
        num = {**_identity(conds, cond, wind), "n_seeds": len(g), "keeps_hovering": keep, "keeps_hovering_ci95": half,
               "learned_seeds": int(learned.sum()), "kept_if_learned": kept, "kept_if_learned_ci95": kept_half,
               "late_success": g["late_success"].mean(), "p_improve_over_ppo": poi[0], "p_improve_ci_low": poi[1],
               "p_improve_ci_high": poi[2], "iqm_final_reward": iqm[0], "iqm_ci_low": iqm[1], "iqm_ci_high": iqm[2],
               **{f"success_{p}": g[_key(p, "success_rate")].mean() for p in SHOWN},
               **{column: g[column].mean() for column in FINALS if column != "final_reward"},
               "wall_minutes": g["wall_minutes"].mean()}
        shown = {"Agent": cond, "Wind": wind, "Seeds": len(g),
                 "Keeps hovering (%)": plus_minus(100 * keep, 100 * half, 0), "per seed": _per_seed(g, "keeps_hovering"),
                 "Learned the hover (seeds)": f"{int(learned.sum())}/{g['learned'].notna().sum()}",
                 "Keeps hovering, seeds that learned (%)": plus_minus(100 * kept, 100 * kept_half, 0),
                 "P(> PPO) [95% CI]": interval(*poi, 2),
                 "IQM final reward [95% CI]": interval(*iqm, 0),
                 **{f"Success {p} (%)": f"{_fixed(100 * num[f'success_{p}'], 0)} ({_per_seed(g, _key(p, 'success_rate'))})"
                    for p in SHOWN},
                 **{c.title: _fixed(c.scale * num[c.final], c.digits) for c in CURVES
                    if c.final and c.final != "final_reward"},
                 "Wall time per run (min)": _fixed(num["wall_minutes"], 1)}
        numbers.append(num)
        display.append(shown)
    numbers, display = pd.DataFrame(numbers), pd.DataFrame(display)
    if len(numbers):
        order = numbers.sort_values(["wind", "keeps_hovering", "iqm_final_reward"], ascending=[True, False, False],
                                    na_position="last", kind="stable").index
        numbers, display = numbers.loc[order], display.loc[order]
    return numbers.reset_index(drop=True), display.reset_index(drop=True)


def versus(runs: pd.DataFrame, late: pd.DataFrame, conds: Conditions,
           references: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Every condition against each reference agent (``--vs``) on the primary measure ``keeps_hovering``, in the
    same wind and with the same --by values (conditions.baseline_of): rliable's P(condition > reference) [95%
    bootstrap CI] and the difference of the seed means in percentage points [95% bootstrap CI]. Rows in the
    leaderboard's order (keeps hovering, highest first, per wind); a reference against itself is left empty."""
    df = runs.merge(late, on="run_id", how="left")
    numbers, display = [], []
    for wind, cond, g in _ordered_groups(df, conds):
        dw = df[df["wind"] == wind]
        present = conds.table.loc[[c for c in conds.order if c in set(dw["condition"])]]
        keep, half, _ = stats.mean_t_ci(g["keeps_hovering"])
        num = {**_identity(conds, cond, wind), "n_seeds": len(g), "keeps_hovering": keep}
        shown = {"Agent": cond, "Wind": wind, "Seeds": len(g), "Keeps hovering (%)": plus_minus(100 * keep, 100 * half, 0)}
        for ref in references:
            other = baseline_of(present, cond, "agent", ref) if ref in set(present["agent"]) else None
            theirs = dw.loc[dw["condition"] == other, "keeps_hovering"] if other is not None else []
            poi = stats.poi_ci(g["keeps_hovering"], theirs) if other is not None else (np.nan,) * 3
            delta = stats.mean_diff_ci(g["keeps_hovering"], theirs) if other is not None else (np.nan,) * 3
            num.update({f"p_improve_over_{ref}": poi[0], f"p_improve_over_{ref}_ci_low": poi[1],
                        f"p_improve_over_{ref}_ci_high": poi[2], f"delta_keeps_vs_{ref}": delta[0],
                        f"delta_keeps_vs_{ref}_ci_low": delta[1], f"delta_keeps_vs_{ref}_ci_high": delta[2]})
            name = conds.labels.get(ref, ref)
            shown[f"P(> {name}) [95% CI]"] = interval(*poi, 2)
            shown[f"Δ vs {name} (pp) [95% CI]"] = interval(*(100 * v for v in delta), 0)
        numbers.append(num)
        display.append(shown)
    numbers, display = pd.DataFrame(numbers), pd.DataFrame(display)
    if len(numbers):
        order = numbers.sort_values(["wind", "keeps_hovering"], ascending=[True, False], na_position="last",
                                    kind="stable").index
        numbers, display = numbers.loc[order], display.loc[order]
    return numbers.reset_index(drop=True), display.reset_index(drop=True)


def reward_at(runs: pd.DataFrame, histories: pd.DataFrame, conds: Conditions, steps: list[int],
              baseline: tuple[str, str] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The training reward at given timesteps: per run the last ``rollout/ep_rew_mean`` logged at or before each
    step (itself a mean over the last 100 episodes); per condition x wind x step the rliable IQM over seeds with
    its 95% CI and, with ``baseline`` = (KEY, VALUE), the IQM difference to the baseline condition with its 95%
    CI. Returns (numbers, display: one row per condition x wind)."""
    rewards = histories[histories["key"] == REWARD].sort_values("step")
    at = {s: rewards[rewards["step"] <= s].groupby("run_id")["value"].last() for s in steps}
    df = runs[["run_id", "wind", "condition"]].copy()
    for s in steps:
        df[s] = df["run_id"].map(at[s])
    numbers, display = [], []
    for wind, cond, g in _ordered_groups(df, conds):
        dw = df[df["wind"] == wind]
        present = conds.table.loc[[c for c in conds.order if c in set(dw["condition"])]]
        base = baseline_of(present, cond, *baseline) if baseline is not None else None
        shown = {"Agent": cond, "Wind": wind, "Seeds": len(g)}
        for s in steps:
            iqm = stats.iqm_ci(g[s])
            delta = stats.iqm_diff_ci(g[s], dw.loc[dw["condition"] == base, s]) if base is not None else (np.nan,) * 3
            numbers.append({**_identity(conds, cond, wind), "step": s, "n_seeds": int(g[s].notna().sum()),
                            "iqm": iqm[0], "iqm_ci_low": iqm[1], "iqm_ci_high": iqm[2], "baseline": base or "",
                            "delta_iqm": delta[0], "delta_ci_low": delta[1], "delta_ci_high": delta[2]})
            shown[f"IQM at {_steps(s)}"] = interval(*iqm, 1)
            if baseline is not None:
                shown[f"Δ at {_steps(s)}"] = interval(*delta, 1) if base is not None else ""
        display.append(shown)
    return pd.DataFrame(numbers), pd.DataFrame(display)


def _fixed(value: float, digits: int) -> str:
    return f"{value:.{digits}f}" if np.isfinite(value) else "–"


def eval_wind(runs: pd.DataFrame) -> str:
    """The evaluation wind the runs logged, as text: 'a constant 3 m/s wind' (several speeds joined by ' / ')."""
    speeds = sorted(set(pd.to_numeric(runs["eval_wind_speed"], errors="coerce").dropna()))
    return f"a constant {' / '.join(f'{v:g}' for v in speeds)} m/s wind" if speeds else "constant wind"


def provenance(runs: pd.DataFrame) -> str:
    """A sentence naming the CPU models and float modes (train.portable) the runs were made on when they differ
    (in native mode a seed run on another CPU model can be another sample); '' when all runs share one."""
    made = runs.groupby(["cpu_model", "float_mode"]).size()
    if len(made) < 2:
        return ""
    parts = "; ".join(f"{n} on {cpu} ({mode})" for (cpu, mode), n in made.items())
    return (f"Note: these runs were made on {len(made)} CPU model / float mode combinations ({parts}). In native "
            "mode a seed run on another CPU model can be another sample; in portable mode the JAX learner's "
            "reference runs were bitwise equal on an AMD EPYC and an Intel Xeon (README, Determinism)."
            "\n\n")


def write_tables(runs: pd.DataFrame, histories: pd.DataFrame, conds: Conditions, out: Path,
                 baseline: tuple[str, str] | None = None, at: list[int] = (),
                 late: pd.DataFrame | None = None, vs: list[str] = (),
                 per_run: pd.DataFrame | None = None, evals: pd.DataFrame | None = None,
                 scores: tuple | None = None) -> list[Path]:
    """Every table of the report; ``late`` is stats.late_evaluations(histories), computed by the caller once for
    the leaderboard and the performance profile (computed here when not given); ``vs``: reference agents of
    versus.md (none: no such table); ``per_run`` is stats.per_run_curve_stats(histories), likewise; ``evals`` is
    stats.segment_evaluations(histories, runs), likewise, and ``scores`` segment_scores(runs, evals, conds)."""
    per_run = stats.per_run_curve_stats(histories) if per_run is None else per_run
    t3_numbers, t3_display = table3(runs, per_run, conds)
    t3_numbers.to_csv(out / "table3.csv", index=False)
    policies = ("final = the policy at the end of training (eval/*); best = the policy kept during training at its "
                "highest mean training episode reward (rollout/ep_rew_mean at a rollout end, eval_best/*), the "
                "paper's \"policy that produced the highest reward\"; both evaluated at the end of the run")
    missing = ("– = not evaluated: runs logged before eval.policy existed or with eval.policy=final have no best "
               "policy's evaluation, runs with eval.policy=best no final policy's; (n=k) = only k of the seeds "
               "evaluated that policy")
    made = provenance(runs)
    (out / "table3.md").write_text(
        made + f"Evaluation under {eval_wind(runs)} (eval.wind_speed; Table III): success rate and per-axis position MSE, "
        f"mean ± 95% Student-t CI over seeds, of two policies of each run: {policies}. Best taken at = the "
        f"timestep the best policy was kept at (mean over seeds). {missing}. Top seed = the seed whose final "
        f"training reward (mean episode reward over the last {stats.FINAL_FRACTION:.0%} of timesteps) is highest "
        "in its condition; its final policy's success rate and per-axis MSE. table3.csv also has the policy kept "
        "at the highest in-training evaluation return (*_best_eval_*, eval_best_eval/*).\n\n"
        + markdown(t3_display))
    (out / "table3.tex").write_text(latex(
        t3_display, "Evaluation under wind: success rate and per-axis position MSE, mean $\\pm$ 95\\% CI over seeds, "
        "of the final policy (final) and of the policy kept at the highest training reward (best), the timestep "
        "the best was kept at (mean over seeds), and the final policy's values of the seed with the highest final "
        "training reward (top seed). -- = not evaluated.", "tab:eval"))
    s_numbers, s_display = summary(runs, per_run, conds, baseline)
    s_numbers.to_csv(out / "summary.csv", index=False)
    note = (f"Final = mean over the last {stats.FINAL_FRACTION:.0%} of training timesteps (mean over seeds); "
            "collapse = largest drop of the reward curve below its running peak; dormant = share of the policy's "
            "hidden units that are τ-dormant (Sokar et al., τ = plasticity.tau); saturated = share of policy "
            "activations with |h| above plasticity.saturation; dead tanh = share of the policy's hidden units with "
            "|h| above plasticity.saturation on at least plasticity.dead_fraction of the batch; signed-mean≈0 = "
            "share of the policy's hidden units whose signed mean output |E h| is at most plasticity.signed_mean_tau "
            "times the layer's mean E|h| (a unit swinging between ±1 counts: not an idle unit; – where the runs "
            "predate these two readings); weight norm = L2 norm of all policy and value "
            "parameters; LR at bound = share of RECOM's learning-rate updates clipped to lr_min or lr_max "
            "(– without RECOM); eval success / crash = the success and crash rates of the evaluation at the end of "
            f"the run, mean over seeds, of two policies: {policies}; best taken at = the timestep the best policy "
            f"was kept at (mean over seeds); {missing}; IQM with 95% "
            "stratified-bootstrap CI (rliable); P(> PPO) = rliable probability of improvement of the final reward "
            "over PPO in the same wind condition; wall time per run = MLflow start to end (training, "
            "diagnostics, evaluation), mean over seeds.")
    if baseline is not None:
        key, value = baseline
        note += (f" Δ IQM vs {key}={value} = IQM of the final reward minus that of the condition with "
                 f"{key}={value} and otherwise the same agent and --by values in the same wind (a setting that does "
                 "not apply to it matches any), 95% percentile-bootstrap CI resampling both conditions' seeds.")
    (out / "summary.md").write_text(made + note + "\n\n" + markdown(s_display))
    seg_numbers, seg_display = segments(runs, stats.segment_rewards(histories, runs), conds)
    seg_numbers.to_csv(out / "segments.csv", index=False)
    (out / "segments.md").write_text(
        "Training reward per wind segment: mean episode reward (rollout/ep_rew_mean) logged during each hold of "
        "the wind schedule (wind.segment_steps timesteps at the speed in the header), mean ± 95% Student-t CI "
        "over seeds. A policy that collapses shows as a falling row; one that adapts, as a row that recovers "
        "after each change.\n\n" + markdown(seg_display.fillna("–")))
    evals = stats.segment_evaluations(histories, runs) if evals is None else evals
    if len(evals) and (evals.groupby("run_id")["segment"].nunique() > 1).any():   # in-training evaluations per segment
        e_numbers, e_display = segment_scores(runs, evals, conds) if scores is None else scores
        e_numbers.to_csv(out / "segment_scores.csv", index=False)
        per_segment = runs[[c for c in IDENTITY if c in runs]].merge(evals, on="run_id")
        per_segment.sort_values(["wind", "agent", "condition", "seed", "segment"]).to_csv(
            out / "segment_runs.csv", index=False)   # every run's segments: for analyses the report does not make
        flown = ", ".join(sorted({str(v) for v in runs.get("eval_condition", pd.Series(dtype=object)).dropna()})) or "fixed"
        (out / "segment_scores.md").write_text(
            made + "Learning within each segment of the schedule (segment k = timesteps (k S, (k+1) S], S = "
            "wind.segment_steps): AUC = the area under the in-training eval-success curve within the segment "
            "normalised by its length (the mean of its evenly spaced evaluations), % mean ± 95% Student-t CI over "
            f"seeds (evaluations flown under eval.condition = {flown}: 'current' scores the condition being learned); "
            "Δ = the agent's AUC minus reset_all's (a fresh network at every change) on the same segment, 95% "
            "percentile-bootstrap CI resampling both agents' seeds. Δ > 0 on later segments: forward transfer; a Δ "
            "that falls below 0 and keeps falling with the segment index: loss of plasticity.\n\n"
            "## Learning speed: eval-success AUC within the segment (%)\n\n" + markdown(e_display["auc"].fillna("–"))
            + "\n\n## Success at the segment's end (%): the last evaluation before the next change\n\n"
            + markdown(e_display["end"].fillna("–")))
        written_segments = [out / "segment_scores.csv", out / "segment_scores.md", out / "segment_runs.csv"]
    else:
        written_segments = []
    (out / "brief.txt").write_text(brief(s_display))
    written = [out / f for f in ("table3.csv", "table3.md", "table3.tex", "summary.csv", "summary.md",
                                 "segments.csv", "segments.md", "brief.txt")] + written_segments
    if (histories["key"] == PROBE).any():
        p_numbers, p_display = at_steps(runs, histories, conds, PROBE)
        text = ("Plasticity probe (Lyle et al. 2022; plasticity/probe_loss): a copy of the policy network fitted for "
                "plasticity.probe.steps Adam steps to fixed random targets on the most recent observations, at every "
                "wind change and at the end of training (the column: the timestep); the final regression loss, mean "
                "± 95% Student-t CI over seeds. A network that has lost plasticity fits worse: a rising row.\n\n"
                + markdown(p_display.fillna("–")))
        if (histories["key"] == PROBE_FRESH).any():
            f_numbers, f_display = at_steps(runs, histories, conds, PROBE_FRESH)
            p_numbers = pd.concat([p_numbers.assign(key=PROBE), f_numbers.assign(key=PROBE_FRESH)])
            text += ("\n\nThe reference (plasticity/probe_loss_fresh): the same fit, at the same moments, from a "
                     "network drawn afresh from the init distribution on the same observations, targets and "
                     "minibatches. A trained network above its row has lost plasticity against a new one.\n\n"
                     + markdown(f_display.fillna("–")))
        p_numbers.to_csv(out / "probe.csv", index=False)
        (out / "probe.md").write_text(text)
        written += [out / "probe.csv", out / "probe.md"]
    late = stats.late_evaluations(histories) if late is None else late
    if len(late):
        l_numbers, l_display = leaderboard(runs, per_run, late, conds)
        l_numbers.to_csv(out / "leaderboard.csv", index=False)
        (out / "leaderboard.md").write_text(
            made + "Leaderboard, sorted by the primary measure: keeps hovering = the share of a run's evaluations in the "
            f"second half of training (in-training ones and the final one) at >= {stats.HOVER:.0%} success, mean ± "
            "95% Student-t CI over seeds (per seed in the next column); P(> PPO) = rliable's probability that a run "
            "of the agent keeps hovering more than a PPO run in the same wind, 95% bootstrap CI; IQM final reward "
            f"(mean over the last {stats.FINAL_FRACTION:.0%} of training) with its 95% stratified-bootstrap CI; "
            f"success of the final and of the best policy at the end of the run: {policies}; then the summary's "
            "final readings (mean over seeds) and the mean wall time of a run (MLflow start to end).\n\n" + markdown(l_display))
        written += [out / "leaderboard.csv", out / "leaderboard.md"]
        if vs:
            v_numbers, v_display = versus(runs, late, conds, list(vs))
            v_numbers.to_csv(out / "versus.csv", index=False)
            (out / "versus.md").write_text(
                "Each agent against the references (--vs) on the leaderboard's primary measure, keeps hovering (the "
                f"share of a run's evaluations in the second half of training at >= {stats.HOVER:.0%} success), in the "
                "same wind and --by values: P(> reference) = rliable's probability that a run of the agent keeps "
                "hovering more than a run of the reference (ties count half), 95% bootstrap CI; Δ = difference of "
                "the seed means in percentage points, 95% percentile-bootstrap CI resampling both agents' seeds. "
                "An interval that excludes 0.5 (P) or 0 (Δ) separates the two.\n\n" + markdown(v_display))
            written += [out / "versus.csv", out / "versus.md"]
    if at:
        a_numbers, a_display = reward_at(runs, histories, conds, list(at), baseline)
        a_numbers.to_csv(out / "reward_at.csv", index=False)
        vs = (f"; Δ = IQM minus that of the condition with {baseline[0]}={baseline[1]} and otherwise the same agent, "
              "--by values and wind, 95% percentile-bootstrap CI resampling both") if baseline else ""
        (out / "reward_at.md").write_text(
            "Training reward at given timesteps (--at): per run the last rollout/ep_rew_mean logged at or before "
            "the step (a mean over its last 100 episodes); IQM over seeds with its 95% stratified-bootstrap CI "
            f"(rliable){vs}.\n\n" + markdown(a_display))
        written += [out / "reward_at.csv", out / "reward_at.md"]
    return written


BRIEF = {"Agent": "Agent", "Wind": "Wind", "Seeds": "Seeds", "Eval success final (%)": "Success: final policy (%)",
         "Eval success best (%)": "Success: best-train-reward policy (%)", "Eval crash final (%)": "Crash: final (%)",
         "Final reward": "Final train reward"}
BRIEF_LEGEND = ("final policy = the policy at the end of training; best-train-reward policy = the one kept at its highest "
                "mean training episode reward (rollout/ep_rew_mean, the paper's reading), which a crash-free but "
                "distant flight can win; success = share of the end-of-run evaluation flights within eval.success_radius "
                "for the last eval.success_hold_s.")


def brief(display: pd.DataFrame) -> str:
    """The summary's few columns a terminal shows at the end of a sweep (plain fixed-width text), headed by which
    policy each evaluation scored, with a legend."""
    rows = [list(BRIEF.values())] + [[str(r[c]) for c in BRIEF] for _, r in display.iterrows()]
    widths = [max(len(row[i]) for row in rows) for i in range(len(BRIEF))]
    lines = ["  ".join(cell.ljust(w) if i < 2 else cell.rjust(w) for i, (cell, w) in enumerate(zip(row, widths)))
             for row in rows]
    return "\n".join([lines[0], "  ".join("-" * w for w in widths), *lines[1:], "", BRIEF_LEGEND]) + "\n"
