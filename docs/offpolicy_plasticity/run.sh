#!/usr/bin/env bash
# The plasticity question off-policy (issue 56, item 4; experiment=offpolicy_plasticity; docs/offpolicy_plasticity.md):
# TD3 (JAX) on the anchor's task, under a wind flip or a payload, against its fresh twin (twin=fresh).
#
#   docs/offpolicy_plasticity/run.sh pilot     # seeds 100,101 x flip, payload x TD3, its fresh twin; 4 x 500k (8 runs)
#   docs/offpolicy_plasticity/run.sh transfer  # the continual pilot runs' final policies flown under other conditions
#   docs/offpolicy_plasticity/run.sh report    # the report, fresh networks' learning times -> .../pilot
#   docs/offpolicy_plasticity/run.sh stop      # stop a running phase (a re-run resumes: FINISHED jobs are skipped)
#   docs/offpolicy_plasticity/run.sh export    # FINISHED runs -> docs/offpolicy_plasticity/runs (commit them)
#   docs/offpolicy_plasticity/run.sh import    # the archive -> the store (re-make every table without training)
#
# Every training phase is a Hydra multirun with resume=auto. Store, checkpoints and sweep dirs live in $STUDY; each
# training phase runs the code of MAIN_COMMIT from a worktree there (transfer, report, export and import run this
# checkout's). Seeds 100 and 101 are the pilot's (every choice); seeds 0-15 are kept for the study.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
STUDY=${STUDY:-/work/studies/offpolicy}
MAIN_COMMIT=${MAIN_COMMIT:-22e3f4a}   # the pilot of 12-07 (its twins' last change reset them: fixed in 6a13cd5)
PY=${PYTHON:-$ROOT/.venv/bin/python}
ARCHIVE=$ROOT/docs/offpolicy_plasticity/runs
PILOT=$ROOT/docs/offpolicy_plasticity/pilot
export MLFLOW_TRACKING_URI=sqlite:///$STUDY/mlflow.db
mkdir -p "$STUDY"

sweep() {  # sweep NAME OVERRIDES...: MAIN_COMMIT's code, the study's store and checkpoints; output under $STUDY
  local commit name=$1; shift
  commit=$(git -C "$ROOT" rev-parse --short "$MAIN_COMMIT")
  local code=$STUDY/code-$commit
  [ -d "$code" ] || git -C "$ROOT" worktree add --detach "$code" "$commit"
  (cd "$STUDY" && PYTHONPATH=$code/src "$PY" -m sweep -m experiment=offpolicy_plasticity \
     train.checkpoint_dir="$STUDY/ckpt" hydra.sweep.dir="$STUDY/multirun/$name" "$@")
  for job in "$STUDY"/ckpt/*/; do   # a FINISHED job's checkpoint holds its replay buffer: dead weight
    if grep -q '"status": "FINISHED"' "$job/job.json" 2>/dev/null; then rm -f "$job/checkpoint.pt"; fi
  done
}

table() {  # table SCRIPT FILE: the script's table into $PILOT/FILE, replaced only when the script succeeds
  (cd "$STUDY" && "$PY" "$ROOT/docs/offpolicy_plasticity/$1") > "$PILOT/$2.tmp" && mv "$PILOT/$2.tmp" "$PILOT/$2"
}

case ${1:-} in
  pilot)   set -f   # the words below are split, not globbed
           for change in "flip wind=flip" "payload wind=none vehicle=payload"; do
             set -- $change
             sweep "pilot-$1" "${@:2}" seed=100,101                       # the continual agent
             sweep "pilot-$1-fresh" "${@:2}" seed=100,101 twin=fresh      # its fresh twin
           done ;;
  transfer)  set -f   # eval.direction=[1,0,0] is a glob pattern to the shell
             for spec in "still eval.wind_speed=0" "plus3 eval.wind_speed=3 eval.direction=[1,0,0]" \
                        "minus3 eval.wind_speed=3 eval.direction=[-1,0,0]" \
                        "plus5 eval.wind_speed=5 eval.direction=[1,0,0]" \
                        "minus5 eval.wind_speed=5 eval.direction=[-1,0,0]" "mass1 eval.wind_speed=0 eval.mass=1.0" \
                        "mass15 eval.wind_speed=0 eval.mass=1.5" "mass2 eval.wind_speed=0 eval.mass=2.0" \
                        "rotor07 eval.wind_speed=0 eval.rotor_efficiency=[0.7,1.0,1.0,1.0]" \
                        "rotor05 eval.wind_speed=0 eval.rotor_efficiency=[0.5,1.0,1.0,1.0]"; do
               set -- $spec   # the continual pilot runs' final policies flown under one fixed condition each
               (cd "$STUDY" && "$PY" -m sweep.reevaluate --experiment offpolicy-plasticity --where agent=td3 \
                  --name "$1" eval.condition=fixed "${@:2}")
             done
             table transfer.py transfer.md ;;
  report)  (cd "$STUDY" && "$PY" -m sweep.report --experiment offpolicy-plasticity --out "$PILOT")
           table fresh_networks.py fresh_networks.md ;;
  stop)    drivers=$(pgrep -f "offpolicy_plasticity/run.sh (pilot|transfer)" || true)
           sweeps=$(pgrep -f "sweep -m experiment=offpolicy_plasticity" || true)
           workers=$(for p in $sweeps; do pgrep -P "$p" || true; done)
           [ -n "$drivers$sweeps" ] || { echo "no phase is running"; exit 0; }
           kill $drivers 2>/dev/null || true; sleep 1
           kill $sweeps 2>/dev/null || true; sleep 2
           kill $workers 2>/dev/null || true
           echo "stopped: drivers" $drivers "| sweeps" $sweeps "| jobs" $workers ;;
  export)  (cd "$STUDY" && "$PY" -m sweep.archive export --experiment offpolicy-plasticity \
              --out "$ARCHIVE/offpolicy-plasticity") ;;
  import)  for dir in "$ARCHIVE"/*/; do (cd "$STUDY" && "$PY" -m sweep.archive import "$dir"); done ;;
  *) sed -n 2,14p "$0"; exit 2 ;;
esac
