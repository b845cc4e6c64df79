"""Each agent against a fresh network of its own kind (issue 56; README "Against a fresh network of its own kind").

An agent's fresh twin (twin=fresh, logged as ``<agent>_fresh``; PPO's twin is ``reset_all``) flies segment 0 as its
agent does, bit for bit (same seed, no change yet), then draws the agent's own networks and optimizer afresh at every
change. So the twin's runs pair with the agent's by seed, exactly, and per agent x wind (x --by values):

* per segment k >= 1, and for the re-learning AUC (relearning.per_run: the mean AUC over the segments after the
  first): Δ = agent − own twin, the mean of the per-seed differences with a 95% percentile-bootstrap CI over the
  pairs (stats.paired_diff_ci), and P(> own twin) over the same seeds (rliable's probability of improvement [95%
  CI], as every other reference of the report); beside it Δ vs reset_all (PPO's fresh network, the study's reference
  until twins);
* the same for the re-learning distance (relearning.per_run's ``relearning_distance``: the evaluations' mean final
  distance to the target over the later segments, metres, lower is better) where the runs logged it: paired Δ vs
  own twin [CI] and P(nearer than own twin) [CI], the continuous reading of the same flights;
* the runs stuck from the start (relearning.stuck_later): of the agent's runs and of its twin's that never learned
  segment 0, how many hover in a later segment [Wilson CI]: a continual network that failed its first condition
  against fresh networks of its kind;
* segment 0: how many pairs flew it identically (equal AUC, end success and, where logged, final distances). It
  should be all of them; a pair that differs ran other code or settings, and the report says so.

Negative Δ vs own twin: the agent re-learns worse than a fresh network of its own kind (plasticity lost); positive:
what it kept helps (transfer). ``write``: twins.csv (per segment), twins.md, and the figure twins (segment AUC,
then Δ vs own twin per segment; figures.segment_scores).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from sweep.config import TWIN_SUFFIX
from sweep.report import figures, relearning, stats
from sweep.report.conditions import baseline_of
from sweep.report.highlight import Highlight
from sweep.report.tables import _identity, _ordered_groups, interval, markdown, provenance

REFERENCE = "reset_all"   # a fresh plain PPO network at every change: PPO's own twin
SAME_RUN = ("auc", "end", "distance_auc", "distance_end")   # equal in a pair's segment 0: the same run


def twin_agent(agent: str) -> str:
    """The agent whose runs are ``agent``'s fresh twin: reset_all for PPO, else ``<agent>_fresh``."""
    return REFERENCE if agent == "ppo" else agent + TWIN_SUFFIX


def _present(conds, conditions) -> pd.DataFrame:
    """The rows of ``conds.table`` of the conditions that ran (in a wind)."""
    return conds.table.loc[[c for c in conds.order if c in set(conditions)]]


def twin_conditions(conds, runs: pd.DataFrame) -> dict[tuple[str, str], str]:
    """(wind, condition) -> its twin's condition (same --by values), for each condition whose twin ran in that wind."""
    out = {}
    for wind, g in runs.groupby("wind"):
        table = _present(conds, g["condition"])
        for cond in table.index:
            twin = baseline_of(table, cond, "agent", twin_agent(conds.agent(cond)))
            if twin is not None:
                out[(wind, cond)] = twin
    return out


def _by_seed(df: pd.DataFrame, cond: str, column: str) -> pd.Series:
    rows = df[df["condition"] == cond]
    return pd.Series(rows[column].to_numpy(dtype=float), index=rows["seed"].to_numpy())


def _paired(mine: pd.Series, its: pd.Series, lower_is_better: bool = False) -> dict[str, float]:
    """Δ = mine − its over the seeds both have [CI], their number, and P(mine better than its) [CI] over the same
    seeds: P(mine > its), or P(mine < its) if ``lower_is_better`` (a distance)."""
    d, lo, hi, n = stats.paired_diff_ci(mine, its)
    both = pd.concat([mine.rename("x"), its.rename("y")], axis=1, join="inner").dropna()
    sign = -1.0 if lower_is_better else 1.0
    p = stats.poi_ci(sign * both["x"], sign * both["y"]) if len(both) else (np.nan,) * 3
    return {"delta": d, "low": lo, "high": hi, "pairs": n, "p": p[0], "p_low": p[1], "p_high": p[2]}


