"""Re-learning after changes (the plasticity study's primary measure, issue 35, docs/plasticity_study.md) and
whether a plasticity reading (the probe, the network's dormant, dead-tanh and saturated shares, its weight norm)
predicts it.

A change the network must re-learn (docs/conditions.md: a wind flip, a payload) starts every segment after the
first. Per run evaluated under the condition being learned (eval.condition=current; a run evaluated under a fixed
condition, as the remedies study's, scores no re-learning and is left out), from stats.segment_evaluations'
per-segment eval-success AUCs:

* ``relearning``: the mean AUC over the segments after the first, i.e. how fast and how well the network learns
  each new condition. Averaging the segments weighs every change alike; the first segment is left out because
  it is learning from scratch for every agent (``first_auc`` keeps it).
* ``relearning_end``: the mean success at the end of those segments (how much was learned by the next change).
* ``learned_share``: the share of those segments with an evaluation at >= 50% success (stats.HOVER), and
  ``hover_after``: the median timesteps from a change to that first evaluation, over the segments that reach it.
* ``relearning_distance``: the same mean over the later segments of the evaluations' mean final distance to the
  target (metres, lower is better; ``first_distance`` for segment 0): the continuous reading of the same
  evaluations, for learners whose flights come near the target in most seeds but whose success at the 0.1 m
  radius comes and goes between evaluations (the off-policy anchor task, docs/anchor_task.md).
* ``learned_first``: 1.0 if the first segment had such an evaluation (the network learned the hover from scratch
  before the first change), else 0.0 (NaN without evaluations in it). Outcomes on the hover task are bimodal per
  seed: a seed whose network never learned has lost no plasticity, it never had the skill. So the table also
  reads ``relearning`` over the seeds that learned, each reading's correlation within those runs, and
  ``segment_gains`` per segment over them. (reset_all's later segments are fresh networks, so over its seeds that
  learned they read how often a fresh draw re-learns on those seeds.) The other side, ``stuck_later``: of the runs
  that never learned segment 0, how many hover in some later segment (k of n, Wilson 95% CI): does a network that
  failed its first condition ever learn one afterwards? A fresh network at every change gets a new draw each time.

``table`` ranks the agents on ``relearning`` with P(> PPO) and P(> reset_all) (rliable's probability of
improvement) and the difference to reset_all (a fresh network at every change: what an agent that keeps no
plasticity problem and no prior knowledge would do). ``reading_correlation`` asks whether a plasticity reading
ranks runs as their re-learning does: the probe (Lyle et al.'s fit to random targets, which needs no change of
task) and the network's dormant, dead-tanh and saturated shares and weight norm at the changes. Spearman's rank
correlation between a run's reading and its ``relearning``, across runs (agents x seeds), across the runs that
learned segment 0 and across agents (seed means), with 95% bootstrap CIs. reset_all and the fresh twins are left out
of it (``fresh_draws``): their remedy hook runs before the probe at every change, so their probe reads a freshly
drawn network by construction.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pandas as pd

from sweep.config import TWIN_SUFFIX
from sweep.metrics import CURVES, PROBE
from sweep.report import figures, stats
from sweep.report.conditions import baseline_of
from sweep.report.tables import (IDENTITY, _fixed, _identity, _ordered_groups, _per_seed, interval, markdown,
                                 plus_minus, provenance, segment_scores)

REFERENCE = "reset_all"   # the fresh network at every change
ALL_RUNS = "runs (agents x seeds)"          # reading_correlation's across-runs reading
LEARNED_RUNS = "runs that learned segment 0"   # reading_correlation's within-runs reading
LEARNED_TITLE = "the seeds that learned segment 0"
FIRST = "first"           # segment_gains' reference: the run's own segment 0
COLUMNS = ["run_id", "relearning", "relearning_end", "learned_share", "hover_after", "first_auc", "learned_first",
           "later_segments", "relearning_distance", "first_distance"]
# network readings read at the changes (plasticity_readings): column -> metric; higher should mean less plastic
AT_CHANGES = {"dormant_at_changes": "plasticity/dormant_ratio", "dead_tanh_at_changes": "plasticity/dead_tanh_ratio",
              "saturated_at_changes": "plasticity/saturated_ratio", "weight_norm_at_changes": "plasticity/weight_norm"}


class Reading(NamedTuple):
    """How the report shows a reading: its name in tables, its figure axis' label, the axis' scale and whether the
    axis is logarithmic."""
    name: str
    axis: str
    scale: float = 1.0
    log: bool = False


READINGS = {"probe_first": Reading("probe loss at the first change", "Probe loss at the first change", log=True),
            "probe_mean": Reading("probe loss, mean of the run's readings", "Probe loss, mean of the readings",
                                  log=True),
            "dormant_at_changes": Reading("Sokar dormant share at the changes", "Sokar dormant at the changes (%)",
                                          100.0),
            "dead_tanh_at_changes": Reading("dead tanh share at the changes", "Dead tanh at the changes (%)", 100.0),
            "saturated_at_changes": Reading("saturated share at the changes", "Saturated at the changes (%)", 100.0),
            "weight_norm_at_changes": Reading("weight norm at the changes", "Weight norm at the changes")}
MIN_CI_PAIRS = 6          # fewer pairs: a rank correlation's bootstrap CI would look precise and mean nothing


def per_run(evals: pd.DataFrame, runs: pd.DataFrame) -> pd.DataFrame:
    """One row per run evaluated under eval.condition=current in a segment after the first (``evals``:
    stats.segment_evaluations). ``later_segments``: how many segments after the first it has evaluations in."""
    current = runs.loc[runs.get("eval_condition", pd.Series(index=runs.index, dtype=object)) == "current", "run_id"]
    rows = []
    for run_id, g in evals[evals["run_id"].isin(set(current))].groupby("run_id"):
        later = g[g["segment"] >= 1]
        if not len(later):
            continue
        first = g.loc[g["segment"] == 0, "auc"]
        rows.append({"run_id": run_id, "relearning": float(later["auc"].mean()),
                     "relearning_end": float(later["end"].mean()),
                     "learned_share": float(later["hover_after"].notna().mean()),
                     "hover_after": float(later["hover_after"].median()) if later["hover_after"].notna().any()
                     else np.nan,
                     "first_auc": float(first.iloc[0]) if len(first) else np.nan,
                     "learned_first": float(g.loc[g["segment"] == 0, "hover_after"].notna().any()) if len(first)
                     else np.nan,
                     "later_segments": int(len(later)),
                     "relearning_distance": float(later["distance_auc"].mean(skipna=False)),
                     "first_distance": float(g.loc[g["segment"] == 0, "distance_auc"].iloc[0]) if len(first)
                     else np.nan})
    return pd.DataFrame(rows, columns=COLUMNS)


def plasticity_readings(histories: pd.DataFrame, evals: pd.DataFrame) -> pd.DataFrame:
    """Per run, the READINGS that could predict re-learning: ``probe_first``, the probe loss at its earliest reading
    (the first change: after the first condition was learned, before any re-learning), ``probe_mean``, the mean of
    all its readings (at every change and at the end of training), and for each logged network reading of
    AT_CHANGES its value at the changes: the last value logged at or before each change (the start of every
    segment after the first in ``evals``, stats.segment_evaluations), averaged over the run's changes. A column
    is there when its metric was logged."""
    out = pd.DataFrame({"run_id": pd.unique(evals["run_id"]) if len(evals) else []})
    probe = histories[histories["key"] == PROBE].sort_values(["run_id", "step"])
    if len(probe):
        out = out.merge(probe.groupby("run_id")["value"].agg(probe_first="first", probe_mean="mean").reset_index(),
                        on="run_id", how="outer")
    changes = evals.loc[evals["segment"] >= 1, ["run_id", "start"]].astype({"start": float}).sort_values("start")
    for column, key in AT_CHANGES.items():
        logged = histories.loc[histories["key"] == key, ["run_id", "step", "value"]]
        if not len(logged) or not len(changes):
            continue
        at = pd.merge_asof(changes, logged.astype({"step": float}).sort_values("step"), left_on="start",
                           right_on="step", by="run_id", direction="backward")
        out = out.merge(at.groupby("run_id")["value"].mean().rename(column).reset_index(), on="run_id", how="left")
    return out


def _off_mode(values: np.ndarray) -> int:
    """How many values differ from the most common one."""
    return int(len(values) - np.unique(values, return_counts=True)[1].max())


def spearman_ci(x, y) -> tuple[float, float, float, int]:
    """Spearman's rank correlation of paired samples, its 95% percentile-bootstrap CI (pairs resampled together,
    stats.RESAMPLES times) and n. No CI below MIN_CI_PAIRS pairs, nor when a side has fewer than MIN_CI_PAIRS
    values off its most common one (a reading at 0 in all runs but a few: the correlation is those few runs, and
    the resamples that leave them out, constant on that side, have none; dropping them would give an interval
    conditioned on those runs being drawn). Otherwise the rare constant resample is left out."""
    from scipy.stats import rankdata

    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    if len(x) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return np.nan, np.nan, np.nan, int(len(x))
    pick = np.random.default_rng(stats.RNG_SEED).integers(0, len(x), (stats.RESAMPLES, len(x)))
    rx, ry = rankdata(np.vstack([x, x[pick]]), axis=1), rankdata(np.vstack([y, y[pick]]), axis=1)
    rx, ry = rx - rx.mean(axis=1, keepdims=True), ry - ry.mean(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):   # a constant resample: 0 / 0
        rho = (rx * ry).sum(axis=1) / np.sqrt((rx ** 2).sum(axis=1) * (ry ** 2).sum(axis=1))
    if min(len(x), _off_mode(x), _off_mode(y)) < MIN_CI_PAIRS:
        return float(rho[0]), np.nan, np.nan, int(len(x))
    low, high = np.nanpercentile(rho[1:], [2.5, 97.5])
    return float(rho[0]), float(low), float(high), int(len(x))


def table(runs: pd.DataFrame, per_run: pd.DataFrame, relearn: pd.DataFrame, conds, reference: str = REFERENCE,
          vs: list[str] = ()) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per condition x wind, sorted by ``relearning`` (mean ± 95% Student-t CI over seeds, per seed): its difference
    to ``reference``'s (95% bootstrap CI resampling both agents' seeds), P(> reference) and P(> PPO) [95% CI],
    against each further agent of ``vs`` (--vs) its difference and P(>), the first segment's AUC, the later
    segments' end success, and the final readings (``per_run``: stats.per_run_curve_stats)."""
    df = runs.merge(per_run, on="run_id", how="left").merge(relearn, on="run_id", how="inner")
    extra = [a for a in dict.fromkeys(vs) if a not in (reference, "ppo")]
    delta_ppo = "ppo" in vs   # P(> PPO) is always there; --vs ppo adds the difference too
    numbers, display = [], []
    for wind, cond, g in _ordered_groups(df, conds):
        dw = df[df["wind"] == wind]
        present = conds.table.loc[[c for c in conds.order if c in set(dw["condition"])]]
        others = {a: baseline_of(present, cond, "agent", a) for a in ("ppo", reference, *extra)}   # their conditions
        theirs = {a: dw.loc[dw["condition"] == other, "relearning"] if other is not None else None
                  for a, other in others.items()}
        mean, half, _ = stats.mean_t_ci(g["relearning"])
        delta = {a: stats.mean_diff_ci(g["relearning"], theirs[a]) if theirs[a] is not None else (np.nan,) * 3
                 for a in theirs}
        poi = {a: stats.poi_ci(g["relearning"], theirs[a]) if theirs[a] is not None else (np.nan,) * 3
               for a in theirs}
        p_ref, p_ppo = poi[reference], poi["ppo"]
        first, first_half, _ = stats.mean_t_ci(g["first_auc"])
        end, end_half, _ = stats.mean_t_ci(g["relearning_end"])
        learned, learned_half, _ = stats.mean_t_ci(g["learned_share"])
        learned_first = g["learned_first"] == 1.0
        relearning_learned, relearning_learned_half, _ = stats.mean_t_ci(g.loc[learned_first, "relearning"])
        stuck = stuck_later(g)
        distance, distance_half, _ = stats.mean_t_ci(g["relearning_distance"])
        delta_distance = (stats.mean_diff_ci(g["relearning_distance"],
                                             dw.loc[dw["condition"] == others[reference], "relearning_distance"])
                          if others[reference] is not None else (np.nan,) * 3)
        finals = [c for c in CURVES if c.final and c.final != "final_reward" and c.final in g]
        num = {**_identity(conds, cond, wind), "n_seeds": len(g), "later_segments": int(g["later_segments"].max()),
               "relearning": mean, "relearning_ci95": half,
               **{f"delta_vs_{a}{suffix}": delta[a][i] for a in (reference, *(["ppo"] if delta_ppo else []), *extra)
                  for i, suffix in enumerate(("", "_low", "_high"))},
               **{f"p_improve_over_{a}{suffix}": poi[a][i] for a in (reference, "ppo", *extra)
                  for i, suffix in enumerate(("", "_low", "_high"))},
               "first_auc": first, "first_auc_ci95": first_half, "relearning_end": end, "relearning_end_ci95": end_half,
               "learned_share": learned, "learned_share_ci95": learned_half,
               "learned_first_seeds": int(learned_first.sum()), "relearning_if_learned": relearning_learned,
               "relearning_if_learned_ci95": relearning_learned_half, **stuck,
               "hover_after_median": float(g["hover_after"].median()),
               "relearning_distance": distance, "relearning_distance_ci95": distance_half,
               **{f"distance_delta_vs_{reference}{suffix}": delta_distance[i]
                  for i, suffix in enumerate(("", "_low", "_high"))},
               **{c.final: g[c.final].mean() for c in finals}}
        shown = {"Agent": cond, "Wind": wind, "Seeds": len(g),
                 "Re-learning AUC (%)": plus_minus(100 * mean, 100 * half, 0), "per seed": _per_seed(g, "relearning"),
                 f"Δ vs {reference} (pp) [95% CI]": interval(*(100 * v for v in delta[reference]), 0),
                 f"P(> {reference}) [95% CI]": interval(*p_ref, 2), "P(> PPO) [95% CI]": interval(*p_ppo, 2),
                 **({"Δ vs PPO (pp) [95% CI]": interval(*(100 * x for x in delta["ppo"]), 0)} if delta_ppo else {}),
                 **{column: cell for a in extra for column, cell in (
                     (f"Δ vs {conds.labels.get(a, a)} (pp) [95% CI]", interval(*(100 * x for x in delta[a]), 0)),
                     (f"P(> {conds.labels.get(a, a)}) [95% CI]", interval(*poi[a], 2)))},
                 "Learned segment 0 (seeds)": f"{int(learned_first.sum())}/{int(g['learned_first'].notna().sum())}",
                 "Re-learning AUC, seeds that learned (%)": plus_minus(100 * relearning_learned,
                                                                       100 * relearning_learned_half, 0),
                 STUCK_COLUMN: stuck_cell(stuck),
                 "First segment AUC (%)": plus_minus(100 * first, 100 * first_half, 0),
                 "Success at segment ends (%)": plus_minus(100 * end, 100 * end_half, 0),
                 "Segments hovered (%)": plus_minus(100 * learned, 100 * learned_half, 0),
                 "Steps to hover (M)": _fixed(num["hover_after_median"] / 1e6, 2),
                 **({"Re-learning distance (m)": plus_minus(distance, distance_half, 2),
                     f"Distance Δ vs {reference} (m) [95% CI]": interval(*delta_distance, 2)}
                    if np.isfinite(distance) else {}),
                 **{c.title: _fixed(c.scale * num[c.final], c.digits) for c in finals}}
        numbers.append(num)
        display.append(shown)
    numbers, display = pd.DataFrame(numbers), pd.DataFrame(display)
    if len(numbers):
        order = numbers.sort_values(["wind", "relearning"], ascending=[True, False], kind="stable").index
        numbers, display = numbers.loc[order], display.loc[order]
    return numbers.reset_index(drop=True), display.reset_index(drop=True)


