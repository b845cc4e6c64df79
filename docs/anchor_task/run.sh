#!/usr/bin/env bash
# The anchor task (issue 56, item 4's first step; experiment=anchor_task; docs/anchor_task.md): does TD3 learn the task
# of "Learning to Fly in Seconds" in this simulator, and with which reward form?
#
#   docs/anchor_task/run.sh pilot    # seeds 100-103, 300k: the reward's power (1, 2) x w_p (2.5, 10); chose power=1, w_p=2.5
#   docs/anchor_task/run.sh long     # seeds 100-103, 1M: does the chosen form come in closer with training?
#   docs/anchor_task/run.sh main     # the preset as chosen on seeds 0-15, which chose nothing
#   docs/anchor_task/run.sh curriculum  # seeds 100-103, 1M: the anchor's reward-weight curriculum on each power
#   docs/anchor_task/run.sh curriculum-main  # the curriculum as chosen on seeds 16-31, which chose nothing
#   docs/anchor_task/run.sh report   # the tables and figures -> docs/anchor_task/pilot (pilot, long, curriculum), main,
#                                    #   curriculum (its held-out seeds)
#   docs/anchor_task/run.sh export   # FINISHED runs -> docs/anchor_task/runs (commit them)
#   docs/anchor_task/run.sh import   # the archive -> the store (re-make every table without training)
#
# Every phase is a Hydra multirun with resume=auto (a FINISHED job is skipped). Store, checkpoints and sweep dirs live in
# $STUDY; each phase runs the code of MAIN_COMMIT from a worktree there. The runs of 12-07 ran that code from the
# working tree before it was committed; the pilot's first sweep (power 2, w_p 2.5, when that was the preset) is the
# pilot's power=2 w_p=2.5 cell here.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
STUDY=${STUDY:-/work/studies/anchor}
MAIN_COMMIT=${MAIN_COMMIT:-e3d845e}
CURRICULUM_COMMIT=${CURRICULUM_COMMIT:-6e05257}   # env.reward_curriculum
CURRICULUM=(env.reward_curriculum.every=100000 train.total_timesteps=1000000)
PY=${PYTHON:-$ROOT/.venv/bin/python}
ARCHIVE=$ROOT/docs/anchor_task/runs
BY=env.reward.power,env.reward.w_p,env.reward_curriculum.every
export MLFLOW_TRACKING_URI=sqlite:///$STUDY/mlflow.db   # the store of 12-07 also holds the pilot's cells in a
                                                      # sweep named weights (run.sh pilot names them all pilot)
mkdir -p "$STUDY"

sweep() {  # sweep NAME OVERRIDES...: COMMIT's code (MAIN_COMMIT), the study's store and checkpoints; output under $STUDY
  local commit=${COMMIT:-$MAIN_COMMIT} name=$1; shift
  local code=$STUDY/code-$commit
  [ -d "$code" ] || git -C "$ROOT" worktree add --detach "$code" "$commit"
  (cd "$STUDY" && PYTHONPATH=$code/src "$PY" -m sweep -m experiment=anchor_task train.checkpoint_dir="$STUDY/ckpt" \
     hydra.sweep.dir="$STUDY/multirun/$name" "$@")
  for job in "$STUDY"/ckpt/*/; do   # a FINISHED job's checkpoint holds its replay buffer: dead weight
    if grep -q '"status": "FINISHED"' "$job/job.json" 2>/dev/null; then rm -f "$job/checkpoint.pt"; fi
  done
}
report() {  # report NAME SEEDS [--by KEYS]
  (cd "$STUDY" && "$PY" -m sweep.report.reliability --experiment anchor-task --seeds "$2" "${@:3}" \
     --out "$ROOT/docs/anchor_task/$1")
}

case ${1:-} in
  pilot)   sweep pilot seed=100,101,102,103 env.reward.power=1,2 env.reward.w_p=2.5,10 ;;
  long)    sweep long seed=100,101,102,103 train.total_timesteps=1000000 eval.every_timesteps=100000 ;;
  main)    sweep main seed=0,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15 ;;
  curriculum)  COMMIT=$CURRICULUM_COMMIT sweep curriculum seed=100,101,102,103 env.reward.power=1,2 "${CURRICULUM[@]}" ;;
  curriculum-main)  COMMIT=$CURRICULUM_COMMIT sweep curriculum-main seed=16,17,18,19,20,21,22,23,24,25,26,27,28,29,30,31 \
                      "${CURRICULUM[@]}" ;;   # the preset's linear costs (power 1)
  report)  report pilot 100-103 --by "$BY,train.total_timesteps"   # the pilot's four cells and the long runs
           report main 0-15
           (cd "$STUDY" && "$PY" "$ROOT/docs/anchor_task/distance.py" 100-103 "$BY,train.total_timesteps" 800000) \
             > "$ROOT/docs/anchor_task/pilot/distance.md"   # where each seed ends: distance, crashes
           (cd "$STUDY" && "$PY" "$ROOT/docs/anchor_task/distance.py" 0-15) > "$ROOT/docs/anchor_task/main/distance.md"
           report curriculum 16-31   # the curriculum's held-out seeds
           (cd "$STUDY" && "$PY" "$ROOT/docs/anchor_task/distance.py" 16-31 "" 800000) \
             > "$ROOT/docs/anchor_task/curriculum/distance.md" ;;
  export)  (cd "$STUDY" && "$PY" -m sweep.archive export --experiment anchor-task --out "$ARCHIVE/anchor-task") ;;
  import)  for dir in "$ARCHIVE"/*/; do (cd "$STUDY" && "$PY" -m sweep.archive import "$dir"); done ;;
  *) sed -n 2,11p "$0"; exit 2 ;;
esac
