#!/usr/bin/env bash
# The plasticity study (issue 35; experiment=plasticity), phase by phase, resumable across sessions.
#
#   docs/plasticity_study/run.sh pilot-flip      # every agent, seeds 0-2, 3 segments of 4M (12M) under wind=flip
#   docs/plasticity_study/run.sh pilot-payload   # the same under vehicle=payload (still air)
#   docs/plasticity_study/run.sh pilot-report    # the pilot's per-segment tables and curves -> docs/plasticity_study/pilot
#   docs/plasticity_study/run.sh main-flip       # experiment=plasticity: 12 agents x seeds 0-7 x 18M (6 segments of 3M)
#   docs/plasticity_study/run.sh main-payload    # the same under vehicle=payload (still air)
#   docs/plasticity_study/run.sh extra-flip      # seeds 8-15 of PPO, reset_all and the pilot's top 3 (AGENTS_EXTRA)
#   docs/plasticity_study/run.sh extra-payload   # the same under vehicle=payload
#   docs/plasticity_study/run.sh combo-flip      # seeds 0-7 of the combination added after the pilot (COMBO)
#   docs/plasticity_study/run.sh combo-payload   # the same under vehicle=payload
#   docs/plasticity_study/run.sh main            # the six phases, the flip change's three first (what a session resumes)
#   docs/plasticity_study/run.sh twins-flip      # issue 56: the fresh twins of the headline agents (TWINNED), seeds 0-15,
#   docs/plasticity_study/run.sh twins-payload   #   at their continual runs' code; twins.md pairs each with its continual run
#   docs/plasticity_study/run.sh more-flip       # seeds 8-15 of the continual agents that have 8 (relative RECOM at
#   docs/plasticity_study/run.sh more-payload    #   MAIN_COMMIT, the combination at COMBO_COMMIT), so every pair has 16
#   docs/plasticity_study/run.sh stop            # pause: stop the running phase and its jobs (they resume from their checkpoints)
#   docs/plasticity_study/run.sh report          # the main phases' tables, figures, decline.md, weight_norm.md -> docs/plasticity_study/main
#   docs/plasticity_study/run.sh report flip     # the same for one change's phases only -> docs/plasticity_study/flip
#   docs/plasticity_study/run.sh export          # FINISHED runs -> docs/plasticity_study/runs (commit them)
#   docs/plasticity_study/run.sh import          # the archive -> the store (re-make every table without training)
#
# Every phase is an ordinary Hydra multirun with resume=auto: a job whose run is FINISHED in the store is skipped, an
# interrupted one continues from its checkpoint. Store, checkpoints and sweep dirs live in $STUDY; each phase runs the
# code of a pinned commit from a worktree there (a job's key hashes its config, so the same commit and store find the
# same jobs). PILOT_COMMIT: the code of the pilot (experiment=plasticity as committed). The pilot flies 4M segments, the
# longest the issue allows, so that reset_all's fresh networks show whether they hover by 2M, 3M or 4M into a segment
# (a 3M pilot could not tell whether 4M is needed). It measured 3M to be enough (docs/plasticity_study.md: 17 of
# the 18 fresh networks that hovered within 4M did so by 3M), so the main phases run the preset as committed,
# 6 segments of 3M, at MAIN_COMMIT: the pilot's training code plus the fused torch Adam (README, Determinism),
# which should make the probe's readings portable across CPU vendors and leaves the JAX learner's training as it was.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
STUDY=${STUDY:-/work/studies/plasticity}
PILOT_COMMIT=9ff7f41
MAIN_COMMIT=01b8be3
CONTROLS=l2_lr_decay,l2_lr_decay_8m,recom_l2_relative   # the remedies study's winners: relearning.md's --vs columns
# the main report also puts every agent against layer_norm, added 12-05 after the flip change was read (it led there):
# does any agent, the combination included, re-learn as well?
VERSUS=$CONTROLS,layer_norm
# COMBO_COMMIT: MAIN_COMMIT's JAX training code plus conf/agent/layer_norm_l2_lr_decay_8m.yaml, the combination of the
# pilot's top two (LayerNorm, L2 + LR decay by 8M), added after the pilot and run after the other phases
COMBO_COMMIT=be84f2b
COMBO=layer_norm_l2_lr_decay_8m
# seeds 8-15: PPO, reset_all and the three agents the pilot ranked highest (docs/plasticity_study.md, The pilot)
AGENTS_EXTRA=${AGENTS_EXTRA:-ppo,reset_all,layer_norm,l2_lr_decay_8m,l2_lr_decay}
# issue 56: each headline agent against its own fresh twin, paired by seed with its archived continual run. A twin
# must fly segment 0 as that run did, bit for bit, so it runs the continual run's code (MAIN_COMMIT, COMBO_COMMIT for
# the combination), not today's: measured 12-07, today's code (7e63a95) flies the first rollout of layer_norm under
# the flip, seed 0, to a mean return of -934.6388080162661, MAIN_COMMIT (and the archive) to -934.6388079822063, and
# the runs part from there. Those commits predate twin=fresh, so the twin is composed as twin=fresh composes it: the
# reset_all remedy switched on (every agent carries it there, off), named <agent>_fresh, labelled "<label> (fresh)".
# twins.md's "Segment 0 the same run" column checks the pairing on every pair.
TWINNED=${TWINNED:-layer_norm,layer_norm_l2_lr_decay_8m,l2_lr_decay,l2_lr_decay_8m,recom_l2_relative}  # TWINNED=a,b: those only
SEEDS16=0,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15
PY=${PYTHON:-$ROOT/.venv/bin/python}
ARCHIVE=$ROOT/docs/plasticity_study/runs
export MLFLOW_TRACKING_URI=sqlite:///$STUDY/mlflow.db
mkdir -p "$STUDY"

