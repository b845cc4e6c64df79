"""python -m sweep.report on one small real store (built once per module by a real Hydra multirun), plus a
hand-logged experiment in the same store whose numbers are chosen to tell right from nearly right."""
from __future__ import annotations

import contextlib
import io
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib import image
from matplotlib.colors import to_hex
from matplotlib.container import ErrorbarContainer
from mlflow.entities import Metric, Param
from mlflow.tracking import MlflowClient
from scipy.stats import t as t_dist
from scipy.stats import trim_mean

from conftest import new_store
from sweep.report import conditions, figures, load, stats, style, tables
from sweep.report.__main__ import main

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = "report-test"
HAND = "report-hand"  # hand-logged runs: no training, known histories
# ppo and recom_l2 x two L2 coefficients x two seeds: the PPO runs of either coefficient are the same condition
# (PPO has no L2: its agent.l2 settings are switched off, sweep.config.switch_off_unrun_remedy_settings), RECOM logs recom/at_bound, eval.every_timesteps gives evaluation curves. The SB3 learner:
# at this size faster than JAX, whose compilation takes ~10 s per job.
SWEEP = ["-m", "agent=ppo,recom_l2", "++agent.l2.coef=0.001,0.01", "seed=0,1", "wind=paper",
         "train.total_timesteps=1536", "agent.ppo.n_steps=512", "wind.segment_steps=512", "++agent.recom.interval=512",
         "eval.episodes=2", "eval.every_timesteps=512", "tracking.log_model=false", "train.progress_every_s=1000",
         f"tracking.experiment={EXPERIMENT}", "hydra.launcher.n_jobs=2"]
BY = ["--by", "agent.l2.coef", "--baseline", "agent=ppo"]
CURVE_METRICS = {stem: panels[0].key for stem, panels in figures.CURVES.items()}  # figure -> its first panel
SPARSE = {"eval_success", "eval_crash", "eval_distance"}  # a figure only for >= 2 logged steps
ARTIFACTS = {"final": "eval_trajectories.npz", "best": "eval_best_trajectories.npz"}  # the flights (sweep.run)
TABLES = ["table3.md", "table3.tex", "table3.csv", "summary.md", "summary.csv", "segments.md", "segments.csv"]


def env_with(uri: str) -> dict:
    return {**os.environ, "MLFLOW_TRACKING_URI": uri, "HYDRA_FULL_ERROR": "0"}