STUCK_COLUMN = "Never learned segment 0: hovered later (runs) [95% CI]"


def stuck_later(per_run: pd.DataFrame) -> dict[str, float]:
    """Of ``per_run``'s runs that never learned segment 0 (``learned_first`` 0), ``stuck_runs``, how many hovered in
    some later segment (``stuck_hovered_later``: ``learned_share`` > 0) and that share with its Wilson 95% CI."""
    never = per_run[per_run["learned_first"] == 0.0]
    k, n = int((never["learned_share"] > 0).sum()), len(never)
    share, low, high = stats.wilson(k, n)
    return {"stuck_runs": n, "stuck_hovered_later": k, "stuck_hovered_later_share": share,
            "stuck_hovered_later_low": low, "stuck_hovered_later_high": high}


def stuck_cell(v) -> str:
    """'k/n [low, high]' of stuck_later's numbers (a dict or a row), '–' without such runs."""
    if not v["stuck_runs"]:
        return "–"
    return (f"{int(v['stuck_hovered_later'])}/{int(v['stuck_runs'])} "
            f"[{v['stuck_hovered_later_low']:.2f}, {v['stuck_hovered_later_high']:.2f}]")


def fresh_draws(agents: pd.Series) -> pd.Series:
    """Whether each agent draws fresh networks at every change (reset_all and every fresh twin, ``<agent>_fresh``):
    its probe at a change reads the fresh draw, and the networks it re-learns with are not the ones read."""
    return (agents == REFERENCE) | agents.str.endswith(TWIN_SUFFIX)


