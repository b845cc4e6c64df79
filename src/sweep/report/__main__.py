"""CLI: build every figure and table of one experiment; errors are one line on stderr and exit code 1.

Interval-estimate figures first (intervals.py): interval_keeps_hovering, interval_success_final,
interval_success_best, interval_final_reward, one panel per arm (wind x --by values). The curves below draw a
--by split as small multiples (conditions.Conditions.panels) and, with more than 6 agents in a panel, only the
--top agents of each panel, PPO and --highlight agents in colour (highlight.py).
Figures (PNG + PDF; --draft: PNG only, at 100 dpi) per training wind W: reward_W, episode_length_W, dormant_W (the
policy's readings, a panel each: Sokar's dormant share at plasticity.tau and at 0.1, dead tanh units, signed mean
≈ 0, saturated activations; those the runs logged), weight_norm_W, ppo_update_W (policy std, approx KL, clip fraction),
learning_rate_W, eval_success_W, eval_crash_W and eval_distance_W (only if runs evaluated during training,
eval.every_timesteps > 0); eval_flights_3d and eval_position_axes (the final policy's flights; the best policy's
where no run evaluated its final policy). Tables: table3.{md,tex,csv} (evaluation under wind of the final policy
and of the best one kept during training, side by side, and the top seed's numbers), summary.{md,csv} (training
outcome per condition), segments.{md,csv} (training reward in each hold of the wind schedule), leaderboard.{md,csv}
(runs evaluated during training; sorted by "keeps hovering"), versus.{md,csv} (with --vs: each agent against
reference agents on that measure). Runs evaluated in two segments of the schedule or more (the plasticity study)
add segment_scores.{md,csv} and the figures segment_scores (the AUC per segment against reset_all, a column per
wind) and segment_scores_end (the same for the success at each segment's end), the AUC over the seeds that
learned segment 0 (segment_scores_learned.{md,csv,png}), segment_runs.csv (every run's segments),
relearning.{md,csv} (sorted by the re-learning AUC, relearning.py; with the rank correlation of the probe and
the network's readings to it, reading_correlation.csv and the figure readings_<wind>; every run's measures and
readings in relearning_runs.csv), interval_relearning and interval_relearning_distance (the same flights' mean
final distance). Agents whose fresh twins ran beside them (twin=fresh; PPO's
is reset_all) add twins.{md,csv} and the figure twins (each agent against its own twin, paired by seed: twins.py).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def build(experiment: str | None, sweep: str | None, out: str | None, by: list[str] = (),
          baseline: str | None = None, at: list[int] = (), agents: list[str] = (), vs: list[str] = (),
          highlight: list[str] = (), top: int = 3, draft: bool = False) -> Path:
    from mlflow.exceptions import MlflowException

    from sweep import metrics
    from sweep.config import one_line
    from sweep.report import (conditions, figures, highlight as emphasis, intervals, load, relearning, stats, style,
                              tables, twins)

    uri = load.tracking_uri()
    try:
        client = load.client_for(uri)
        exp_id, exp_name = load.pick_experiment(client, experiment)
        loaded = load.read_runs(client, exp_id, sweep, by, exp_name)
    except MlflowException as err:
        raise load.ReportError(f"cannot read the MLflow store {uri}: {one_line(err)}") from err
    runs, notes = loaded.runs, loaded.notes
    curves, hook_notes = load.hook_curves(runs)
    metrics.register(curves)   # what the runs' own hooks log (a diagnostic's curves), drawn like the report's own
    for note in notes + hook_notes:
        print(f"sweep.report: note: {note}")
    if runs.empty:
        where = f" of sweep {sweep!r}" if sweep else ""
        raise load.ReportError(f"experiment {exp_name!r}{where} has no finished runs in {uri}")
    if agents:
        unknown = sorted(set(agents) - set(runs["agent"]))
        if unknown:
            raise load.ReportError(f"--agents {','.join(unknown)}: no finished runs of experiment {exp_name!r}; it has "
                                   f"{', '.join(sorted(set(runs['agent'])))}")
        runs = runs[runs["agent"].isin(agents)].reset_index(drop=True)
    for flag, names in (("--vs", vs), ("--highlight", highlight)):
        unknown = sorted(set(names) - set(runs["agent"]))
        if unknown:
            raise load.ReportError(f"{flag} {','.join(unknown)}: no finished runs of that agent in experiment "
                                   f"{exp_name!r}{' among --agents' if agents else ''}; it has "
                                   f"{', '.join(sorted(set(runs['agent'])))}")
    if top < 1:
        raise load.ReportError(f"--top {top}: must be at least 1 (the conditions of each panel drawn in colour)")
    runs, by, split = load.split_learners(runs, list(by))
    if split:
        print(f"sweep.report: note: {split}")
    runs, conds = conditions.build(runs, by)
    base = conditions.parse_baseline(baseline, conds) if baseline is not None else None

    out_dir = Path(out) if out else Path("reports") / exp_name
    out_dir.mkdir(parents=True, exist_ok=True)
    print(f"sweep.report: experiment {exp_name!r}: {len(runs)} finished runs from {uri}")
    made = tables.provenance(runs)
    if made:
        print("sweep.report: " + made.strip())
    for missing in missing_conditions(loaded.asked, agents):
        print(f"sweep.report: missing: {missing}")

    histories = load.load_histories(client, runs)
    for key in metrics.CURVE_KEYS:
        lacking = runs.loc[~runs["run_id"].isin(histories.loc[histories["key"] == key, "run_id"]), "run_name"]
        if len(lacking):
            print(f"sweep.report: missing: {key} history in {', '.join(lacking)}")
    style.apply(draft)
    per_run, late = stats.per_run_curve_stats(histories), stats.late_evaluations(histories)
    evals = stats.segment_evaluations(histories, runs)
    relearn = relearning.per_run(evals, runs)   # runs evaluated under the condition being learned, after a change
    shown = emphasis.choose(emphasis.ranking(runs, per_run, late, relearn), runs, conds, top, list(highlight))
    per_run_all = (runs.merge(per_run, on="run_id", how="left").merge(late, on="run_id", how="left")
                   .merge(relearn, on="run_id", how="left"))
    written = []
    for name in intervals.MEASURES:
        written += intervals.interval_figure(per_run_all, name, conds, out_dir)
    for wind in sorted(runs["wind"].unique()):
        for stem in figures.CURVES:
            written += figures.curve_figure(runs, histories, wind, stem, conds, shown, out_dir)
    for wind in sorted(runs["wind"].unique()):
        written += figures.performance_profile(runs, late, wind, conds, shown, out_dir)
    scores = None   # per segment against reset_all: the figure here, the table in write_tables
    if len(evals) and (evals.groupby("run_id")["segment"].nunique() > 1).any():
        scores = tables.segment_scores(runs, evals, conds)
        written += figures.segment_scores(scores[0], conds, shown, out_dir)
        written += figures.segment_scores(scores[0], conds, shown, out_dir, name="segment_scores_end", measure="end")

    wind, picked, policy = figures.eval_runs(runs)
    coloured = [shown.is_coloured(wind, conds.agent(c)) for c in picked.index]
    if not all(coloured):
        print(f"sweep.report: note: the flight figures show the agents the curves of wind {wind!r} draw in colour "
              f"(--top {top}, PPO, --highlight), not the {len(coloured) - sum(coloured)} grey conditions")
    picked = picked[coloured]
    if policy != "final":
        print(f"sweep.report: note: no run trained with wind {wind!r} evaluated its final policy (eval.policy=best): "
              f"the flight figures show the {figures.POLICY_NAMES[policy]}")
    trajs = {}
    for cond, run in picked.iterrows():
        t = load.load_trajectories(client, run["run_id"], policy)
        if t is None:
            print(f"sweep.report: missing: {load.trajectories_name(policy)} of {run['run_name']}")
        else:
            trajs[cond] = t
    if trajs:
        radius = float(picked["success_radius"].astype(float).iloc[0]) if picked["success_radius"].notna().any() \
            else np.nan
        written += figures.flights_3d(trajs, picked, wind, conds, out_dir, policy)
        written += figures.position_axes(trajs, picked, wind, conds, radius, out_dir, policy)

    written += tables.write_tables(runs, histories, conds, out_dir, base, at, late, vs, per_run, evals, scores)
    written += relearning.write(runs, per_run, histories, evals, relearn, conds, shown, out_dir, vs)
    written += relearning.write_learned(runs, evals, relearn, conds, shown, out_dir)
    written += twins.write(runs, evals, relearn, conds, shown, out_dir)
    print(f"sweep.report: wrote {len(written)} files")
    print("\n" + (out_dir / "brief.txt").read_text())
    print("Figures to open:\n" + "\n".join(f"  {p.resolve()}" for p in written if p.suffix == ".png"))
    return out_dir.resolve()


def missing_conditions(asked, agents=()) -> list[str]:
    """One line per cell a sweep asked for without a finished run (``load.read_runs``: a run that did not finish,
    a multirun job that failed before its run existed), grouped over seeds; of ``agents`` only if given. Agents
    nobody ran are not named: the report does not guess a design."""
    from sweep.report.load import CELL, NA

    if agents:
        asked = asked[asked["agent"].isin(agents)]
    by = [c for c in asked.columns if c not in (*CELL, "what")]
    lines = []
    for cell, group in asked.groupby(["agent", *by, "wind", "learner"], sort=True):
        values = dict(zip(["agent", *by, "wind", "learner"], cell))
        text = " ".join(f"{k}={v}" for k, v in values.items() if v != NA)
        seeds = ",".join(str(s) for s in sorted(group["seed"]))
        lines.append(f"{text} seed={seeds} (no finished run: {'; '.join(group.sort_values('seed')['what'])})")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sweep.report", description=__doc__)
    parser.add_argument("--experiment", help="MLflow experiment (default: the one whose latest run started last)")
    parser.add_argument("--sweep", help="only runs of this sweep: its directory, or a substring of the 'sweep' tag")
    parser.add_argument("--out", help="output folder (default: reports/<experiment>/)")
    parser.add_argument("--agents", metavar="NAME[,NAME...]", type=lambda s: [a for a in s.split(",") if a], default=[],
                        help="only these agents' runs (conf/agent names), e.g. ppo,recom_l2_relative for curves of "
                             "the top agents against PPO")
    parser.add_argument("--by", metavar="KEY[,KEY...]", type=lambda s: [k for k in s.split(",") if k], default=[],
                        help="split each agent's runs by the values of these logged params (flattened config "
                             "names, e.g. agent.l2.coef,agent.l2.mode or agent.learner); a condition is then "
                             "(agent, values), labelled e.g. 'L2 + PPO (coef=0.001, mode=decoupled)'. A setting of "
                             "a disabled component (agent.l2.* of PPO) does not apply and does not split")
    parser.add_argument("--baseline", metavar="KEY=VALUE",
                        help="with --by: add 'Δ IQM vs KEY=VALUE [95%% CI]' to the summary, each condition's IQM of "
                             "the final reward minus that of the condition with KEY=VALUE and otherwise the same "
                             "agent, --by values and wind (KEY: agent or a --by key), e.g. agent=ppo or "
                             "agent.learner=sb3")
    parser.add_argument("--at", metavar="STEP[,STEP...]", default=[],
                        type=lambda s: [int(float(x)) for x in s.split(",") if x],
                        help="also write reward_at.md/.csv: the IQM [95%% CI] of the training reward at these "
                             "timesteps (and with --baseline the IQM difference to the baseline), e.g. "
                             "--at 100000,250000,500000")
    parser.add_argument("--vs", metavar="NAME[,NAME...]", type=lambda s: [a for a in s.split(",") if a], default=[],
                        help="also write versus.md/.csv: every agent against each of these reference agents on the "
                             "leaderboard's primary measure (P(> reference) and the difference of means, each with "
                             "its 95%% CI), e.g. ppo,l2_lr_decay,ppo_target_kl; runs scored on re-learning also "
                             "get these columns on the re-learning AUC in relearning.md")
    parser.add_argument("--highlight", metavar="NAME[,NAME...]", type=lambda s: [a for a in s.split(",") if a],
                        default=[], help="with more than 6 agents in a panel, draw these agents in colour with "
                        "their bands too (besides PPO, reset_all and the --top agents of each panel; the rest grey)")
    parser.add_argument("--top", type=int, default=3, metavar="N",
                        help="with more than 6 agents in a panel, the N best of each panel by the leaderboard's "
                             "primary measure are drawn in colour (default 3)")
    parser.add_argument("--draft", action="store_true",
                        help="figures as PNG only at 100 dpi (about 3x faster): a quick look at a study; without "
                             "it, PNG at 300 dpi and PDF for the paper")
    args = parser.parse_args(argv)
    from sweep.report.load import ReportError

    try:
        out = build(args.experiment, args.sweep, args.out, args.by, args.baseline, args.at, args.agents, args.vs,
                    args.highlight, args.top, args.draft)
    except ReportError as err:
        print(f"sweep.report: {err}", file=sys.stderr)
        return 1
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