def run_report(store: str, out: Path, *args: str, draft: bool = True) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of one in-process report run; ``draft`` (--draft, PNG only at 100 dpi) unless a
    test reads the figures' files as the paper gets them (sizes in pixels at 300 dpi, the PDFs)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("MLFLOW_TRACKING_URI", store)
    stdout, stderr = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = main(["--out", str(out), *args, *(["--draft"] if draft else [])])
    finally:
        mp.undo()
    return code, stdout.getvalue(), stderr.getvalue()


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> str:
    tmp = tmp_path_factory.mktemp("store")
    uri = new_store(tmp / "mlflow.db")
    # module-scoped: built before the autouse fixtures that keep a test's checkpoints and files in its temp dir
    env = {**env_with(uri), "SWEEP_CHECKPOINT_DIR": str(tmp / "checkpoints")}
    proc = subprocess.run([sys.executable, "-m", "sweep", *SWEEP, f"hydra.sweep.dir={tmp / 'sweep'}"], cwd=tmp,
                          env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    log_hand_runs(MlflowClient(uri))
    return uri


@pytest.fixture(scope="module")
def report(store, tmp_path_factory):
    """(output dir, stdout) of the report split by the L2 coefficient, with PPO as the baseline."""
    out = tmp_path_factory.mktemp("report")
    code, stdout, stderr = run_report(store, out, "--experiment", EXPERIMENT, *BY, draft=False)
    assert code == 0, stdout + stderr
    return out, stdout


@pytest.fixture(scope="module")
def hand_report(store, tmp_path_factory):
    """(output dir, stdout) of the report of the hand-logged experiment."""
    out = tmp_path_factory.mktemp("hand")
    code, stdout, stderr = run_report(store, out, "--experiment", HAND, draft=False)
    assert code == 0, stdout + stderr
    return out, stdout


@pytest.fixture(scope="module")
def plain_report(store, tmp_path_factory):
    """(output dir, stdout) of the report without --by."""
    out = tmp_path_factory.mktemp("plain")
    code, stdout, stderr = run_report(store, out, "--experiment", EXPERIMENT)
    assert code == 0, stdout + stderr
    return out, stdout


# -- the runs and their numbers, by hand from the store ------------------------------------------------------

def hand_runs(store: str, experiment: str = EXPERIMENT, by_coef: bool = True) -> pd.DataFrame:
    """Finished runs with their condition (the agent, plus the L2 coefficient where L2 is on) and final
    histories, the latest run of each condition/seed only."""
    client = MlflowClient(store)
    exp = client.get_experiment_by_name(experiment)
    rows = []
    for r in client.search_runs([exp.experiment_id]):
        agent, params = r.data.tags["agent"], r.data.params
        coef = params["agent.l2.coef"] if by_coef and params.get("agent.l2.enabled") == "True" else None
        row = {"run_id": r.info.run_id, "agent": agent, "seed": int(r.data.tags["seed"]),
               "start": r.info.start_time,
               "condition": r.data.tags["agent_label"] + (f" (coef={coef})" if coef else ""),
               **{k: v for k, v in r.data.metrics.items() if k.split("/")[0] in ("eval", "eval_best")}}
        for name, key in [("reward", "rollout/ep_rew_mean"), ("dormant", "plasticity/dormant_ratio"),
                          ("at_bound", "recom/at_bound")]:
            hist = sorted(client.get_metric_history(r.info.run_id, key), key=lambda m: m.step)
            row[name] = (np.array([m.step for m in hist], dtype=float), np.array([m.value for m in hist]))
        rows.append(row)
    df = pd.DataFrame(rows).sort_values("start")
    return df.drop_duplicates(["condition", "seed"], keep="last").reset_index(drop=True)


def final(history) -> float:
    """Mean of the values in the last 10% of the run's logged timesteps."""
    steps, values = history
    return float(values[steps >= steps[-1] - 0.1 * (steps[-1] - steps[0])].mean())


def g_final(hand: pd.DataFrame, condition: str) -> np.ndarray:
    """Final training rewards of a condition's seeds."""
    return hand.loc[hand["condition"] == condition, "reward"].map(final).to_numpy()


def collapse(history) -> float:
    """Largest drop below the running peak."""
    values = history[1]
    return float(max(max(values[: i + 1]) - v for i, v in enumerate(values)))


def log_hand_runs(client: MlflowClient) -> None:
    """Experiment HAND: PPO seeds 0-1 and RECOM seeds 0-2, reward and dormant histories only (no saturated
    units, weight norm, episode length, learning rate, evaluation curve; one final evaluation)."""
    exp_id = client.create_experiment(HAND)
    steps = np.arange(0, 1001, 100)
    # RECOM: seed 0 has the highest last reward, seed 2 the best evaluation return; seed 1 the highest final
    # training reward (mean over steps 900 and 1000): -15 against -22.5 and -30.
    runs = [("ppo", 0, -60 + steps / 50, None, 0.0), ("ppo", 1, -70 + steps / 40, None, 0.0),
            ("recom_l2", 0, np.r_[np.full(9, -50.0), -40.0, -5.0], [1, 0, 0, 1], -300.0),
            ("recom_l2", 1, np.r_[np.full(9, -50.0), -15.0, -15.0], [0, 0, 0, 1], -200.0),
            ("recom_l2", 2, np.r_[np.full(9, -50.0), -30.0, -30.0], [0, 0], -100.0)]
    for agent, seed, rewards, bound, ret in runs:
        run_id = client.create_run(exp_id, tags={"agent": agent, "wind": "paper", "seed": str(seed),
                                                 "run_name": f"{agent}-s{seed}", "sweep": "hand"}).info.run_id
        params = {"wind.speeds": "[3.0]", "wind.segment_steps": "100000", "agent.l2.enabled": str(agent != "ppo"),
                  "agent.l2.coef": "0.001", "agent.recom.enabled": str(agent == "recom_l2")}
        metrics = [Metric("rollout/ep_rew_mean", float(r), 0, int(s)) for s, r in zip(steps, rewards)]
        metrics += [Metric("plasticity/dormant_ratio", 0.01 * seed, 0, int(s)) for s in steps]
        metrics += [Metric("recom/at_bound", float(b), 0, 250 * (i + 1)) for i, b in enumerate(bound or [])]
        metrics += [Metric(k, v, 0, 1000) for k, v in [("eval/success_rate", 0.1 * seed), ("eval/mse_x", 1.0 + seed),
                                                       ("eval/mse_y", 2.0), ("eval/mse_z", 3.0 + seed),
                                                       ("eval/return", ret), ("eval/crash_rate", 0.5)]]
        client.log_batch(run_id, metrics=metrics, params=[Param(k, v) for k, v in params.items()])
        client.set_terminated(run_id)


# Twelve agents of made-up names, none of the paper's: more than the colours, so line styles must tell them apart.
# Labels as agent YAMLs may have them (long, '&', '%', '_'); 'delta_cbp' logged its label only as the param
# agent.label (the tag agent_label came later), 'zeta_plain' logged none (labelled with its name); 'kappa_sp' was
# relabelled between its seeds (the newest run's label counts).
MANY = {"alpha_redo": "ReDo (τ=0.1) + PPO", "beta_snp": "Shrink & Perturb + PPO", "gamma_l2i": "L2 Init + PPO",
        "delta_cbp": "Continual Backprop + L2", "eps_ln": "LayerNorm PPO", "eta_crelu": "CReLU PPO",
        "theta_reset": "Reset last layer (10%)", "iota_plast": "Plasticity Injection",
        "kappa_sp": "S&P + LayerNorm", "lambda_dw": "DASH warm start", "mu_hare": "Hare & Tortoise",
        "zeta_plain": "zeta_plain"}


def log_many_agents(client: MlflowClient, experiment: str, seeds: int = 2, flights: Path | None = None,
                    policy: str = "final") -> None:
    """Experiment ``experiment``: every MANY agent x ``seeds`` seeds in wind 'paper', reward, episode length and
    dormant histories (all curves if ``flights``, a folder for evaluation-flight artifacts, is given). The
    evaluation at the end scores the final policy (eval/*, eval_trajectories.npz, no eval.policy param: a store
    logged before it existed) or, with ``policy="best"``, only the best one (eval.policy=best: eval_best/*,
    eval_best_trajectories.npz; eval/* are then the evaluations during training only)."""
    exp_id = client.create_experiment(experiment, None if flights is None else (flights / "artifacts").as_uri())
    steps = np.arange(0, 20_001, 500)
    rng = np.random.default_rng(0)
    for k, (agent, label) in enumerate(MANY.items()):
        for seed in range(seeds):
            tags = {"agent": agent, "wind": "paper", "seed": str(seed), "run_name": f"{agent}-s{seed}",
                    "sweep": "many"}
            logged = "older label" if agent == "kappa_sp" and seed == 0 else label
            params = {"wind.speeds": "[3.0, 2.0, 2.5]", "wind.segment_steps": "5000", "eval.success_radius": "0.5"}
            if policy != "final":
                params["eval.policy"] = policy
            if agent not in ("delta_cbp", "zeta_plain"):
                tags["agent_label"] = logged
            if agent != "zeta_plain":
                params["agent.label"] = logged
            run_id = client.create_run(exp_id, tags=tags, start_time=1000 * (10 * k + seed)).info.run_id
            t = steps / steps[-1]
            curves = {"rollout/ep_rew_mean": -900 + (500 + 25 * k) * (1 - np.exp(-4 * t)) - 60 * (k % 3) * t,
                      "rollout/ep_len_mean": 100 + 400 * t ** (1 + k / 6), "plasticity/dormant_ratio": 0.004 * k * t}
            if flights is not None:
                curves |= {"plasticity/saturated_ratio": 0.01 * k * t, "plasticity/weight_norm": 30 + (2 + k) * t,
                           "train/learning_rate": 3e-4 * (1 + 0.05 * k * t), "train/std": np.exp(-(1 + k / 4) * t),
                           "train/approx_kl": 0.01 * (1 + k * t), "train/clip_fraction": 0.1 + 0.02 * k * t}
            metrics = [Metric(key, float(v + rng.normal(0, 0.02 * (abs(v) + 1e-4))), 0, int(s))
                       for key, values in curves.items() for s, v in zip(steps, values)]
            metrics += [Metric(key, v, 0, int(s)) for s in steps[::10] for key, v in
                        [("eval/success_rate", min(1.0, s / 20_000 * (0.3 + k / 20))),
                         ("eval/crash_rate", max(0.0, 0.5 - s / 40_000 - k / 40)),
                         ("eval/final_distance", max(0.05, 2.0 - s / 10_000 * (1 + k / 10)))]]
            end = "eval" if policy == "final" else "eval_best"
            metrics += [Metric(f"{end}/{key}", v, 1, 20_000) for key, v in
                        [("mse_x", 0.1 * (k + 1) + seed), ("mse_y", 0.2), ("mse_z", 0.3), ("return", -100.0 * k - seed)]
                        + ([] if policy == "final" else [("success_rate", 0.05 * k), ("crash_rate", 0.0),
                                                         ("source_step", 10_000.0 + 500 * seed),
                                                         ("source_score", -300.0)])]
            client.log_batch(run_id, metrics=metrics, params=[Param(key, v) for key, v in params.items()])
            if flights is not None:
                time = np.linspace(0, 5, 101)[None, :, None]
                start = rng.uniform(-2, 2, (4, 1, 3))
                positions = start * np.exp(-(0.5 + k / 8) * time) + 0.05 * k * np.sin(3 * time)
                path = flights / f"{agent}-{seed}" / ARTIFACTS[policy]
                path.parent.mkdir(parents=True)
                np.savez_compressed(path, positions=positions, crashed=np.arange(4) < k % 3,
                                    success=np.arange(4) >= k % 3, dt=np.array(0.05), wind=np.array([2.0, 0, 0]))
                client.log_artifact(run_id, str(path))
            client.set_terminated(run_id)


# The dormant figure's readings of the policy network, top to bottom: key -> words its panel's y label must have.
READINGS = {"plasticity/dormant_ratio": "Sokar dormant,\nτ = 0.05", "plasticity/dormant_ratio_tau0.1":
            "Sokar dormant,\nτ = 0.1", "plasticity/dead_tanh_ratio": "Dead tanh",
            "plasticity/signed_mean_ratio": "Signed mean\n≈ 0", "plasticity/saturated_ratio": "Saturated"}
NEW_READINGS = ["plasticity/dormant_ratio_tau0.1", "plasticity/dead_tanh_ratio", "plasticity/signed_mean_ratio",
                "plasticity/active_ratio"]


def reading(key: str, k: int, seed: int, t: np.ndarray) -> np.ndarray:
    """Known history of a plasticity reading of agent number ``k`` (t: 0 -> 1 over training): a different line
    for every key, agent and seed, linear in t (so that the report's interpolation is exact); Sokar's ratio at
    the run's τ is 0 throughout, as in a tanh network."""
    if key == "plasticity/dormant_ratio":
        return np.zeros_like(t)
    j = list(READINGS).index(key) if key in READINGS else 5
    return 0.02 * (j + 1) + 0.1 * k + 0.01 * seed + 0.05 * (j + 1) * (k + 1) * t


def log_reading_runs(client: MlflowClient, experiment: str) -> None:
    """Experiment ``experiment``: PPO and L2 log every reading (NEW_READINGS too), RECOM logged before the new
    readings existed (Sokar's ratio and the saturated share only); two seeds each, steps 0-1000, one wind."""
    exp_id = client.create_experiment(experiment)
    steps = np.arange(0, 1001, 100)
    for k, agent in enumerate(["ppo", "l2", "recom_l2"]):
        keys = ["plasticity/dormant_ratio", "plasticity/saturated_ratio"] + (NEW_READINGS if k < 2 else [])
        for seed in range(2):
            run_id = client.create_run(exp_id, tags={"agent": agent, "wind": "paper", "seed": str(seed),
                                                     "run_name": f"{agent}-s{seed}", "sweep": "readings"}).info.run_id
            params = {"wind.speeds": "[3.0]", "wind.segment_steps": "100000", "plasticity.tau": "0.05",
                      "plasticity.saturation": "0.95", "plasticity.signed_mean_tau": "0.2"}
            if k < 2:
                params["plasticity.dead_fraction"] = "0.9"
            metrics = [Metric("rollout/ep_rew_mean", -100.0 + k + seed + s / 100, 0, int(s)) for s in steps]
            metrics += [Metric(key, float(v), 0, int(s)) for key in keys
                        for s, v in zip(steps, reading(key, k, seed, steps / 1000))]
            metrics += [Metric(key, 0.5, 0, 1000) for key in ("eval/success_rate", "eval/mse_x", "eval/mse_y",
                                                              "eval/mse_z", "eval/return", "eval/crash_rate")]
            client.log_batch(run_id, metrics=metrics, params=[Param(key, v) for key, v in params.items()])
            client.set_terminated(run_id)


def spy_figures(monkeypatch) -> dict:
    """Stem -> what figures.save was given: per panel its y label, its curves (label -> y values; points with error
    bars too) and texts; the figure's own texts (the note below the legend) and the legend's labels. A panel
    without a y label of its own (a shared axis' second column) is left out of "panels"; "scatter" has every
    visible panel's title, x label and scale and its labelled scatter points (label -> (x, y) rows)."""
    drawn, save = {}, figures.save

    def spy(fig, out, stem):
        axes = [ax for ax in fig.axes if ax.get_ylabel()]
        drawn[stem] = {
            "panels": [{"ylabel": ax.get_ylabel(), "texts": [t.get_text() for t in ax.texts],
                        "curves": {**{line.get_label(): line.get_ydata() for line in ax.get_lines()
                                      if not line.get_label().startswith("_")},
                                   **{bars.get_label(): bars.lines[0].get_ydata() for bars in ax.containers
                                      if isinstance(bars, ErrorbarContainer) and not bars.get_label().startswith("_")}}}
                       for ax in axes],
            "scatter": [{"title": ax.get_title(), "xlabel": ax.get_xlabel(), "xscale": ax.get_xscale(),
                         "points": {c.get_label(): np.asarray(c.get_offsets()) for c in ax.collections
                                    if not c.get_label().startswith("_") and len(c.get_offsets())}}
                        for ax in fig.axes if ax.get_visible()],
            "note": " ".join(t.get_text() for t in fig.texts).replace("\n", " "),
            "legend": [t.get_text() for leg in [*fig.legends, *(ax.get_legend() for ax in fig.axes)] if leg
                       for t in leg.get_texts()]}
        return save(fig, out, stem)

    monkeypatch.setattr(figures, "save", spy)
    return drawn


def md_table(path: Path, which: int = 0) -> pd.DataFrame:
    """The ``which``-th Markdown table of a report file (0: the first), cells as text."""
    tables, inside = [], False
    for line in path.read_text().splitlines():
        if line.startswith("|") and not line.startswith("|---"):
            if not inside:
                tables.append([])
            tables[-1].append([c.strip() for c in line.strip().strip("|").split("|")])
        inside = line.startswith("|")
    rows = tables[which]
    return pd.DataFrame(rows[1:], columns=rows[0])


def figure_stems(out: Path) -> set[str]:
    pngs, pdfs = {p.stem for p in out.glob("*.png")}, {p.stem for p in out.glob("*.pdf")}
    assert pdfs in (pngs, set())   # every figure in both, or a --draft report: PNG only
    return pngs


def expected_curves(store: str, experiment: str) -> set[str]:
    """Curve figures whose data exist: some run has the metric (evaluation metrics at >= 2 steps)."""
    client = MlflowClient(store)
    runs = client.search_runs([client.get_experiment_by_name(experiment).experiment_id])
    stems = set()
    for stem, key in CURVE_METRICS.items():
        steps = [len({m.step for m in client.get_metric_history(r.info.run_id, key)}) for r in runs]
        if max(steps) >= (2 if stem in SPARSE else 1):
            stems.add(f"{stem}_paper")
    if "eval_success_paper" in stems:  # evaluations during training: the performance profile of the late ones
        stems |= {"performance_profile_paper", "interval_keeps_hovering"}
    for r in runs:   # evaluations in more than one segment of the wind schedule: the per-segment scores
        if "wind.segment_steps" not in r.data.params:   # hand-logged runs without the schedule's params
            continue
        length = int(r.data.params["wind.segment_steps"])
        total = int(r.data.params.get("train.total_timesteps", 1 << 62))
        history = client.get_metric_history(r.info.run_id, "eval/success_rate")
        steps = {m.step for m in history}
        if len({-(-min(s, total) // length) for s in steps if s > 0}) > 1:
            stems |= {"segment_scores", "segment_scores_end"}
            if r.data.params.get("eval.condition") == "current":   # and re-learning in the segments after the first
                stems.add("interval_relearning")
                if any(0 < m.step <= length and m.value >= 0.5 for m in history):   # a run that learned segment 0
                    stems.add("segment_scores_learned")
    finals = {k for r in runs for k in r.data.metrics}
    stems |= {f"interval_{name}" for name, key in [("final_reward", "rollout/ep_rew_mean"),
                                                    ("success_final", "eval/success_rate"),
                                                    ("success_best", "eval_best/success_rate")] if key in finals}
    return stems


PANELLED = ("eval_flights_3d", "eval_position_axes",  # a panel per condition: one column wide whatever --by says
            "segment_scores", "segment_scores_end", "segment_scores_learned")  # agents side by side, a column per wind


# -- tests ---------------------------------------------------------------------------------------------------

def test_report_writes_every_file_and_says_what_is_missing(store, report):
    out, stdout = report
    assert figure_stems(out) == expected_curves(store, EXPERIMENT) | {"eval_flights_3d", "eval_position_axes"}
    assert {"episode_length_paper", "weight_norm_paper", "eval_success_paper", "eval_crash_paper"} <= figure_stems(out)
    for stem in figure_stems(out):
        pixels = image.imread(out / f"{stem}.png")
        height, width = pixels.shape[:2]
        tallest = 2600 if stem.startswith("dormant") else 2000  # the dormant figure: five readings, a note
        # one column (3.5 in at 300 dpi), or both (7.16 in) for the small multiples of the two L2 coefficients
        narrow, wide = 900 <= width <= 1200, 1700 <= width <= 2200
        shortest = 250 if stem.startswith("interval") else 500  # an interval figure: a row per agent (here two)
        assert (narrow if stem in PANELLED else wide) and shortest <= height <= tallest, (stem, pixels.shape)
        rgba = np.ascontiguousarray((pixels * 255).astype(np.uint8)).view(np.uint32)  # one number per pixel
        assert len(np.unique(rgba)) > 20, f"{stem}.png is blank"
        pdf = (out / f"{stem}.pdf").read_bytes()
        assert pdf.startswith(b"%PDF") and re.search(rb"/Type\s*/Page[^s]", pdf), f"{stem}.pdf"
    # the dormant figure carries the saturated-unit panel below it
    assert image.imread(out / "dormant_paper.png").shape[0] > 1.3 * image.imread(out / "reward_paper.png").shape[0]
    assert {"interval_keeps_hovering", "interval_success_final", "interval_success_best"} <= figure_stems(out)
    for name in TABLES:
        assert (out / name).stat().st_size > 0, name
    assert stdout.strip().splitlines()[-1] == str(out.resolve())
    # every job of the sweep finished: nothing is missing (the paper's L2 and wind none were never asked for)
    assert "missing: agent=" not in stdout
    # PPO was asked for once per L2 coefficient, but PPO has no L2: one job per seed, run once (sweep.checkpoint.job_key
    # leaves settings it does not run out), so no duplicate is left out
    assert "older duplicate run(s)" not in stdout and "6 finished runs" in stdout


def test_curve_figures_exist_exactly_when_their_data_exist(store, hand_report):
    tmp_path, stdout = hand_report
    assert figure_stems(tmp_path) == expected_curves(store, HAND) == {"reward_paper", "dormant_paper",
                                                                     "interval_final_reward", "interval_success_final"}
    # no saturated share logged: the dormant figure has a single panel (a second adds 1.4 in, 60% of this height;
    # the note below its legend, two lines)
    assert image.imread(tmp_path / "dormant_paper.png").shape[0] < 1.3 * image.imread(
        tmp_path / "reward_paper.png").shape[0]
    assert "missing: eval_trajectories.npz of ppo-s0" in stdout


def test_by_splits_conditions_by_the_logged_params(store, report):
    out, _ = report
    hand = hand_runs(store)
    summary = pd.read_csv(out / "summary.csv", dtype={"agent.l2.coef": str}, keep_default_na=False)
    assert list(summary["condition"]) == ["PPO", "RECOM + L2 PPO (coef=0.001)", "RECOM + L2 PPO (coef=0.01)"]
    assert list(summary["agent.l2.coef"]) == ["n/a", "0.001", "0.01"]
    assert sorted(summary["condition"]) == sorted(hand["condition"].unique())
    counts = hand.groupby("condition").size()
    assert all(summary["n_seeds"] == summary["condition"].map(counts)) and (summary["n_seeds"] == 2).all()
    for label in summary["condition"]:
        assert f"| {label} | paper |" in (out / "summary.md").read_text()
    table3 = pd.read_csv(out / "table3.csv")
    assert list(table3["condition"]) == list(summary["condition"])


def test_table3_equals_a_hand_aggregation_with_the_top_seed(store, report):
    out, _ = report
    hand = hand_runs(store)
    table = pd.read_csv(out / "table3.csv").set_index("condition")
    assert "Top seed = the seed whose final training reward" in (out / "table3.md").read_text()
    shown = md_table(out / "table3.md").set_index("Control policy")
    for cond, g in hand.groupby("condition"):
        row = table.loc[cond]
        assert row["n_seeds"] == row["n_seeds_final"] == row["n_seeds_best"] == len(g) == 2
        # the real runs (eval.policy=both) scored the final and the best policy: both, side by side
        for prefix, suffix in [("eval", ""), ("eval_best", "_best")]:
            assert row[f"success_rate{suffix}_mean"] == pytest.approx(100 * g[f"{prefix}/success_rate"].mean())
            for axis in "xyz":
                assert row[f"mse_{axis}{suffix}_mean"] == pytest.approx(g[f"{prefix}/mse_{axis}"].mean())
            assert np.isfinite(row[f"mse_x{suffix}_ci95"])  # two seeds: a Student-t interval exists
        assert row["source_step_best_mean"] == pytest.approx(g["eval_best/source_step"].mean())
        assert 0 < row["source_step_best_mean"] <= 1536
        top = g.loc[g["reward"].map(final).idxmax()]
        assert row["top_seed"] == top["seed"]
        assert row["top_seed_success_rate"] == pytest.approx(100 * top["eval/success_rate"])
        for axis in "xyz":
            assert row[f"top_seed_mse_{axis}"] == pytest.approx(top[f"eval/mse_{axis}"])
        assert shown.loc[cond, "Top seed"] == str(top["seed"])
        assert shown.loc[cond, "Top seed: success final (%)"] == f"{100 * top['eval/success_rate']:.0f}"
        assert shown.loc[cond, "Top seed: MSE x/y/z final (m²)"] == " / ".join(
            f"{top[f'eval/mse_{a}']:.2f}" for a in "xyz")
        assert shown.loc[cond, "MSE y best (m²)"] == f"{row['mse_y_best_mean']:.2f} ± {row['mse_y_best_ci95']:.2f}"


def test_summary_equals_a_hand_computation_from_the_histories(store, report):
    out, _ = report
    hand = hand_runs(store)
    summary = pd.read_csv(out / "summary.csv").set_index("condition")
    for cond, g in hand.groupby("condition"):
        row = summary.loc[cond]
        assert row["collapse"] == pytest.approx(g["reward"].map(collapse).mean())
        assert row["final_dormant_ratio"] == pytest.approx(g["dormant"].map(final).mean())
        assert row["final_reward"] == pytest.approx(g["reward"].map(final).mean())
        assert row["eval_success_pct"] == pytest.approx(100 * g["eval/success_rate"].mean())
        assert row["eval_crash_pct"] == pytest.approx(100 * g["eval/crash_rate"].mean())
        assert row["eval_best_success_pct"] == pytest.approx(100 * g["eval_best/success_rate"].mean())
        assert row["eval_best_crash_pct"] == pytest.approx(100 * g["eval_best/crash_rate"].mean())
        # two seeds: rliable's IQM (a 25% trimmed mean) trims nothing, and a percentile bootstrap of 2 values
        # resamples {a, a} a quarter of the time, so the 2.5% and 97.5% points are the two seeds themselves
        scores = g["reward"].map(final)
        assert len(scores) == 2 and row["iqm_final_reward"] == pytest.approx(scores.mean())
        assert (row["iqm_ci_low"], row["iqm_ci_high"]) == pytest.approx((scores.min(), scores.max()))
        shares = [v.mean() for _, v in g["at_bound"] if len(v)]
        if g["agent"].iloc[0] == "recom_l2":
            assert len(shares) == 2 and row["lr_at_bound_pct"] == pytest.approx(100 * np.mean(shares))
        else:
            assert not shares and np.isnan(row["lr_at_bound_pct"])
    ppo = g_final(hand, "PPO")
    for cond in ["RECOM + L2 PPO (coef=0.001)", "RECOM + L2 PPO (coef=0.01)"]:
        recom = g_final(hand, cond)
        # Mann-Whitney by hand: the share of (RECOM seed, PPO seed) pairs RECOM wins, ties counting a half
        wins = np.mean([1.0 if x > y else 0.5 if x == y else 0.0 for x in recom for y in ppo])
        assert summary.loc[cond, "p_improve_over_ppo"] == pytest.approx(wins)
    assert np.isnan(summary.loc["PPO", "p_improve_over_ppo"])


def test_segments_are_the_reward_in_each_hold_of_the_wind_schedule(store, report):
    out, _ = report
    hand = hand_runs(store)
    table = pd.read_csv(out / "segments.csv")
    # wind.segment_steps=512, rollouts of 512, 1536 steps: the rewards logged at 512, 1024, 1536 are segments 0, 1, 2
    assert sorted(table["segment"].unique()) == [0, 1, 2]
    assert list(table.groupby("segment")["speed"].first()) == [3.0, 2.0, 2.5]  # wind=paper's schedule
    for (cond, k), row in table.set_index(["condition", "segment"]).iterrows():
        g = hand[hand["condition"] == cond]
        per_seed = [values[(steps > 512 * k) & (steps <= 512 * (k + 1))].mean() for steps, values in g["reward"]]
        assert row["n_seeds"] == len(per_seed) == 2
        assert row["reward_mean"] == pytest.approx(np.mean(per_seed))
    shown = md_table(out / "segments.md").set_index("Agent")
    assert list(shown.columns[2:]) == ["0–512 (3 m/s)", "512–1.024k (2 m/s)", "1.024k–1.536k (2.5 m/s)"]
    ppo = table[(table["condition"] == "PPO") & (table["segment"] == 1)].iloc[0]
    assert shown.loc["PPO", "512–1.024k (2 m/s)"] == f"{ppo['reward_mean']:.0f} ± {ppo['reward_ci95']:.0f}"


def test_baseline_is_the_iqm_difference_to_the_matching_condition(store, report):
    out, _ = report
    hand = hand_runs(store)
    iqm = {cond: trim_mean(g["reward"].map(final), 0.25) for cond, g in hand.groupby("condition")}
    summary = pd.read_csv(out / "summary.csv", keep_default_na=False).set_index("condition")
    assert summary.loc["PPO", "baseline"] == "" and summary.loc["PPO", "delta_iqm"] == ""
    for cond in ["RECOM + L2 PPO (coef=0.001)", "RECOM + L2 PPO (coef=0.01)"]:
        row = summary.loc[cond]
        assert row["baseline"] == "PPO"  # PPO's L2 coefficient does not apply: it is the baseline of both
        delta, low, high = (float(row[c]) for c in ("delta_iqm", "delta_iqm_ci_low", "delta_iqm_ci_high"))
        assert delta == pytest.approx(iqm[cond] - iqm["PPO"])
        # two seeds each: the bootstrap's 2.5% point is the worst pairing (both resamples at their extremes,
        # probability 1/16), the 97.5% point the best one
        x, y = g_final(hand, cond), g_final(hand, "PPO")
        assert (low, high) == pytest.approx((x.min() - y.max(), x.max() - y.min())) and low < high
    shown = md_table(out / "summary.md").set_index("Agent")["Δ IQM vs agent=ppo [95% CI]"]
    row = summary.loc["RECOM + L2 PPO (coef=0.01)"]
    assert shown.loc["PPO"] == "" and shown.loc["RECOM + L2 PPO (coef=0.01)"] == (
        f"{float(row['delta_iqm']):.1f} [{float(row['delta_iqm_ci_low']):.1f}, {float(row['delta_iqm_ci_high']):.1f}]")

    # the other direction, a --by key as the baseline (1e-3 names the logged 0.001); the summary without figures
    client = load.client_for(store)
    runs, _ = load.load_runs(client, load.pick_experiment(client, EXPERIMENT)[0], None, ["agent.l2.coef"])
    runs, conds = conditions.build(runs, ["agent.l2.coef"])
    per_run = stats.per_run_curve_stats(load.load_histories(client, runs))
    numbers, display = tables.summary(runs, per_run, conds, conditions.parse_baseline("agent.l2.coef=1e-3", conds))
    by_coef = numbers.set_index("condition")
    assert by_coef["delta_iqm"].isna().tolist() == [True, True, False]  # PPO (n/a) and coef=0.001 itself
    row = by_coef.loc["RECOM + L2 PPO (coef=0.01)"]
    assert row["baseline"] == "RECOM + L2 PPO (coef=0.001)"
    assert row["delta_iqm"] == pytest.approx(iqm["RECOM + L2 PPO (coef=0.01)"] - iqm["RECOM + L2 PPO (coef=0.001)"])
    x, y = g_final(hand, "RECOM + L2 PPO (coef=0.01)"), g_final(hand, "RECOM + L2 PPO (coef=0.001)")
    assert (row["delta_iqm_ci_low"], row["delta_iqm_ci_high"]) == pytest.approx((x.min() - y.max(),
                                                                                x.max() - y.min()))
    assert "Δ IQM vs agent.l2.coef=0.001 [95% CI]" in display.columns


def test_hand_logged_runs_give_the_chosen_best_seed_and_bound_share(hand_report):
    tmp_path, _ = hand_report
    table = pd.read_csv(tmp_path / "table3.csv").set_index("agent")
    assert table.loc["recom_l2", "top_seed"] == 1  # not 0 (highest last reward) nor 2 (best evaluation return)
    assert table.loc["recom_l2", "top_seed_mse_x"] == 2.0 and table.loc["recom_l2", "top_seed_success_rate"] == 10.0
    assert table.loc["ppo", "top_seed"] == 0  # final rewards -41 (seed 0) and -46.25 (seed 1)
    summary = pd.read_csv(tmp_path / "summary.csv").set_index("agent")
    # RECOM's updates at a bound: 2 of 4, 1 of 4, 0 of 2 -> 50%, 25%, 0% -> 25% (pooled: 30%, last value: 67%)
    assert summary.loc["recom_l2", "lr_at_bound_pct"] == pytest.approx(25.0)
    assert np.isnan(summary.loc["ppo", "lr_at_bound_pct"])
    shown = md_table(tmp_path / "summary.md").set_index("Agent")
    assert shown.loc["PPO", "LR at bound (%)"] == "–" and shown.loc["RECOM + L2 PPO", "LR at bound (%)"] == "25"
    assert summary.loc["recom_l2", "final_reward"] == pytest.approx(np.mean([-22.5, -15.0, -30.0]))
    assert summary.loc["recom_l2", "final_dormant_ratio"] == pytest.approx(0.01)
    assert np.isnan(summary.loc["recom_l2", "final_saturated_ratio"])


def test_hand_logged_improvement_over_ppo_is_certain_and_its_iqm_the_middle_seed(hand_report):
    """Every RECOM seed's final reward (-22.5, -15, -30) beats every PPO seed's (-41, -46.25): P(RECOM > PPO) is
    exactly 1 and so is every bootstrap resample of it; with three seeds the 25% trimmed mean trims nothing
    (int(0.75) = 0), so the IQM is their mean, -22.5. (Comparing the wrong way round gives 0, counting ties or
    losses as wins anything but exactly 1.)"""
    out, _ = hand_report
    summary = pd.read_csv(out / "summary.csv").set_index("agent")
    recom = summary.loc["recom_l2"]
    assert (recom["p_improve_over_ppo"], recom["p_improve_ci_low"], recom["p_improve_ci_high"]) == (1.0, 1.0, 1.0)
    assert recom["iqm_final_reward"] == pytest.approx(-22.5)
    assert (recom["iqm_ci_low"], recom["iqm_ci_high"]) == pytest.approx((-30.0, -15.0))  # 1/27 all-worst, all-best
    assert np.isnan(summary.loc["ppo", "p_improve_over_ppo"])
    shown = md_table(out / "summary.md").set_index("Agent")
    assert shown.loc["RECOM + L2 PPO", "P(> PPO) [95% CI]"] == "1.00 [1.00, 1.00]"


def test_probability_of_improvement_on_hand_built_scores():
    # every x above every y: 1, with a degenerate CI; interleaved (1 < 2, 3 < 4): 2 of 4 pairs won -> 0.5
    assert stats.poi_ci([5.0, 6.0, 7.0], [1.0, 2.0]) == (1.0, 1.0, 1.0)
    assert stats.poi_ci([1.0, 4.0], [2.0, 3.0])[0] == 0.5
    assert stats.poi_ci([1.0, 2.0], [3.0, 4.0])[0] == 0.0
    # ties count a half: all-equal scores give 0.5, and so does every resample of them
    assert stats.poi_ci([2.0, 2.0, 2.0], [2.0, 2.0]) == (0.5, 0.5, 0.5)
    # one run per side: the point, no interval; NaN scores are left out
    point, low, high = stats.poi_ci([3.0, np.nan], [1.0])
    assert point == 1.0 and np.isnan(low) and np.isnan(high)


def test_bootstrap_statistics_equal_rliable_on_every_resample():
    """The IQM and P(X > Y) of a batch of resamples at once (what the bootstrap evaluates, 2,000 at a time)
    equal rliable's own functions on each resample, bit for bit: scores with many ties (success shares),
    continuous ones, identical sides (rliable's 0.5 case) and unequal sizes."""
    from rliable import metrics
    rng = np.random.default_rng(7)
    cases = [(rng.integers(0, 5, (300, 8)) / 4, rng.integers(0, 5, (300, 16)) / 4),
             (rng.normal(size=(300, 9)), rng.normal(0.3, 1.0, (300, 3)))]
    same = rng.integers(0, 3, (50, 6)) / 2.0
    cases.append((same, same.copy()))
    cases.append((rng.normal(size=(100, 40)), rng.integers(0, 9, (100, 33)) / 8))  # NumPy sums >= 8 values pairwise
    for x, y in cases:
        want = [metrics.probability_of_improvement(a[:, None], b[:, None]) for a, b in zip(x, y)]
        assert stats._p_improve(x, y).tolist() == want
        assert stats._p_improve(x.T, y.T, axis=0).tolist() == want
        assert stats._iqm(x).tolist() == [metrics.aggregate_iqm(a[:, None]) for a in x]
    # and the intervals: scipy's bootstrap calling rliable once per resample (the report's method before) gives the
    # same CI, bit for bit
    from scipy.stats import bootstrap
    x, y = rng.integers(0, 9, 12) / 8, rng.normal(0.5, 0.3, 9)

    def per_resample(func):
        return lambda *samples, axis=-1: np.array([func(*(r[:, None] for r in row)) for row in zip(*samples)])

    for func, data, ours in ((metrics.probability_of_improvement, (x, y), stats.poi_ci(x, y)),
                             (metrics.aggregate_iqm, (x,), stats.iqm_ci(x))):
        ci = bootstrap(data, per_resample(func), n_resamples=stats.RESAMPLES, method="percentile", vectorized=True,
                       paired=False, rng=np.random.default_rng(stats.RNG_SEED)).confidence_interval
        assert (ci.low, ci.high) == ours[1:] and ours[1] < ours[2]

def test_iqm_and_its_interval_on_hand_built_scores():
    """IQM of 12 scores = mean of the middle six, whatever the two outliers. The CI against an independent
    percentile bootstrap written here in NumPy (its own generator, 20,000 resamples, IQM by sorting): the two
    estimate the same quantiles to ~0.2, while a 90% or a 99% interval would be >= 0.5 off at one end."""
    x = np.array([2.0, 9.0, 4.0, 100.0, 7.0, 1.0, 5.0, 8.0, 3.0, 6.0, -50.0, 10.0])
    point, low, high = stats.iqm_ci(x)
    assert point == pytest.approx((3.0 + 4.0 + 5.0 + 6.0 + 7.0 + 8.0) / 6)
    rng = np.random.default_rng(12345)
    resamples = np.sort(x[rng.integers(0, len(x), size=(20_000, len(x)))], axis=1)
    iqms = resamples[:, 3:9].mean(axis=1)
    ref_low, ref_high = np.percentile(iqms, [2.5, 97.5])
    assert low == pytest.approx(ref_low, abs=0.25) and high == pytest.approx(ref_high, abs=0.25)
    # two runs: nothing is trimmed, and the 95% percentile interval is the two runs themselves
    assert stats.iqm_ci([-3.0, 5.0]) == pytest.approx((1.0, -3.0, 5.0))


def test_iqm_difference_interval_on_hand_built_scores():
    # two runs per side: the interval spans the worst pairing to the best (each has probability 1/16 > 2.5%)
    assert stats.iqm_diff_ci([10.0, 14.0], [1.0, 3.0]) == pytest.approx((12.0 - 2.0, 10.0 - 3.0, 14.0 - 1.0))
    # identical samples: a difference of exactly 0, but not a zero-width interval
    point, low, high = stats.iqm_diff_ci([1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 3.0, 4.0])
    assert point == 0.0 and low < 0.0 < high


# Hand-logged end-of-run evaluations, per agent the values of seeds 0, 1, 2 (None: that seed did not score that
# policy). PPO: eval.policy=both for seeds 0 and 1, final for seed 2 (no best: the best columns are over 2 seeds);
# L2: a store logged before eval.policy existed (final only); RECOM: eval.policy=best, whose eval/* are
# evaluations during training only (seed 0's last one at the final step, 1000), never the final policy's.
POLICY_RUNS = {
    "ppo": {"policy": ["both", "both", "final"],
            "eval": {"success_rate": [0.2, 0.4, 0.9], "mse_x": [0.5, 0.7, 0.3], "mse_y": [1.0, 1.2, 1.4],
                     "mse_z": [0.1, 0.3, 0.2], "crash_rate": [0.1, 0.0, 0.3], "return": [-300.0, -250.0, -200.0]},
            "eval_best": {"success_rate": [0.8, 0.5, None], "mse_x": [0.05, 0.15, None], "mse_y": [0.2, 0.4, None],
                          "mse_z": [0.3, 0.9, None], "crash_rate": [0.0, 0.2, None], "return": [-90.0, -120.0, None],
                          "source_step": [300.0, 600.0, None], "source_score": [-10.0, -20.0, None]},
            "eval_best_eval": {"success_rate": [0.6, 0.7, None], "mse_x": [0.4, 0.4, None],
                               "mse_y": [0.4, 0.4, None], "mse_z": [0.4, 0.4, None], "crash_rate": [0.1, 0.3, None],
                               "return": [-150.0, -140.0, None], "source_step": [500.0, 500.0, None],
                               "source_score": [-150.0, -140.0, None]}},
    "l2": {"policy": [None, None],
           "eval": {"success_rate": [0.3, 0.1], "mse_x": [0.9, 1.1], "mse_y": [0.8, 0.6], "mse_z": [0.5, 0.7],
                    "crash_rate": [0.4, 0.6], "return": [-400.0, -500.0]}},
    "recom_l2": {"policy": ["best", "best"],
                 "eval_best": {"success_rate": [1.0, 0.6], "mse_x": [0.02, 0.06], "mse_y": [0.03, 0.05],
                               "mse_z": [0.04, 0.08], "crash_rate": [0.0, 0.1], "return": [-80.0, -95.0],
                               "source_step": [900.0, 700.0], "source_score": [-5.0, -7.0]}}}


def log_policy_runs(client: MlflowClient, experiment: str) -> None:
    """Experiment ``experiment``: POLICY_RUNS in wind 'paper', a reward history each (the higher the seed, the
    higher), evaluations during training at step 500 (every eval/* key 0.05: never a final value) and, for RECOM
    seed 0, 1000; the end-of-run evaluations at step 1000."""
    exp_id = client.create_experiment(experiment)
    steps = np.arange(0, 1001, 100)
    for agent, spec in POLICY_RUNS.items():
        for seed, policy in enumerate(spec["policy"]):
            run_id = client.create_run(exp_id, tags={"agent": agent, "wind": "paper", "seed": str(seed),
                                                     "run_name": f"{agent}-s{seed}", "sweep": "policies"}).info.run_id
            params = {"wind.speeds": "[3.0]", "wind.segment_steps": "100000", "eval.wind_speed": "3.0"}
            if policy is not None:
                params["eval.policy"] = policy
            metrics = [Metric("rollout/ep_rew_mean", -100.0 + 10 * seed + s / 100, 0, int(s)) for s in steps]
            metrics += [Metric("plasticity/dormant_ratio", 0.0, 0, int(s)) for s in steps]
            during = [500] + ([1000] if agent == "recom_l2" and seed == 0 else [])
            metrics += [Metric(f"eval/{key}", 0.05, 0, step) for step in during
                        for key in ("success_rate", "mse_x", "mse_y", "mse_z", "crash_rate", "return")]
            metrics += [Metric(f"{prefix}/{key}", values[seed], 1, 1000) for prefix in ("eval", "eval_best",
                                                                                       "eval_best_eval")
                        for key, values in spec.get(prefix, {}).items() if values[seed] is not None]
            client.log_batch(run_id, metrics=metrics, params=[Param(k, v) for k, v in params.items()])
            client.set_terminated(run_id)


def by_hand(agent: str, prefix: str, key: str, scale: float = 1.0) -> tuple[float, float, int]:
    """(mean, half-width of the 95% Student-t CI (NaN for one seed), seeds) of POLICY_RUNS' values."""
    x = scale * np.array([v for v in POLICY_RUNS[agent].get(prefix, {}).get(key, []) if v is not None])
    if len(x) < 2:
        return (x.mean() if len(x) else np.nan), np.nan, len(x)
    return x.mean(), t_dist.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x)), len(x)


@pytest.fixture(scope="module")
def policy_report(tmp_path_factory):
    """(output dir, stdout) of the report of POLICY_RUNS."""
    tmp = tmp_path_factory.mktemp("policies")
    uri = new_store(tmp / "mlflow.db")
    log_policy_runs(MlflowClient(uri), "policies")
    code, stdout, stderr = run_report(uri, tmp / "out", "--experiment", "policies")
    assert code == 0, stdout + stderr
    return tmp / "out", stdout


def test_table3_shows_the_final_and_the_best_policy_side_by_side(policy_report):
    out, _ = policy_report
    table = pd.read_csv(out / "table3.csv").set_index("agent")
    shown = md_table(out / "table3.md").set_index("Control policy")
    assert list(shown.index) == ["PPO", "L2 + PPO", "RECOM + L2 PPO"]
    columns = ["Seeds", "Success final (%)", "Success best (%)", "MSE x final (m²)", "MSE x best (m²)",
               "MSE y final (m²)", "MSE y best (m²)", "MSE z final (m²)", "MSE z best (m²)", "Best taken at (step)"]
    assert list(shown.columns[1:1 + len(columns)]) == columns  # after the training wind
    cells = {"ppo": shown.loc["PPO"], "l2": shown.loc["L2 + PPO"], "recom_l2": shown.loc["RECOM + L2 PPO"]}
    for agent, cell in cells.items():
        seeds = len(POLICY_RUNS[agent]["policy"])
        assert table.loc[agent, "n_seeds"] == seeds and cell["Seeds"] == str(seeds)
        for prefix, suffix, policy in [("eval", "", "final"), ("eval_best", "_best", "best"),
                                       ("eval_best_eval", "_best_eval", None)]:
            assert table.loc[agent, f"n_seeds{suffix or '_final'}"] == by_hand(agent, prefix, "success_rate")[2]
            for key, scale, title, digits in [("success_rate", 100.0, "Success", 0), ("mse_x", 1.0, "MSE x", 2),
                                              ("mse_y", 1.0, "MSE y", 2), ("mse_z", 1.0, "MSE z", 2)]:
                mean, half, n = by_hand(agent, prefix, key, scale)
                for got, want in [(table.loc[agent, f"{key}{suffix}_mean"], mean),
                                  (table.loc[agent, f"{key}{suffix}_ci95"], half)]:
                    assert (np.isnan(got) and np.isnan(want)) or got == pytest.approx(want), (agent, prefix, key)
                if policy is None:  # the policy kept at the best in-training evaluation: in the CSV only
                    continue
                text = "–" if n == 0 else f"{mean:.{digits}f}" + (f" ± {half:.{digits}f}" if n > 1 else "")
                text += f" (n={n})" if 0 < n < seeds else ""
                assert cell[f"{title} {policy} ({'%' if key == 'success_rate' else 'm²'})"] == text, (agent, key)
    # PPO: final over 3 seeds, best over the 2 that kept one; success 20/40/90 -> 50 ± 90, 80/50 -> 65 ± 191
    assert cells["ppo"]["Success final (%)"] == "50 ± 90" and cells["ppo"]["Success best (%)"] == "65 ± 191 (n=2)"
    assert cells["ppo"]["MSE x best (m²)"] == "0.10 ± 0.64 (n=2)"
    assert table.loc["ppo", "source_step_best_mean"] == 450.0 and cells["ppo"]["Best taken at (step)"] == "450 (n=2)"
    assert table.loc["ppo", "source_step_best_eval_mean"] == 500.0
    assert table.loc["ppo", "source_score_best_mean"] == -15.0
    # L2, an older store: final only; RECOM, eval.policy=best: its evaluations during training are not final
    assert [cells["l2"][c] for c in columns[2::2]] == ["–"] * 4 and cells["l2"]["Best taken at (step)"] == "–"
    assert [cells["recom_l2"][c] for c in columns[1:9:2]] == ["–"] * 4
    assert cells["recom_l2"]["Success best (%)"] == "80 ± 254" and cells["recom_l2"]["Best taken at (step)"] == "800"
    # the top seed (highest final training reward: the highest seed) scores the final policy; RECOM's has none
    assert table.loc["ppo", "top_seed"] == 2 and cells["ppo"]["Top seed: success final (%)"] == "90"
    assert cells["ppo"]["Top seed: MSE x/y/z final (m²)"] == "0.30 / 1.40 / 0.20"
    assert cells["recom_l2"]["Top seed"] == "1" and cells["recom_l2"]["Top seed: success final (%)"] == "–"
    assert cells["recom_l2"]["Top seed: MSE x/y/z final (m²)"] == "–"
    caption = (out / "table3.md").read_text().split("\n\n")[0]
    for words in ["a constant 3 m/s wind", "final = the policy at the end of training (eval/*)",
                  "best = the policy kept during training at its highest mean training episode reward",
                  "Best taken at = the timestep", "runs with eval.policy=best no final policy's",
                  "its final policy's success rate"]:
        assert words in caption, words
    tex = (out / "table3.tex").read_text()
    assert "Success final (\\%) & Success best (\\%)" in tex and "policy kept at the highest training reward" in tex


def test_summary_and_brief_show_final_and_best_evaluation(policy_report):
    out, stdout = policy_report
    summary = pd.read_csv(out / "summary.csv").set_index("agent")
    shown = md_table(out / "summary.md").set_index("Agent")
    labels = {"ppo": "PPO", "l2": "L2 + PPO", "recom_l2": "RECOM + L2 PPO"}
    for agent, label in labels.items():
        seeds = len(POLICY_RUNS[agent]["policy"])
        for prefix, policy in [("eval", "final"), ("eval_best", "best"), ("eval_best_eval", None)]:
            column = "eval" + prefix.removeprefix("eval")
            for what in ("success", "crash"):
                mean, _, n = by_hand(agent, prefix, f"{what}_rate", 100.0)
                got = summary.loc[agent, f"{column}_{what}_pct"]
                assert (np.isnan(got) and n == 0) or got == pytest.approx(mean), (agent, prefix, what)
                if policy is not None:
                    text = "–" if n == 0 else f"{mean:.0f}" + (f" (n={n})" if n < seeds else "")
                    assert shown.loc[label, f"Eval {what} {policy} (%)"] == text, (agent, prefix, what)
    assert shown.loc["PPO", "Eval crash final (%)"] == "13" and shown.loc["PPO", "Eval crash best (%)"] == "10 (n=2)"
    assert shown.loc["RECOM + L2 PPO", "Eval success final (%)"] == "–"  # not its in-training 5%
    assert shown.loc["RECOM + L2 PPO", "Best taken at (step)"] == "800"
    assert summary.loc["ppo", "eval_best_source_step"] == 450.0
    assert summary.loc["ppo", "eval_best_eval_source_step"] == 500.0
    note = (out / "summary.md").read_text().split("\n\n")[0]
    assert "eval success / crash = the success and crash rates of the evaluation at the end of the run" in note
    assert "best = the policy kept during training at its highest mean training episode reward" in note
    # the terminal's table: final and best evaluation success
    brief = (out / "brief.txt").read_text().splitlines()
    assert brief[0].split()[:7] == ["Agent", "Wind", "Seeds", "Success:", "final", "policy", "(%)"]
    assert "Success: best-train-reward policy (%)" in brief[0] and "Crash: final (%)" in brief[0]
    assert brief[-1].startswith("final policy = the policy at the end of training; best-train-reward policy = the one "
                                "kept at its highest mean training episode reward")   # the printed table says which best
    rows = {line.split("  ")[0].strip(): line.split() for line in brief[2:-2]}
    assert rows["PPO"][2:6] == ["3", "50", "65", "(n=2)"]
    assert rows["L2 + PPO"][4:8] == ["2", "20", "–", "50"]
    assert rows["RECOM + L2 PPO"][6:8] == ["–", "80"]
    assert "\n".join(brief) in stdout


def test_a_store_of_best_policies_only_still_builds_every_file(tmp_path, monkeypatch):
    """eval.policy=best everywhere: no final policy's evaluation at the end (only the ones during training). Every
    figure and table is written, the flight figures from the best policy's flights and saying so, the final
    columns '–'."""
    uri = new_store(tmp_path / "mlflow.db")
    log_many_agents(MlflowClient(uri), "best", seeds=1, flights=tmp_path / "flights", policy="best")
    titles, save = {}, figures.save

    def spy(fig, out, stem):
        titles[stem] = " ".join([fig.get_suptitle(), *(leg.get_title().get_text() for leg in fig.legends)])
        return save(fig, out, stem)

    monkeypatch.setattr(figures, "save", spy)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "best")
    assert code == 0, stdout + stderr
    out = tmp_path / "out"
    assert figure_stems(out) == ({f"{stem}_paper" for stem in figures.CURVES if stem != "probe"}  # no probes logged
                                 | {"eval_flights_3d", "eval_position_axes", "performance_profile_paper",
                                    "interval_keeps_hovering", "interval_final_reward", "interval_success_best",
                                    "segment_scores", "segment_scores_end"})   # evaluated in several segments
    for name in TABLES + ["brief.txt"]:
        assert (out / name).stat().st_size > 0, name
    assert "missing: eval" not in stdout and "the flight figures show the best policy" in stdout
    for stem in ("eval_flights_3d", "eval_position_axes"):
        assert "best policy (by training reward)" in titles[stem] and "final policy" not in titles[stem], stem
    table = md_table(out / "table3.md")
    for column in ["Success final (%)", "MSE x final (m²)", "MSE y final (m²)", "MSE z final (m²)",
                   "Top seed: success final (%)"]:
        assert (table[column] == "–").all(), column
    best = pd.read_csv(out / "table3.csv").set_index("agent")
    for k, agent in enumerate(MANY):
        assert best.loc[agent, "success_rate_best_mean"] == pytest.approx(5.0 * k)
        assert best.loc[agent, "mse_x_best_mean"] == pytest.approx(0.1 * (k + 1))
        assert best.loc[agent, "source_step_best_mean"] == 10_000
    assert (table["Best taken at (step)"] == "10k").all()
    summary = md_table(out / "summary.md")
    assert (summary["Eval success final (%)"] == "–").all() and (summary["Eval crash final (%)"] == "–").all()
    assert (summary["Eval crash best (%)"] == "0").all()
    # the evaluation during training is drawn as before, from eval/*
    assert "eval_success_paper" in titles and "eval_crash_paper" in titles


def test_without_by_conditions_are_agents_and_look_as_before(plain_report):
    out, stdout = plain_report
    summary = pd.read_csv(out / "summary.csv")
    assert list(summary["agent"]) == ["ppo", "recom_l2"] and (summary["n_seeds"] == 2).all()
    assert "condition" not in summary and "delta_iqm" not in summary
    # the RECOM runs of the two L2 coefficients are one agent here: the older of each seed's pair left out (PPO, asked
    # for once per coefficient, ran once per seed: one job)
    assert "2 older duplicate run(s) of the same agent/learner/wind/seed left out" in stdout
    assert "| PPO | paper |" in (out / "summary.md").read_text() and "coef=" not in (out / "table3.md").read_text()
    looks = style.looks({"PPO": "ppo", "L2 + PPO": "l2", "RECOM + L2 PPO": "recom_l2", "mine": "mine"})
    assert looks["PPO"] == (style.AGENT_COLOURS["ppo"], "-")
    assert looks["RECOM + L2 PPO"][0] == style.AGENT_COLOURS["recom_l2"]
    # an agent of no fixed colour: the one its name picks, whatever else the report holds
    assert looks["mine"] == (style.agent_colour("mine"), style.OTHER_DASH) == style.looks({"m": "mine"})["m"]


def test_every_condition_looks_different():
    agent_of = {f"{a} {i}": a for a in ("ppo", "l2", "mine") for i in range(12)} | {"RECOM": "recom_l2"}
    looks = style.looks(agent_of)
    assert len({(c, str(d)) for c, d in looks.values()}) == len(agent_of) == 37
    assert looks["ppo 0"] == (style.AGENT_COLOURS["ppo"], "-")
    assert looks["RECOM"] == (style.AGENT_COLOURS["recom_l2"], style.DASHES["recom_l2"])
    assert looks == style.looks(agent_of)  # the same in every figure


def spy_legends(monkeypatch) -> dict:
    """Stem -> the legend entries of that figure: (label, colour, dash pattern); and under '<stem>:grey' the
    figure's lines drawn in style.GREY."""
    drawn, save = {}, figures.save

    def spy(fig, out, stem):
        legends = [leg for leg in [*fig.legends, *(ax.get_legend() for ax in fig.axes)] if leg is not None]
        drawn[stem] = [(text.get_text(), to_hex(handle.get_color()), handle._unscaled_dash_pattern)
                       for leg in legends for text, handle in zip(leg.get_texts(), leg.legend_handles)]
        drawn[f"{stem}:grey"] = [line for ax in fig.axes for line in ax.get_lines()
                                 if to_hex(line.get_color()) == style.GREY.lower()]
        drawn[f"{stem}:note"] = " ".join(t.get_text() for t in fig.texts).replace("\n", " ")
        return save(fig, out, stem)

    monkeypatch.setattr(figures, "save", spy)
    return drawn


# MANY's ranking (log_many_agents): agent k's evaluations at 15k and 20k steps succeed in 0.75 (0.3 + k/20) and
# 0.3 + k/20, so k >= 8 keeps hovering in both late evaluations, 4 <= k <= 7 in one; among k = 8..11 the IQM final
# reward (-900 + 0.98 (500 + 25 k) - 60 (k mod 3)) orders 9, 10, 11, 8.
MANY_RANKED = [list(MANY)[k] for k in (9, 10, 11, 8)]  # the first four
CURVE_STEMS = {"reward_paper", "episode_length_paper", "dormant_paper", "eval_success_paper", "eval_crash_paper",
               "performance_profile_paper"}


def test_many_agents_show_the_top_three_in_colour_and_the_rest_grey(tmp_path, monkeypatch):
    """Twelve agents, more than a panel shows in colour: every curve figure's legend has the top three by the
    primary measure, in its order, each with one look in all figures; the other nine are thin grey lines, named in
    the note; --highlight adds an agent; --top 12 colours all twelve with twelve distinct colours. Every table
    still names all twelve by the label their runs logged, and the legends fit the column."""
    uri = new_store(tmp_path / "mlflow.db")
    log_many_agents(MlflowClient(uri), "many")
    drawn = spy_legends(monkeypatch)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "many", draft=False)
    assert code == 0, stdout + stderr
    assert CURVE_STEMS <= set(drawn)
    top = [MANY[a] for a in MANY_RANKED[:3]]
    assert top == ["DASH warm start", "Hare & Tortoise", "zeta_plain"]
    look = {}
    for stem in CURVE_STEMS:
        assert [text for text, _, _ in drawn[stem]] == top, stem
        for text, colour, dash in drawn[stem]:
            assert look.setdefault(text, (colour, dash)) == (colour, dash), (stem, text)  # one look per agent
        greyed = sorted(set(MANY.values()) - set(top), key=str.casefold)
        assert f"Grey, without band: {', '.join(greyed)} (not among the top 3" in drawn[f"{stem}:note"], stem
        width = image.imread(tmp_path / "out" / f"{stem}.png").shape[1]
        assert width <= 1200, f"{stem}.png is {width} px wide: its legend is wider than the column"
    assert len(drawn["reward_paper:grey"]) == 9  # one thin grey line per greyed agent
    labels = sorted(MANY.values(), key=str.casefold)  # paper agents first, then by label: here by label only
    for table, column in [("table3.md", "Control policy"), ("summary.md", "Agent"), ("segments.md", "Agent")]:
        assert list(md_table(tmp_path / "out" / table)[column]) == labels, table
    assert set(pd.read_csv(tmp_path / "out" / "summary.csv")["agent"]) == set(MANY)
    tex = (tmp_path / "out" / "table3.tex").read_text()
    assert r"Shrink \& Perturb + PPO & paper &" in tex and r"Reset last layer (10\%) & paper &" in tex
    assert "older label" not in stdout + "".join(p.read_text() for p in (tmp_path / "out").glob("*.md"))

    drawn.clear()
    code, stdout, stderr = run_report(uri, tmp_path / "hl", "--experiment", "many", "--highlight", "alpha_redo")
    assert code == 0, stdout + stderr
    assert [text for text, _, _ in drawn["reward_paper"]] == [*top, MANY["alpha_redo"]]  # ranked last of the four

    drawn.clear()
    code, stdout, stderr = run_report(uri, tmp_path / "all", "--experiment", "many", "--top", "12")
    assert code == 0, stdout + stderr
    for stem in CURVE_STEMS:
        assert len(drawn[stem]) == 12 and [t for t, _, _ in drawn[stem]][:4] == [MANY[a] for a in MANY_RANKED], stem
        assert not drawn[f"{stem}:grey"] and "Grey" not in drawn[f"{stem}:note"]
        for text, colour, dash in drawn[stem]:
            assert look.setdefault(text, (colour, dash)) == (colour, dash), (stem, text)  # the same look as before
    # no agent of a fixed colour here: twelve colours derived from their names, one each
    assert len({colour for colour, _ in look.values()}) == len(look) == 12, look


