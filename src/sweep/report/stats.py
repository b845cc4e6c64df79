"""Aggregation over seeds: curves on a common timestep grid, per-run summaries, CIs, rliable scores.

Statistics used (all over seeds; a seed is one run):
* curve bands: 95% percentile-bootstrap CI of the mean at each grid point (``scipy.stats.bootstrap``);
* Table III: mean +- half-width of the 95% Student-t CI (n - 1 degrees of freedom);
* IQM: rliable's ``metrics.aggregate_iqm`` with a 95% stratified-bootstrap percentile CI;
* IQM difference to a baseline condition: 95% percentile-bootstrap CI, both conditions' runs resampled
  independently;
* difference of means to a reference condition (the leaderboard's ``--vs``): 95% percentile-bootstrap CI,
  both conditions' runs resampled independently;
* difference to a paired condition (an agent and its fresh twin, the same seeds): the mean of the per-seed
  differences, 95% percentile-bootstrap CI resampling the pairs;
* a share of runs (k of n, e.g. the runs that hover): the Wilson 95% score interval (``scipy.stats.binomtest``);
* probability of improvement: rliable's ``metrics.probability_of_improvement`` (Mann-Whitney U / (n_x n_y)),
  with a 95% CI from independent bootstrap resampling of both agents' runs.

rliable's own ``library.get_interval_estimates`` cannot be imported with the pinned stack (arch 7.2 calls
pandas 3's ``deprecate_kwarg`` with the old signature; arch 8 drops the ``random_state`` rliable passes), so its
stratified bootstrap is done with ``scipy.stats.bootstrap``: with one task (one agent x wind condition) a
stratified bootstrap over runs is exactly an i.i.d. bootstrap over runs.
"""
from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from rliable import metrics
from scipy import stats

# FINALS: per-run column -> the curve whose final value it holds
from sweep.metrics import AT_BOUND, EVAL_DISTANCE, EVAL_SUCCESS, FINALS, REWARD

RESAMPLES = 2000
FINAL_FRACTION = 0.1  # "final" value of a curve: mean over the last 10% of the run's timesteps
RNG_SEED = 0


