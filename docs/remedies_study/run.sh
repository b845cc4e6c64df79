#!/usr/bin/env bash
# The remedies study (docs/remedies_study.md, issue 19), phase by phase, resumable on a new machine.
#
#   docs/remedies_study/run.sh import        # the finished runs carried in docs/remedies_study/runs -> the store
#   docs/remedies_study/run.sh equivalence   # SB3 vs JAX: PPO, 16 x 128, 20 seeds each, 500k steps
#   docs/remedies_study/run.sh pilot         # every agent, 3 seeds, 6M steps
#   docs/remedies_study/run.sh main          # experiment=remedies: 11 agents x 8 seeds x 20M, wind paper
#   docs/remedies_study/run.sh none          # PPO and the 3 best agents, wind none (AGENTS_NONE)
#   docs/remedies_study/run.sh fast          # PPO and the 4 best agents, 16 envs x 128 steps (AGENTS_FAST)
#   docs/remedies_study/run.sh export        # new FINISHED runs -> docs/remedies_study/runs (commit them)
#   docs/remedies_study/run.sh report        # every table and figure of docs/remedies_study.md
#
# Every phase is an ordinary Hydra multirun with resume=auto (the default): a job whose run is FINISHED in the
# store (trained here, or imported) is skipped, an interrupted one continues from its checkpoint. The store,
# checkpoints and sweep dirs live outside the work tree in $STUDY; the sweeps run the code of one commit
# (STUDY_COMMIT) from a worktree there, because a job's key hashes its config: the same commit and the same
# $STUDY find the same jobs, and so do the runs imported from the archive.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
STUDY=${STUDY:-/work/studies/remedies}
STUDY_COMMIT=fce62f7
CODE=$STUDY/code
PY=${PYTHON:-$ROOT/.venv/bin/python}
ARCHIVE=$ROOT/docs/remedies_study/runs
AGENTS_NONE=${AGENTS_NONE:-}   # set from the main phase's leaderboard, e.g. ppo,a,b,c
AGENTS_FAST=${AGENTS_FAST:-}   # e.g. ppo,a,b,c,d
export MLFLOW_TRACKING_URI=sqlite:///$STUDY/mlflow.db

mkdir -p "$STUDY"
[ -d "$CODE" ] || git -C "$ROOT" worktree add --detach "$CODE" "$STUDY_COMMIT"

sweep() {  # the study's code, the study's store and checkpoints; all output under $STUDY
  local name=$1; shift
  (cd "$STUDY" && PYTHONPATH=$CODE/src "$PY" -m sweep -m train.checkpoint_dir="$STUDY/ckpt" \
     hydra.sweep.dir="$STUDY/multirun/$name" "$@")
}
need() { [ -n "$2" ] || { echo "run.sh: set $1 (comma-separated agents, PPO first) from the main leaderboard" >&2; exit 2; }; }

case ${1:-} in
  import)      (cd "$STUDY" && "$PY" -m sweep.archive import "$ARCHIVE") ;;
  equivalence) sweep equivalence experiment=equivalence train.total_timesteps=500000 "seed=$(seq -s, 0 19)" \
                 eval.every_timesteps=0 tracking.experiment=equivalence-20 ;;
  pilot)       sweep pilot experiment=remedies train.total_timesteps=6000000 seed=0,1,2 tracking.experiment=remedies-pilot ;;
  main)        sweep main experiment=remedies ;;
  none)        need AGENTS_NONE "$AGENTS_NONE"; sweep none experiment=remedies wind=none "agent=$AGENTS_NONE" ;;
  fast)        need AGENTS_FAST "$AGENTS_FAST"
               sweep fast experiment=remedies env.n_envs=16 agent.ppo.n_steps=128 "agent=$AGENTS_FAST" ;;
  export)      for exp in equivalence-20 remedies-pilot remedies; do
                 (cd "$STUDY" && "$PY" -m sweep.archive export --experiment "$exp" --out "$ARCHIVE/$exp") || true
               done ;;
  report)      out=$ROOT/docs/remedies_study
               (cd "$STUDY" && "$PY" -m sweep.report --experiment equivalence-20 --out "$out/equivalence" \
                  --by agent.learner --baseline agent.learner=sb3 --at 100000,250000,500000)
               (cd "$STUDY" && "$PY" -m sweep.report --experiment remedies-pilot --out "$out/pilot")
               (cd "$STUDY" && "$PY" -m sweep.report --experiment remedies --out "$out/main" --by env.n_envs \
                  --baseline agent=ppo) ;;
  *) sed -n 2,11p "$0"; exit 2 ;;
esac
