"""eval.policy: the best policy kept while training (the paper's "policy that produced the highest reward") is
the one scored under eval_best/*, not the final one; the best by in-training eval return under eval_best_eval/*."""
from __future__ import annotations

import numpy as np
import pytest
from mlflow.tracking import MlflowClient
from stable_baselines3 import PPO

from conftest import compose_cfg
from sweep.evaluate import evaluate
from sweep.run import run

# A short JAX run whose ep_rew_mean peaks early (at 1,536 of 8,192 steps): best and final differ.
CONFIG = ["agent.learner=jax", "seed=0", "env.n_envs=4", "agent.ppo.n_steps=128", "train.total_timesteps=8192",
          "env.episode_seconds=0.5", "eval.episodes=2", "eval.every_timesteps=2048"]


def test_the_best_policy_is_kept_and_scored_not_the_final_one(store, tmp_path):
    cfg = compose_cfg(CONFIG)
    run_id = run(cfg, tmp_path / "job")
    client = MlflowClient(store)
    metrics = client.get_run(run_id).data.metrics
    reward = [(m.step, m.value) for m in client.get_metric_history(run_id, "rollout/ep_rew_mean")]
    best_step, best_score = max(reward, key=lambda t: t[1])   # max() keeps the first of ties, as the callback
    assert metrics["eval_best/source_step"] == best_step and metrics["eval_best/source_score"] == pytest.approx(best_score)
    assert best_step < 8192   # the best is not the final policy
    evals = [(m.step, m.value) for m in client.get_metric_history(run_id, "eval/return") if m.step < 8192]
    assert metrics["eval_best_eval/source_step"] == max(evals, key=lambda t: t[1])[0]

    def scored(artifact: str, prefix: str) -> None:
        path = client.download_artifacts(run_id, artifact, str(tmp_path / "dl"))
        ours, _ = evaluate(PPO.load(path, device="cpu"), cfg.eval, cfg.env)
        for field, value in ours.items():
            assert metrics[f"{prefix}/{field}"] == pytest.approx(value, rel=1e-5, abs=1e-6), (prefix, field)

    scored("model.zip", "eval")            # the final policy's evaluation is the final model's
    scored("model_best.zip", "eval_best")  # eval_best/* is the kept policy's, not the final one's
    assert metrics["eval_best/return"] != metrics["eval/return"]
    final = np.load(client.download_artifacts(run_id, "eval_trajectories.npz", str(tmp_path / "f")))
    kept = np.load(client.download_artifacts(run_id, "eval_best_trajectories.npz", str(tmp_path / "b")))
    assert not np.array_equal(final["positions"], kept["positions"])


@pytest.mark.parametrize("policy,prefixes", [("final", {"eval"}), ("best", {"eval_best"}),
                                             ("both", {"eval", "eval_best"})])
def test_eval_policy_chooses_what_is_scored(store, tmp_path, policy, prefixes):
    cfg = compose_cfg([*CONFIG, "train.total_timesteps=2048", "eval.every_timesteps=0", f"eval.policy={policy}"])
    metrics = MlflowClient(store).get_run(run(cfg, tmp_path / "job")).data.metrics
    assert {k.split("/")[0] for k in metrics if k.startswith("eval")} == prefixes