def reading_correlation(runs: pd.DataFrame, relearn: pd.DataFrame, readings: pd.DataFrame) -> pd.DataFrame:
    """Spearman's rho [95% CI] between each plasticity reading (plasticity_readings) and ``relearning``, per wind:
    across runs (agents x seeds), across the runs that learned the first segment (``learned_first``: does the
    reading still predict re-learning once "never learned at all" is out?) and across conditions (their seed
    means); reset_all and the fresh twins left out (``fresh_draws``: their remedy hook runs before the probe at every
    change, so their probe reads a freshly drawn network by construction, and their later networks are not the ones
    read). Every reading is one where
    higher should mean less plastic (a worse fit to the probe's random targets, more dormant, dead or saturated
    units, larger weights), so a reading that predicts re-learning gives a negative rho."""
    df = runs.loc[~fresh_draws(runs["agent"]), ["run_id", "wind", "condition"]]
    df = df.merge(relearn, on="run_id").merge(readings, on="run_id")
    rows = []
    for wind, dw in df.groupby("wind"):
        present = [r for r in READINGS if r in dw and dw[r].notna().any()]   # logged in this wind's runs
        means = dw.groupby("condition")[["relearning", *present]].mean()
        for reading in present:
            for across, d in ((ALL_RUNS, dw), (LEARNED_RUNS, dw[dw["learned_first"] == 1.0]),
                              ("agents (seed means)", means)):
                rho, low, high, n = spearman_ci(d[reading], d["relearning"])
                rows.append({"wind": wind, "reading": reading, "across": across, "rho": rho, "rho_low": low,
                             "rho_high": high, "n": n})
    return pd.DataFrame(rows, columns=["wind", "reading", "across", "rho", "rho_low", "rho_high", "n"])