def test_dormant_figure_draws_each_reading_in_a_named_panel(tmp_path, monkeypatch):
    """Every reading a run logged gets a panel named for it, with each agent's seed mean of that reading; a reading
    no run of an agent logged has no curve of it; thresholds in labels and note are the ones the runs logged."""
    uri = new_store(tmp_path / "mlflow.db")
    log_reading_runs(MlflowClient(uri), "readings")
    drawn = spy_figures(monkeypatch)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "readings", draft=False)
    assert code == 0, stdout + stderr
    figure = drawn["dormant_paper"]
    panels = figure["panels"]
    assert len(panels) == len(READINGS) == 5  # no panel for the active share: for tanh, 100 - saturated
    new = {"PPO": 0, "L2 + PPO": 1}
    for panel, (key, words) in zip(panels, READINGS.items()):
        assert words in panel["ylabel"], (key, panel["ylabel"])
        old = key in ("plasticity/dormant_ratio", "plasticity/saturated_ratio")
        assert sorted(panel["curves"]) == sorted([*new, "RECOM + L2 PPO"] if old else new), key
        for label, k in new.items():  # the mean of the two seeds' lines, in %
            expected = 100 * np.mean([reading(key, k, seed, np.linspace(0, 1, 200)) for seed in range(2)], axis=0)
            assert panel["curves"][label] == pytest.approx(expected), (key, label)
        assert ("0 throughout for every agent" in panel["texts"]) == (key == "plasticity/dormant_ratio"), key
    # the legend in the ranking's order: no evaluations during training, so by the IQM final reward (RECOM's highest)
    assert figure["legend"] == ["RECOM + L2 PPO", "L2 + PPO", "PPO"]
    note = figure["note"]
    for words in ["Sokar dormant: units with E|h| ≤ τ", "Dead tanh: units with |h| > 0.95 on ≥ 90%",
                  "Signed mean ≈ 0: units with |E h| ≤ 0.2", "not an idle unit",
                  "Saturated: activations with |h| > 0.95"]:
        assert words in note, (words, note)
    assert image.imread(tmp_path / "out" / "dormant_paper.png").shape[1] <= 1200  # one column wide


