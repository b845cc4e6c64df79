"""The cluster path against a real shared tracking server: PostgreSQL (Debian's package) behind ``mlflow server``,
a 4-job joblib multirun over HTTP, one job SIGKILLed mid-run and resumed; and what the SQLite default holds.

Slow (``make test-slow``): it installs PostgreSQL with apt-get when missing (as root) and runs ~2 min. The
README's "Running on a cluster" section gives the same commands.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
VENV_BIN = Path(sys.executable).parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def postgres_bin() -> Path:
    """Debian's PostgreSQL server binaries, installed with apt-get if missing (needs root)."""
    found = sorted(Path("/usr/lib/postgresql").glob("*/bin/initdb"))
    if not found and os.geteuid() == 0 and shutil.which("apt-get"):
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        subprocess.run(["apt-get", "update", "-qq"], check=False, env=env, capture_output=True)
        subprocess.run(["apt-get", "install", "-y", "-qq", "postgresql"], check=False, env=env, capture_output=True)
        found = sorted(Path("/usr/lib/postgresql").glob("*/bin/initdb"))
    if not found:
        pytest.skip("no PostgreSQL server (apt-get install postgresql) and not root to install it")
    return found[-1].parent


def as_postgres(cmd: list[str], **kwargs) -> subprocess.CompletedProcess:
    """PostgreSQL refuses to run as root: run as the package's ``postgres`` user when we are root."""
    if os.geteuid() == 0:
        cmd = ["runuser", "-u", "postgres", "--", *cmd]
    return subprocess.run(cmd, check=True, capture_output=True, text=True, **kwargs)


@pytest.fixture
def postgres(tmp_path):
    """A PostgreSQL server on 127.0.0.1 only, with a database ``mlflow``; stopped and removed afterwards."""
    bin_dir, port = postgres_bin(), free_port()
    data = Path(tempfile.mkdtemp(prefix="sweep-pg-"))   # pytest's tmp dirs are root-only; postgres must reach it
    if os.geteuid() == 0:
        shutil.chown(data, "postgres", "postgres")
    as_postgres([str(bin_dir / "initdb"), "-D", str(data), "-U", "sweep", "--auth=trust"])
    as_postgres([str(bin_dir / "pg_ctl"), "-D", str(data), "-l", str(data / "server.log"), "-w", "start",
                 "-o", f"-c listen_addresses=127.0.0.1 -p {port} -k {data}"])
    try:
        as_postgres([str(bin_dir / "createdb"), "-h", "127.0.0.1", "-p", str(port), "-U", "sweep", "mlflow"])
        yield f"postgresql+psycopg2://sweep@127.0.0.1:{port}/mlflow"
    finally:
        as_postgres([str(bin_dir / "pg_ctl"), "-D", str(data), "-m", "fast", "-w", "stop"])
        shutil.rmtree(data, ignore_errors=True)


@pytest.fixture
def mlflow_server(postgres, tmp_path):
    """``mlflow server`` on 127.0.0.1 with the PostgreSQL backend and a local artifact root; stopped afterwards."""
    port, artifacts = free_port(), tmp_path / "artifacts"
    env = {**os.environ, "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false", "MLFLOW_DISABLE_TELEMETRY": "true"}
    proc = subprocess.Popen([str(VENV_BIN / "mlflow"), "server", "--backend-store-uri", postgres,
                             "--artifacts-destination", str(artifacts), "--host", "127.0.0.1", "--port", str(port),
                             "--workers", "1"], env=env, stdout=subprocess.DEVNULL, stderr=open(tmp_path / "server.log", "w"))
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.time() + 120
        while True:
            try:
                if urllib.request.urlopen(f"{url}/health", timeout=2).status == 200:
                    break
            except OSError:
                if time.time() > deadline or proc.poll() is not None:
                    raise RuntimeError(f"mlflow server did not start: {(tmp_path / 'server.log').read_text()[-2000:]}")
                time.sleep(0.5)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
        shutil.rmtree(artifacts, ignore_errors=True)