def segment_gains(runs: pd.DataFrame, evals: pd.DataFrame, relearn: pd.DataFrame, conds) -> pd.DataFrame:
    """Per condition x wind x segment over the runs of ``relearn`` that learned segment 0 (``learned_first``; every
    agent alike, reset_all too): tables.segment_scores' AUC and end success, and the paired gain over the run's own
    segment 0, ``auc_vs_first`` (per seed AUC_k - AUC_0, mean with its 95% Student-t CI). Segment 0 is the same
    network learning from scratch, so the gain compares like with like; another agent's seeds would be selected
    otherwise (most fresh networks never learn). Gain >= 0: re-learns each change at least as well as it first
    learned; falling with k: loss of plasticity. reset_all's later segments are fresh draws: its gain is what a
    new network gives against a first one that learned."""
    kept = evals[evals["run_id"].isin(set(relearn.loc[relearn["learned_first"] == 1.0, "run_id"]))]
    numbers, _ = segment_scores(runs, kept, conds, reference=None)   # against reset_all's seeds: not like with like
    first = kept.loc[kept["segment"] == 0, ["run_id", "auc"]].rename(columns={"auc": "auc_first"})
    per_seed = kept.merge(first, on="run_id").merge(runs[["run_id", "wind", "condition"]], on="run_id")
    rows = []
    for (wind, cond, k), g in per_seed.groupby(["wind", "condition", "segment"]):
        mean, half, _ = stats.mean_t_ci(g["auc"] - g["auc_first"])
        rows.append({"wind": wind, "condition": cond, "segment": k, f"auc_vs_{FIRST}": mean,
                     f"auc_vs_{FIRST}_low": mean - half, f"auc_vs_{FIRST}_high": mean + half})
    gains = pd.DataFrame(rows, columns=["wind", "condition", "segment", *(f"auc_vs_{FIRST}{s}" for s in
                                                                         ("", "_low", "_high"))])
    return numbers.merge(gains, on=["wind", "condition", "segment"], how="left")