def test_summary_has_the_final_dead_tanh_and_signed_mean_shares(tmp_path):
    """Final = mean over the last 10% of timesteps, then over seeds; '–' for an agent whose runs lack the key."""
    uri = new_store(tmp_path / "mlflow.db")
    log_reading_runs(MlflowClient(uri), "readings")
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "readings")
    assert code == 0, stdout + stderr
    summary = pd.read_csv(tmp_path / "out" / "summary.csv").set_index("agent")
    shown = md_table(tmp_path / "out" / "summary.md").set_index("Agent")
    steps = np.arange(0, 1001, 100, dtype=float)
    for agent, label, k in [("ppo", "PPO", 0), ("l2", "L2 + PPO", 1)]:
        for key, column, title in [("plasticity/dead_tanh_ratio", "final_dead_tanh_ratio", "Final dead tanh (%)"),
                                   ("plasticity/signed_mean_ratio", "final_signed_mean_ratio",
                                    "Final signed-mean≈0 (%)")]:
            by_hand = np.mean([final((steps, reading(key, k, seed, steps / 1000))) for seed in range(2)])
            assert summary.loc[agent, column] == pytest.approx(by_hand), (agent, key)
            assert shown.loc[label, title] == f"{100 * by_hand:.2f}", (agent, key)
    # PPO's dead tanh share: 0.06 + 0.01 s + 0.15 t, final (t = 0.9, 1) 0.2025 + 0.01 s -> 20.75% over seeds 0, 1
    assert shown.loc["PPO", "Final dead tanh (%)"] == "20.75"
    assert np.isnan(summary.loc["recom_l2", "final_dead_tanh_ratio"])
    assert np.isnan(summary.loc["recom_l2", "final_signed_mean_ratio"])
    assert shown.loc["RECOM + L2 PPO", "Final dead tanh (%)"] == "–"
    assert shown.loc["RECOM + L2 PPO", "Final signed-mean≈0 (%)"] == "–"
    assert shown.loc["RECOM + L2 PPO", "Final saturated (%)"] != "–"  # the readings it logged are there


def test_a_store_without_the_new_readings_still_builds_every_file(tmp_path, monkeypatch):
    """Runs logged before the readings existed (every other curve, flights): every figure and table is written,
    the dormant figure has Sokar's ratio and the saturated share, the new summary columns say '–'."""
    uri = new_store(tmp_path / "mlflow.db")
    log_many_agents(MlflowClient(uri), "old", seeds=1, flights=tmp_path / "flights")
    drawn = spy_figures(monkeypatch)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "old")
    assert code == 0, stdout + stderr
    out = tmp_path / "out"
    assert figure_stems(out) == ({f"{stem}_paper" for stem in figures.CURVES if stem != "probe"}  # no probes logged
                                 | {"eval_flights_3d", "eval_position_axes", "performance_profile_paper",
                                    "interval_keeps_hovering", "interval_final_reward", "interval_success_final",
                                    "segment_scores", "segment_scores_end"})   # evaluated in several segments
    for name in TABLES:
        assert (out / name).stat().st_size > 0, name
    panels = drawn["dormant_paper"]["panels"]
    assert [p["ylabel"] for p in panels] == ["Sokar dormant,\nτ = 0.025 (%)", "Saturated\nactivations (%)"]
    assert all(len(p["curves"]) == 3 for p in panels)  # the top three in colour, the other nine grey, unlabelled
    note = drawn["dormant_paper"]["note"]
    assert "Sokar dormant" in note and "Saturated" in note and "Dead tanh" not in note and "Signed mean" not in note
    shown = md_table(out / "summary.md")
    assert (shown["Final dead tanh (%)"] == "–").all() and (shown["Final signed-mean≈0 (%)"] == "–").all()
    assert (shown["Final saturated (%)"] != "–").all()
    for key in NEW_READINGS:
        assert key not in stdout  # keys older stores lack are not reported missing run by run


def test_labels_fall_back_for_older_stores_never_collide_and_title_panels():
    assert load.agent_label("l2", {"agent_label": "Tag"}, {"agent.label": "Param"}) == "Tag"
    assert load.agent_label("l2", {}, {"agent.label": "Param"}) == "Param"
    assert load.agent_label("l2", {}, {}) == "L2 + PPO" and load.agent_label("mine", {}, {}) == "mine"
    runs = pd.DataFrame({"agent": ["a", "a", "b", "c"], "label": ["Old", "Same", "Same", "C"],
                         "start_time": [2, 3, 1, 1]})
    assert conditions.agent_labels(runs) == {"a": "Same [a]", "b": "Same [b]", "c": "C"}
    assert conditions.agent_labels(runs.assign(start_time=[3, 2, 1, 1])) == {"a": "Old", "b": "Same", "c": "C"}
    # a narrow panel's title: the agent's label, then the --by values (a label's own brackets are no --by value)
    runs = pd.DataFrame({"agent": ["ppo", "x", "x"], "label": ["PPO", "Reset (10%)", "Reset (10%)"],
                         "start_time": [1, 1, 1], "agent.l2.coef": [load.NA, "0.1", "0.2"]})
    _, conds = conditions.build(runs, ["agent.l2.coef"])
    assert conds.order == ["PPO", "Reset (10%) (coef=0.1)", "Reset (10%) (coef=0.2)"]
    titles = [figures._title(c, conds, 24) for c in conds.order]
    assert titles == ["PPO", "Reset (10%)\ncoef=0.1", "Reset (10%)\ncoef=0.2"]


@pytest.mark.parametrize("args, message", [
    (["--by", "agent.l2.coeff"], "unknown --by key 'agent.l2.coeff': no run logged that param"),
    (["--by", "agent.l2.coef", "--baseline", "agent.learner=sb3"], "--baseline key 'agent.learner' is neither"),
    (["--by", "agent.l2.coef", "--baseline", "agent.l2.coef=0.5"], "no run has agent.l2.coef=0.5 (values: 0.001, 0.01"),
    (["--baseline", "agent=ppo"], "--baseline needs --by"),
    (["--highlight", "ppo,nope"], "--highlight nope: no finished runs of that agent"),
    (["--top", "0"], "--top 0: must be at least 1"),
])
def test_by_and_baseline_mistakes_are_one_error_line_and_exit_1(store, tmp_path, args, message):
    code, _, stderr = run_report(store, tmp_path / "out", "--experiment", EXPERIMENT, *args)
    lines = stderr.strip().splitlines()
    assert code == 1 and len(lines) == 1 and lines[0].startswith("sweep.report: ") and message in lines[0], stderr
    if "coeff" in args[1]:
        assert "agent.l2.coef" in lines[0]  # names params that exist
    assert not (tmp_path / "out").exists()