TOTAL, ROLLOUT = 40960, 512
SWEEP = ["-m", "agent=ppo,l2", "seed=0,1", "agent.learner=jax", "agent.ppo.n_steps=512",
         f"train.total_timesteps={TOTAL}", "train.checkpoint_every=2048", "train.progress_every_s=1000",
         "eval.episodes=1", "env.episode_seconds=1.0", "tracking.experiment=server-test", "hydra.launcher.n_jobs=2"]


def test_multirun_against_postgres_backed_mlflow_server_survives_a_sigkill(mlflow_server, tmp_path, checkpoint_dir):
    from mlflow.tracking import MlflowClient

    from sweep.checkpoint import load_checkpoint
    from sweep.status import read_json

    env = {**os.environ, "MLFLOW_TRACKING_URI": mlflow_server, "HYDRA_FULL_ERROR": "0"}
    args = [sys.executable, "-m", "sweep", *SWEEP, f"hydra.sweep.dir={tmp_path / 'sweep'}"]
    proc = subprocess.Popen(args, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    killed = None
    deadline = time.time() + 300
    while killed is None and time.time() < deadline and proc.poll() is None:
        for record in checkpoint_dir.glob("*/job.json"):
            job = read_json(record)
            ckpt = record.parent / "checkpoint.pt"
            if job.get("pid") and ckpt.exists() and 8192 <= load_checkpoint(ckpt)["num_timesteps"] < TOTAL:
                os.kill(job["pid"], signal.SIGKILL)   # the job's worker process dies, as on a lost node
                killed = job["run_id"]
                break
        time.sleep(0.2)
    assert killed is not None, "no job could be killed mid-run"
    first = proc.wait(300)
    client = MlflowClient(mlflow_server)
    assert client.get_run(killed).info.status == "RUNNING"   # left unfinished by the kill

    again = subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, (first, again.stderr[-3000:])
    exp = client.get_experiment_by_name("server-test")
    runs = client.search_runs([exp.experiment_id])
    assert len(runs) == 4 and all(r.info.status == "FINISHED" for r in runs)   # no run lost, none doubled
    assert sorted((r.data.tags["agent"], r.data.tags["seed"]) for r in runs) == [
        ("l2", "0"), ("l2", "1"), ("ppo", "0"), ("ppo", "1")]
    assert killed in {r.info.run_id for r in runs}   # the killed job finished its own run
    for run in runs:
        for key in ("time/total_timesteps", "rollout/ep_rew_mean", "train/loss"):
            steps = [m.step for m in client.get_metric_history(run.info.run_id, key)]
            expected = list(range(ROLLOUT, TOTAL + 1, ROLLOUT))
            if key == "train/loss":   # SB3 logs train/* from the second rollout on
                expected = expected[1:]
            assert steps == expected, (run.data.tags["run_name"], key)   # none missing, none duplicated
        names = {a.path for a in client.list_artifacts(run.info.run_id)}
        assert {"config.yaml", "eval_trajectories.npz", "model.zip"} <= names
    local = client.download_artifacts(killed, "config.yaml", str(tmp_path / "download"))
    assert "server-test" in Path(local).read_text()

    report = subprocess.run([sys.executable, "-m", "sweep.report", "--experiment", "server-test", "--out",
                             str(tmp_path / "report")], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert report.returncode == 0, report.stderr[-2000:]
    assert "4 finished runs from http://127.0.0.1" in report.stdout
    assert (tmp_path / "report" / "reward_paper.png").stat().st_size > 10_000


def _writer(uri: str, experiment_id: str, index: int, batches: int, queue) -> None:
    """One job's metric traffic: ``batches`` log_batch calls of 100 metrics (as MlflowWriter sends them)."""
    os.environ["MLFLOW_DISABLE_TELEMETRY"] = "true"
    from mlflow.entities import Metric
    from mlflow.tracking import MlflowClient

    client = MlflowClient(uri)
    run_id = client.create_run(experiment_id, tags={"writer": str(index)}).info.run_id
    errors = 0
    for b in range(batches):
        metrics = [Metric(f"m/{k}", float(b), 0, b) for k in range(100)]
        try:
            client.log_batch(run_id, metrics=metrics)
        except Exception as err:  # noqa: BLE001 - counted: a lost batch is what this test measures
            errors += 1
            queue.put(("error", index, str(err).splitlines()[0]))
    client.set_terminated(run_id)
    queue.put(("done", index, errors))


@pytest.mark.parametrize("writers", [8])
def test_sqlite_default_holds_concurrent_writers(tmp_path, writers):
    """N processes logging metrics into one SQLite store at once: every batch lands (no 'database is locked')."""
    from mlflow.tracking import MlflowClient

    from conftest import new_store
    from sweep.tracking import ensure_store

    uri = new_store(tmp_path / "mlflow.db")
    exp_id = ensure_store(uri, "concurrency")
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    batches = 50
    procs = [ctx.Process(target=_writer, args=(uri, exp_id, i, batches, queue)) for i in range(writers)]
    t0 = time.time()
    for p in procs:
        p.start()
    messages = [queue.get(timeout=600) for _ in range(writers)]
    while not all(m[0] == "done" for m in messages[-writers:]):
        messages.append(queue.get(timeout=600))
    for p in procs:
        p.join(60)
    errors = [m for m in messages if m[0] == "error"]
    client = MlflowClient(uri)
    runs = client.search_runs([exp_id])
    counts = [len(client.get_metric_history(r.info.run_id, "m/0")) for r in runs]
    print(json.dumps({"writers": writers, "batches_each": batches, "seconds": round(time.time() - t0, 1),
                      "errors": len(errors), "first_error": errors[0][2] if errors else None}))
    assert not errors and len(runs) == writers and counts == [batches] * writers


def chromium() -> str:
    """Debian's Chromium, installed with apt-get if missing (needs root)."""
    path = shutil.which("chromium")
    if path is None and os.geteuid() == 0 and shutil.which("apt-get"):
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        subprocess.run(["apt-get", "update", "-qq"], check=False, env=env, capture_output=True)
        subprocess.run(["apt-get", "install", "-y", "-qq", "chromium"], check=False, env=env, capture_output=True)
        path = shutil.which("chromium")
    if path is None:
        pytest.skip("no chromium (apt-get install chromium) and not root to install it")
    return path


def test_printed_link_opens_the_runs_table_in_a_real_browser(tmp_path):
    """A small sweep prints the runs-table link; a real ``mlflow ui`` serves it; headless Chromium's DOM holds every
    run name."""
    from conftest import TINY, new_store, run_cli

    browser = chromium()
    uri = new_store(tmp_path / "mlflow.db")
    sweep = run_cli(["-m", "agent=ppo,l2", "seed=0,1", *TINY, "train.total_timesteps=512", "eval.episodes=1",
                     "tracking.experiment=ui-test", f"hydra.sweep.dir={tmp_path / 'sweep'}"], uri, tmp_path)
    assert sweep.returncode == 0, sweep.stderr[-2000:]
    (link,) = [line.split(": ", 2)[2] for line in sweep.stdout.splitlines() if line.startswith("sweep: then the runs table")]
    assert link.startswith("http://127.0.0.1:5000/#/experiments/") and link.endswith("?workflowType=machine_learning")

    port = free_port()
    env = {**os.environ, "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false", "MLFLOW_DISABLE_TELEMETRY": "true"}
    ui = subprocess.Popen([str(VENV_BIN / "mlflow"), "ui", "--backend-store-uri", uri, "--host", "127.0.0.1",
                           "--port", str(port), "--workers", "1"], env=env, stdout=subprocess.DEVNULL,
                          stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 120
        while True:
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2)
                break
            except OSError:
                assert time.time() < deadline and ui.poll() is None, "mlflow ui did not start"
                time.sleep(0.5)

        def dom(url: str) -> str:
            flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                     "--disable-background-networking", "--disable-component-update", "--disable-sync",
                     f"--user-data-dir={tmp_path / 'chromium'}", "--virtual-time-budget=20000", "--dump-dom"]
            return subprocess.run([browser, *flags, url], capture_output=True, text=True, timeout=180).stdout

        page = dom(link.replace("127.0.0.1:5000", f"127.0.0.1:{port}"))
        names = [f"{agent}-paper-s{seed}" for agent in ("ppo", "l2") for seed in (0, 1)]
        assert all(name in page for name in names), page[-3000:]
    finally:
        ui.terminate()
        ui.wait(30)
