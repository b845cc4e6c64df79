"""Run paths not covered elsewhere, on real short runs: a ReLU network on the SB3 learner, and the NaN guard
ending a run on either learner (the JAX learner has no torch policy, so the fault goes through the Learner
contract; it is attached by patching the run's remedy list, not through a config key)."""
from __future__ import annotations

import types

import numpy as np
import pytest
import torch
from mlflow.tracking import MlflowClient
from stable_baselines3 import PPO

from conftest import TINY, compose_cfg, new_store
from sweep.checkpoint import load_checkpoint
import sweep.run as run_module
from sweep.run import run, run_job
from sweep.status import read_status
from sweep.training.hooks import Hook, Hooks


class PoisonWeight(Hook):
    """At the first rollout end at or past ``at_step``: one weight of ``weight`` becomes NaN (before the update)."""

    name = "poison"

    def __init__(self, at_step: int, weight: str = "mlp_extractor.value_net.0.weight") -> None:
        self.at_step, self.weight, self.done = int(at_step), weight, False

    def after_rollout(self, learner, rollout) -> dict:
        if self.done or rollout.timesteps < self.at_step:
            return {}
        weight = learner.parameter_arrays()[self.weight]
        weight[0, 0] = np.nan
        learner.write_parameters({self.weight: weight})
        self.done = True
        return {}


def test_relu_policy_on_the_sb3_learner(store, tmp_path):
    """agent.policy.activation=relu: the run finishes, and the trained network it stored has ReLU after each
    hidden layer of both MLPs, whose outputs on a batch of observations are >= 0 with exact zeros and positive
    values (a tanh network gives negatives; a ReLU network whose units were all dead or all live would not be
    telling us much either)."""
    out = tmp_path / "job"
    run_id = run(compose_cfg(["agent.policy.activation=relu", *TINY, "env.episode_seconds=1.0"]), out)
    r = MlflowClient(store).get_run(run_id)
    assert r.info.status == "FINISHED" and r.data.params["agent.policy.activation"] == "relu"
    model = PPO.load(out / "model.zip", device="cpu")
    assert model.policy_kwargs["activation_fn"] is torch.nn.ReLU
    obs = torch.as_tensor(np.random.default_rng(0).normal(size=(512, 13)), dtype=torch.float32)
    for net in (model.policy.mlp_extractor.policy_net, model.policy.mlp_extractor.value_net):
        nonlinear = [m for m in net if not isinstance(m, torch.nn.Linear)]
        assert len(nonlinear) == 2 and all(isinstance(m, torch.nn.ReLU) for m in nonlinear), net
        h = obs
        with torch.no_grad():
            for module in net:
                h = module(h)
                if isinstance(module, torch.nn.ReLU):
                    assert (h >= 0).all() and (h == 0).any() and (h > 0).any()


@pytest.mark.parametrize("learner", ["sb3", "jax"])
def test_nan_guard_ends_the_run_failed(learner, store, tmp_path, monkeypatch, capsys):
    """A value weight set to NaN after the rollout ending at 1,024 steps makes that update's loss NaN. The guard
    stops the run after that update: exit code 1, the project's one failure line naming the loss and
    the step, status.json FAILED, the MLflow run FAILED with the reason (none left RUNNING), and the checkpoint
    the last good state (512), not the poisoned one. Without the guard (NonFiniteGuard patched out) the NaN
    surfaces later as an unrelated error (SB3: "LinAlgError: SVD did not converge" in the diagnostics; JAX:
    "ZeroDivisionError"), and the message check fails."""
    out = tmp_path / "job"
    monkeypatch.setattr("sweep.run.tempfile", types.SimpleNamespace(mkdtemp=lambda: str(out)))  # run_job's job dir
    build = run_module.build_hooks
    monkeypatch.setattr(run_module, "build_hooks", lambda cfg: Hooks([*build(cfg), PoisonWeight(at_step=1024)]))
    cfg = compose_cfg([f"agent.learner={learner}", "train.total_timesteps=2048", "agent.ppo.n_steps=512",
                       "train.checkpoint_every=512", "eval.episodes=2", "env.episode_seconds=1.0",
                       "train.progress_every_s=1000"])
    with pytest.raises(SystemExit) as exit_:
        run_job(cfg)
    assert exit_.value.code == 1
    reason = "NonFiniteError: train/loss=nan after the update at 1024 timesteps"
    failures = [line for line in capsys.readouterr().err.splitlines() if line.startswith("sweep:")]
    assert failures == [f"sweep: job failed: {reason}  (log in {out})"]
    status = read_status(out)
    assert status["status"] == "FAILED" and status["reason"] == reason
    client = MlflowClient(store)
    runs = client.search_runs([e.experiment_id for e in client.search_experiments()])
    assert [(r.info.status, r.data.tags["failure_reason"], r.data.tags["learner"]) for r in runs] == \
           [("FAILED", reason, learner)]
    assert load_checkpoint(read_status(out)["checkpoint_dir"] + "/checkpoint.pt")["num_timesteps"] == 512


def test_a_sweep_that_lists_one_job_twice_runs_it_once(tmp_path):
    """`agent=ppo ++agent.recom.interval=512,1024`: settings PPO does not run, so both jobs are the same job (one key).
    Run concurrently (two joblib workers), the second waits for the first's lock on the job and reports its run:
    one MLflow run, both jobs FINISHED with its id, no checkpoint written by two processes."""
    from conftest import run_cli

    uri = new_store(tmp_path / "x.db")
    proc = run_cli(["-m", "agent=ppo", "++agent.recom.interval=512,1024", *TINY, "hydra.launcher.n_jobs=2",
                    f"hydra.sweep.dir={tmp_path / 'sweep'}"], uri, tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    client = MlflowClient(uri)
    (r,) = client.search_runs([e.experiment_id for e in client.search_experiments()])
    assert r.info.status == "FINISHED" and r.data.params["agent.recom.enabled"] == "False"
    statuses = [read_status(tmp_path / "sweep" / str(job)) for job in (0, 1)]
    assert [(s["status"], s["run_id"]) for s in statuses] == [("FINISHED", r.info.run_id)] * 2