def _bootstrap(data: tuple, statistic, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # degenerate resamples (identical seeds) -> a zero-width interval
        return stats.bootstrap(data, statistic, n_resamples=RESAMPLES, method="percentile",
                               confidence_level=0.95, rng=np.random.default_rng(RNG_SEED), **kwargs)


def wilson(k: int, n: int) -> tuple[float, float, float]:
    """(share, low, high): k of n with the Wilson 95% interval (NaN for n = 0)."""
    if n == 0:
        return np.nan, np.nan, np.nan
    ci = stats.binomtest(int(k), int(n)).proportion_ci(0.95, method="wilson")
    return k / n, ci.low, ci.high


def _iqm(x, axis=-1):
    """rliable's ``aggregate_iqm`` (a 25% trimmed mean) of each resample along ``axis``."""
    return stats.trim_mean(x, 0.25, axis=axis)


def _p_improve(x, y, axis=-1):
    """rliable's ``probability_of_improvement`` of each pair of resamples along ``axis``: the Mann-Whitney U of X
    over Y divided by n_x n_y, i.e. the share of pairs (x_i, y_j) with x_i > y_j, ties counted half (0.5 when
    X equals Y, as rliable sets it). Exact: the counts are sums of halves. Finite scores only (poi_ci drops the
    others; rliable would give NaN); memory grows as resamples x n_x x n_y (4 MB at 16 vs 16 seeds)."""
    x, y = np.moveaxis(x, axis, -1), np.moveaxis(y, axis, -1)
    a, b = x[..., :, None], y[..., None, :]
    return ((a > b) + 0.5 * (a == b)).mean(axis=(-2, -1))


def common_grid(histories: pd.DataFrame, points: int = 200) -> np.ndarray:
    """Evenly spaced timesteps from the first to the last logged step of any run (one point if they agree)."""
    return np.unique(np.linspace(histories["step"].min(), histories["step"].max(), points))


def aligned(histories: pd.DataFrame, key: str, run_ids, grid: np.ndarray) -> np.ndarray:
    """(runs, grid) matrix of ``key`` linearly interpolated on ``grid``; NaN outside a run's logged range."""
    rows = []
    for run_id in run_ids:
        h = histories[(histories["run_id"] == run_id) & (histories["key"] == key)]
        if len(h):
            rows.append(np.interp(grid, h["step"], h["value"], left=np.nan, right=np.nan))
    return np.array(rows).reshape(len(rows), len(grid))


def mean_band(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(mean, CI low, CI high, n seeds) per grid point; the band is NaN where fewer than 2 seeds have data."""
    n = np.sum(~np.isnan(matrix), axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(matrix, axis=0) if len(matrix) else np.full(matrix.shape[1], np.nan)
    lo, hi = np.full_like(mean, np.nan), np.full_like(mean, np.nan)
    full = n == len(matrix)
    if len(matrix) >= 2 and full.any():
        ci = _bootstrap((matrix[:, full],), np.mean, axis=0, vectorized=True).confidence_interval
        lo[full], hi[full] = ci.low, ci.high
    return mean, lo, hi, n


def final_value(steps: np.ndarray, values: np.ndarray) -> float:
    """Mean of the values logged in the last FINAL_FRACTION of the run's timesteps (at least the last one)."""
    if len(values) == 0:
        return np.nan
    last = steps[-1]
    return float(np.mean(values[steps >= last - FINAL_FRACTION * (last - steps[0])]))


def collapse(values: np.ndarray) -> float:
    """Largest drop of a reward curve below its running peak (0 for a curve that never falls)."""
    s = pd.Series(values)
    return float((s.cummax() - s).max()) if len(s) else np.nan


def per_run_curve_stats(histories: pd.DataFrame) -> pd.DataFrame:
    """One row per run: final value of each FINALS curve (NaN for a curve the run did not log), collapse of the
    reward curve, and ``at_bound``: the share of RECOM's LR updates clipped to a bound (mean of the recom/at_bound
    history; NaN without one)."""
    rows = []
    for run_id, h in histories.groupby("run_id"):
        row = {"run_id": run_id}
        for column, key in FINALS.items():
            k = h[h["key"] == key]
            row[column] = final_value(k["step"].to_numpy(), k["value"].to_numpy())
        row["collapse"] = collapse(h.loc[h["key"] == REWARD, "value"].to_numpy())
        bound = h.loc[h["key"] == AT_BOUND, "value"]
        row["at_bound"] = float(bound.mean()) if len(bound) else np.nan
        rows.append(row)
    return pd.DataFrame(rows, columns=["run_id", *FINALS, "collapse", "at_bound"])


def segment_rewards(histories: pd.DataFrame, runs: pd.DataFrame) -> pd.DataFrame:
    """One row per run and wind segment k (the schedule's k-th hold of ``segment_steps`` timesteps): the mean of
    ``rollout/ep_rew_mean`` logged at steps in (k S, (k+1) S] (a value logged at the end of a rollout covers the
    episodes that rollout finished; a rollout that ends past total_timesteps counts in the last segment). Columns run_id, segment, start, end, speed, reward."""
    rows = []
    rewards = histories[histories["key"] == REWARD]
    for run in runs.itertuples():
        h = rewards[rewards["run_id"] == run.run_id]
        length = run.segment_steps
        if not len(h) or not np.isfinite(length) or length <= 0:
            continue
        steps = h["step"].to_numpy(dtype=float)
        total = pd.to_numeric(getattr(run, "total_timesteps", None), errors="coerce")
        if np.isfinite(total):  # the last rollout may end past total_timesteps: it belongs to the last segment
            steps = np.minimum(steps, total)
        segment = np.ceil(steps / length).astype(int) - 1  # step S -> 0, S + 1 -> 1
        speeds = list(run.speeds) or [np.nan]
        for k in np.unique(segment[segment >= 0]):
            rows.append({"run_id": run.run_id, "segment": int(k), "start": int(k * length),
                         "end": int((k + 1) * length), "speed": float(speeds[k % len(speeds)]),
                         "reward": float(h["value"].to_numpy()[segment == k].mean())})
    return pd.DataFrame(rows, columns=["run_id", "segment", "start", "end", "speed", "reward"])


SEGMENT_COLUMNS = ["run_id", "segment", "start", "end_step", "auc", "end", "n_evals", "hover_after", "distance_auc",
                   "distance_end"]


def segment_evaluations(histories: pd.DataFrame, runs: pd.DataFrame) -> pd.DataFrame:
    """Per run and segment k (the k-th hold of the run's ``wind.segment_steps``; a vehicle schedule on another clock is
    not split by it: give it the same ``segment_steps``): the in-training evaluations logged
    at steps in (k S, (k+1) S]. A run's last update ends past ``train.total_timesteps`` (a rollout is not cut), so
    its final evaluation may be logged in the next segment: under a fixed condition it counts in the last segment;
    under eval.condition=current it flew under that next condition (the one at its step - 1: evaluate.py), which the
    run never learned, and is left out. ``auc``: the area under the
    eval-success curve within the segment, normalised by its length (the evaluations are evenly spaced, so their
    mean); ``end``: the success of the segment's last evaluation; ``n_evals``; ``hover_after``: the timesteps from
    the segment's start to its first evaluation at >= HOVER success (NaN if none); ``distance_auc`` and
    ``distance_end``: the same area and last value for the evaluations' mean final distance to the target
    (EVAL_DISTANCE, metres, lower is better; NaN where a run did not log it at those steps), the continuous
    reading of the same evaluations. Segments with no evaluation are left out. Columns run_id, segment, start,
    end_step, auc, end, n_evals, hover_after, distance_auc, distance_end."""
    rows = []
    evals = histories[histories["key"] == EVAL_SUCCESS]
    distances = histories[histories["key"] == EVAL_DISTANCE]
    for run in runs.itertuples():
        h = evals[evals["run_id"] == run.run_id].sort_values("step")
        logged = distances[distances["run_id"] == run.run_id]
        distance = (pd.Series(logged["value"].to_numpy(dtype=float), index=logged["step"].to_numpy())
                    .reindex(h["step"].to_numpy()).to_numpy(dtype=float))   # at the success' steps
        length = run.segment_steps
        if not len(h) or not np.isfinite(length) or length <= 0:
            continue
        steps, values = h["step"].to_numpy(dtype=float), h["value"].to_numpy(dtype=float)
        total = pd.to_numeric(getattr(run, "total_timesteps", None), errors="coerce")
        current = getattr(run, "eval_condition", None) == "current"
        if np.isfinite(total) and not current:
            steps = np.minimum(steps, total)
        segment = np.ceil(steps / length).astype(int) - 1
        if np.isfinite(total) and current:
            segment[segment >= np.ceil(total / length)] = -1   # flown under a condition the run did not train on
        for k in np.unique(segment[segment >= 0]):
            v, at, d = values[segment == k], steps[segment == k], distance[segment == k]
            hovered = at[v >= HOVER]
            rows.append({"run_id": run.run_id, "segment": int(k), "start": int(k * length),
                         "end_step": int((k + 1) * length), "auc": float(v.mean()), "end": float(v[-1]),
                         "n_evals": int(len(v)),
                         "hover_after": float(hovered[0] - k * length) if len(hovered) else np.nan,
                         "distance_auc": float(d.mean()), "distance_end": float(d[-1])})
    return pd.DataFrame(rows, columns=SEGMENT_COLUMNS)


def mean_t_ci(values) -> tuple[float, float, int]:
    """(mean, half-width of the 95% Student-t CI, n) of the finite values; half-width NaN for n < 2."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return np.nan, np.nan, 0
    if len(x) < 2:
        return float(x.mean()), np.nan, 1
    half = stats.t.ppf(0.975, len(x) - 1) * stats.sem(x) if np.ptp(x) > 0 else 0.0
    return float(x.mean()), float(half), len(x)


def iqm_ci(scores) -> tuple[float, float, float]:
    """rliable IQM of per-run scores and its 95% stratified-bootstrap CI (NaN CI for fewer than 2 runs)."""
    x = np.asarray(scores, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return np.nan, np.nan, np.nan
    point = float(metrics.aggregate_iqm(x[:, None]))
    if len(x) < 2:
        return point, np.nan, np.nan
    ci = _bootstrap((x,), _iqm, vectorized=True).confidence_interval
    return point, float(ci.low), float(ci.high)


def iqm_diff_ci(scores_x, scores_y) -> tuple[float, float, float]:
    """IQM(X) - IQM(Y) over runs and its 95% percentile-bootstrap CI (both samples resampled independently;
    NaN CI if either has fewer than 2 runs)."""
    x, y = (np.asarray(s, dtype=float) for s in (scores_x, scores_y))
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    if len(x) == 0 or len(y) == 0:
        return np.nan, np.nan, np.nan
    point = float(metrics.aggregate_iqm(x[:, None]) - metrics.aggregate_iqm(y[:, None]))
    if len(x) < 2 or len(y) < 2:
        return point, np.nan, np.nan

    def diff(a, b, axis=-1):
        return _iqm(a, axis) - _iqm(b, axis)

    ci = _bootstrap((x, y), diff, vectorized=True, paired=False).confidence_interval
    return point, float(ci.low), float(ci.high)


def mean_diff_ci(scores_x, scores_y) -> tuple[float, float, float]:
    """mean(X) - mean(Y) over runs and its 95% percentile-bootstrap CI (both samples resampled independently;
    NaN CI if either has fewer than 2 runs)."""
    x, y = (np.asarray(s, dtype=float) for s in (scores_x, scores_y))
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    if len(x) == 0 or len(y) == 0:
        return np.nan, np.nan, np.nan
    point = float(x.mean() - y.mean())
    if len(x) < 2 or len(y) < 2:
        return point, np.nan, np.nan

    def diff(a, b, axis=-1):
        return a.mean(axis=axis) - b.mean(axis=axis)

    ci = _bootstrap((x, y), diff, vectorized=True, paired=False).confidence_interval
    return point, float(ci.low), float(ci.high)


def paired_diff_ci(scores_x: pd.Series, scores_y: pd.Series) -> tuple[float, float, float, int]:
    """mean(X_s - Y_s) over the seeds s both have (two Series indexed by seed), its 95% percentile-bootstrap CI
    resampling the pairs (NaN CI below 2 pairs), and the number of pairs."""
    both = pd.concat([scores_x.rename("x"), scores_y.rename("y")], axis=1, join="inner").dropna()
    d = (both["x"] - both["y"]).to_numpy(dtype=float)
    if len(d) == 0:
        return np.nan, np.nan, np.nan, 0
    if len(d) < 2:
        return float(d.mean()), np.nan, np.nan, 1
    ci = _bootstrap((d,), np.mean, vectorized=True).confidence_interval
    return float(d.mean()), float(ci.low), float(ci.high), len(d)


def poi_ci(scores_x, scores_y) -> tuple[float, float, float]:
    """rliable P(X > Y) over runs and its 95% CI (both samples resampled independently)."""
    x, y = (np.asarray(s, dtype=float) for s in (scores_x, scores_y))
    x, y = x[np.isfinite(x)], y[np.isfinite(y)]
    if len(x) == 0 or len(y) == 0:
        return np.nan, np.nan, np.nan
    point = float(metrics.probability_of_improvement(x[:, None], y[:, None]))
    if len(x) < 2 or len(y) < 2:
        return point, np.nan, np.nan
    ci = _bootstrap((x, y), _p_improve, vectorized=True, paired=False).confidence_interval
    return point, float(ci.low), float(ci.high)


HOVER = 0.5  # an evaluation "hovers" at >= 50% success (the leaderboard's primary measure)


def late_evaluations(histories: pd.DataFrame) -> pd.DataFrame:
    """Per run with evaluations during training (eval/success_rate at >= 2 steps): ``keeps_hovering``, the share
    of its evaluations in the second half of training (steps > half its last step; the end-of-run evaluation
    included) at >= HOVER success, ``late_success``, their mean success, and ``learned`` (1.0 or 0.0): whether
    any of its evaluations, early or late, reached HOVER. Outcomes on the hover task are bimodal per seed, so the
    leaderboard reads "keeps hovering" apart as the share of seeds that learned the hover and what they kept."""
    ev = histories[histories["key"] == EVAL_SUCCESS]
    rows = []
    for run_id, h in ev.groupby("run_id"):
        if h["step"].nunique() < 2:
            continue
        values = h["value"].to_numpy(dtype=float)
        late = h.loc[h["step"] > h["step"].max() / 2, "value"].to_numpy(dtype=float)
        rows.append({"run_id": run_id, "keeps_hovering": float(np.mean(late >= HOVER)),
                     "late_success": float(np.mean(late)), "late_evaluations": len(late),
                     "learned": float(np.max(values) >= HOVER)})
    return pd.DataFrame(rows, columns=["run_id", "keeps_hovering", "late_success", "late_evaluations", "learned"])


def performance_profile(scores, taus: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """rliable's performance profile of per-run ``scores``: the share of runs with score > tau for each tau, and
    its 95% percentile-bootstrap band over runs (rliable's ``create_performance_profile`` with one task; its
    ``library`` module cannot be imported here, see the module docstring)."""
    x = np.asarray(scores, dtype=float)
    x = x[np.isfinite(x)]
    point = (x[:, None] > taus[None, :]).mean(axis=0)
    if len(x) < 2:
        return point, np.full_like(point, np.nan), np.full_like(point, np.nan)
    rng = np.random.default_rng(RNG_SEED)
    resampled = x[rng.integers(0, len(x), (RESAMPLES, len(x)))]
    curves = (resampled[:, :, None] > taus[None, None, :]).mean(axis=1)
    return point, np.percentile(curves, 2.5, axis=0), np.percentile(curves, 97.5, axis=0)