def write_learned(runs: pd.DataFrame, evals: pd.DataFrame, relearn: pd.DataFrame, conds, shown, out) -> list:
    """segment_scores_learned.csv/.md and its figure (segment_gains): per segment, what a network that once learned
    the hover does after each change, against its own first learning. Nothing without a run that learned."""
    if not len(relearn) or not (relearn["learned_first"] == 1.0).any():
        return []
    numbers = segment_gains(runs, evals, relearn, conds)
    numbers.to_csv(out / "segment_scores_learned.csv", index=False)
    rows = []
    for (wind, cond), g in numbers.groupby(["wind", "condition"], sort=False):
        row = {"Agent": cond, "Wind": wind, "Seeds": int(g["n_seeds"].max())}
        for r in g.sort_values("segment").itertuples():
            cell = plus_minus(100 * r.auc_mean, 100 * r.auc_ci95, 0)
            if r.segment > 0:
                cell += " (gain " + interval(100 * r.auc_vs_first, 100 * r.auc_vs_first_low,
                                             100 * r.auc_vs_first_high, 0) + ")"
            row[f"{r.segment}"] = cell
        rows.append(row)
    (out / "segment_scores_learned.md").write_text(
        provenance(runs) + f"Per segment over {LEARNED_TITLE} (an evaluation at >= 50% success in it; every agent "
        "alike): the eval-success AUC within the segment, % mean ± 95% Student-t CI over those seeds, and its gain "
        "over the run's own segment 0 (per seed AUC_k - AUC_0, mean [95% Student-t CI], points). A seed that never "
        "hovered has no skill to lose, and outcomes on the hover task are bimodal per seed, so segment_scores.md "
        "over every seed mixes 'never learned' with 'stopped re-learning'. The gain compares each network with its "
        "own first learning; against reset_all's seeds it would not be like with like (most fresh networks never "
        "learn, and these seeds are selected for having learned). A gain that falls with the segment index is "
        "loss of plasticity; reset_all's row (fresh networks after segment 0) shows what a new draw gives.\n\n"
        + markdown(pd.DataFrame(rows).fillna("–")))
    return ([out / "segment_scores_learned.csv", out / "segment_scores_learned.md"]
            + figures.segment_scores(numbers, conds, shown, out, reference=FIRST, name="segment_scores_learned",
                                     runs_shown=LEARNED_TITLE, diff_label="AUC gain over its\nown segment 0 (points)"))


