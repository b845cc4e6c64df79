"""The README's recipes, followed as written: "Add a diagnostic" and "Add a remedy" each write one module and one YAML
into a copy of conf/ and src/, run the README's commands there, and need nothing else: the new diagnostic and the new
remedy run, log, validate and report, and no existing agent's job key moves."""
from __future__ import annotations

import filecmp
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from conftest import ROOT, new_store

RECIPES = {"diagnostic": "### Add a diagnostic (one module, one YAML)", "remedy": "### Add a remedy (one module, one YAML)"}
# the README's command, shortened to a tiny run (a budget, the store, quiet progress), never changed otherwise
TINY = ["train.total_timesteps=1024", "agent.ppo.n_steps=256", "agent.ppo.n_epochs=2", "eval.episodes=1",
        "train.progress_every_s=1000", "tracking.experiment=recipe", "hooks.probe.steps=0"]


def recipe(name: str) -> tuple[dict[str, str], list[list[str]]]:
    """The files (path -> text, from the fenced blocks whose first line is `# <path>`) and the commands (the fenced
    bash lines) of one README section."""
    readme = (ROOT / "README.md").read_text()
    start = readme.index(RECIPES[name])
    end = re.compile(r"\n#{2,3} ").search(readme, start + 1)   # the next heading (a code comment has one #)
    section = readme[start:end.start()]
    files, commands = {}, []
    for lang, body in re.findall(r"```(\w+)\n(.*?)```", section, re.S):
        first, _, rest = body.partition("\n")
        if lang == "bash":
            commands += [line.split() for line in body.splitlines() if line.startswith("python -m sweep")]
        elif first.startswith("# ") and "/" in first:
            files[first[2:].strip()] = body if lang == "python" else rest
    return files, commands


def copy_project(dst: Path) -> None:
    for part in ("conf", "src"):
        shutil.copytree(ROOT / part, dst / part, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))


def run_in(tree: Path, command: list[str], uri: str, *extra: str) -> subprocess.CompletedProcess:
    """A README command in the copy: its own src/ first on the path, so `python -m sweep` is the copy's."""
    args = [a.strip("'") for a in command[1:]]
    env = {**os.environ, "PYTHONPATH": str(tree / "src"), "MLFLOW_TRACKING_URI": uri, "HYDRA_FULL_ERROR": "0",
           "SWEEP_CHECKPOINT_DIR": str(tree / "checkpoints")}
    return subprocess.run([sys.executable, *args, *extra], cwd=tree, env=env, capture_output=True, text=True,
                          timeout=600)


def job_keys(conf: Path) -> dict[str, str]:
    """The job key of every agent the project ships, composed from ``conf``."""
    from hydra import compose, initialize_config_dir

    from sweep.checkpoint import job_key

    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        return {a.stem: job_key(compose(config_name="config", overrides=[f"agent={a.stem}"]), "sqlite:///x.db")
                for a in sorted((ROOT / "conf" / "agent").glob("*.yaml"))}


def changed_files(tree: Path) -> set[str]:
    """Files of the copy's conf/ and src/ that are new or differ from the project's."""
    out = set()
    for path in (p for part in ("conf", "src") for p in (tree / part).rglob("*") if p.is_file()):
        if "__pycache__" in path.parts:
            continue
        original = ROOT / path.relative_to(tree)
        if not original.exists() or not filecmp.cmp(path, original, shallow=False):
            out.add(str(path.relative_to(tree)))
    return out


@pytest.mark.parametrize("name, often, metric, figure, bad", [
    ("diagnostic", [], "diag/head_norm", "head_norm",   # every 2 of the 4 rollouts
     ("hooks.head_norm.every=0", "hooks.head_norm.every=0: must be an integer > 0 (rollouts)")),
    ("remedy", ["agent.head_reset.every_updates=1"], "remedy/head_reset/head_norm", "head_reset",   # after 3 updates
     ("agent.head_reset.every_updates=0", "agent.head_reset.every_updates=0: must be an integer > 0 (updates)")),
])
def test_the_readme_recipe_is_one_module_and_one_yaml(tmp_path, name, often, metric, figure, bad):
    files, commands = recipe(name)
    assert len(files) == 2 and len(commands) == 2, (files.keys(), commands)
    tree = tmp_path / "project"
    copy_project(tree)
    for path, text in files.items():
        (tree / path).write_text(text)
    assert changed_files(tree) == set(files)   # the recipe's two files, nothing else
    assert job_keys(tree / "conf") == job_keys(ROOT / "conf")   # every shipped agent keeps its job

    uri = new_store(tmp_path / "mlflow.db")
    train, report = commands
    proc = run_in(tree, train, uri, *TINY, *often)
    assert proc.returncode == 0, proc.stderr[-3000:]
    client = MlflowClient(uri)
    (run,) = client.search_runs([client.get_experiment_by_name("recipe").experiment_id])
    history = client.get_metric_history(run.info.run_id, metric)
    assert len(history) >= 2 and all(m.value > 0 for m in history), (metric, history)

    proc = run_in(tree, report, uri, "--experiment", "recipe", "--out", str(tmp_path / "report"), "--draft")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "report" / f"{figure}_paper.png").exists(), proc.stdout

    proc = run_in(tree, train, uri, *TINY, bad[0])
    assert proc.returncode == 2
    assert [line for line in proc.stderr.splitlines() if line.startswith("sweep:")] == [f"sweep: invalid config: {bad[1]}"]
