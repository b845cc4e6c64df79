#!/usr/bin/env bash
# The transfer-gap table of docs/conditions.md (issue 33 §2), phase by phase. train resumes (resume=auto); reevaluate
# flies every cell again when re-run (the scores logged anew at the same step, the newest read).
#
#   docs/conditions/run.sh train        # PPO (JAX, 16 x 128, 5M steps, seeds 0-3; SEEDS=4,5,6,7 for more) under
#                                       # each condition alone
#   docs/conditions/run.sh reevaluate   # every run's kept policy flown under each condition of its family (the wind
#                                       # family and the still-air vehicles: reevaluate-wind, reevaluate-still)
#   docs/conditions/run.sh gust-scan    # the x3 runs' kept policies under 3 m/s +x with Dryden gusts of each sigma in
#                                       # GUST_SCAN (A on B without training: which sigma has a gap)
#   docs/conditions/run.sh train-gusts  # PPO under 3 m/s +x with gusts of sigma GUST (the fresh network, B on B)
#   docs/conditions/run.sh reevaluate-gusts  # the x3g<GUST> runs' kept policies under their gusts and without
#   docs/conditions/run.sh table        # docs/conditions/transfer_gap.md/.csv
#   docs/conditions/run.sh import       # the archived runs (docs/conditions/runs, re-evaluations included) -> the
#                                       # store, so that `table` re-makes the table without training
#   docs/conditions/run.sh export       # the store's FINISHED runs -> docs/conditions/runs
#
# Conditions (arms: the wind tag, +vehicle where not nominal): x3 (3 m/s +x), x1p5 (1.5 m/s +x), mx3 (3 m/s -x),
# y3 (3 m/s +y); none (still air), none+mass1p5 (x1.5 mass and inertia), none+motor0p7 (rotor 1 at 70% thrust);
# x3g<S> (3 m/s +x with Dryden gusts of sigma S, RotorPy's sig_wind: realised std 0.0326 S m/s per axis; the gust
# phases need COMMIT=ae4f713 or later: the first whose gusts start settled, in training and in every evaluation).
# The store, checkpoints and sweep dirs live in $STUDY; the code is the pinned commit's (a worktree there).
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
STUDY=${STUDY:-/work/studies/conditions}
COMMIT=${COMMIT:-HEAD}
PY=${PYTHON:-$ROOT/.venv/bin/python}
export MLFLOW_TRACKING_URI=sqlite:///$STUDY/mlflow.db
mkdir -p "$STUDY"
CODE=$STUDY/code-$(git -C "$ROOT" rev-parse --short "$COMMIT")
[ -d "$CODE" ] || git -C "$ROOT" worktree add --detach "$CODE" "$COMMIT"

sweep() {  # sweep NAME OVERRIDES...
  local name=$1; shift
  (cd "$STUDY" && PYTHONPATH=$CODE/src "$PY" -m sweep -m experiment=transfer train.checkpoint_dir="$STUDY/ckpt" \
     hydra.sweep.dir="$STUDY/multirun/$name" ${SEEDS:+"seed=$SEEDS"} "$@")
}
fly() {  # fly TRAINED_WHERE... -- NAME OVERRIDES...: the runs' kept policy (best_eval) under a condition (start seed 7)
  local where=() ; while [ "$1" != "--" ]; do where+=(--where "$1"); shift; done; shift
  local name=$1; shift
  (cd "$STUDY" && PYTHONPATH=$CODE/src "$PY" -m sweep.reevaluate --experiment transfer "${where[@]}" --name "$name" \
     --policy best_eval eval.condition=fixed eval.seed=7 eval.episodes=20 "$@")
}
WIND_ARMS=(x3 x1p5 mx3 y3)
declare -A WIND=([x3]="3.0 [1.0,0.0,0.0]" [x1p5]="1.5 [1.0,0.0,0.0]" [mx3]="3.0 [-1.0,0.0,0.0]" [y3]="3.0 [0.0,1.0,0.0]")
declare -A STILL=([nominal]="1.0 [1.0,1.0,1.0,1.0]" [mass1p5]="1.5 [1.0,1.0,1.0,1.0]" [motor0p7]="1.0 [0.7,1.0,1.0,1.0]")
GUST=${GUST:-60}                       # train-gusts, reevaluate-gusts: the sigma trained under
GUST_SCAN=${GUST_SCAN:-10 30 60 100}   # gust-scan: the sigmas the x3 policies fly under
GUST_TABLE=${GUST_TABLE:-60 100}       # table: a row per sigma trained under
still_name() { [ "$1" = nominal ] && echo on_none || echo "on_none_$1"; }