def segment_pairs(runs: pd.DataFrame, seg: pd.DataFrame, conds, pairs: dict) -> pd.DataFrame:
    """Per condition x wind x segment, for each agent of ``pairs`` and each twin: the AUC (seed mean, 95% Student-t
    half-width), and for the agent the paired Δ AUC vs its twin [CI], the pairs, P(> twin) [CI], the paired Δ of
    the segment's mean final distance (``distance_vs_twin`` [CI], metres), and on segment 0 ``same_pairs`` (pairs
    whose AUC, end success and final distances are equal: SAME_RUN)."""
    df = runs[["run_id", "wind", "condition", "seed"]].merge(seg, on="run_id")
    drawn = {(wind, c) for (wind, cond), twin in pairs.items() for c in (cond, twin)}
    rows = []
    for wind, cond, g in _ordered_groups(df, conds):
        if (wind, cond) not in drawn:
            continue
        twin = pairs.get((wind, cond))
        theirs = df[(df["wind"] == wind) & (df["condition"] == twin)] if twin else df.iloc[0:0]
        for k, s in g.groupby("segment"):
            mean, half, n = stats.mean_t_ci(s["auc"])
            row = {**_identity(conds, cond, wind), "condition": cond, "segment": int(k),
                   "start": int(s["start"].iloc[0]), "end_step": int(s["end_step"].iloc[0]), "n_seeds": n,
                   "auc_mean": mean, "auc_ci95": half, "twin": twin or ""}
            other = theirs[theirs["segment"] == k]
            if twin and len(other):
                mine, its = _by_seed(s, cond, "auc"), _by_seed(other, twin, "auc")
                v = _paired(mine, its)
                row.update({"auc_vs_twin": v["delta"], "auc_vs_twin_low": v["low"], "auc_vs_twin_high": v["high"],
                            "pairs": v["pairs"], "p_improve_over_twin": v["p"],
                            "p_improve_over_twin_low": v["p_low"], "p_improve_over_twin_high": v["p_high"]})
                far = stats.paired_diff_ci(_by_seed(s, cond, "distance_auc"), _by_seed(other, twin, "distance_auc"))
                row.update({"distance_vs_twin": far[0], "distance_vs_twin_low": far[1],
                            "distance_vs_twin_high": far[2]})
                if k == 0:   # the same run: equal AUC, end success and (where logged) final distances
                    a, b = (pd.concat([_by_seed(frame, c, column) for column in SAME_RUN], axis=1, keys=SAME_RUN)
                            for frame, c in ((s, cond), (other, twin)))
                    a, b = a.align(b, join="inner", axis=0)
                    row["same_pairs"] = int(((a == b) | (a.isna() & b.isna())).all(axis=1).sum())
            rows.append(row)
    return pd.DataFrame(rows)


def relearning_pairs(runs: pd.DataFrame, relearn: pd.DataFrame, conds, pairs: dict) -> pd.DataFrame:
    """Per agent x wind of ``pairs``: the re-learning AUC's paired Δ vs its own twin [CI], P(> twin) [CI], Δ vs
    reset_all [CI] (unpaired: other networks on the same seeds) where reset_all ran, and the re-learning
    distance's paired Δ vs its twin [CI] and P(nearer than twin) [CI] over ``distance_pairs`` pairs (0: not
    logged), and for the agent and (``twin_``) its twin relearning.stuck_later: of the runs that never learned
    segment 0, how many hovered later [Wilson CI]."""
    df = runs[["run_id", "wind", "condition", "seed"]].merge(
        relearn[["run_id", "relearning", "relearning_distance", "learned_first", "learned_share"]], on="run_id")
    rows = []
    for (wind, cond), twin in pairs.items():
        here = df[df["wind"] == wind]
        v = _paired(_by_seed(here, cond, "relearning"), _by_seed(here, twin, "relearning"))
        far = _paired(_by_seed(here, cond, "relearning_distance"), _by_seed(here, twin, "relearning_distance"), True)
        ref = baseline_of(_present(conds, here["condition"]), cond, "agent", REFERENCE)
        r = (stats.mean_diff_ci(_by_seed(here, cond, "relearning"), _by_seed(here, ref, "relearning")) if ref
             else (np.nan,) * 3)
        rows.append({**_identity(conds, cond, wind), "condition": cond, "twin": twin, "pairs": v["pairs"],
                     "relearning_vs_twin": v["delta"], "relearning_vs_twin_low": v["low"],
                     "relearning_vs_twin_high": v["high"], "p_improve_over_twin": v["p"],
                     "p_improve_over_twin_low": v["p_low"], "p_improve_over_twin_high": v["p_high"],
                     f"relearning_vs_{REFERENCE}": r[0], f"relearning_vs_{REFERENCE}_low": r[1],
                     f"relearning_vs_{REFERENCE}_high": r[2], "distance_pairs": far["pairs"],
                     "distance_vs_twin": far["delta"], "distance_vs_twin_low": far["low"],
                     "distance_vs_twin_high": far["high"], "p_nearer_than_twin": far["p"],
                     "p_nearer_than_twin_low": far["p_low"], "p_nearer_than_twin_high": far["p_high"],
                     **relearning.stuck_later(here[here["condition"] == cond]),
                     **{f"twin_{k}": v for k, v in relearning.stuck_later(here[here["condition"] == twin]).items()}})
    return pd.DataFrame(rows)