def test_empty_store_is_one_error_line_and_exit_1(tmp_path):
    uri = new_store(tmp_path / "empty.db")   # a store without runs
    proc = subprocess.run([sys.executable, "-m", "sweep.report", "--out", str(tmp_path / "out")], cwd=tmp_path,
                          env=env_with(uri), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sweep.report: ") and "no runs" in lines[0], proc.stderr
    assert not (tmp_path / "out").exists()


def test_unknown_experiment_is_one_error_line_and_exit_1(store, monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", store)
    assert main(["--experiment", "no-such-experiment", "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sweep.report: unknown experiment 'no-such-experiment'")
    assert EXPERIMENT in err[0]


def test_probe_table_and_figure_from_hand_built_probe_losses(tmp_path):
    """probe.md / probe.csv: the probe loss at each step it was logged (wind changes, the end), mean ± 95% t CI
    over seeds per agent; the probe figure is drawn; a store without probes writes neither (HAND)."""
    from scipy import stats as sst

    uri = new_store(tmp_path / "mlflow.db")
    client = MlflowClient(uri)
    exp_id = client.create_experiment("probe")
    losses = {("ppo", 0): [0.010, 0.020, 0.040], ("ppo", 1): [0.012, 0.018, 0.050], ("l2", 0): [0.010, 0.011, 0.012]}
    for (agent, seed), values in losses.items():
        run_id = client.create_run(exp_id, tags={"agent": agent, "wind": "paper", "seed": str(seed),
                                                 "run_name": f"{agent}-s{seed}"}).info.run_id
        metrics = [Metric("rollout/ep_rew_mean", -100.0 + s / 100, 0, int(s)) for s in range(0, 3001, 500)]
        metrics += [Metric("plasticity/probe_loss", v, 0, step) for v, step in zip(values, (1000, 2000, 3000))]
        metrics += [Metric("plasticity/probe_loss_early", 10 * v, 0, step) for v, step in zip(values, (1000, 2000, 3000))]
        client.log_batch(run_id, metrics=metrics)
        client.set_terminated(run_id)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "probe")
    assert code == 0, stdout + stderr
    numbers = pd.read_csv(tmp_path / "out" / "probe.csv")
    ppo_end = numbers[(numbers["agent"] == "ppo") & (numbers["step"] == 3000)].iloc[0]
    assert ppo_end["mean"] == pytest.approx(0.045) and ppo_end["n_seeds"] == 2
    assert ppo_end["ci95"] == pytest.approx(sst.t.ppf(0.975, 1) * np.std([0.04, 0.05], ddof=1) / np.sqrt(2))
    shown = md_table(tmp_path / "out" / "probe.md").set_index("Agent")
    assert list(shown.columns[-3:]) == ["1k", "2k", "3k"] and shown.loc["L2 + PPO", "3k"] == "0.012"
    assert (tmp_path / "out" / "probe_paper.png").exists()
    summary = pd.read_csv(tmp_path / "out" / "summary.csv").set_index("agent")
    assert summary.loc["ppo", "final_probe_loss"] == pytest.approx(0.045)  # the last probe (within the last 10%)


def test_reward_at_steps_gives_the_iqm_and_its_difference_to_the_baseline(tmp_path):
    """--at: per run the last reward logged at or before each step; HAND at step 550 (logged at 500): PPO seeds
    -50 and -57.5 (IQM of two = their mean), RECOM -50 x 3; Δ = 3.75 with a bootstrap CI of exactly [0, 7.5]
    (PPO's resamples are {-50,-50}, mixed, {-57.5,-57.5}); without --at no such file."""
    uri = new_store(tmp_path / "mlflow.db")
    log_hand_runs(MlflowClient(uri))
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", HAND, "--by", "agent.l2.coef",
                                      "--baseline", "agent=ppo", "--at", "550,1000")
    assert code == 0, stdout + stderr
    got = pd.read_csv(tmp_path / "out" / "reward_at.csv").set_index(["agent", "step"])
    assert got.loc[("ppo", 550), "iqm"] == pytest.approx(-53.75) and got.loc[("recom_l2", 550), "iqm"] == -50.0
    row = got.loc[("recom_l2", 550)]
    assert (row["delta_iqm"], row["delta_ci_low"], row["delta_ci_high"]) == pytest.approx((3.75, 0.0, 7.5))
    # the last values -5, -15, -30: rliable's IQM trims int(0.25 n) = 0 of 3 runs per side, so their mean
    assert got.loc[("recom_l2", 1000), "iqm"] == pytest.approx(-50 / 3)
    assert np.isnan(got.loc[("ppo", 1000), "delta_iqm"])               # PPO is the baseline itself
    code, _, _ = run_report(uri, tmp_path / "plain", "--experiment", HAND)
    assert code == 0 and not (tmp_path / "plain" / "reward_at.md").exists()


LATE = {("ppo", 0): [0.6, 0.6, 0.0, 0.0, 0.0], ("ppo", 1): [0.0] * 5, ("l2", 0): [1.0] * 5, ("l2", 1): [0.5] * 5}


def log_late_evaluations(tmp_path, late: dict) -> str:
    """Experiment 'lb': per (agent, seed) evaluations every 100 steps to 1000, the last five (steps > 500, the
    'late' ones) given; the first five at 0.1 x seed. Runs of 1 and 2 minutes. Returns the store's URI."""
    uri = new_store(tmp_path / "mlflow.db")
    client = MlflowClient(uri)
    exp_id = client.create_experiment("lb")
    for (agent, seed), values in late.items():
        run_id = client.create_run(exp_id, start_time=1_000_000, tags={"agent": agent, "wind": "paper", "seed": str(seed),
                                                                        "run_name": f"{agent}-s{seed}"}).info.run_id
        evals = [0.1 * seed] * 5 + values
        metrics = [Metric("rollout/ep_rew_mean", -100.0 + s / 100, 0, int(s)) for s in range(0, 1001, 100)]
        metrics += [Metric("eval/success_rate", v, 0, 100 * (i + 1)) for i, v in enumerate(evals)]
        client.log_batch(run_id, metrics=metrics, params=[Param("agent.l2.enabled", str(agent == "l2"))])
        client.set_terminated(run_id, end_time=1_000_000 + 60_000 * (seed + 1))  # runs of 1 and 2 minutes
    return uri


def test_leaderboard_and_performance_profile_on_hand_built_evaluations(tmp_path):
    """Evaluations every 100 steps to 1000, 'late' = steps > 500 (five of them). PPO seed 0 hovers in 2 of 5 late
    evaluations, seed 1 never; L2 seed 0 at 100%, seed 1 at 50% (counts: >= 50%). Leaderboard: L2 first at
    100 ± 0%, PPO 20% (per seed 40, 0); P(L2 > PPO) = 1 (every pair). Learned the hover (any evaluation at
    >= 50%): both L2 seeds, PPO's seed 0 only (its seed 1 peaks at 0.1), so PPO's seeds that learned kept 40%
    and L2's 100%. Profile of the late mean success:
    L2's runs (1.0, 0.5) -> 100% above τ = 0.4, 50% above 0.5 (strictly) and 0.99, 0% above 1."""
    from sweep.report import stats as rstats

    uri = log_late_evaluations(tmp_path, LATE)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "lb")
    assert code == 0, stdout + stderr
    board = pd.read_csv(tmp_path / "out" / "leaderboard.csv")
    assert list(board["agent"]) == ["l2", "ppo"]
    assert board.loc[0, "keeps_hovering"] == 1.0 and board.loc[0, "keeps_hovering_ci95"] == 0.0
    assert board.loc[1, "keeps_hovering"] == pytest.approx(0.2)
    assert board.loc[0, "p_improve_over_ppo"] == 1.0 and np.isnan(board.loc[1, "p_improve_over_ppo"])
    assert list(board["learned_seeds"]) == [2, 1] and list(board["kept_if_learned"]) == pytest.approx([1.0, 0.4])
    shown = md_table(tmp_path / "out" / "leaderboard.md").set_index("Agent")
    assert shown.loc["PPO", "per seed"] == "40, 0" and shown.loc["L2 + PPO", "Keeps hovering (%)"] == "100 ± 0"
    assert shown.loc["PPO", "Learned the hover (seeds)"] == "1/2"
    assert shown.loc["PPO", "Keeps hovering, seeds that learned (%)"] == "40"   # one seed: no interval
    assert list(board["wall_minutes"]) == [1.5, 1.5] and shown.loc["PPO", "Wall time per run (min)"] == "1.5"
    summary = md_table(tmp_path / "out" / "summary.md").set_index("Agent")
    assert summary.loc["L2 + PPO", "Wall time per run (min)"] == "1.5"
    assert (tmp_path / "out" / "performance_profile_paper.png").exists()
    point, lo, hi = rstats.performance_profile([1.0, 0.5], np.array([0.4, 0.5, 0.99, 1.0]))
    assert list(point) == [1.0, 0.5, 0.5, 0.0] and lo[0] == hi[0] == 1.0 and (lo[1], hi[1]) == (0.0, 1.0)


def test_versus_table_compares_every_agent_with_each_reference(tmp_path):
    """--vs ppo,l2 on LATE (keeps hovering: PPO 0.4 and 0; L2 1 and 1; a third agent ReDo 0.4 and 0, PPO's):
    L2 vs PPO: P = 1, Δ = +80 pp with the bootstrap CI [60, 100] (L2's resamples are all 1; PPO's means are 0.4,
    0.2 or 0 with probabilities 1/4, 1/2, 1/4); ReDo vs PPO: P = 0.5 [0, 1], Δ 0; each reference against itself
    empty. --vs nope: one error line naming the agents there are."""
    late = {**LATE, ("l2", 1): [1.0] * 5, ("redo", 0): LATE[("ppo", 0)], ("redo", 1): LATE[("ppo", 1)]}
    uri = log_late_evaluations(tmp_path, late)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "lb", "--vs", "ppo,l2")
    assert code == 0, stdout + stderr
    got = pd.read_csv(tmp_path / "out" / "versus.csv").set_index("agent")
    assert list(got.index) == ["l2", "ppo", "redo"]  # keeps hovering, highest first (PPO and ReDo tie: display order)
    l2 = got.loc["l2"]
    assert (l2["p_improve_over_ppo"], l2["delta_keeps_vs_ppo"]) == pytest.approx((1.0, 0.8))
    assert (l2["delta_keeps_vs_ppo_ci_low"], l2["delta_keeps_vs_ppo_ci_high"]) == pytest.approx((0.6, 1.0))
    assert np.isnan(l2["p_improve_over_l2"]) and np.isnan(got.loc["ppo", "p_improve_over_ppo"])
    redo = got.loc["redo"]
    assert (redo["p_improve_over_ppo"], redo["delta_keeps_vs_ppo"]) == pytest.approx((0.5, 0.0))
    assert redo["p_improve_over_l2"] == 0.0 and redo["delta_keeps_vs_l2"] == pytest.approx(-0.8)
    shown = md_table(tmp_path / "out" / "versus.md").set_index("Agent")
    assert shown.loc["L2 + PPO", "Δ vs PPO (pp) [95% CI]"] == "80 [60, 100]"
    assert shown.loc["PPO", "P(> L2 + PPO) [95% CI]"] == "0.00 [0.00, 0.00]"
    code, _, stderr = run_report(uri, tmp_path / "bad", "--experiment", "lb", "--vs", "ppo,nope")
    lines = stderr.strip().splitlines()
    assert code == 1 and len(lines) == 1 and "--vs nope" in lines[0] and "l2, ppo, redo" in lines[0]


def test_agents_option_keeps_only_those_agents_and_names_unknown_ones(tmp_path):
    """--agents l2: every table holds L2 only; --agents l2,nope: one error line naming what the experiment has."""
    uri = new_store(tmp_path / "mlflow.db")
    client = MlflowClient(uri)
    exp_id = client.create_experiment("pick")
    for agent, seed in [("ppo", 0), ("ppo", 1), ("l2", 0), ("l2", 1)]:
        run_id = client.create_run(exp_id, tags={"agent": agent, "wind": "paper", "seed": str(seed),
                                                 "run_name": f"{agent}-s{seed}"}).info.run_id
        client.log_batch(run_id, metrics=[Metric("rollout/ep_rew_mean", -100.0 + s / 100, 0, s) for s in (0, 500, 1000)])
        client.set_terminated(run_id)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "pick", "--agents", "l2")
    assert code == 0, stdout + stderr
    assert list(pd.read_csv(tmp_path / "out" / "summary.csv")["agent"]) == ["l2"]
    assert "missing: agent=" not in stdout  # the agents left out on purpose are not reported missing
    code, _, stderr = run_report(uri, tmp_path / "bad", "--experiment", "pick", "--agents", "l2,nope")
    lines = stderr.strip().splitlines()
    assert code == 1 and len(lines) == 1 and "--agents nope: no finished runs" in lines[0] and "l2, ppo" in lines[0]


def log_cells(client: MlflowClient, experiment: str, cells, sweep: str = "hand") -> dict[tuple, str]:
    """Runs of ``experiment``, one per (agent, seed, learner tag or None, status, final reward), in this order
    (later = newer), wind paper, reward history 0..1000 ending at the final reward; -> (agent, seed, learner,
    status) -> run id."""
    exp_id = client.create_experiment(experiment)
    ids = {}
    for i, (agent, seed, learner, status, reward) in enumerate(cells):
        tags = {"agent": agent, "wind": "paper", "seed": str(seed), "run_name": f"{agent}-{learner}-s{seed}",
                "sweep": sweep} | ({"learner": learner} if learner else {})
        run_id = client.create_run(exp_id, tags=tags, start_time=1000 * (i + 1)).info.run_id
        client.log_batch(run_id, metrics=[Metric("rollout/ep_rew_mean", reward * s / 1000, 0, s)
                                          for s in (0, 500, 1000)],
                         params=[Param("agent.learner", learner)] if learner else [])
        client.set_terminated(run_id, status)
        ids[(agent, seed, learner, status)] = run_id
    return ids


def test_runs_of_two_learners_are_two_conditions(tmp_path):
    """PPO on SB3 (one run from before the learner tag: SB3) and on JAX, two seeds each, and L2 on SB3: the
    duplicate filter keeps every learner's run (only the older SB3 run of seed 0 goes), and the report splits the
    learners as --by agent.learner would, saying so."""
    uri = new_store(tmp_path / "mlflow.db")
    client = MlflowClient(uri)
    log_cells(client, "learners", [("ppo", 0, "sb3", "FINISHED", -500.0), ("ppo", 0, None, "FINISHED", -100.0),
                                   ("ppo", 1, "sb3", "FINISHED", -120.0), ("ppo", 0, "jax", "FINISHED", -300.0),
                                   ("ppo", 1, "jax", "FINISHED", -320.0), ("l2", 0, "sb3", "FINISHED", -50.0),
                                   ("l2", 1, "sb3", "FINISHED", -60.0)])
    loaded = load.read_runs(client, client.get_experiment_by_name("learners").experiment_id)
    assert sorted(zip(loaded.runs["agent"], loaded.runs["learner"], loaded.runs["seed"])) == [
        ("l2", "sb3", 0), ("l2", "sb3", 1), ("ppo", "jax", 0), ("ppo", "jax", 1), ("ppo", "sb3", 0), ("ppo", "sb3", 1)]
    assert loaded.notes == ["1 older duplicate run(s) of the same agent/learner/wind/seed left out "
                            "(use --sweep to pick one sweep)"] and loaded.asked.empty
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "learners")
    assert code == 0, stdout + stderr
    assert "runs of ppo come from several learners (jax, sb3): kept apart as with --by agent.learner" in stdout
    summary = pd.read_csv(tmp_path / "out" / "summary.csv").set_index("condition")
    assert set(summary.index) == {"PPO (learner=jax)", "PPO (learner=sb3)", "L2 + PPO (learner=sb3)"}
    assert (summary["n_seeds"] == 2).all()
    # the SB3 seed 0 kept is the newer run (-100), not the older -500; JAX's mean is its own
    assert summary.loc["PPO (learner=sb3)", "final_reward"] == pytest.approx(-110.0)
    assert summary.loc["PPO (learner=jax)", "final_reward"] == pytest.approx(-310.0)
    # one learner per agent: nothing to split
    code, stdout, _ = run_report(uri, tmp_path / "sb3", "--experiment", "learners", "--agents", "l2")
    assert code == 0 and "several learners" not in stdout
    assert list(pd.read_csv(tmp_path / "sb3" / "summary.csv")["agent"]) == ["l2"]


def test_missing_lines_name_only_what_a_sweep_asked_for(tmp_path):
    """Missing lines name a cell whose run failed without a finished run of the same agent/wind/seed/learner, and
    a multirun job that ended INVALID before its run existed; not a failed run that was run again, not a job of
    another experiment, and not the paper's agents or winds nobody ran."""
    uri = new_store(tmp_path / "mlflow.db")
    client = MlflowClient(uri)
    sweep = tmp_path / "multirun"
    ids = log_cells(client, "asked", [("ppo", 0, "sb3", "FINISHED", -100.0), ("ppo", 1, "sb3", "FAILED", -900.0),
                                      ("ppo", 1, "sb3", "FINISHED", -110.0), ("l2", 0, "sb3", "FINISHED", -50.0),
                                      ("l2", 1, "sb3", "FAILED", -900.0), ("l2", 1, "jax", "KILLED", -900.0)],
                    sweep=str(sweep))
    jobs = {"0": ("FINISHED", {"run_id": ids[("ppo", 0, "sb3", "FINISHED")]}, "asked"),
            "1": ("INVALID", {"reason": "agent.weight_clip.kappa=-1: must be > 0"}, "asked"),
            "2": ("INVALID", {"reason": "some other study"}, "elsewhere"),
            "3": ("FAILED", {"run_id": ids[("l2", 1, "sb3", "FAILED")], "reason": "RuntimeError: boom"}, "asked")}
    for job, (status, fields, experiment) in jobs.items():
        (sweep / job / ".hydra").mkdir(parents=True)
        (sweep / job / ".hydra" / "config.yaml").write_text(
            f"seed: 0\nagent:\n  name: weight_clip\n  learner: sb3\nwind:\n  name: paper\n"
            f"vehicle:\n  name: nominal\ntracking:\n  experiment: {experiment}\n")
        (sweep / job / "status.json").write_text(json.dumps({"status": status, **fields}))
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "asked")
    assert code == 0, stdout + stderr
    missing = [line.removeprefix("sweep.report: missing: ") for line in stdout.splitlines()
               if line.startswith("sweep.report: missing: agent=")]
    assert missing == ["agent=l2 wind=paper learner=jax seed=1 (no finished run: run l2-jax-s1 KILLED)",
                       "agent=l2 wind=paper learner=sb3 seed=1 (no finished run: run l2-sb3-s1 FAILED)",
                       f"agent=weight_clip wind=paper learner=sb3 seed=0 (no finished run: job 1 of {sweep} "
                       "INVALID: agent.weight_clip.kappa=-1: must be > 0)"], missing
    assert "recom_l2" not in stdout and "wind=none" not in stdout   # the paper's design is not asked for here
    code, stdout, _ = run_report(uri, tmp_path / "l2", "--experiment", "asked", "--agents", "ppo")
    assert code == 0 and "missing: agent=" not in stdout           # PPO's failed seed 1 ran again and finished


