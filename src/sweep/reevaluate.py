"""Re-evaluation: fly a finished run's stored policies under another evaluation protocol, without training again.

    python -m sweep.reevaluate --experiment remedies --where wind=none --name still_air --vs ppo eval.wind_speed=0

A run is evaluated under the protocol it was trained with (``eval.*``: e.g. the paper's 3 m/s wind, whatever the
training wind). This flies each stored policy of every FINISHED run of ``--experiment`` whose tags or params match
every ``--where KEY=VALUE`` (``agent``, ``wind``, ``seed`` or a flattened config name such as ``env.n_envs``, matched
as the logged string) with the run's own config and the ``eval.*`` overrides given, and

* logs the scores to that run under ``<name>/<policy prefix>/<field>`` (``still_air/eval/success_rate``,
  ``still_air/eval_best/crash_rate``, ...: the ``sweep.metrics`` eval keys behind ``<name>/``) at the step of its
  final evaluation, with the overrides as the tag ``reeval.<name>`` (the run stays FINISHED, its other metrics
  untouched);
* prints, and with ``--out`` writes as Markdown, one row per agent (and wind): seeds, each policy's success rate
  (seed mean ± 95% Student-t CI, then per seed in parentheses), with ``--vs AGENT`` the difference of the final and
  best policies' mean success to that agent's [95% bootstrap CI], and the final policy's crash rate. Like the
  report, it keeps the newest run of an agent, wind and seed run more than once (the older ones are named).

The stored policies are the run artifacts ``model.zip`` (final), ``model_best.zip`` and ``model_best_eval.zip``
(``sweep.best_policy``), kept when ``tracking.log_model`` is true; a run without them (e.g. one imported from a
study archive without ``--artifacts model*``) is skipped and named. They load with SB3's ``PPO.load`` (``SAC.load``,
``TD3.load`` for the off-policy agents' runs) for both
learners (the JAX learner saves its policy as an SB3 model), so a JAX run's flights use torch's forward pass: under
its own protocol its re-evaluation matches its logged evaluation up to float rounding (tests/test_reevaluate.py).
Only the eval keys a flight depends on may change (``FLIGHT_KEYS``): the policy was trained under the rest. Every
run's config is checked before the first flight, so bad input is one line, exit code 2, nothing flown or logged.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from omegaconf import DictConfig, OmegaConf
from stable_baselines3 import PPO, SAC, TD3

from sweep import metrics
from sweep.config import ConfigError, algorithm_of, validate_section
from sweep.evaluate import evaluate, flight_conditions
from sweep.report import stats
from sweep.report.load import agent_label
from sweep.report.tables import interval, markdown, plus_minus
from sweep.tracking import add_to_finished_run, download_artifacts, finished_runs, parse_where, tracking_uri

ALGORITHM_CLASSES = {"ppo": PPO, "sac": SAC, "td3": TD3}   # the SB3 class that loads a run's model*.zip

CONFIG = "config.yaml"
MODELS = {policy: "model.zip" if policy == "final" else f"model_{policy}.zip" for policy in metrics.POLICIES}
# The eval keys a flight depends on; eval.policy and eval.every_timesteps say what training kept and when it flew.
FLIGHT_KEYS = ("condition", "wind_speed", "direction", "gust", "mass", "rotor_efficiency", "episodes", "seed",
               "success_radius", "success_hold_s")


@dataclass
class StoredRun:
    """A finished run to fly again: who it is, its config with the overrides, and its downloaded models."""
    run_id: str
    name: str
    agent: str
    wind: str
    seed: int
    label: str
    cfg: DictConfig
    models: dict[str, Path]  # policy (metrics.POLICIES key) -> model file


# eval keys added with eval.condition (issue 33): what a run stored before them flew under
EVAL_BEFORE_CONDITIONS = {"condition": "fixed", "gust": 0.0, "mass": 1.0, "rotor_efficiency": [1.0, 1.0, 1.0, 1.0]}


def parse_overrides(items: list[str]) -> DictConfig:
    """``["eval.wind_speed=0", ...]`` as a config to merge onto a run's; ConfigError for any key but
    ``eval.<FLIGHT_KEYS>`` (the policy was trained under the rest of its config)."""
    for item in items:
        key = item.partition("=")[0]
        if "=" not in item or not key.startswith("eval.") or key.removeprefix("eval.") not in FLIGHT_KEYS:
            raise ConfigError(f"{item!r}: only eval.KEY=VALUE overrides, KEY one of {', '.join(FLIGHT_KEYS)}; "
                              "the policy was trained under the rest of its config")
    return OmegaConf.from_dotlist(items)


def run_config(stored: Path, overrides: DictConfig) -> DictConfig:
    """The run's own config with the ``eval.*`` overrides, its ``eval`` block checked like a new run's (ConfigError;
    the rest is the run's as it trained, which may predate keys added since)."""
    cfg = OmegaConf.merge({"eval": EVAL_BEFORE_CONDITIONS}, OmegaConf.load(stored), overrides)
    validate_section(cfg, "eval")
    return cfg


def prepare(uri: str, runs: list[tuple[str, dict[str, str], dict[str, str]]], overrides: DictConfig,
            work: Path, policies: tuple[str, ...] = tuple(MODELS)) -> tuple[list[StoredRun], list[str], list[str]]:
    """Download every run's config and models and check its eval block with the overrides, before any flight:
    (the newest run of each agent, wind and seed that stored a config and a model, the names of the runs without
    them, the names of the older runs of a repeated agent/wind/seed, left out like the report leaves them out)."""
    stored, skipped = {}, []
    for i, (run_id, params, tags) in enumerate(runs):
        name, agent = tags.get("run_name", run_id[:8]), tags.get("agent", "?")
        files = download_artifacts(uri, run_id, [CONFIG, *(MODELS[p] for p in policies)], work / str(i))
        models = {policy: files[MODELS[policy]] for policy in policies if MODELS[policy] in files}
        if CONFIG not in files or not models:
            skipped.append(name)
            continue
        run = StoredRun(run_id, name, agent, metrics.condition_arm(tags), int(tags.get("seed", -1)),
                        agent_label(agent, tags, params), run_config(files[CONFIG], overrides), models)
        stored.setdefault((run.agent, run.wind, run.seed), []).append(run)  # runs come oldest first
    older = [r.name for same in stored.values() for r in same[:-1]]
    return [same[-1] for same in stored.values()], skipped, older


def fly_and_log(uri: str, run: StoredRun, name: str, overrides: list[str]) -> dict[str, dict[str, float]]:
    """Fly the run's stored policies under its (overridden) protocol; {policy: scores}, logged to the run under
    ``<name>/`` at the step of its final evaluation, with the overrides as the tag ``reeval.<name>``."""
    total = int(run.cfg.train.total_timesteps)
    conditions = flight_conditions(run.cfg.eval, run.cfg.get("wind"), run.cfg.get("vehicle"), total, total)
    cls = ALGORITHM_CLASSES[algorithm_of(run.cfg.get("agent") or {})]
    scores = {policy: evaluate(cls.load(path, device="cpu"), run.cfg.eval, run.cfg.env, conditions)[0]
              for policy, path in run.models.items()}
    logged = {f"{name}/{metrics.eval_key(policy, key)}": value
              for policy, values in scores.items() for key, value in values.items()}
    add_to_finished_run(uri, run.run_id, logged, {f"reeval.{name}": " ".join(overrides) or "(own protocol)"},
                        step_of=metrics.eval_key("final", "success_rate"))
    return scores


def table(rows: pd.DataFrame, vs: str | None = None) -> pd.DataFrame:
    """One row per agent (and wind, where the rows have several): seeds, success rate (%) of each policy (seed mean
    ± 95% Student-t CI, then per seed in parentheses), with ``vs`` (an agent) the difference of the final and best
    policies' mean success to that agent's in the same wind [95% bootstrap CI] (``sweep.report.stats``), and the
    final policy's crash rate."""
    rows = rows.sort_values("seed")
    winds = rows["wind"].nunique() > 1
    vs_label = rows.loc[rows["agent"] == vs, "label"].iloc[-1] if vs in set(rows["agent"]) else vs
    out = []
    for (agent, wind), runs in rows.groupby(["agent", "wind"], sort=False):
        row = {"Agent": runs["label"].iloc[-1] + (f" (wind {wind})" if winds else ""), "Seeds": len(runs)}
        for policy in MODELS:
            column = f"{policy}_success_rate"
            if column in runs and runs[column].notna().any():
                mean, half, _ = stats.mean_t_ci(100 * runs[column])
                per_seed = ", ".join("–" if np.isnan(v) else f"{100 * v:.0f}" for v in runs[column])
                row[f"Success {policy} (%) (per seed)"] = f"{plus_minus(mean, half, 0)} ({per_seed})"
        if vs:
            base = rows[(rows["agent"] == vs) & (rows["wind"] == wind)]
            for policy in ("final", "best"):
                column = f"{policy}_success_rate"
                point = (np.nan,) * 3
                if agent != vs and column in rows:
                    point = stats.mean_diff_ci(100 * runs[column], 100 * base[column])
                row[f"Δ {policy} vs {vs_label} (pp)"] = interval(*point, 0)
        crash = runs["final_crash_rate"].mean() if "final_crash_rate" in runs else np.nan
        row["Crash final (%)"] = "–" if np.isnan(crash) else f"{100 * crash:.0f}"
        out.append(row)
    return pd.DataFrame(out).sort_values("Agent", key=lambda c: c.str.casefold(), kind="stable")


def main(argv: list[str] | None = None) -> int:
    """The CLI: select and prepare the runs (any bad input: one line, exit 2, nothing flown or logged), fly and log
    each, print the table (exit 1 if no run had a stored config and model)."""
    parser = argparse.ArgumentParser(prog="python -m sweep.reevaluate", description=__doc__.split("\n\n")[0])
    parser.add_argument("overrides", nargs="*", help="eval.* overrides, e.g. eval.wind_speed=0 eval.episodes=20")
    parser.add_argument("--experiment", required=True, help="the MLflow experiment of the runs")
    parser.add_argument("--where", action="append", default=[], metavar="KEY=VALUE",
                        help="only runs with this tag (agent, wind, seed) or param (its logged string, e.g. "
                             "env.n_envs=16); repeat with other keys to require several")
    parser.add_argument("--name", required=True, help="the metric prefix of these scores, e.g. still_air")
    parser.add_argument("--policy", action="append", choices=list(MODELS), metavar="POLICY",
                        help=f"fly only this stored policy ({', '.join(MODELS)}; repeat for several; default: all)")
    parser.add_argument("--vs", metavar="AGENT", help="add each agent's success difference to this agent's, e.g. ppo")
    parser.add_argument("--out", type=Path, help="also write the table to this Markdown file")
    parser.add_argument("--uri", help="MLflow store (default: $MLFLOW_TRACKING_URI, else <project root>/mlflow.db)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    uri = tracking_uri(args.uri)
    with tempfile.TemporaryDirectory() as tmp:
        try:
            if not args.name.replace("_", "").isalnum() or args.name in metrics.POLICIES.values():
                raise ConfigError(f"--name {args.name!r}: letters, digits and _ only, not an eval prefix "
                                  f"({', '.join(metrics.POLICIES.values())})")
            overrides = parse_overrides(args.overrides)
            where = parse_where(args.where)
            runs = finished_runs(uri, args.experiment, where)
            if not runs:
                raise ConfigError(f"no FINISHED run of {args.experiment!r} matches "
                                  + " ".join(f"{k}={v}" for k, v in where.items()))
            stored, skipped, older = prepare(uri, runs, overrides, Path(tmp), tuple(args.policy or MODELS))
            if args.vs and args.vs not in {r.agent for r in stored}:
                raise ConfigError(f"--vs {args.vs}: no selected run of that agent (tag agent, e.g. ppo) stored a model")
        except (ConfigError, ValueError) as err:
            print(f"reevaluate: {err}", file=sys.stderr)
            return 2
        if skipped:
            print(f"reevaluate: skipped {len(skipped)} run(s) without a stored config or model: {', '.join(skipped)}",
                  file=sys.stderr)
        if older:
            print(f"reevaluate: left out {len(older)} older run(s) of an agent, wind and seed run again: "
                  f"{', '.join(older)}", file=sys.stderr)
        rows = []
        for run in stored:
            scores = fly_and_log(uri, run, args.name, args.overrides)
            rows.append({"agent": run.agent, "wind": run.wind, "seed": run.seed, "label": run.label}
                        | {f"{p}_{key}": v for p, values in scores.items() for key, v in values.items()})
            print(f"reevaluate: {run.name}: " + ", ".join(f"{p} success {100 * v['success_rate']:.0f}%"
                                                        for p, v in scores.items()), flush=True)
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