warm() {  # warm CODE OVERRIDES...: one short LayerNorm run of that code, under the phase's change (its wind= and
          # vehicle= overrides), in a throwaway store, so that numba caches the compiled rollout before any job
          # starts. At the study's commits a process that compiles the rollout itself (a job that finds no cache, and
          # the later jobs of its joblib worker) flies LayerNorm networks with other last bits than one that loads it
          # from numba's cache (README, Determinism); warmed, every job loads it.
  local code=$1 tmp change=() arg; shift
  for arg in "$@"; do case $arg in wind=*|vehicle=*) change+=("$arg") ;; esac; done
  tmp=$(mktemp -d)
  (cd "$tmp" && MLFLOW_TRACKING_URI=sqlite:///$tmp/mlflow.db PYTHONPATH=$code/src "$PY" -m sweep experiment=plasticity \
     agent=layer_norm "${change[@]}" train.total_timesteps=4096 wind.segment_steps=2048 eval.every_timesteps=2048 \
     eval.episodes=2 train.checkpoint_dir="$tmp/ckpt" hydra.run.dir="$tmp/run" > "$tmp/log" 2>&1) \
    || { tail -5 "$tmp/log"; echo "run.sh: warming numba's cache failed; its log: $tmp/log"; exit 1; }
  rm -rf "$tmp"
}