# -- figures for many agents and arms (issue 34) ---------------------------------------------------------------

# twelve agents of fixed colour (not conf/agent/: adding a YAML there changes nothing here); PPO is agent 0
ARM_AGENTS = [a for a in style.AGENT_COLOURS if a != "reset_all"][:12]


def log_arms(client: MlflowClient, experiment: str) -> None:
    """Experiment ``experiment``: the twelve agents of conf/agent (agent i = ARM_AGENTS[i]) in two layouts
    (env.n_envs 1 and 16), two seeds, evaluations every 50 steps to 1200, the 12 after step 600 'late'. Agent i
    keeps hovering in i of 12 late evaluations with 1 env and in 11 - i with 16; its final reward is -100 + i with
    1 env and -99.5 + 11 - i with 16 (so the pooled ranking has no ties)."""
    exp_id = client.create_experiment(experiment)
    steps = np.arange(50, 1201, 50)
    for i, agent in enumerate(ARM_AGENTS):
        for n_envs, keeps, reward in (("1", i, -100.0 + i), ("16", 11 - i, -99.5 + 11 - i)):
            for seed in range(2):
                run_id = client.create_run(exp_id, tags={"agent": agent, "wind": "paper", "seed": str(seed),
                                                         "run_name": f"{agent}-{n_envs}-s{seed}"}).info.run_id
                late = [1.0] * keeps + [0.0] * (12 - keeps)
                metrics = [Metric("rollout/ep_rew_mean", reward * s / 1200, 0, int(s)) for s in steps]
                metrics += [Metric("eval/success_rate", v, 0, int(s)) for s, v in zip(steps, [0.0] * 12 + late)]
                client.log_batch(run_id, metrics=metrics, params=[Param("env.n_envs", n_envs)])
                client.set_terminated(run_id)


def spy_panels(monkeypatch) -> dict:
    """Stem -> per axes (left to right, top to bottom): its title, its y tick labels bottom to top, its labelled
    lines (label -> colour) and the number of its grey lines; and the figure's legend labels."""
    drawn, save = {}, figures.save

    def spy(fig, out, stem):
        axes = [ax for ax in fig.axes if ax.get_visible()]
        drawn[stem] = {
            "axes": [{"title": ax.get_title(),
                      "yticks": [t.get_text() for _, t in sorted(zip(ax.get_yticks(), ax.get_yticklabels()))],
                      "lines": {ln.get_label(): to_hex(ln.get_color()) for ln in ax.get_lines()
                                if not ln.get_label().startswith("_")},
                      "grey": sum(to_hex(ln.get_color()) == style.GREY.lower() for ln in ax.get_lines())}
                     for ax in axes],
            "legend": [t.get_text() for leg in fig.legends for t in leg.get_texts()]}
        return save(fig, out, stem)

    monkeypatch.setattr(figures, "save", spy)
    return drawn


def test_twelve_agents_in_two_layouts_give_small_multiples_ranked_intervals_and_one_look_each(tmp_path, monkeypatch):
    """--by env.n_envs with twelve agents: one panel per layout side by side. The interval figure sorts each panel
    by its own ranking (layout 1: agent 11 on top; layout 16: agent 0). The curves colour the top three of each
    panel (agents 9-11 and 0-2), PPO (agent 0) and the --highlight agent (layer_norm), each in its own colour
    (style.AGENT_COLOURS) in both panels, the legend in ranking order; the other five are grey in both panels."""
    uri = new_store(tmp_path / "mlflow.db")
    log_arms(MlflowClient(uri), "arms")
    drawn = spy_panels(monkeypatch)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "arms", "--by", "env.n_envs",
                                      "--highlight", "layer_norm", draft=False)
    assert code == 0, stdout + stderr
    labels = {a: conditions.agent_labels(load_arm_runs(uri)).get(a, a) for a in ARM_AGENTS}
    one, sixteen = drawn["interval_keeps_hovering"]["axes"]
    assert (one["title"], sixteen["title"]) == ("wind paper, n_envs=1 (2 seeds)", "wind paper, n_envs=16 (2 seeds)")
    assert one["yticks"] == [labels[a] for a in ARM_AGENTS]  # bottom to top: agent 0 ... agent 11 (the best)
    assert sixteen["yticks"] == [labels[a] for a in reversed(ARM_AGENTS)]
    coloured = [ARM_AGENTS[i] for i in (0, 1, 2, 7, 9, 10, 11)]
    # pooled ranking: keeps 11/12 (agent 0 in 16 envs, reward -88.5; agent 11 in 1 env, -89), 10/12, 9/12, ...
    ranked = [ARM_AGENTS[i] for i in (0, 11, 1, 10, 2, 9, 7)]
    for stem in ("reward_paper", "eval_success_paper", "performance_profile_paper"):
        figure = drawn[stem]
        assert [ax["title"] for ax in figure["axes"]] == ["n_envs=1", "n_envs=16"], stem
        assert figure["legend"] == [labels[a] for a in ranked], stem
        for ax in figure["axes"]:
            assert ax["lines"] == {labels[a]: style.AGENT_COLOURS[a].lower() for a in coloured}, stem
            assert ax["grey"] >= 5, stem  # the other five agents (markers of sparse curves may add more)
    assert drawn["reward_paper"]["axes"][0]["grey"] == 5
    for stem, figure in drawn.items():  # no two series of a figure look alike
        colours = [c for ax in figure["axes"] for c in ax["lines"].values()]
        series = {(label, c) for ax in figure["axes"] for label, c in ax["lines"].items()}
        assert len({c for _, c in series}) == len({label for label, _ in series}), stem
    width = image.imread(tmp_path / "out" / "reward_paper.png").shape[1]
    assert width <= 2200, "both columns at most"


def load_arm_runs(uri: str) -> pd.DataFrame:
    client = MlflowClient(uri)
    runs, _ = load.load_runs(client, client.get_experiment_by_name("arms").experiment_id)
    return runs


def test_intervals_are_the_seed_mean_with_its_t_interval_and_the_iqm_with_its_bootstrap():
    from sweep.report import intervals

    values = [0.0, 0.5, 1.0]
    half = t_dist.ppf(0.975, 2) * np.std(values, ddof=1) / np.sqrt(3)
    assert intervals.estimate(values, "mean") == pytest.approx((0.5, 0.5 - half, 0.5 + half, 3))
    assert intervals.estimate([0.4, np.nan], "mean") == (0.4, 0.4, 0.4, 1)  # one seed: a point, no interval
    # a share in percent: the t-interval of 0, 50, 100 reaches past both ends and is cut to [0, 100]
    runs, conds = conditions.build(pd.DataFrame({"run_id": ["a", "b", "c"], "agent": "ppo", "label": "PPO",
                                                 "wind": "flip", "start_time": 0, "share": values}), [])
    for percent, bounds in ((True, (0.0, 100.0)), (False, (100 * (0.5 - half), 100 * (0.5 + half)))):
        got = intervals.estimates(runs, intervals.Measure("share", "Share", "mean", 100.0, percent), conds)
        assert tuple(got[["low", "high"]].iloc[0]) == pytest.approx(bounds) and got["point"].iloc[0] == 50.0
        assert got["cut"].iloc[0] == percent  # the caption says "cut to 0-100" only then
    inside = intervals.estimates(runs.assign(share=[0.4, 0.5, 0.6]),
                                 intervals.Measure("share", "Share", "mean", 100.0, True), conds)
    assert not inside["cut"].iloc[0]  # 50 ± 25: nothing to cut
    rewards = [-300.0, -250.0, -100.0, -90.0, -80.0, -20.0, 0.0, 10.0]
    point, lo, hi, n = intervals.estimate(rewards, "iqm")
    assert point == pytest.approx(trim_mean(rewards, 0.25)) and (lo, hi) == stats.iqm_ci(rewards)[1:] and n == 8


def test_interval_rows_are_drawn_as_rliable_draws_them():
    """One panel's rows: the same bars (x, width, y, height) and point ticks as rliable's plot_interval_estimates."""
    from matplotlib import pyplot as plt
    from rliable import plot_utils

    from sweep.report import intervals

    rows = {"a": (0.2, 0.1, 0.35), "b": (0.5, 0.45, 0.7), "c": (0.9, 0.8, 0.95)}
    colours = dict(zip(rows, ["#D55E00", "#0072B2", "#009E73"]))
    fig, theirs = plot_utils.plot_interval_estimates(
        {a: np.array([p]) for a, (p, _, _) in rows.items()},
        {a: np.array([[lo], [hi]]) for a, (_, lo, hi) in rows.items()}, ["m"], algorithms=list(rows), colors=colours)
    _, ours = plt.subplots()
    for y, (a, (p, lo, hi)) in enumerate(rows.items()):
        intervals._row(ours, y, p, lo, hi, colours[a])

    def drawn(ax):
        bars = [(r.get_x(), r.get_width(), r.get_y(), r.get_height(), to_hex(r.get_facecolor())) for r in ax.patches]
        ticks = [np.asarray(c.get_segments()).round(12).tolist() for c in ax.collections]
        return bars, ticks
    assert drawn(ours) == drawn(theirs)
    plt.close("all")


NEW_AGENTS = ["weight_clip", "sac", "td3", "layer_norm_reset_all"]  # agents of no fixed colour (a twin, <agent>_fresh,
# takes its agent's colour on purpose: tests/test_twin.py)


def test_every_agent_has_a_colour_apart_from_the_others_for_colour_blind_readers():
    """Every agent of conf/agent/ (and reset_all), plus new ones, gets its colour from style.agent_colours (what the
    report's looks use): the named keep AGENT_COLOURS, any two differ by at least style.MIN_DELTA_E where both are
    named and style.DERIVED_MIN_DELTA_E otherwise (CIE76 ΔE in CIELAB, D65, for normal vision and as seen with
    deuteranopia and protanopia, Machado et al. 2009, severity 1); grey stands apart. Nothing here is counted."""
    assert style.lab("#FFFFFF") == pytest.approx([100.0, 0.0, 0.0], abs=0.05)
    assert style.lab("#FF0000") == pytest.approx([53.24, 80.09, 67.20], abs=0.05)  # sRGB red, D65
    assert style.lab("#FF0000", "protanopia")[0] < 45 < style.lab("#FF0000")[0]  # red looks darker to a protanope
    agents = sorted({path.stem for path in (ROOT / "conf" / "agent").glob("*.yaml")} | {"reset_all", *NEW_AGENTS})
    colour = style.agent_colours(agents)
    assert colour == {a: look[0] for a, look in style.looks(dict(zip(agents, agents))).items()}
    assert {a: colour[a] for a in agents if a in style.AGENT_COLOURS} == {
        a: c for a, c in style.AGENT_COLOURS.items() if a in agents}   # the published colours, unchanged
    named = [*style.PALETTE, style.GREY]
    for a, b in [(a, b) for i, a in enumerate(agents) for b in agents[i + 1:]]:
        both = a in style.AGENT_COLOURS and b in style.AGENT_COLOURS
        assert style.delta_e(colour[a], colour[b]) >= (style.MIN_DELTA_E if both else style.DERIVED_MIN_DELTA_E), (a, b)
    assert min(style.delta_e(c, style.GREY) for c in colour.values()) >= 10
    # the whole set a new agent picks from: apart from every named colour, grey and each other
    for i, c in enumerate(style.DERIVED):
        assert min(style.delta_e(c, other) for other in named + style.DERIVED[i + 1:]) >= style.DERIVED_MIN_DELTA_E, c


def test_a_new_agents_colour_comes_from_its_name_and_stays_apart_from_the_reports_agents():
    """A new agent's colour is the one its name picks, in every report (alone, beside the paper's agents, beside
    all of conf/agent); of two new agents whose names pick the same colour the later by name takes the next free
    one; more new agents than derived colours still give every series a look of its own."""
    paper = list(style.KNOWN)
    every = sorted(path.stem for path in (ROOT / "conf" / "agent").glob("*.yaml"))
    for agent in NEW_AGENTS:
        own = style.agent_colour(agent)
        assert own in style.DERIVED and own not in style.PALETTE
        for others in ([], paper, every):
            got = style.agent_colours([*others, agent])[agent]
            # two shipped agents may pick one colour (td3 and weight_clip): the earlier by name keeps it
            earlier = [o for o in others if o < agent and o not in style.AGENT_COLOURS and style.agent_colour(o) == own]
            if earlier:
                assert got != own and got in style.DERIVED, (agent, earlier)
            else:
                assert got == own, (agent, others)
        assert style.looks({"x": "ppo", "mine": agent})["mine"] == (own, style.OTHER_DASH)
    # a name that picks weight_clip's colour: the earlier name keeps its own, the later steps on
    twin = next(name for name in (f"agent_{i}" for i in range(10_000))
                if style.agent_colour(name) == style.agent_colour("weight_clip"))
    got = style.agent_colours(["weight_clip", "ppo", twin])
    assert got[twin] == style.agent_colour(twin) and got["weight_clip"] in set(style.DERIVED) - {got[twin]}
    assert style.delta_e(got["weight_clip"], got[twin]) >= style.DERIVED_MIN_DELTA_E
    assert got == style.agent_colours([twin, "weight_clip", "ppo"])   # whatever the display order
    crowd = {f"new_{i}": f"new_{i}" for i in range(len(style.DERIVED) + 5)} | {"PPO": "ppo"}
    looks = style.looks(crowd)
    assert len(set(looks.values())) == len(crowd) and looks["PPO"] == (style.AGENT_COLOURS["ppo"], "-")


def test_tables_say_when_runs_come_from_different_cpus_or_float_modes(tmp_path):
    """Two PPO seeds on one CPU in portable mode and two L2 seeds on another in native mode: the summary, Table III
    and the leaderboard name both; runs of one CPU and mode (or all untagged, older runs) get no such note."""
    uri = log_late_evaluations(tmp_path, LATE)
    client = MlflowClient(uri)
    for run in client.search_runs([client.get_experiment_by_name("lb").experiment_id]):
        agent = run.data.tags["agent"]
        client.set_tag(run.info.run_id, "cpu_model", "AMD EPYC")
        client.set_tag(run.info.run_id, "cpu_flags", "aaaa1111" if agent == "ppo" else "bbbb2222")
        client.set_tag(run.info.run_id, "portable", "true" if agent == "ppo" else "false")
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "lb")
    assert code == 0, stdout + stderr
    note = ("made on 2 CPU model / float mode combinations (2 on AMD EPYC (flags aaaa1111) (portable); 2 on AMD EPYC "
            "(flags bbbb2222) (native))")
    for table in ("summary.md", "table3.md", "leaderboard.md"):
        assert note in (tmp_path / "out" / table).read_text(), table
    assert note in stdout
    (tmp_path / "plain").mkdir()
    plain = log_late_evaluations(tmp_path / "plain", LATE)
    code, stdout, _ = run_report(plain, tmp_path / "out2", "--experiment", "lb")
    assert code == 0 and "CPU model" not in (tmp_path / "out2" / "summary.md").read_text() + stdout


SEGMENT_EVALS = {  # agent -> evaluations every 100 steps in each of three segments of 400 steps (both seeds alike)
    "reset_all": [[0.0, 0.5, 1.0, 1.0]] * 3,
    "ppo": [[0.0, 0.5, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.5]],
}


def log_segment_runs(client, experiment: str, runs: list[tuple], wind: str = "flip", vehicle: str = "nominal",
                     dormant: dict | None = None, distances: dict | None = None) -> None:
    """Experiment ``experiment`` (made if new): per (agent, evaluations by segment, probe losses, eval.condition) two
    seeds (the evaluations a dict by seed where the seeds differ) on a ``wind`` schedule (with ``vehicle``) of
    segments of 400 steps to 1200, evaluations every 100 steps; the probe (+0.001 x seed) at 400, 800 and 1200;
    with ``dormant`` (agent -> four values) the dormant share (+0.001 x seed) at 400, 500, 700 and 900; with
    ``distances`` (agent -> final distances by segment, as the evaluations) eval/final_distance at the same steps."""
    known = client.get_experiment_by_name(experiment)
    exp_id = known.experiment_id if known else client.create_experiment(experiment)
    for agent, segs, probe, condition in runs:
        for seed in (0, 1):
            run_id = client.create_run(exp_id, start_time=1_000_000, tags={
                "agent": agent, "wind": wind, "vehicle": vehicle, "seed": str(seed),
                "run_name": f"{agent}-{wind}-{vehicle}-s{seed}"}).info.run_id
            evals = [v for seg in (segs[seed] if isinstance(segs, dict) else segs) for v in seg]
            metrics = [Metric("rollout/ep_rew_mean", -100.0, 0, int(s)) for s in range(100, 1201, 100)]
            metrics += [Metric("eval/success_rate", v, 0, 100 * (i + 1)) for i, v in enumerate(evals)]
            far = (distances or {}).get(agent, [])
            far = [v for seg in (far[seed] if isinstance(far, dict) else far) for v in seg]
            metrics += [Metric("eval/final_distance", v, 0, 100 * (i + 1)) for i, v in enumerate(far)]
            metrics += [Metric("plasticity/probe_loss", p + 0.001 * seed, 0, 400 * (i + 1)) for i, p in enumerate(probe)]
            metrics += [Metric("plasticity/dormant_ratio", v + 0.001 * seed, 0, step) for step, v in
                        zip((400, 500, 700, 900), (dormant or {}).get(agent, []))]
            client.log_batch(run_id, metrics=metrics, params=[
                Param("wind.segment_steps", "400"), Param("train.total_timesteps", "1200"),
                Param("eval.condition", condition), Param("agent.l2.enabled", str(agent in ("l2", "cbp_l2")))])
            client.set_terminated(run_id, end_time=1_060_000)


