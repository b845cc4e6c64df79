#!/usr/bin/env bash
# The plasticity question off-policy (issue 56, item 4; experiment=offpolicy_plasticity; docs/offpolicy_plasticity.md):
# TD3 (JAX) on the anchor's task, under a wind flip or a payload, against its fresh twin (twin=fresh).
#
#   docs/offpolicy_plasticity/run.sh pilot         # seeds 100,101 x flip, payload x TD3, its fresh twin; 4 x 500k (8 runs)
#   docs/offpolicy_plasticity/run.sh pilot-agents  # seeds 100,101 x flip, payload x td3_reset, td3_layer_norm (8 runs)
#   docs/offpolicy_plasticity/run.sh transfer      # the continual pilot runs' final policies flown under other conditions
#   docs/offpolicy_plasticity/run.sh report        # the report, fresh networks' learning times -> .../pilot
#   docs/offpolicy_plasticity/run.sh study         # seeds 0-15 x flip, payload x AGENTS x {continual, twin} (192 runs),
#                                                  #   2 seeds at a time, each sweep exported when it ends
#   docs/offpolicy_plasticity/run.sh study-report  # the study's report -> .../study
#   docs/offpolicy_plasticity/run.sh stop          # stop a running phase (a re-run resumes: FINISHED jobs are skipped)
#   docs/offpolicy_plasticity/run.sh export        # FINISHED runs -> docs/offpolicy_plasticity/runs (commit them)
#   docs/offpolicy_plasticity/run.sh import        # the archive -> the store (re-make every table without training)
#
# Every training phase is a Hydra multirun with resume=auto. Store, checkpoints and sweep dirs live in $STUDY; each
# training phase runs the code of a pinned commit from a worktree there (transfer, report, export and import run this
# checkout's). Seeds 100 and 101 are the pilot's (every choice); seeds 0-15 are kept for the study.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
STUDY=${STUDY:-/work/studies/offpolicy}
PILOT_COMMIT=22e3f4a   # the pilot's continual runs (12-07); its twins ran there first, and their last change reset them
STUDY_COMMIT=${STUDY_COMMIT:-261429e}   # 6a13cd5's fix of that, and agents td3_reset, td3_layer_norm: the twins, the study
AGENTS=td3,td3_reset,td3_layer_norm     # the issue's: the anchor's TD3, with the primacy-bias reset, with LayerNorm
PY=${PYTHON:-$ROOT/.venv/bin/python}
ARCHIVE=$ROOT/docs/offpolicy_plasticity/runs
PILOT=$ROOT/docs/offpolicy_plasticity/pilot
export MLFLOW_TRACKING_URI=sqlite:///$STUDY/mlflow.db
mkdir -p "$STUDY"

sweep() {  # sweep COMMIT NAME OVERRIDES...: that commit's code, the study's store and checkpoints; output under $STUDY
  local commit name=$2
  commit=$(git -C "$ROOT" rev-parse --short "$1"); shift 2
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
             sweep $PILOT_COMMIT "pilot-$1" "${@:2}" seed=100,101                 # the continual agent
             sweep $STUDY_COMMIT "pilot-$1-fresh" "${@:2}" seed=100,101 twin=fresh  # its fresh twin
           done ;;
  pilot-agents)  set -f
           for change in "flip wind=flip" "payload wind=none vehicle=payload"; do
             set -- $change
             sweep $STUDY_COMMIT "pilot-agents-$1" "${@:2}" seed=100,101 agent=td3_reset,td3_layer_norm
           done ;;
  study)   set -f   # 2 seeds at a time, both changes, every agent and its twin; exported as each sweep (~40 min) ends
           for seeds in 0,1 2,3 4,5 6,7 8,9 10,11 12,13 14,15; do
             for change in "flip wind=flip" "payload wind=none vehicle=payload"; do
               set -- $change
               sweep $STUDY_COMMIT "study-$1" "${@:2}" "seed=$seeds" "agent=$AGENTS"
               "$0" export
               sweep $STUDY_COMMIT "study-$1-fresh" "${@:2}" "seed=$seeds" "agent=$AGENTS" twin=fresh
               "$0" export
             done
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
  report)  (cd "$STUDY" && "$PY" -m sweep.report --experiment offpolicy-plasticity --sweep multirun/pilot- --out "$PILOT")
           table fresh_networks.py fresh_networks.md ;;
  study-report)  mkdir -p "$ROOT/docs/offpolicy_plasticity/study"
           (cd "$STUDY" && "$PY" -m sweep.report --experiment offpolicy-plasticity \
              --sweep multirun/study- --out "$ROOT/docs/offpolicy_plasticity/study") ;;
  stop)    drivers=$(pgrep -f "offpolicy_plasticity/run.sh (pilot|transfer|study)" || true)
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
  *) sed -n 2,18p "$0"; exit 2 ;;
esac
