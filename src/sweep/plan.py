"""What a sweep will cost before it starts: jobs x timesteps / measured throughput (printed by ``SweepCallback``).

Rates are end-to-end timesteps per second of one run (diagnostics, tracking and checkpoints included) on this
project's 2-core reference machine, from benchmarks/RESULTS.md:

    learner  layout (n_envs x n_steps)   ts/s     source
    sb3      1 x 2048                     1,737   bench row (b): SB3 PPO, fast backend
    sb3      16 x 128                     3,699   bench row (c)
    jax      1 x 2048                    43,842   bench "JAX run end to end (experiment=paper)"
    jax      16 x 128                    47,600   the same x (e)/(d) = 55,635 / 51,258 (the bare learners' ratio)

Off-policy learners (SAC, TD3: SB3's defaults, one env step and one gradient step per turn, 64x64, batch 256), the
learner alone (bench "off-policy" rows; SB3's SAC and TD3 pay their gradient steps, so the hooks add little):
SAC sb3 184, jax 656; TD3 sb3 329, jax 805 ts/s (``OFF_POLICY_RATES``; the turn's size and the replay ratio move them).

Two runs on two cores: SB3 1.91x one run's rate, JAX 1.64x (bench rows "joblib aggregate" and "2 concurrent
runs"). The backend ``rotorpy`` runs SB3 at 672 ts/s (row (a)). Each job also pays ~10 s of start-up (imports,
MLflow) and evaluation (README, "Simulator backends and speed"). Another machine scales all of it.
"""
from __future__ import annotations

import math
import os
from itertools import product

RATES = {("sb3", False): 1_737, ("sb3", True): 3_699, ("jax", False): 43_842, ("jax", True): 47_600}
ROTORPY_RATE = 672
TWO_CORE_SPEEDUP = {"sb3": 1.91, "jax": 1.64}
JOB_FIXED_S = 10.0  # start-up and evaluation of one job
OFF_POLICY_RATES = {("sac", "sb3"): 184, ("sac", "jax"): 656, ("td3", "sb3"): 329, ("td3", "jax"): 805}
JAX_VS_SB3 = 20  # ~ 43,842 / 1,737 = 25 at 1 x 2048, 47,600 / 3,699 = 13 at 16 x 128: "about a twentieth"


def _duration(seconds: float) -> str:
    if seconds >= 3600:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 60:.0f} min" if seconds >= 60 else f"{seconds:.0f} s"


def job_overrides(task: list[str], sweeper_params: dict[str, str]) -> list[dict[str, str]]:
    """Every job's overrides of a multirun (the command line wins over ``hydra.sweeper.params``)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parser = OverridesParser.create()
    spec: dict[str, list[str]] = {}
    for text in [f"{k}={v}" for k, v in sweeper_params.items()] + list(task):
        o = parser.parse_overrides([text])[0]
        spec[o.key_or_group] = list(o.sweep_string_iterator()) if o.is_sweep_override() else [str(o.value())]
    keys = list(spec)
    return [dict(zip(keys, values)) for values in product(*(spec[k] for k in keys))]


def agent_algorithm(name: str) -> str:
    """The algorithm of conf/agent/<name>.yaml: its ``algorithm`` key, else that of the agent its defaults extend."""
    import yaml

    from sweep.config import REMEDY_GROUP

    path = REMEDY_GROUP.parent / "agent" / f"{name}.yaml"
    if not path.exists():
        return "ppo"
    spec = yaml.safe_load(path.read_text()) or {}
    if "algorithm" in spec:
        return str(spec["algorithm"])
    parents = [d for d in spec.get("defaults", []) if isinstance(d, str) and d != "_self_"]
    return agent_algorithm(parents[0]) if parents else "ppo"


def run_seconds(learner: str, n_envs: int, n_steps: int, total_timesteps: int, backend: str = "fast",
                algorithm: str = "ppo") -> float:
    if algorithm != "ppo":
        return total_timesteps / OFF_POLICY_RATES[(algorithm, learner)] + JOB_FIXED_S
    rate = ROTORPY_RATE if learner == "sb3" and backend != "fast" else RATES[(learner, n_envs >= 16)]
    rollout = n_envs * n_steps
    return math.ceil(total_timesteps / rollout) * rollout / rate + JOB_FIXED_S


def estimate(cfg, task: list[str], sweeper_params: dict[str, str], n_jobs: int) -> tuple[float, int, set[str]]:
    """(expected wall seconds of the sweep, number of jobs, learners) for a composed base config."""
    jobs = job_overrides(task, sweeper_params)
    seconds: dict[str, float] = {}
    for job in jobs:
        get = lambda key, default: job.get(key, default)  # noqa: E731
        learner = get("agent.learner", cfg.agent.learner)
        algorithm = agent_algorithm(job["agent"]) if "agent" in job else cfg.agent.get("algorithm", "ppo")
        ppo = cfg.agent.get("ppo") or {}
        n_steps = int(get("agent.ppo.n_steps", ppo.get("n_steps", 2048))) if algorithm == "ppo" else 0
        t = run_seconds(learner, int(get("env.n_envs", cfg.env.n_envs)), n_steps,
                        int(get("train.total_timesteps", cfg.train.total_timesteps)), get("env.backend", cfg.env.backend),
                        algorithm)
        seconds[learner] = seconds.get(learner, 0.0) + t
    cores = os.cpu_count() or 1
    parallel = min(cores if n_jobs in (-1, None) else n_jobs, len(jobs), cores)
    wall = 0.0
    for learner, total in seconds.items():
        speedup = 1.0 if parallel <= 1 else TWO_CORE_SPEEDUP[learner] * parallel / 2
        wall += total / speedup
    return wall, len(jobs), set(seconds)


def announce(cfg, task: list[str], sweeper_params: dict[str, str], n_jobs: int) -> str:
    wall, n, learners = estimate(cfg, task, sweeper_params, n_jobs)
    line = (f"sweep: {n} job{'s' * (n != 1)}, expected wall time ~{_duration(wall)} on this machine "
            f"(measured rates, src/sweep/plan.py)")
    if "sb3" in learners:
        line += (f"\nsweep: hint: agent.learner=jax runs the same algorithm (tested equivalent, docs/jax_learner.md) in "
                 f"about 1/{JAX_VS_SB3} of the time")
    return line