case ${1:-} in
  train)
    for arm in "${WIND_ARMS[@]}"; do
      read -r speed dir <<<"${WIND[$arm]}"
      sweep "$arm" wind=none wind.name="$arm" "wind.speeds=[$speed]" "wind.direction=$dir"
    done
    for vehicle in nominal mass1p5 motor0p7; do
      read -r mass eff <<<"${STILL[$vehicle]}"
      sweep "none-$vehicle" wind=none vehicle.name="$vehicle" "vehicle.segments=[{mass:$mass,rotor_efficiency:$eff}]"
    done ;;
  reevaluate) "$0" reevaluate-wind && "$0" reevaluate-still ;;
  reevaluate-wind)
    for trained in "${WIND_ARMS[@]}"; do
      for target in "${WIND_ARMS[@]}"; do
        read -r speed dir <<<"${WIND[$target]}"
        fly wind="$trained" -- "on_$target" eval.wind_speed="$speed" "eval.direction=$dir"
      done
    done ;;
  reevaluate-still)
    for trained in nominal mass1p5 motor0p7; do
      for target in nominal mass1p5 motor0p7; do
        read -r mass eff <<<"${STILL[$target]}"
        fly wind=none vehicle="$trained" -- "$(still_name "$target")" eval.wind_speed=0.0 eval.mass="$mass" \
            "eval.rotor_efficiency=$eff"
      done
    done ;;
  gust-scan)
    for sigma in $GUST_SCAN; do
      fly wind=x3 -- "on_x3g$sigma" eval.wind_speed=3.0 "eval.direction=[1.0,0.0,0.0]" eval.gust="$sigma"
    done ;;
  train-gusts) sweep "x3g$GUST" wind=none wind.name="x3g$GUST" "wind.speeds=[3.0]" "wind.gusts=[$GUST]" ;;
  reevaluate-gusts)   # the gust runs under gusts (B on B) and without (B on A); x3 under both: reevaluate-wind, gust-scan
    fly wind="x3g$GUST" -- "on_x3g$GUST" eval.wind_speed=3.0 "eval.direction=[1.0,0.0,0.0]" eval.gust="$GUST"
    fly wind="x3g$GUST" -- on_x3 eval.wind_speed=3.0 "eval.direction=[1.0,0.0,0.0]" ;;
  import) (cd "$STUDY" && PYTHONPATH=$CODE/src "$PY" -m sweep.archive import "$ROOT/docs/conditions/runs") ;;
  export) (cd "$STUDY" && PYTHONPATH=$CODE/src "$PY" -m sweep.archive export --experiment transfer --out "$ROOT/docs/conditions/runs") ;;
  table)
    gust_changes=(); for sigma in $GUST_TABLE; do gust_changes+=(--change "gusts sigma 0 -> $sigma at 3 m/s=x3:x3g$sigma"); done
    (cd "$STUDY" && PYTHONPATH=$CODE/src "$PY" -m sweep.report.transfer --experiment transfer --out "$ROOT/docs/conditions" \
       --change "paper speed 3 -> 1.5 m/s=x3:x1p5" --change "flip +x -> -x=x3:mx3" --change "rotate +x -> +y=x3:y3" \
       --change "payload x1.0 -> x1.5=none:none+mass1p5" --change "motor 1 at 100% -> 70%=none:none+motor0p7" \
       "${gust_changes[@]}") ;;
  *) echo "usage: $0 train|reevaluate|reevaluate-wind|reevaluate-still|gust-scan|train-gusts|reevaluate-gusts|table|import|export" >&2; exit 2 ;;
esac
