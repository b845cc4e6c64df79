"""Re-evaluation: fly a finished run's stored policies under another evaluation protocol, without training again.

    python -m sweep.reevaluate --experiment remedies --where wind=none --name still_air eval.wind_speed=0

A run is evaluated under the protocol it was trained with (``eval.*``: e.g. the paper's 3 m/s wind, whatever the
training wind). This flies each stored policy of every FINISHED run of ``--experiment`` whose tags or params match
every ``--where KEY=VALUE`` (``agent``, ``wind``, ``seed`` or a flattened config name such as ``agent.ppo.lr``) with
the run's own config and the ``eval.*`` overrides given, and

* logs the scores to that run under ``<name>/<policy prefix>/<field>`` (``still_air/eval/success_rate``,
  ``still_air/eval_best/crash_rate``, ...: the ``sweep.metrics`` eval keys behind ``<name>/``) at the step of its
  final evaluation, with the overrides as the tag ``reeval.<name>`` (the run stays FINISHED, its other metrics
  untouched);
* prints, and with ``--out`` writes as Markdown, one row per agent: seeds, each policy's success rate (seed mean ±
  95% Student-t CI, then per seed in brackets), with ``--vs AGENT`` the difference of the final and best policies'
  mean success to that agent's [95% bootstrap CI], and the final policy's crash rate.

The stored policies are the run artifacts ``model.zip`` (final), ``model_best.zip`` and ``model_best_eval.zip``
(``sweep.best_policy``), kept when ``tracking.log_model`` is true; a run without them (e.g. one imported from a
study archive without ``--artifacts model*``) is skipped and named. They load with SB3's ``PPO.load`` for both
learners (the JAX learner saves its policy as an SB3 model), so a JAX run's flights use torch's forward pass: under
its own protocol its re-evaluation matches its logged evaluation up to float rounding (tests/test_reevaluate.py).
Only ``eval.*`` keys may change: the policy was trained under the rest.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from omegaconf import DictConfig, OmegaConf
from stable_baselines3 import PPO

from sweep import metrics
from sweep.config import ConfigError, validate_section
from sweep.evaluate import evaluate
from sweep.report import stats
from sweep.report.tables import markdown
from sweep.tracking import (WHERE_TAGS, add_to_finished_run, download_artifact, finished_runs, parse_where,
                            run_matches, tracking_uri)

CONFIG = "config.yaml"
MODELS = {policy: "model.zip" if policy == "final" else f"model_{policy}.zip" for policy in metrics.POLICIES}


def parse_overrides(items: list[str]) -> DictConfig:
    for item in items:
        key = item.partition("=")[0]
        if "=" not in item or not key.startswith("eval.") or key == "eval.":
            raise ConfigError(f"{item!r}: only eval.* overrides (KEY=VALUE, e.g. eval.wind_speed=0) may change; "
                              "the policy was trained under the rest of its config")
    return OmegaConf.from_dotlist(items)


def select(uri: str, experiment: str, where: dict[str, str]) -> list[tuple[str, dict[str, str], dict[str, str]]]:
    """(run id, params, tags) of the FINISHED runs of ``experiment`` that match ``where``, oldest first."""
    runs = finished_runs(uri, experiment)
    known = set(WHERE_TAGS).union(*(params for _, params, _ in runs))
    for key in where:
        if key not in known:
            raise ConfigError(f"--where {key}: no run of {experiment!r} has that tag or param "
                              "(agent, wind, seed or a flattened config name, e.g. agent.ppo.lr)")
    chosen = [run for run in runs if run_matches(run[1], run[2], where)]
    if not chosen:
        raise ConfigError(f"no FINISHED run of {experiment!r} matches "
                          + (" ".join(f"{k}={v}" for k, v in where.items()) or "(no --where)"))
    return chosen


def run_config(stored: Path, overrides: DictConfig) -> DictConfig:
    """The run's own config with the ``eval.*`` overrides, its ``eval`` block checked like a new run's (ConfigError;
    the rest is the run's as it trained, which may predate keys added since)."""
    cfg = OmegaConf.merge(OmegaConf.load(stored), overrides)
    validate_section(cfg, "eval")
    return cfg


def reevaluate_run(uri: str, run_id: str, overrides: list[str], name: str, work: Path) -> dict[str, dict] | None:
    """Fly the run's stored policies under its protocol with the ``eval.*`` ``overrides``; {policy: scores},
    logged to the run under ``<name>/``. None if the run stored no config or no model."""
    config = download_artifact(uri, run_id, CONFIG, work)
    if config is None:
        return None
    cfg = run_config(config, parse_overrides(overrides))
    scores = {}
    for policy, artifact in MODELS.items():
        path = download_artifact(uri, run_id, artifact, work)
        if path is not None:
            values, _ = evaluate(PPO.load(path, device="cpu"), cfg.eval, cfg.env)
            scores[policy] = values
    if not scores:
        return None
    logged = {f"{name}/{metrics.eval_key(policy, field)}": value
              for policy, values in scores.items() for field, value in values.items()}
    add_to_finished_run(uri, run_id, logged, {f"reeval.{name}": " ".join(overrides) or "(own protocol)"},
                        step_of=metrics.eval_key("final", "success_rate"))
    return scores


def table(rows: pd.DataFrame, vs: str | None = None) -> pd.DataFrame:
    """One row per agent: seeds, success rate (%) of each policy (seed mean ± 95% Student-t CI, per seed), with
    ``vs`` (an agent) the difference of the final and best policies' mean success to that agent's [95% bootstrap
    CI] (``sweep.report.stats``), and the final crash rate."""
    rows = rows.sort_values("seed")
    base = rows[rows["agent"] == vs] if vs else None
    out = []
    for agent, runs in rows.groupby("agent", sort=False):
        row = {"Agent": runs["label"].iloc[-1], "Seeds": len(runs)}
        for policy in MODELS:
            column = f"{policy}_success_rate"
            if column in runs and runs[column].notna().any():
                mean, half, _ = stats.mean_t_ci(100 * runs[column])
                per_seed = ", ".join("–" if np.isnan(v) else f"{100 * v:.0f}" for v in runs[column])
                row[f"Success {policy} (%) (per seed)"] = (f"{mean:.0f}" + (f" ± {half:.0f}" if np.isfinite(half) else "")
                                                           + f" ({per_seed})")
        if base is not None:
            for policy in ("final", "best"):
                column = f"{policy}_success_rate"
                if agent != vs and column in runs and column in base:
                    point, lo, hi = stats.mean_diff_ci(100 * runs[column], 100 * base[column])
                    row[f"Δ {policy} vs {base['label'].iloc[-1]} (pp)"] = f"{point:.0f} [{lo:.0f}, {hi:.0f}]"
                else:
                    row[f"Δ {policy} vs {base['label'].iloc[-1]} (pp)"] = "–"
        row["Crash final (%)"] = f"{100 * runs['final_crash_rate'].mean():.0f}"
        out.append(row)
    return pd.DataFrame(out).sort_values("Agent", key=lambda c: c.str.casefold(), kind="stable")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sweep.reevaluate", description=__doc__.split("\n\n")[0])
    parser.add_argument("overrides", nargs="*", help="eval.* overrides, e.g. eval.wind_speed=0 eval.episodes=20")
    parser.add_argument("--experiment", required=True, help="the MLflow experiment of the runs")
    parser.add_argument("--where", action="append", default=[], metavar="KEY=VALUE",
                        help="only runs with this tag (agent, wind, seed) or param; repeat to require several")
    parser.add_argument("--name", required=True, help="the metric prefix of these scores, e.g. still_air")
    parser.add_argument("--vs", metavar="AGENT", help="add each agent's success difference to this agent's, e.g. ppo")
    parser.add_argument("--out", type=Path, help="also write the table to this Markdown file")
    parser.add_argument("--uri", help="MLflow store (default: $MLFLOW_TRACKING_URI, else <project root>/mlflow.db)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    uri = tracking_uri(args.uri)
    try:
        if not args.name.replace("_", "").isalnum() or args.name in metrics.POLICIES.values():
            raise ConfigError(f"--name {args.name!r}: letters, digits and _ only, not an eval prefix "
                              f"({', '.join(metrics.POLICIES.values())})")
        overrides = parse_overrides(args.overrides)
        runs = select(uri, args.experiment, parse_where(args.where))
        if args.vs and args.vs not in {tags.get("agent") for _, _, tags in runs}:
            raise ConfigError(f"--vs {args.vs}: none of the selected runs is of that agent (the tag agent, e.g. ppo)")
        rows, skipped = [], []
        with tempfile.TemporaryDirectory() as tmp:
            first = download_artifact(uri, runs[0][0], CONFIG, Path(tmp) / "check")
            if first is not None:
                run_config(first, overrides)  # a bad override value fails before any flight
            for i, (run_id, params, tags) in enumerate(runs):
                scores = reevaluate_run(uri, run_id, args.overrides, args.name, Path(tmp) / str(i))
                name = tags.get("run_name", run_id[:8])
                if scores is None:
                    skipped.append(name)
                    continue
                row = {"run": name, "agent": tags.get("agent"), "seed": int(tags.get("seed", -1)),
                       "label": tags.get("agent_label") or params.get("agent.label") or tags.get("agent")}
                row |= {f"{p}_{field}": v for p, values in scores.items() for field, v in values.items()}
                rows.append(row)
                print(f"reevaluate: {name}: " + ", ".join(f"{p} success {100 * v['success_rate']:.0f}%"
                                                            for p, v in scores.items()), flush=True)
    except (ConfigError, ValueError) as err:
        print(f"reevaluate: {err}", file=sys.stderr)
        return 2
    if skipped:
        print(f"reevaluate: skipped {len(skipped)} run(s) without a stored config or model: {', '.join(skipped)}",
              file=sys.stderr)
    if not rows:
        return 1
    text = (f"Re-evaluation {args.name!r} ({' '.join(args.overrides) or 'the runs’ own protocol'}) of "
            f"{len(rows)} run(s) of {args.experiment!r}" + (f" with {' '.join(args.where)}" if args.where else "")
            + "\n\n" + markdown(table(pd.DataFrame(rows), args.vs)))
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(f"# {text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