def test_segment_scores_against_reset_all_on_hand_built_evaluations(tmp_path, monkeypatch):
    """Segments of 400 steps, four evaluations each. reset_all learns every segment alike: AUC 62.5%, end 100%. PPO
    matches it on segment 0 (Δ 0), transfers forward on segment 1 (AUC 100%, Δ +37.5 points) and fails on segment 2
    (AUC 12.5%, end 50%: Δ −50 points). Both seeds alike, so every interval has zero width."""
    uri = new_store(tmp_path / "mlflow.db")
    log_segment_runs(MlflowClient(uri), "seg", [(agent, segs, [], "current") for agent, segs in SEGMENT_EVALS.items()])
    drawn = spy_figures(monkeypatch)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "seg")
    assert code == 0, stdout + stderr
    # the figures draw those numbers in %: segment_scores the AUC, segment_scores_end the success at the end
    for stem, top, bottom in (("segment_scores", [62.5, 100, 12.5], [0, 37.5, -50]),
                              ("segment_scores_end", [100, 100, 50], [0, 0, -50])):
        panels = drawn[stem]["panels"]
        assert [p["curves"]["PPO"] for p in panels] == [pytest.approx(top), pytest.approx(bottom)], stem
        assert list(panels[0]["curves"]["reset_all"]) == pytest.approx([62.5] * 3 if stem == "segment_scores"
                                                                       else [100] * 3)
    got = pd.read_csv(tmp_path / "out" / "segment_scores.csv").set_index(["agent", "segment"])
    assert got.loc[("reset_all", 0), "auc_mean"] == 0.625 and got.loc[("reset_all", 2), "end_mean"] == 1.0
    assert np.isnan(got.loc[("reset_all", 1), "auc_vs_reset_all"])   # the reference against itself: none
    ppo = got.loc["ppo"]
    assert list(ppo["auc_mean"]) == [0.625, 1.0, 0.125] and list(ppo["end_mean"]) == [1.0, 1.0, 0.5]
    assert list(ppo["auc_vs_reset_all"]) == [0.0, 0.375, -0.5] and list(ppo["end_vs_reset_all"]) == [0.0, 0.0, -0.5]
    assert list(ppo["auc_vs_reset_all_low"]) == list(ppo["auc_vs_reset_all_high"]) == [0.0, 0.375, -0.5]
    assert list(ppo["evals_per_run"]) == [4.0] * 3 and list(ppo["auc_ci95"]) == [0.0] * 3
    shown = md_table(tmp_path / "out" / "segment_scores.md").set_index("Agent")
    assert shown.loc["PPO", "2 (800–1.2k)"] == "12 ± 0 (Δ -50 [-50, -50])"
    ends = md_table(tmp_path / "out" / "segment_scores.md", 1).set_index("Agent")   # the second: success at the end
    assert ends.loc["PPO", "2 (800–1.2k)"] == "50 ± 0 (Δ -50 [-50, -50])" and ends.loc["PPO", "1 (400–800)"] == "100 ± 0 (Δ 0 [0, 0])"
    assert "eval.condition = current" in (tmp_path / "out" / "segment_scores.md").read_text()
    assert (tmp_path / "out" / "segment_scores.png").exists()
    per_run = pd.read_csv(tmp_path / "out" / "segment_runs.csv")   # the same numbers per run: 2 agents x 2 seeds x 3
    assert len(per_run) == 12 and list(per_run.columns[:7]) == ["run_id", "run_name", "agent", "condition", "wind",
                                                                "seed", "eval_condition"]
    ppo = per_run[(per_run["agent"] == "ppo") & (per_run["seed"] == 1)]
    assert list(ppo["segment"]) == [0, 1, 2] and list(ppo["auc"]) == [0.625, 1.0, 0.125]
    assert list(ppo["end"]) == [1.0, 1.0, 0.5] and list(ppo["hover_after"]) == [200, 100, 400]
    assert "missing: agent=" not in stdout   # a study of flips only is not asked for the paper's winds and agents


def test_a_final_evaluation_past_the_run_under_the_next_condition_is_left_out():
    """Segments of 400 steps, a run of 1200 whose last update ends at 1210 (a rollout is not cut). Its final
    evaluation, at 1210: under eval.condition=current it flew under segment 3's condition (the one at step 1209),
    never trained on, and is left out (segment 2 ends with its evaluation at 1200); under a fixed condition it is
    the last segment's end."""
    from sweep.report import stats

    values = [0.0, 0.5, 1.0, 1.0] * 3 + [0.0]
    steps = [100 * (i + 1) for i in range(12)] + [1210]
    histories = pd.DataFrame({"run_id": "r", "key": "eval/success_rate", "step": steps, "value": values})
    for condition, last_end, last_evals in (("current", 1.0, 4), ("fixed", 0.0, 5)):
        runs = pd.DataFrame({"run_id": ["r"], "segment_steps": [400.0], "total_timesteps": [1200],
                             "eval_condition": [condition]})
        got = stats.segment_evaluations(histories, runs).set_index("segment")
        assert list(got.index) == [0, 1, 2], condition
        assert (got.loc[2, "end"], got.loc[2, "n_evals"]) == (last_end, last_evals), condition
        assert got.loc[0, "auc"] == 0.625


def test_a_draft_report_writes_its_figures_as_png_only_at_100_dpi(tmp_path):
    """--draft: the same figures, PNG only, a third of the paper's resolution (a one-column figure ~3.5 in wide)."""
    uri = new_store(tmp_path / "mlflow.db")
    log_segment_runs(MlflowClient(uri), "draft", [(a, segs, probe, "current") for a, (segs, probe) in
                                                  RELEARN_EVALS.items()])
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "draft")
    assert code == 0, stdout + stderr
    out = tmp_path / "out"
    assert not list(out.glob("*.pdf")) and {"segment_scores", "eval_success_flip"} <= {p.stem for p in out.glob("*.png")}
    assert 250 <= image.imread(out / "eval_success_flip.png").shape[1] <= 400


def test_segment_scores_draw_each_change_as_a_column_of_one_figure(tmp_path, monkeypatch):
    """Two changes in one experiment (a wind flip, a payload in still air): one segment_scores figure two columns
    wide, each change's numbers in the table under its own arm."""
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)   # matplotlib would stamp that date alike in both
    uri = new_store(tmp_path / "mlflow.db")
    client = MlflowClient(uri)
    runs = [(agent, segs, [], "current") for agent, segs in SEGMENT_EVALS.items()]
    log_segment_runs(client, "two", runs)
    log_segment_runs(client, "two", runs, wind="none", vehicle="payload")
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "two", draft=False)
    assert code == 0, stdout + stderr
    got = pd.read_csv(tmp_path / "out" / "segment_scores.csv")
    assert set(got["wind"]) == {"flip", "none+payload"}
    shown = md_table(tmp_path / "out" / "segment_scores.md")
    assert sorted(shown["Wind"]) == ["flip", "flip", "none+payload", "none+payload"]   # PPO and reset_all per arm
    assert sorted(p.name for p in (tmp_path / "out").glob("segment_scores*.png")) == [
        "segment_scores.png", "segment_scores_end.png", "segment_scores_learned.png"]
    height, width = image.imread(tmp_path / "out" / "segment_scores.png").shape[:2]
    assert 1700 <= width <= 2200 and height > 900, (width, height)   # both columns of the page, two rows
    # re-made from the same runs, every file has the same bytes (PDFs carry no creation date): a committed report
    # changes only where its numbers do
    time.sleep(1.1)
    code, stdout, stderr = run_report(uri, tmp_path / "again", "--experiment", "two", draft=False)
    assert code == 0, stdout + stderr
    made = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert made == sorted(p.name for p in (tmp_path / "again").iterdir())
    assert [n for n in made if (tmp_path / "out" / n).read_bytes() != (tmp_path / "again" / n).read_bytes()] == []


RELEARN_EVALS = {  # agent -> (evaluations every 100 steps in three segments of 400 steps, probe loss at 400, 800, 1200)
    "reset_all": ([[0.0, 0.5, 1.0, 1.0]] * 3, [0.001, 0.001, 0.001]),
    "ppo": ([[0.0, 0.5, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.5]], [0.050, 0.060, 0.070]),
    "redo": ([[0.0, 0.5, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0], [0.5] * 4], [0.030, 0.030, 0.030]),
    "l2": ([[0.0, 0.0, 0.5, 1.0], [1.0] * 4, [1.0] * 4], [0.010, 0.200, 0.200]),
}


def test_relearning_table_and_reading_correlation_on_hand_built_evaluations(tmp_path, monkeypatch):
    """Re-learning = the mean eval-success AUC over the segments after the first. reset_all: 62.5% in every segment;
    PPO: 100% then 12.5% -> 56.25% (Δ −6.25 pp, P(> reset_all) 0), its later segments end at 100% and 50%; ReDo
    75%; L2: 100% (Δ +37.5 pp, P 1), its first segment 37.5%. Seeds alike except the probe (+0.001 x seed).
    The probe (reset_all left out: its probe reads a fresh network) ranks the runs differently by its first
    reading (L2 < ReDo < PPO: ranks 1..6 against re-learning's 5.5, 5.5, 3.5, 3.5, 1.5, 1.5, ρ = −16 / sqrt(17.5 x
    16)) and by the mean of its readings (ReDo < PPO < L2, whose probe rises: against 3.5, 3.5, 1.5, 1.5, 5.5, 5.5,
    ρ = +8 / sqrt(17.5 x 16)); both equal scipy's spearmanr. Across the 3 agents' means ρ = −1 with no CI (< 6
    pairs). A run evaluated under a fixed condition is left out of re-learning. The dormant share at the changes
    (400, 800) is the value logged last at or before each (at 400 and 700, not 500 and 900): L2 0.1, PPO
    (0.2 + 0.6) / 2 = 0.4, an inverse ranking of re-learning; 500's and 900's values would rank it the other way.
    ReDo logged no dormant share: left out of that reading only (n 4, no CI). No dead-tanh share was logged: no
    row for it."""
    from scipy.stats import spearmanr

    uri = new_store(tmp_path / "mlflow.db")
    dormant = {"l2": [0.1, 0.9, 0.1, 0.9], "ppo": [0.2, 0.0, 0.6, 0.0], "reset_all": [0.0] * 4}
    log_segment_runs(MlflowClient(uri), "relearn", [(agent, segs, probe, "current")
                                                    for agent, (segs, probe) in RELEARN_EVALS.items()]
                     + [("cbp_l2", *RELEARN_EVALS["l2"], "fixed")],   # CBP: flown under one fixed wind
                     dormant=dormant)
    drawn = spy_figures(monkeypatch)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "relearn", "--vs", "redo,ppo")
    assert code == 0, stdout + stderr
    got = pd.read_csv(tmp_path / "out" / "relearning.csv").set_index("agent")
    assert list(got.index) == ["l2", "redo", "reset_all", "ppo"]          # best re-learner first; no CBP
    assert list(got["relearning"]) == pytest.approx([1.0, 0.75, 0.625, 0.5625])
    assert list(got["first_auc"]) == pytest.approx([0.375, 0.625, 0.625, 0.625])
    assert got.loc["ppo", "relearning_end"] == pytest.approx(0.75) and list(got["later_segments"]) == [2] * 4
    # first evaluation at >= 50% after a change: PPO at 100 steps into segment 1 and 400 into segment 2 (0.5 at
    # its end), reset_all at 200 in both; L2 and ReDo at 100 in both
    assert list(got["learned_share"]) == [1.0] * 4
    assert list(got["hover_after_median"]) == [100, 100, 200, 250]
    assert got.loc["ppo", "delta_vs_reset_all"] == pytest.approx(-0.0625)
    assert got.loc["l2", "delta_vs_reset_all"] == pytest.approx(0.375)
    assert np.isnan(got.loc["reset_all", "delta_vs_reset_all"])   # the reference against itself
    assert (got.loc["l2", "p_improve_over_reset_all"], got.loc["ppo", "p_improve_over_reset_all"]) == (1.0, 0.0)
    assert got.loc["l2", "p_improve_over_ppo"] == 1.0 and np.isnan(got.loc["ppo", "p_improve_over_ppo"])
    shown = md_table(tmp_path / "out" / "relearning.md").set_index("Agent")
    assert shown.loc["PPO", "Re-learning AUC (%)"] == "56 ± 0" and shown.loc["PPO", "per seed"] == "56, 56"
    assert shown.loc["PPO", "Δ vs reset_all (pp) [95% CI]"] == "-6 [-6, -6]"
    # --vs redo: each agent against ReDo (75%) on re-learning too; ReDo against itself empty
    assert got.loc["l2", "delta_vs_redo"] == pytest.approx(0.25) and got.loc["l2", "p_improve_over_redo"] == 1.0
    assert got.loc["ppo", "delta_vs_redo"] == pytest.approx(-0.1875) and got.loc["ppo", "p_improve_over_redo"] == 0.0
    assert np.isnan(got.loc["redo", "delta_vs_redo"])
    assert got.loc["l2", "delta_vs_ppo"] == pytest.approx(0.4375) and np.isnan(got.loc["ppo", "delta_vs_ppo"])
    assert shown.loc["L2 + PPO", "Δ vs PPO (pp) [95% CI]"] == "44 [44, 44]"
    versus_redo = [c for c in shown.columns if c.startswith("Δ vs") and not c.startswith(("Δ vs reset_all", "Δ vs PPO"))]
    assert len(versus_redo) == 1 and shown.loc["PPO", versus_redo[0]] == "-19 [-19, -19]"
    corr = pd.read_csv(tmp_path / "out" / "reading_correlation.csv").set_index(["reading", "across"])
    assert set(corr.index.get_level_values("reading")) == {"probe_first", "probe_mean", "dormant_at_changes"}
    relearn = [1.0, 1.0, 0.75, 0.75, 0.5625, 0.5625]                                   # L2, ReDo, PPO; seeds 0, 1
    for reading, probe, rho in (("probe_first", [0.010, 0.011, 0.030, 0.031, 0.050, 0.051], -16),
                                ("probe_mean", [0.410 / 3, 0.413 / 3, 0.030, 0.031, 0.060, 0.061], 8)):
        row = corr.loc[(reading, "runs (agents x seeds)")]
        assert row["rho"] == pytest.approx(rho / np.sqrt(17.5 * 16)) == pytest.approx(spearmanr(probe, relearn)[0])
        assert row["n"] == 6 and np.isnan(row["rho_low"])   # re-learning: 3 values in pairs, 4 runs off the mode
    agents = corr.loc[("probe_first", "agents (seed means)")]
    assert agents["rho"] == pytest.approx(-1) and agents["n"] == 3 and np.isnan(agents["rho_low"])
    at_changes = corr.loc[("dormant_at_changes", "runs (agents x seeds)")]
    expected = spearmanr([0.1, 0.101, 0.4, 0.401], relearn[:2] + relearn[4:])[0]
    assert at_changes["rho"] == pytest.approx(expected) and expected < -0.8 and at_changes["n"] == 4
    assert np.isnan(at_changes["rho_low"])
    text = (tmp_path / "out" / "relearning.md").read_text()
    assert "Sokar dormant share at the changes" in text and "dead tanh share" not in text
    # the figure: each run a point at its reading and re-learning (%), filled (learned segment 0) here; the
    # panel's title has the ρ of the table; reset_all and the fixed-condition run are not drawn
    panels = {p["xlabel"]: p for p in drawn["readings_flip"]["scatter"]}
    assert set(panels) == {"Probe loss at the first change", "Probe loss, mean of the readings",
                           "Sokar dormant at the changes (%)"}
    dormant = panels["Sokar dormant at the changes (%)"]
    assert dormant["points"]["PPO (learned)"].ravel().tolist() == pytest.approx([40.0, 56.25, 40.1, 56.25])
    assert set(dormant["points"]) == {"PPO (learned)", "L2 + PPO (learned)"}   # no reset_all, CBP; ReDo: no reading
    assert f"{at_changes['rho']:.2f}" in dormant["title"] and panels["Probe loss at the first change"]["xscale"] == "log"
    per_run = pd.read_csv(tmp_path / "out" / "relearning_runs.csv").set_index(["agent", "seed"])   # the same, per run
    assert len(per_run) == 8 and "cbp_l2" not in per_run.index.get_level_values("agent")   # fixed condition: out
    assert per_run.loc[("ppo", 1), "dormant_at_changes"] == pytest.approx(0.401)
    assert per_run.loc[("l2", 0), "relearning"] == 1.0 and np.isnan(per_run.loc[("redo", 0), "dormant_at_changes"])
    assert per_run.loc[("ppo", 0), "probe_first"] == pytest.approx(0.050)
    assert (tmp_path / "out" / "interval_relearning.png").exists()


def test_rank_correlation_interval_needs_enough_runs_off_the_most_common_value():
    """A reading at 0 in 41 runs and not in one: ρ is that one run, so there is no interval (dropping the resamples
    that miss it, constant on that side, would give one entirely below 0). Six runs off the mode give one, and a
    continuous pair gives one around its ρ, which is scipy's."""
    from scipy.stats import spearmanr

    from sweep.report.relearning import spearman_ci

    relearn = np.linspace(0.3, 0.8, 42)
    one = np.r_[np.zeros(41), 0.1]
    rho, low, high, n = spearman_ci(one, relearn[::-1])
    assert rho == pytest.approx(spearmanr(one, relearn[::-1])[0]) and n == 42 and np.isnan(low) and np.isnan(high)
    six = np.r_[np.zeros(36), np.arange(1, 7)]
    assert np.isfinite(spearman_ci(six, relearn)[1])
    noisy = relearn + np.random.default_rng(0).normal(0, 0.1, 42)
    rho, low, high, n = spearman_ci(noisy, relearn)
    assert rho == pytest.approx(spearmanr(noisy, relearn)[0]) and low < rho < high