sweep() {  # sweep COMMIT NAME OVERRIDES...: that commit's code, the study's store and checkpoints; output under $STUDY
  local commit=$1 code=$STUDY/code-$1 name=$2; shift 2
  [ -d "$code" ] || git -C "$ROOT" worktree add --detach "$code" "$commit"
  [ -n "${WARMED:-}" ] || warm "$code" "$@"
  (cd "$STUDY" && PYTHONPATH=$code/src "$PY" -m sweep -m experiment=plasticity train.checkpoint_dir="$STUDY/ckpt" \
     hydra.sweep.dir="$STUDY/multirun/$name" "$@")
}
twins() {  # twins CHANGE CHANGE_OVERRIDES...: each TWINNED agent's fresh twin, seeds 0-15 (SEEDS), at its continual code,
           # 2 seeds at a time, the FINISHED runs exported after each pair (a session's machine may not come back)
  local change=$1 agent commit label seeds list todo seed; shift
  for agent in ${TWINNED//,/ }; do
    commit=$MAIN_COMMIT; [ "$agent" != "$COMBO" ] || commit=$COMBO_COMMIT
    label=$(git -C "$ROOT" show "$commit:conf/agent/$agent.yaml" | sed -n 's/^label: //p')
    list=${SEEDS:-$SEEDS16}
    todo=$(for seed in ${list//,/ }; do   # the seeds whose twin the archive lacks: no import needed
             compgen -G "$ARCHIVE/plasticity/${agent}_fresh-*$change-s$seed-*.npz" > /dev/null || echo -n "$seed,"
           done)
    for seeds in $(echo "${todo%,}" | sed -E 's/([^,]+,[^,]+),/\1 /g'); do
      sweep "$commit" "twins-$agent-$change" "$@" "seed=$seeds" "agent=$agent" \
        agent.reset_all.enabled=true "agent.name=${agent}_fresh" "agent.label='$label (fresh)'"
      WARMED=1; "$0" export
    done
    WARMED=
  done
}
PILOT=(wind.segment_steps=4000000 train.total_timesteps=12000000 seed=0,1,2 tracking.experiment=plasticity-pilot)

case ${1:-} in
  pilot-flip)    sweep $PILOT_COMMIT pilot-flip wind=flip "${PILOT[@]}" ;;
  pilot-payload) sweep $PILOT_COMMIT pilot-payload wind=none vehicle=payload "${PILOT[@]}" ;;
  main-flip)     sweep $MAIN_COMMIT main-flip wind=flip ${SEEDS:+"seed=$SEEDS"} ;;
  main-payload)  sweep $MAIN_COMMIT main-payload wind=none vehicle=payload ${SEEDS:+"seed=$SEEDS"} ;;
  extra-flip)    sweep $MAIN_COMMIT extra-flip wind=flip "seed=${SEEDS:-8,9,10,11,12,13,14,15}" "agent=$AGENTS_EXTRA" ;;
  extra-payload) sweep $MAIN_COMMIT extra-payload wind=none vehicle=payload "seed=${SEEDS:-8,9,10,11,12,13,14,15}" \
                   "agent=$AGENTS_EXTRA" ;;
  combo-flip)    sweep $COMBO_COMMIT combo-flip wind=flip "seed=${SEEDS:-0,1,2,3,4,5,6,7}" "agent=$COMBO" ;;
  combo-payload) sweep $COMBO_COMMIT combo-payload wind=none vehicle=payload "seed=${SEEDS:-0,1,2,3,4,5,6,7}" \
                   "agent=$COMBO" ;;
  twins-flip)    twins flip wind=flip ;;
  twins-payload) twins payload wind=none vehicle=payload ;;
  more-flip)     sweep $MAIN_COMMIT more-flip wind=flip "seed=${SEEDS:-8,9,10,11,12,13,14,15}" agent=recom_l2_relative
                 sweep $COMBO_COMMIT more-combo-flip wind=flip "seed=${SEEDS:-8,9,10,11,12,13,14,15}" "agent=$COMBO" ;;
  more-payload)  sweep $MAIN_COMMIT more-payload wind=none vehicle=payload "seed=${SEEDS:-8,9,10,11,12,13,14,15}" \
                   agent=recom_l2_relative
                 sweep $COMBO_COMMIT more-combo-payload wind=none vehicle=payload "seed=${SEEDS:-8,9,10,11,12,13,14,15}" \
                   "agent=$COMBO" ;;
  main)          for phase in main-flip extra-flip combo-flip main-payload extra-payload combo-payload; do  # one change complete first
                   SEEDS= "$0" "$phase"   # each phase its own seeds (SEEDS=... is for one phase)
                 done ;;
  stop)          drivers=$(pgrep -f "plasticity_study/run.sh (main|pilot-|extra-|combo-|twins-|more-)" || true)
                 sweeps=$(pgrep -f "sweep -m experiment=plasticity" || true)
                 workers=$(for p in $sweeps; do pgrep -P "$p" || true; done)   # the jobs: joblib's worker processes
                 [ -n "$drivers$sweeps" ] || { echo "no phase is running"; exit 0; }
                 kill $drivers 2>/dev/null || true; sleep 1   # first the driver, so that no next phase starts
                 kill $sweeps 2>/dev/null || true; sleep 2
                 kill $workers 2>/dev/null || true
                 echo "stopped: drivers" $drivers "| sweeps" $sweeps "| jobs" $workers ;;
  report)        change=${2:-}   # report flip|payload: that change's phases only (their sweep dirs end in -flip, -payload)
                 out=$ROOT/docs/plasticity_study/${change:-main}
                 (cd "$STUDY" && "$PY" -m sweep.report --experiment plasticity ${change:+"--sweep=-$change"} \
                    --highlight reset_all --vs "$VERSUS" --out "$out")
                 "$PY" "$ROOT/docs/plasticity_study/decline.py" "$out" > "$out/decline.md"   # the early-vs-late test
                 "$PY" "$ROOT/docs/plasticity_study/weight_norm.py" "$out" > "$out/weight_norm.md"   # fixed 12-05
                 "$PY" "$ROOT/docs/plasticity_study/hovered.py" "$out" > "$out/hovered.md" ;;   # seeds hovering per segment
  pilot-report)  (cd "$STUDY" && "$PY" -m sweep.report --experiment plasticity-pilot --highlight reset_all \
                    --vs "$CONTROLS" --out "$ROOT/docs/plasticity_study/pilot") ;;
  export)        for exp in plasticity-pilot plasticity; do
                   (cd "$STUDY" && "$PY" -m sweep.archive export --experiment "$exp" --out "$ARCHIVE/$exp") || true
                 done ;;
  import)        for dir in "$ARCHIVE"/*/; do (cd "$STUDY" && "$PY" -m sweep.archive import "$dir"); done ;;
  *) sed -n 2,22p "$0"; exit 2 ;;
esac
