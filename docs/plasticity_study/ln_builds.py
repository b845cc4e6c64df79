"""Which numba build flew each LayerNorm run of the study: compiled in the job's process, or loaded from numba's cache.

At the study's commits (9ff7f41, 01b8be3, be84f2b) the rollout's LayerNorm networks give other last bits in a
process that compiled the rollout itself than in one that loaded it from numba's cache (README, Determinism; the
fix, rollout.FASTMATH, came after). Which kind made a run was not recorded; this re-flies the first TOTAL steps of
every FINISHED LayerNorm run in the study's store twice, at the run's commit, with its command (stopped once past
TOTAL): once with an empty numba cache (compiled) and once from the cache the first filled (loaded). The run's build
is the one whose metrics equal the store's bitwise at every step the store holds below TOTAL (the builds part at the
second rollout, 4,096 steps), but for IGNORED (the columns count every metric); "either" and "neither" say the check
could not tell. It tells the build of a run's
first session only: a run resumed in another session may have continued in the other build. Appends one CSV row per
run not yet in OUT (two short runs each, ~45 s on this machine kind). Run from the repo root, with the store
imported (run.sh import):

    STUDY=/work/studies/plasticity .venv/bin/python docs/plasticity_study/ln_builds.py \
        docs/plasticity_study/ln_builds.csv
"""
import csv
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
STUDY = Path(os.environ.get("STUDY", "/work/studies/plasticity"))
TOTAL = 51_200   # 25 rollouts of the preset's 2,048 steps; the store's thinned histories hold a few points below it
COMMITS = {"plasticity-pilot": "9ff7f41", "combo": "be84f2b", "plasticity": "01b8be3"}   # run.sh's pinned commits
# a diagnostic the training does not read: one float32 ulp off at one step in 3 runs made on the Intel Xeon and
# re-flown on the AMD EPYC, whose other metrics were all equal (the CPU difference of this reading seen before)
IGNORED = {"plasticity/grad_norm"}
FIELDS = ["experiment", "run", "commit", "build", "compiled_equal", "loaded_equal"]


def layer_norm_runs(db: sqlite3.Connection) -> list[tuple[str, str, dict[str, str]]]:
    """(experiment, run name, tags) of every FINISHED run of a LayerNorm agent in the study's experiments."""
    rows = db.execute("select e.name, r.name, r.run_uuid from runs r join experiments e on e.experiment_id = "
                      "r.experiment_id where e.name in ('plasticity', 'plasticity-pilot') and r.status = 'FINISHED' "
                      "and r.name like 'layer_norm%' order by e.name, r.name").fetchall()
    return [(exp, name, dict(db.execute("select key, value from tags where run_uuid = ?", (uuid,)).fetchall()))
            for exp, name, uuid in rows]


def overrides(experiment: str, tags: dict[str, str]) -> list[str]:
    """The run's command line as run.sh gave it (its change, agent and seed; the pilot's segment length)."""
    change = ["wind=flip"] if "-flip-" in tags["run_name"] else ["wind=none", "vehicle=payload"]
    pilot = (["wind.segment_steps=4000000", "train.total_timesteps=12000000", "tracking.experiment=plasticity-pilot"]
             if experiment.endswith("pilot") else [])
    return ["experiment=plasticity", f"agent={tags['agent']}", *change, f"seed={tags['seed']}", *pilot]


def commit_of(experiment: str, agent: str) -> str:
    return COMMITS["combo"] if agent == "layer_norm_l2_lr_decay_8m" else COMMITS[experiment]


def fly(code: Path, args: list[str], numba_cache: str) -> dict[tuple[str, int], float]:
    """Every metric (key, step) -> value logged below TOTAL by the run's own command (its total_timesteps too: the
    LR schedules read it) at ``code``, in a throwaway store; the run is stopped once it has logged past TOTAL."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "MLFLOW_TRACKING_URI": f"sqlite:///{tmp}/mlflow.db", "PYTHONPATH": f"{code}/src",
               "NUMBA_CACHE_DIR": numba_cache, "SWEEP_PORTABLE": "1"}
        proc = subprocess.Popen([sys.executable, "-m", "sweep", *args, f"train.checkpoint_dir={tmp}/ckpt",
                                 f"hydra.run.dir={tmp}/run"], cwd=tmp, env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        try:
            while proc.poll() is None and last_step(Path(tmp) / "mlflow.db") < TOTAL + 4096:   # all below TOTAL logged
                time.sleep(1)
        finally:
            proc.terminate()
            proc.wait()
        db = sqlite3.connect(f"{tmp}/mlflow.db")
        return {(k, s): v for k, s, v in db.execute("select key, step, value from metrics where step < ?", (TOTAL,))}


def last_step(db: Path) -> int:
    """The largest step a run has logged so far in the store at ``db`` (0 before it has one)."""
    try:
        return sqlite3.connect(db).execute("select coalesce(max(step), 0) from metrics").fetchone()[0]
    except sqlite3.Error:   # not created yet, or busy
        return 0


def build_of(db: sqlite3.Connection, experiment: str, name: str, tags: dict[str, str]) -> dict[str, str]:
    commit = commit_of(experiment, tags["agent"])
    code = STUDY / f"code-{commit}"
    if not code.is_dir():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(code), commit], check=True)
    stored = {(k, s): v for k, s, v in db.execute(
        "select m.key, m.step, m.value from metrics m join runs r on r.run_uuid = m.run_uuid join experiments e on "
        "e.experiment_id = r.experiment_id where e.name = ? and r.name = ? and r.status = 'FINISHED' and m.step < ?",
        (experiment, name, TOTAL)) if not k.startswith("time/")}
    cache = tempfile.mkdtemp()
    try:
        got = {"compiled": fly(code, overrides(experiment, tags), cache),   # an empty cache: numba compiles
               "loaded": fly(code, overrides(experiment, tags), cache)}     # the cache the first run filled
    finally:
        shutil.rmtree(cache)
    equal = {b: sum(h.get(p) == v for p, v in stored.items()) for b, h in got.items()}
    parted = {b: {k for (k, step), v in stored.items() if h.get((k, step)) != v} for b, h in got.items()}
    same = {b: keys <= IGNORED for b, keys in parted.items()}
    build = ("either" if all(same.values()) else "neither" if not any(same.values())
             else next(b for b, s in same.items() if s))
    return {"experiment": experiment, "run": name, "commit": commit, "build": build,
            **{f"{b}_equal": f"{n}/{len(stored)}" for b, n in equal.items()}}


def main(out: Path) -> None:
    done = {(r["experiment"], r["run"]) for r in csv.DictReader(out.open())} if out.exists() else set()
    db = sqlite3.connect(STUDY / "mlflow.db")
    with out.open("a", newline="") as f:
        writer = csv.DictWriter(f, FIELDS)
        if not done:
            writer.writeheader()
        for experiment, name, tags in layer_norm_runs(db):
            if (experiment, name) not in done:
                writer.writerow(build_of(db, experiment, name, tags))
                f.flush()


if __name__ == "__main__":
    main(Path(sys.argv[1]))
