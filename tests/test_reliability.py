"""Long-run reliability: kill -9 and resume, determinism, failures inside a multirun, concurrent jobs."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from conftest import TINY, compose_cfg, new_store, run_cli
from sweep.checkpoint import load_checkpoint
from sweep.run import run

TESTS = Path(__file__).parent


def runs_of(uri):
    client = MlflowClient(uri)
    return client, client.search_runs([e.experiment_id for e in client.search_experiments()])


def history(client, run_id, key):
    return [(m.step, m.value) for m in client.get_metric_history(run_id, key)]


RECOM_RUN = ["agent=recom_l2", "seed=4", "agent.ppo.n_steps=512", "agent.ppo.n_epochs=2",
             "agent.recom.interval=1024", "agent.recom.window=2", "agent.recom.gain=1e-6", "train.checkpoint_every=1024",
             "wind.segment_steps=2048", "eval.episodes=2", "env.episode_seconds=1.0"]


# SB3's run (the reference) in the slow suite: the same process-level path, 4x slower per step; its checkpoint's
# round trip is tested in-process (test_resume.py, test_reset_all.py, test_remedies.py). JAX: faster, a longer run.
@pytest.mark.parametrize("learner,total", [pytest.param("sb3", 6144, marks=pytest.mark.slow), ("jax", 20480)])
def test_kill_minus_9_then_same_command_finishes_the_same_run(tmp_path, checkpoint_dir, learner, total):
    kill_then_resume(tmp_path, checkpoint_dir, [*RECOM_RUN, f"agent.learner={learner}", f"train.total_timesteps={total}"],
                     total, loss="train/loss", step=512, kill_after=2048)


def kill_then_resume(tmp_path, checkpoint_dir, config: list[str], total: int, loss: str, step: int,
                     kill_after: int) -> None:
    """Run ``config`` as a subprocess, SIGKILL it once a checkpoint at >= ``kill_after`` timesteps exists, run the same
    command again: one FINISHED MLflow run whose histories (log lines every ``step``) equal an uninterrupted run's."""
    uri = new_store(tmp_path / "killed.db")
    args = [*config, f"hydra.run.dir={tmp_path / 'out'}"]
    env = {**os.environ, "MLFLOW_TRACKING_URI": uri}
    proc = subprocess.Popen([sys.executable, "-m", "sweep", *args], cwd=tmp_path, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    checkpoint = None
    while time.time() < deadline and proc.poll() is None:
        found = list(checkpoint_dir.glob("*/checkpoint.pt"))
        if found and load_checkpoint(found[0])["num_timesteps"] >= kill_after:
            checkpoint = found[0]
            break
        time.sleep(0.2)
    assert checkpoint is not None and proc.poll() is None, "run ended before it could be killed mid-way"
    time.sleep(0.5)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL, "run ended before it could be killed mid-way"
    killed_at = load_checkpoint(checkpoint)["num_timesteps"]
    assert killed_at < total

    again = run_cli(args, uri, tmp_path)
    assert again.returncode == 0, again.stderr[-2000:]
    client, runs = runs_of(uri)
    assert len(runs) == 1 and runs[0].info.status == "FINISHED"
    run_id = runs[0].info.run_id
    steps = [s for s, _ in history(client, run_id, "time/total_timesteps")]
    assert steps == list(range(step, total + 1, step))  # strictly increasing, none missing, none duplicated

    # The resumed run is the run that would have happened: same histories as an uninterrupted one.
    ref_uri = new_store(tmp_path / "reference.db")
    ref = run_cli([*config, f"hydra.run.dir={tmp_path / 'ref'}"], ref_uri, tmp_path)
    assert ref.returncode == 0, ref.stderr[-2000:]
    ref_client, (ref_run,) = runs_of(ref_uri)
    assert len(history(client, run_id, loss)) > 2
    for key in ("train/learning_rate", "rollout/ep_rew_mean", loss, "recom/cost", "plasticity/dormant_ratio"):
        assert history(client, run_id, key) == history(ref_client, ref_run.info.run_id, key), key
    assert len({v for _, v in history(client, run_id, "train/learning_rate")}) > 1

    # A completed run is not retrained.
    third = run_cli(args, uri, tmp_path)
    assert third.returncode == 0 and len(runs_of(uri)[1]) == 1
    assert len(history(client, run_id, "time/total_timesteps")) == len(steps)


@pytest.mark.parametrize("learner", ["sb3", "jax"])
def test_same_config_and_seed_twice_is_identical(tmp_path, monkeypatch, learner):
    histories = []
    for attempt in range(2):
        uri = new_store(tmp_path / f"{attempt}.db")
        monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
        run_id = run(compose_cfg(["agent=l2", "seed=11", f"agent.learner={learner}", "train.total_timesteps=1536", "agent.ppo.n_steps=512",
                                  "eval.episodes=2", "env.episode_seconds=1.0"]), tmp_path / f"job{attempt}")
        client = MlflowClient(uri)
        histories.append({k: history(client, run_id, k) for k in ("rollout/ep_rew_mean", "train/loss")})
    assert histories[0] == histories[1] and len(histories[0]["train/loss"]) == 2


# the NaN guard's own test is in-process on both learners (test_run_options.py); in a multirun, the slow suite
@pytest.mark.parametrize("kind,reason", [("raise", "RuntimeError: injected failure"),
                                         pytest.param("'nan'", "NonFiniteError", marks=pytest.mark.slow)])
def test_failing_job_in_multirun(tmp_path, checkpoint_dir, kind, reason):
    uri = new_store(tmp_path / "x.db")
    env_path = os.environ.get("PYTHONPATH", "")
    os.environ["PYTHONPATH"] = f"{TESTS}{os.pathsep}{env_path}"
    try:
        proc = run_cli(["-m", "seed=0,1", *TINY, "train.total_timesteps=1536", "train.checkpoint_every=512",
                        "+agent.fault._target_=faults.Fault", "+agent.fault.seed=1", "+agent.fault.at_step=1024",
                        f"+agent.fault.kind={kind}", f"hydra.sweep.dir={tmp_path / 'sweep'}",
                        "hydra.launcher.n_jobs=2"], uri, tmp_path)
    finally:
        os.environ["PYTHONPATH"] = env_path
    assert proc.returncode == 1
    assert "1/2 jobs finished" in proc.stdout
    failed_lines = [line for line in proc.stderr.splitlines() if line.startswith("sweep: job 1 FAILED")]
    assert len(failed_lines) == 1 and reason in failed_lines[0] and "seed=1" in failed_lines[0]
    client, runs = runs_of(uri)
    status = {r.data.tags["seed"]: r for r in runs}
    assert status["0"].info.status == "FINISHED"
    assert status["1"].info.status == "FAILED" and reason in status["1"].data.tags["failure_reason"]
    kept = load_checkpoint(Path(status["1"].data.tags["checkpoint_dir"]) / "checkpoint.pt")
    assert kept is not None and kept["num_timesteps"] == 512   # the last good state, before the fault


def test_four_concurrent_jobs_on_a_fresh_store(tmp_path):
    uri = f"sqlite:///{tmp_path / 'fresh.db'}"  # the store's first creation, not new_store's copy
    proc = run_cli(["-m", "agent=ppo,l2", "seed=0,1", *TINY, "eval.episodes=1", "env.episode_seconds=1.0",
                    f"hydra.sweep.dir={tmp_path / 'sweep'}", "hydra.launcher.n_jobs=4"], uri, tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    client, runs = runs_of(uri)
    assert len(runs) == 4 and all(r.info.status == "FINISHED" for r in runs)
    for r in runs:
        for key in ("rollout/ep_rew_mean", "time/total_timesteps", "plasticity/dormant_ratio"):
            assert [s for s, _ in history(client, r.info.run_id, key)] == [512, 1024], key


def test_submitit_local_launcher(tmp_path):
    uri = new_store(tmp_path / "x.db")
    proc = run_cli(["-m", "hydra/launcher=submitit_local", "hydra.launcher.cpus_per_task=1", "seed=0,1", *TINY,
                    "train.total_timesteps=512", "eval.episodes=1", f"hydra.sweep.dir={tmp_path / 'sweep'}"], uri, tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    _, runs = runs_of(uri)
    assert sorted(r.data.tags["seed"] for r in runs) == ["0", "1"] and all(r.info.status == "FINISHED" for r in runs)


def test_slurm_preset_composes(tmp_path, monkeypatch):
    """hydra/launcher=slurm with the paper study composes into hydra-submitit's SlurmLauncher, and that launcher,
    given the study's jobs, builds the sbatch script the preset promises: 1 CPU and 2 GB per run, 48 h, an array
    of at most 32 runs at once, one thread per library, all jobs (the sweep's 30) in one array. The cluster is
    faked only where submitit touches it: ``srun`` must exist, and the array is captured instead of submitted."""
    import submitit
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    from conftest import CONF

    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=["experiment=paper", "hydra/launcher=slurm",
                                                       f"hydra.sweep.dir={tmp_path / 'sweep'}"],
                      return_hydra_config=True)
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "srun").write_text("#!/bin/sh\nexit 0\n")
    (bin_dir / "srun").chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    submitted = {}

    def capture(executor, fn, *args):
        submitted.update(executor=executor, fn=fn, args=args)
        return []

    monkeypatch.setattr(submitit.AutoExecutor, "map_array", capture)
    launcher = instantiate(cfg.hydra.launcher)
    assert type(launcher).__name__ == "SlurmLauncher"
    launcher.config = cfg  # what Hydra's setup() gives it; only the sweep dir is read before submitting
    params = dict(cfg.hydra.sweeper.params)
    jobs = [[f"wind={w}", f"seed={s}", f"agent={a}"] for w in params["wind"].split(",")
            for s in params["seed"].split(",") for a in params["agent"].split(",")]
    assert launcher.launch(jobs, initial_job_idx=0) == []
    overrides, _, indices = submitted["args"][:3]
    assert len(overrides) == 30 and list(indices) == list(range(30)) and submitted["fn"] is launcher
    slurm = submitted["executor"]._executor
    slurm.parameters["map_count"] = len(overrides)  # what submitit sets when it submits the array
    script = slurm._make_submission_file_text("python -u -m submitit.core._submit <folder>", "uid")
    sbatch = {line.split("=", 1)[0]: line.split("=", 1)[1] for line in script.splitlines()
              if line.startswith("#SBATCH ") and "=" in line}
    assert sbatch["#SBATCH --cpus-per-task"] == "1" and sbatch["#SBATCH --ntasks-per-node"] == "1"
    assert sbatch["#SBATCH --nodes"] == "1" and sbatch["#SBATCH --mem"] == "2GB"
    assert sbatch["#SBATCH --time"] == "2880" and sbatch["#SBATCH --array"] == "0-29%30"
    assert "#SBATCH --partition" not in sbatch  # null: the cluster's default unless set
    assert "export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 MLFLOW_DISABLE_TELEMETRY=true" in script.splitlines()
    assert sbatch["#SBATCH --output"].startswith(str(tmp_path / "sweep" / ".submitit"))
    # more runs than array_parallelism: at most 32 at once
    slurm.parameters["map_count"] = 40
    assert "#SBATCH --array=0-39%32" in slurm._make_submission_file_text("cmd", "uid").splitlines()


def test_sweep_summary_counts_only_the_job_dirs_this_sweep_wrote(tmp_path, capsys):
    """A sweep re-invoked in the same dir with fewer jobs: the earlier invocation's killed job is not this one's. A
    job this sweep resumed in its existing dir counts: Hydra rewrote the config files in its old ``.hydra``."""
    from sweep.status import report_sweep, write_status

    sweep = tmp_path / "sweep"
    old = time.time() - 3600
    for job, status in (("0", "FINISHED"), ("1", "RUNNING")):  # the earlier invocation: job 1 killed mid-run
        (sweep / job / ".hydra").mkdir(parents=True)
        (sweep / job / ".hydra" / "config.yaml").write_text(f"seed: {job}\n")
        write_status(sweep / job, status, overrides=[f"seed={job}"])
        for path in (sweep / job / ".hydra" / "config.yaml", sweep / job / ".hydra"):
            os.utime(path, (old, old))
    (sweep / "0" / ".hydra" / "config.yaml").write_text("seed: 0\n")   # this one re-ran job 0 alone, in its dir
    report_sweep(sweep, "sqlite:///x.db", "mlflow ui", since=time.time() - 60)
    out = capsys.readouterr().out
    assert "1/1 jobs finished" in out and "1 job dirs of an earlier sweep in this dir not counted (1)" in out
    with pytest.raises(SystemExit):  # without the sweep's start every dir counts, the stale RUNNING too
        report_sweep(sweep, "sqlite:///x.db", "mlflow ui")
    assert "1/2 jobs finished" in capsys.readouterr().out