def write(runs: pd.DataFrame, seg: pd.DataFrame, relearn: pd.DataFrame, conds, shown, out) -> list:
    """twins.csv (per segment), twins.md (one row per agent x wind) and the figure twins; nothing when no agent of
    the report has its twin beside it."""
    pairs = twin_conditions(conds, runs)
    if not pairs or not len(seg):
        return []
    per_segment = segment_pairs(runs, seg, conds, pairs)
    whole = relearning_pairs(runs, relearn, conds, pairs) if len(relearn) else pd.DataFrame()
    per_segment.to_csv(out / "twins.csv", index=False)
    display = []
    for (wind, cond), twin in pairs.items():
        mine = per_segment[(per_segment["wind"] == wind) & (per_segment["condition"] == cond)]
        first = mine[mine["segment"] == 0]
        w = whole[(whole["wind"] == wind) & (whole["condition"] == cond)] if len(whole) else whole
        pairs_seen = mine["pairs"].max() if "pairs" in mine else np.nan
        same = first["same_pairs"].iloc[0] if len(first) and "same_pairs" in first else np.nan
        row = {"Agent": cond, "Twin": twin, "Wind": wind, "Pairs": int(pairs_seen) if pd.notna(pairs_seen) else 0,
               "Segment 0 the same run (pairs)": (f"{int(same)}/{int(first['pairs'].iloc[0])}" if pd.notna(same)
                                                  else "–")}
        if len(w):
            v = w.iloc[0]
            row.update({
                "Re-learning AUC Δ vs own twin (pp) [95% CI]": interval(*(100 * v[f"relearning_vs_twin{s}"]
                                                                         for s in ("", "_low", "_high")), 0),
                "P(> own twin) [95% CI]": interval(v["p_improve_over_twin"], v["p_improve_over_twin_low"],
                                                   v["p_improve_over_twin_high"], 2),
                f"Δ vs {REFERENCE} (pp) [95% CI]": interval(*(100 * v[f"relearning_vs_{REFERENCE}{s}"]
                                                             for s in ("", "_low", "_high")), 0),
                "Never learned segment 0: hovered later, agent": relearning.stuck_cell(v),
                "…, own twin": relearning.stuck_cell({k[5:]: x for k, x in v.items() if k.startswith("twin_")})})
            if v["distance_pairs"]:
                row.update({
                    "Re-learning distance Δ vs own twin (m) [95% CI]": interval(
                        *(v[f"distance_vs_twin{s}"] for s in ("", "_low", "_high")), 2),
                    "P(nearer than own twin) [95% CI]": interval(v["p_nearer_than_twin"],
                                                                 v["p_nearer_than_twin_low"],
                                                                 v["p_nearer_than_twin_high"], 2)})
        for r in mine[mine["segment"] >= 1].itertuples() if "auc_vs_twin" in mine else []:
            row[f"segment {r.segment}: Δ (pp)"] = interval(100 * r.auc_vs_twin, 100 * r.auc_vs_twin_low,
                                                            100 * r.auc_vs_twin_high, 0)
        display.append(row)
    text = (provenance(runs) + "Each agent against its own fresh twin (twin=fresh: the agent's networks and optimizer "
            f"drawn afresh at every change; PPO's twin is {REFERENCE}). Both fly segment 0 as the same run (same seed, "
            "no change yet): 'Segment 0 the same run' counts the pairs whose segment-0 AUC, end success and (where "
            "logged) final distances are equal. "
            "Δ = the agent's eval-success AUC minus its twin's, mean of the per-seed differences (runs paired by "
            "seed), 95% percentile-bootstrap CI over the pairs, in percentage points: the re-learning AUC (mean over "
            "the segments after the first) and each later segment. Negative: the agent re-learns worse than a fresh "
            "network of its own kind (plasticity lost); positive: what it kept helps. P(> own twin) = rliable's "
            f"probability of improvement [95% bootstrap CI]; Δ vs {REFERENCE} as in relearning.md (unpaired). Where "
            "the runs logged the evaluations' final distance: the re-learning distance's Δ vs own twin (the mean "
            "final distance to the target over the later segments' evaluations, metres, paired likewise; negative: "
            "the agent flies nearer than its twin) and P(nearer than own twin). Never learned segment 0: hovered later "
            "= of the runs with no evaluation at >= 50% success in segment 0, how many reach one in a later segment "
            "(k/n, Wilson 95% CI), the agent's runs and its twin's (a network that failed its first condition: "
            "does it ever learn one, kept or drawn afresh?).\n\n"
            + markdown(pd.DataFrame(display).fillna("–")))
    (out / "twins.md").write_text(text)
    coloured = {}   # every agent and twin of the figure in colour, however many agents the report has
    for (wind, cond), twin in pairs.items():
        coloured.setdefault(wind, set()).update({conds.agent(cond), conds.agent(twin)})
    return [out / "twins.csv", out / "twins.md"] + figures.segment_scores(
        per_segment.assign(**{c: per_segment.get(c, np.nan) for c in ("auc_vs_twin", "auc_vs_twin_low",
                                                                      "auc_vs_twin_high")}),
        conds, Highlight(shown.rank, coloured, shown.top), out, reference="twin", name="twins", runs_shown="seeds (agents and their fresh twins)",
        diff_label="AUC − its own fresh twin's\n(points, paired by seed)")