def test_relearning_of_the_seeds_that_learned_the_first_segment(tmp_path, monkeypatch):
    """Bimodal seeds: PPO's seed 0 learns segment 0 and re-learns 56.25% (as above), its seed 1 never hovers (0%):
    1 of 2 seeds learned, re-learning 28.125% over both and 56.25% over the one (no CI from one seed). L2 (100%)
    and ReDo (75%) learn in both seeds. The probe's first reading within the 5 runs that learned (PPO's seed 1 out):
    L2 0.010, 0.011, ReDo 0.030, 0.031, PPO 0.050 against re-learning 1, 1, 0.75, 0.75, 0.5625: a perfect inverse
    ranking up to ties, scipy's spearmanr, n 5 and no CI (< 6 pairs); across all 6 runs PPO's seed 1 (probe 0.051,
    re-learning 0) is in. reset_all's seed 1 fails its first network only: 1 of 2 learned segment 0. Per segment
    over the seeds that learned it (every agent alike), the gain over the run's own segment 0: PPO 0, +37.5, -50
    points, ReDo 0, +37.5, -12.5 (both seeds: a zero-width CI)."""
    from scipy.stats import spearmanr

    never = [[0.0] * 4] * 3
    ppo = {0: RELEARN_EVALS["ppo"][0], 1: never}
    fresh = RELEARN_EVALS["reset_all"][0]
    reset_all = {0: fresh, 1: [never[0], *fresh[1:]]}   # seed 1's first network never hovers, its later ones do
    uri = new_store(tmp_path / "mlflow.db")
    log_segment_runs(MlflowClient(uri), "bimodal", [(agent, segs, probe, "current") for agent, (segs, probe) in
                                                    {**RELEARN_EVALS, "ppo": (ppo, RELEARN_EVALS["ppo"][1]),
                                                     "reset_all": (reset_all, RELEARN_EVALS["reset_all"][1])}.items()])
    drawn = spy_figures(monkeypatch)
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "bimodal")
    assert code == 0, stdout + stderr
    probe_panel = drawn["readings_flip"]["scatter"][0]   # PPO's seed that never hovered: its own (hollow) points
    assert probe_panel["points"]["PPO (not learned)"].ravel().tolist() == pytest.approx([0.051, 0.0])
    assert probe_panel["points"]["PPO (learned)"].ravel().tolist() == pytest.approx([0.050, 56.25])
    got = pd.read_csv(tmp_path / "out" / "relearning.csv").set_index("agent")
    assert got.loc["ppo", "relearning"] == pytest.approx(0.28125) and got.loc["ppo", "learned_first_seeds"] == 1
    assert got.loc["ppo", "relearning_if_learned"] == pytest.approx(0.5625)
    assert np.isnan(got.loc["ppo", "relearning_if_learned_ci95"])
    assert list(got.loc[["l2", "redo", "reset_all"], "learned_first_seeds"]) == [2, 2, 1]
    assert list(got.loc[["l2", "redo", "reset_all"], "relearning_if_learned"]) == pytest.approx([1.0, 0.75, 0.625])
    shown = md_table(tmp_path / "out" / "relearning.md").set_index("Agent")
    learned_first = shown["Learned segment 0 (seeds)"]
    assert learned_first["PPO"] == "1/2" and learned_first["L2 + PPO"] == "2/2"
    assert shown.loc["PPO", "Re-learning AUC, seeds that learned (%)"] == "56"
    assert shown.loc["L2 + PPO", "Re-learning AUC, seeds that learned (%)"] == "100 ± 0"
    # of the runs that never learned segment 0: PPO's seed 1 never hovers later (0 of 1), reset_all's seed 1 does
    assert (got.loc["ppo", "stuck_runs"], got.loc["ppo", "stuck_hovered_later"]) == (1, 0)
    assert (got.loc["reset_all", "stuck_runs"], got.loc["reset_all", "stuck_hovered_later"]) == (1, 1)
    assert got.loc["l2", "stuck_runs"] == 0 and np.isnan(got.loc["l2", "stuck_hovered_later_share"])
    stuck = shown["Never learned segment 0: hovered later (runs) [95% CI]"]
    assert stuck["PPO"] == "0/1 [0.00, 0.79]" and stuck["L2 + PPO"] == "–"
    corr = pd.read_csv(tmp_path / "out" / "reading_correlation.csv").set_index(["reading", "across"])
    within = corr.loc[("probe_first", "runs that learned segment 0")]
    probe, relearn = [0.010, 0.011, 0.030, 0.031, 0.050], [1.0, 1.0, 0.75, 0.75, 0.5625]
    assert within["rho"] == pytest.approx(spearmanr(probe, relearn)[0]) and within["n"] == 5
    assert np.isnan(within["rho_low"])
    every = corr.loc[("probe_first", "runs (agents x seeds)")]
    assert every["n"] == 6 and every["rho"] == pytest.approx(spearmanr(probe + [0.051], relearn + [0.0])[0])
    assert "runs that learned segment 0" in (tmp_path / "out" / "relearning.md").read_text()
    # per segment over the seeds that learned segment 0: PPO's seed 0 alone (AUC 62.5, 100, 12.5), reset_all's too
    learned = pd.read_csv(tmp_path / "out" / "segment_scores_learned.csv").set_index(["agent", "segment"])
    assert list(learned.loc["ppo", "auc_mean"]) == [0.625, 1.0, 0.125] and set(learned.loc["ppo", "n_seeds"]) == {1}
    assert list(learned.loc["ppo", "auc_vs_first"]) == [0.0, 0.375, -0.5]
    assert learned.loc["ppo", "auc_vs_first_low"].isna().all()   # one seed: no interval
    assert list(learned.loc["redo", "auc_vs_first"]) == [0.0, 0.375, -0.125]
    assert list(learned.loc["redo", "auc_vs_first_low"]) == list(learned.loc["redo", "auc_vs_first_high"])
    assert list(learned.loc["reset_all", "n_seeds"]) == [1, 1, 1]
    assert list(learned.loc["reset_all", "auc_vs_first"]) == [0.0] * 3
    assert not [c for c in learned.columns if "reset_all" in c]   # no comparison across differently chosen seeds
    cells = md_table(tmp_path / "out" / "segment_scores_learned.md").set_index("Agent")
    assert cells.loc["redo", "2"] == "50 ± 0 (gain -12 [-12, -12])" and cells.loc["PPO", "2"] == "12 (gain -50)"
    every = pd.read_csv(tmp_path / "out" / "segment_scores.csv").set_index(["agent", "segment"])
    assert list(every.loc["ppo", "auc_mean"]) == [0.3125, 0.5, 0.0625]   # both seeds
    assert "the seeds that learned segment 0" in (tmp_path / "out" / "segment_scores_learned.md").read_text()
    assert (tmp_path / "out" / "segment_scores_learned.png").exists()


def test_transfer_gap_table_on_hand_built_flights(tmp_path, capsys):
    """x3 (wind +x) runs flown under x3: success 100% and 80%; under mx3 (wind -x): 20% and 0% (gap 80 pp, both seeds
    alike: zero width); mx3 runs under mx3: 90%, 90%. Position MSE summed over the axes. A missing arm is one line."""
    from sweep.report import transfer

    uri = new_store(tmp_path / "mlflow.db")
    client = MlflowClient(uri)
    exp_id = client.create_experiment("transfer")
    flown = {("x3", 0): {"x3": 1.0, "mx3": 0.2}, ("x3", 1): {"x3": 0.8, "mx3": 0.0},
             ("mx3", 0): {"mx3": 0.9}, ("mx3", 1): {"mx3": 0.9}}
    for (arm, seed), under in flown.items():
        run_id = client.create_run(exp_id, start_time=1_000_000, tags={"agent": "ppo", "wind": arm, "seed": str(seed),
                                                                        "vehicle": "nominal"}).info.run_id
        logged = []
        for target, success in under.items():
            for field, value in (("success_rate", success), ("mse_x", 0.1), ("mse_y", 0.2), ("mse_z", 1 - success)):
                logged.append(Metric(f"{transfer.reeval_name(target)}/eval_best_eval/{field}", value, 0, 100))
        client.log_batch(run_id, metrics=logged)
        client.set_terminated(run_id)
    assert transfer.main(["--experiment", "transfer", "--uri", uri, "--out", str(tmp_path / "out"),
                          "--change", "flip=x3:mx3"]) == 0
    got = pd.read_csv(tmp_path / "out" / "transfer_gap.csv").iloc[0]
    assert (got["A_on_A_success"], got["A_on_B_success"], got["B_on_B_success"]) == pytest.approx((0.9, 0.1, 0.9))
    assert got["gap_success"] == pytest.approx(0.8) and got["gap_success_ci95"] == pytest.approx(0.0, abs=1e-12)
    assert got["A_on_A_mse"] == pytest.approx(0.3 + 0.1) and got["gap_mse"] == pytest.approx(0.8)   # worse under B
    assert got["gap_hovering_success"] == pytest.approx(0.8) and got["gap_hovering_n"] == 2
    seeds = transfer.per_seed(transfer.scores(client, exp_id, "best_eval"), [("flip", "x3", "mx3")], "best_eval")
    assert sorted(seeds[seeds["cell"] == "A on B"]["success"]) == pytest.approx([0.0, 0.2])
    assert len(seeds) == 6 and (tmp_path / "out" / "transfer_gap.png").stat().st_size > 0
    shown = md_table(tmp_path / "out" / "transfer_gap.md").iloc[0]
    assert shown["A on B: success (%)"].startswith("10 ± ") and shown["A on B: success (%)"].endswith("(20, 0)") and shown["Gap A on A − A on B: success (pp)"] == "80 ± 0"
    capsys.readouterr()
    assert transfer.main(["--experiment", "transfer", "--uri", uri, "--change", "payload=none:none+mass1p5"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no FINISHED run under none, none+mass1p5" in err and "mx3, x3" in err


def test_segment_labels_name_what_changes():
    """The bands' labels: speeds alone as numbers; else the wind's speed and direction, gusts, and the vehicle."""
    from sweep.report.load import segment_labels

    assert segment_labels([3.0, 2.0], "null", '[{"mass": 1.0, "rotor_efficiency": [1, 1, 1, 1]}]') == [3.0, 2.0]
    assert segment_labels([3.0, 3.0], "[[1, 0, 0], [-1, 0, 0]]", None) == ["3 +x", "3 −x"]
    assert segment_labels([0.0], "null", '[{"mass": 1.0, "rotor_efficiency": [1, 1, 1, 1]}, '
                          '{"mass": 1.3, "rotor_efficiency": [1, 1, 1, 1]}]') == ["nominal", "m×1.3"]
    assert segment_labels([3.0, 3.0], "null", None, "[0.0, 100.0]") == ["calm", "σ100"]
    assert segment_labels([3.0], "null", None, "[0.0]") == [3.0]   # no gusts anywhere: as before


def test_the_plasticity_study_weight_norm_test_on_a_hand_made_table(tmp_path):
    """docs/plasticity_study/weight_norm.py: within the learned runs of the agents not left out, weight norms ranked
    opposite to re-learning give ρ = −1 and 'confirmed' on the payload change; LayerNorm's, the combination's,
    shrink-and-perturb's and reset_all's runs and a run that never learned segment 0 would break that and are left
    out. A change whose ρ is negative with a CI that reaches 0 is 'not confirmed' (the CI's upper end decides, not
    its lower), as is one with too few runs for a CI; the flip's row is labelled post hoc."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("weight_norm", ROOT / "docs" / "plasticity_study" / "weight_norm.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    agents = ["ppo", "redo", "l2", "l2_lr_decay"]
    rows = [{"wind": wind, "agent": agent, "seed": seed, "learned_first": 1.0,
             "weight_norm_at_changes": 100.0 - 10 * k - seed, "relearning": 0.1 + 0.1 * k + 0.01 * seed}
            for wind in ("flip", "none+payload") for k, agent in enumerate(agents) for seed in range(2)]
    rows += [{"wind": "none+payload", "agent": agent, "seed": 0, "learned_first": 1.0, "weight_norm_at_changes": w,
              "relearning": r} for agent, w, r in (("layer_norm", 120.0, 0.9), ("layer_norm_l2_lr_decay_8m", 130.0,
                                                                                  0.95),
                                                   ("shrink_perturb", 10.0, 0.0), ("reset_all", 200.0, 0.95))]
    rows.append({"wind": "none+payload", "agent": "ppo", "seed": 7, "learned_first": 0.0,
                 "weight_norm_at_changes": 300.0, "relearning": 0.99})
    # weakly negative: weight norms 0..11 against re-learning ranks shuffled, ρ −0.35 with a CI across 0
    noisy = [5, 1, 9, 3, 12, 2, 7, 11, 4, 8, 6, 10]
    rows += [{"wind": "weak", "agent": agents[i % 4], "seed": i, "learned_first": 1.0,
              "weight_norm_at_changes": float(i), "relearning": 1.0 - 0.01 * v} for i, v in enumerate(noisy)]
    rows += [{"wind": "few", "agent": agent, "seed": 0, "learned_first": 1.0, "weight_norm_at_changes": float(k),
              "relearning": 1.0 - 0.1 * k} for k, agent in enumerate(agents)]
    (tmp_path / "relearning_runs.csv").write_text(pd.DataFrame(rows).to_csv(index=False))
    got = module.test(pd.read_csv(tmp_path / "relearning_runs.csv")).set_index("Change")
    assert got.loc["none+payload", "Runs"] == 8 and got.loc["none+payload", "Agents"] == 4
    assert got.loc["none+payload", "ρ [95% CI]"].startswith("-1.00")
    assert got.loc["none+payload", "Verdict"] == "confirmed"
    low, high = (float(v) for v in got.loc["weak", "ρ [95% CI]"].split("[")[1].rstrip("]").split(","))
    assert low < 0 <= high and got.loc["weak", "Verdict"] == "not confirmed"
    assert "[" not in got.loc["few", "ρ [95% CI]"] and got.loc["few", "Verdict"] == "not confirmed"
    assert got.loc["flip", "Verdict"] == "post hoc (suggested the test)"


def _drawn_tick_labels(axis) -> tuple[list[str], list]:
    """The texts and window extents of an axis' tick labels that are drawn (major and minor, non-empty, inside the
    axis' limits)."""
    axis.figure.canvas.draw()
    renderer = axis.figure.canvas.get_renderer()
    low, high = axis.get_view_interval()
    drawn = [t.label1 for t in axis.get_major_ticks() + axis.get_minor_ticks()
             if t.label1.get_visible() and t.label1.get_text() and min(low, high) <= t.get_loc() <= max(low, high)]
    return [label.get_text() for label in drawn], [label.get_window_extent(renderer) for label in drawn]


@pytest.mark.parametrize("span", [(0.013, 0.11), (0.006, 0.09), (0.02, 0.06), (0.006, 0.5), (0.011, 0.25),
                                  (0.021, 0.048), (0.06, 0.095), (0.03, 0.058), (0.03, 0.07), (1e-4, 1e-1),
                                  (1e-6, 10.0)])
def test_log_axis_labels_do_not_overlap(span):
    """A log-scale reading (the probe loss) spanning less than a decade: matplotlib's default labels its minor ticks
    in scientific notation, which overlap in a readings panel; figures.log_axis labels plain numbers, spaced by the
    data's span."""
    from matplotlib import pyplot as plt
    from matplotlib.transforms import Bbox

    fig, ax = plt.subplots(figsize=(style.PAGE_WIDTH / 3 - 0.3, 2.0))   # a panel of three, less its y labels
    ax.scatter(list(span), [0, 1])
    figures.log_axis(ax.xaxis)
    labels, boxes = _drawn_tick_labels(ax.xaxis)
    plt.close(fig)
    assert len(boxes) >= 2, labels
    assert not any(Bbox.intersection(a, b) for i, a in enumerate(boxes) for b in boxes[i + 1:]), labels
    assert all(re.fullmatch(r"[0-9.e-]+", text) for text in labels), labels   # plain numbers, no mathtext


def test_segment_scores_difference_row_shows_every_column(tmp_path, monkeypatch):
    """The difference row is shared across the changes; its limits are set once every column is drawn, so a change
    whose differences reach further than the first column's (here +100 points under the payload, at most +37.5 under
    the flip) is not cut off at the first column's limits."""
    limits, save = {}, figures.save

    def spy(fig, out, stem):
        if stem == "segment_scores":
            for ax in fig.axes:
                ys = [y for line in ax.get_lines() for y in np.asarray(line.get_ydata(), float)]
                ys += [y for coll in ax.collections for seg in coll.get_segments() for y in np.asarray(seg)[:, 1]]
                limits[(ax.get_subplotspec().rowspan.start, ax.get_subplotspec().colspan.start)] = (
                    ax.get_ylim(), np.nanmin(ys), np.nanmax(ys))
        return save(fig, out, stem)

    monkeypatch.setattr(figures, "save", spy)
    uri = new_store(tmp_path / "mlflow.db")
    client = MlflowClient(uri)
    log_segment_runs(client, "two", [(agent, segs, [], "current") for agent, segs in SEGMENT_EVALS.items()])
    far = {"reset_all": [[0.0] * 4] * 3, "ppo": [[1.0] * 4] * 3}
    log_segment_runs(client, "two", [(agent, segs, [], "current") for agent, segs in far.items()],
                     wind="none", vehicle="payload")
    code, stdout, stderr = run_report(uri, tmp_path / "out", "--experiment", "two")
    assert code == 0, stdout + stderr
    assert {key[0] for key in limits} == {0, 1} and {key[1] for key in limits} == {0, 1}, limits
    for key, ((low, high), drawn_low, drawn_high) in limits.items():
        assert low <= drawn_low and drawn_high <= high, (key, low, high, drawn_low, drawn_high)
    assert limits[(1, 1)][2] == pytest.approx(100.0)


def test_log_axis_labels_a_y_axis_spanning_less_than_a_decade():
    """The probe curves' log y axes (figures._panel) go through figures.log_axis too: a panel spanning 0.2-0.9 gets
    at least two plain labels, not a lone decade label or none."""
    from matplotlib import pyplot as plt

    fig, ax = plt.subplots(figsize=(3.0, 1.6))
    ax.plot([0, 1], [0.2, 0.9])
    figures.log_axis(ax.yaxis)
    labels, _ = _drawn_tick_labels(ax.yaxis)
    plt.close(fig)
    assert ax.get_yscale() == "log" and len(labels) >= 2, labels
    assert all(re.fullmatch(r"[0-9.e-]+", text) for text in labels), labels


def test_narrow_small_multiples_keep_their_titles_and_time_labels_apart():
    """Six --by panels across a page (the weight-clipping grid: kappa x heads): each panel's title wraps one value per
    line instead of running into the next panel's, and the time axis is labelled sparsely enough not to overlap."""
    from matplotlib import pyplot as plt
    from matplotlib.transforms import Bbox

    with plt.rc_context(style.RC):   # the report's fonts
        fig, axes = plt.subplots(1, 6, figsize=(style.PAGE_WIDTH, 2.3), sharey=True)
        for ax in axes:
            ax.plot([0, 3e6], [0, 1])
            figures._panel_title(ax, "kappa=1.0, heads=False", [(0, 2e6, 3.0), (2e6, 3e6, 2.0)])
            figures.timestep_axis(ax, 3e6)
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        titles = [ax.title.get_window_extent(renderer) for ax in axes]
        assert not any(Bbox.intersection(a, b) for a, b in zip(titles, titles[1:])), [ax.title.get_text() for ax in axes]
        labels, boxes = _drawn_tick_labels(axes[0].xaxis)
        plt.close(fig)
    assert len(boxes) >= 2 and not any(Bbox.intersection(a, b) for i, a in enumerate(boxes) for b in boxes[i + 1:]), labels