def _rho_title(corr: pd.DataFrame) -> str:
    """A readings panel's title: one reading's ρ [CI] and n across every run and across the runs that learned
    segment 0 ('no CI' where spearman_ci gives none)."""
    lines = []
    for name, across in (("all runs", ALL_RUNS), ("learned", LEARNED_RUNS)):
        for r in corr[(corr["across"] == across) & np.isfinite(corr["rho"])].itertuples():
            lines.append(f"{name} (n {r.n}): ρ {interval(r.rho, r.rho_low, r.rho_high, 2)}"
                         + ("" if np.isfinite(r.rho_low) else ", no CI"))
    return "\n".join(lines)


def write(runs: pd.DataFrame, per_run: pd.DataFrame, histories: pd.DataFrame, evals: pd.DataFrame,
          relearn: pd.DataFrame, conds, shown, out, vs: list[str] = ()) -> list:
    """relearning.csv/.md (the table, with columns against the --vs agents, and each plasticity reading's
    correlation with it), reading_correlation.csv, relearning_runs.csv (per run: per_run's measures and
    plasticity_readings) and the figure readings_<wind> (figures.readings_scatter, ``shown`` in colour); nothing
    without runs that per_run scores."""
    if not len(relearn):
        return []
    numbers, display = table(runs, per_run, relearn, conds, vs=vs)
    numbers.to_csv(out / "relearning.csv", index=False)
    text = (provenance(runs) + "Re-learning after each change: per run, the mean over the segments after the first "
            "of the in-training eval-success AUC within the segment (segment_scores.md; runs evaluated under "
            "eval.condition = current, the condition being learned), mean ± 95% Student-t CI over seeds, per seed "
            f"in the next column. Δ vs {REFERENCE} = the difference of means to {REFERENCE} (a fresh network at every "
            "change) in percentage points, 95% percentile-bootstrap CI resampling both agents' seeds; P(> ...) = "
            "rliable's probability that a run of the agent re-learns better than a run of the reference [95% "
            "bootstrap CI]; with --vs, the same Δ and P against each agent named. Runs with fewer segments (a "
            "shorter run) average fewer changes. First segment AUC = learning from scratch (left out of the "
            "measure); success at "
            "segment ends = the mean over the later segments of the last evaluation before the next change; "
            "segments hovered = the share of the later segments with an evaluation at >= 50% success; learned "
            "segment 0 = the seeds whose first segment had such an evaluation (learned the hover from scratch), and "
            "the re-learning AUC over those seeds alone (a seed that never learned has no plasticity to lose); "
            "never learned segment 0: hovered later = of the runs that did not learn segment 0, how many reach "
            "an evaluation at >= 50% success in some later segment (k/n, Wilson 95% CI; a fresh network at every "
            "change draws anew at each); "
            "steps to hover = the timesteps from a change to that evaluation (median over the runs' medians); "
            "re-learning distance = the same mean over the later segments of the evaluations' mean final distance "
            "to the target (m, lower is better: the continuous reading of the same flights, where runs logged it), "
            f"and its difference to {REFERENCE} [95% bootstrap CI]. Then "
            "the final readings (mean over seeds, over the last 10% of training).\n\n" + markdown(display.fillna("–")))
    readings = plasticity_readings(histories, evals)
    scored = (runs[[c for c in IDENTITY if c in runs]].merge(relearn, on="run_id")
              .merge(readings, on="run_id", how="left").sort_values(["wind", "agent", "condition", "seed"]))
    scored.to_csv(out / "relearning_runs.csv", index=False)   # per run: for analyses the report does not make
    written = [out / "relearning.csv", out / "relearning.md", out / "relearning_runs.csv"]
    corr = reading_correlation(runs, relearn, readings)
    if len(corr):
        corr.to_csv(out / "reading_correlation.csv", index=False)
        corr["cell"] = [interval(r.rho, r.rho_low, r.rho_high, 2) + f" (n {r.n})" for r in corr.itertuples()]
        wide = corr.pivot_table(index=["wind", "reading"], columns="across", values="cell", aggfunc="first",
                                sort=False).reset_index()
        rhos = pd.DataFrame({"Wind": wide["wind"], "Reading": [READINGS[r].name for r in wide["reading"]],
                             **{f"ρ across {a}": wide[a] for a in corr["across"].unique()}})
        text += ("\n\nDoes a plasticity reading predict re-learning? Spearman's rank correlation [95% CI] between a "
                 "run's reading and its re-learning AUC, across runs, across the "
                 f"{LEARNED_RUNS} and across agents (seed means), {REFERENCE} and the fresh twins left out (their "
                 "probe at a change reads the freshly drawn network). The probe loss (plasticity/probe_loss: a copy "
                 "of the policy fitted to "
                 "random targets) at the first change and its mean over the run's readings; the policy network's "
                 "dormant, dead-tanh and saturated shares and the weight norm of the policy and value networks at "
                 "the changes (the last value logged "
                 "at or before each change, averaged over the run's changes). Higher should mean less plastic for "
                 "each, so a reading that predicts re-learning gives ρ < 0. 95% percentile-bootstrap CI (pairs "
                 f"resampled; none below {MIN_CI_PAIRS} pairs, nor when fewer than {MIN_CI_PAIRS} runs read other "
                 "than a side's most common value, e.g. a share at 0 in all runs but a few: ρ is then those few "
                 "runs).\n\n" + markdown(rhos.fillna("–")))
        written.append(out / "reading_correlation.csv")
        titles = {(wind, reading): _rho_title(g) for (wind, reading), g in corr.groupby(["wind", "reading"])}
        written += figures.readings_scatter(scored[~fresh_draws(scored["agent"])], READINGS, titles, conds, shown,
                                            out)
    (out / "relearning.md").write_text(text)
    return written
