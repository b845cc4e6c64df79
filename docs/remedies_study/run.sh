#!/usr/bin/env bash
# The remedies study (docs/remedies_study.md, issue 19), phase by phase, resumable on a new machine.
#
#   docs/remedies_study/run.sh import        # the finished runs carried in docs/remedies_study/runs -> the store
#   docs/remedies_study/run.sh equivalence   # SB3 vs JAX: PPO, 16 x 128, 20 seeds each, 500k steps
#   docs/remedies_study/run.sh pilot         # every agent, 3 seeds, 6M steps
#   docs/remedies_study/run.sh main          # experiment=remedies: the 11 planned agents x 8 seeds x 20M, wind paper
#   docs/remedies_study/run.sh control       # the control added after main's first seeds: l2_lr_decay_8m, 8 seeds
#   docs/remedies_study/run.sh none          # PPO and the 3 best agents, wind none (AGENTS_NONE)
#   docs/remedies_study/run.sh fast          # PPO and the 4 best agents, 16 envs x 128 steps (AGENTS_FAST)
#   docs/remedies_study/run.sh recheck       # issue 32: the six headline agents on 8 new seeds (8-15), portable mode
#   docs/remedies_study/run.sh export        # new FINISHED runs -> docs/remedies_study/runs (commit them; the wind-none
#                                            # runs with their models, for still-air)
#   docs/remedies_study/run.sh still-air     # the wind-none runs' stored policies flown in still air (sweep.reevaluate)
#   docs/remedies_study/run.sh report        # every table and figure of docs/remedies_study.md (AGENTS_TOP=ppo,a,b,c:
#                                            # also the curves of those agents alone, in remedies_study/top)
#
# Every phase is an ordinary Hydra multirun with resume=auto (the default): a job whose run is FINISHED in the
# store (trained here, or imported) is skipped, an interrupted one continues from its checkpoint. The store,
# checkpoints and sweep dirs live outside the work tree in $STUDY; each phase runs the code of one pinned commit
# from a worktree there ($STUDY/code-<commit>), because a job's key hashes its config: the same commit and the
# same $STUDY find the same jobs, and so do the runs imported from the archive. The equivalence and the pilot ran
# at PILOT_COMMIT (diagnostics every rollout); main, none and fast at MAIN_COMMIT, whose experiment=remedies
# computes the diagnostics every 10 rollouts (the run itself unchanged: tests/test_plasticity.py); the control
# l2_lr_decay_8m at CONTROL_COMMIT, the first with its key (agent.ppo.lr_decay_timesteps; otherwise MAIN_COMMIT's
# training code, the other agents' LR schedules bitwise unchanged).
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
STUDY=${STUDY:-/work/studies/remedies}
PILOT_COMMIT=fce62f7
MAIN_COMMIT=88620f6
CONTROL_COMMIT=4160b3b
RECHECK_COMMIT=750890e   # the first commit with train.portable (default true)
AGENTS_RECHECK=ppo,recom_l2_relative,l2_lr_decay,l2_lr_decay_8m,ppo_target_kl,layer_norm
PY=${PYTHON:-$ROOT/.venv/bin/python}
ARCHIVE=$ROOT/docs/remedies_study/runs
AGENTS_NONE=${AGENTS_NONE:-}   # set from the main phase's leaderboard, e.g. ppo,a,b,c
AGENTS_FAST=${AGENTS_FAST:-}   # e.g. ppo,a,b,c,d
AGENTS_TOP=${AGENTS_TOP:-}     # report: the agents whose curves are drawn against PPO's, e.g. ppo,a,b,c
SEEDS=${SEEDS:-}               # none/fast: only these seeds now, e.g. 0,1,2 (unset: the preset's seeds 0-7)
export MLFLOW_TRACKING_URI=sqlite:///$STUDY/mlflow.db

mkdir -p "$STUDY"

sweep() {  # sweep COMMIT NAME OVERRIDES...: that commit's code, the study's store and checkpoints; output under $STUDY
  local code=$STUDY/code-$1 name=$2; shift 2
  [ -d "$code" ] || git -C "$ROOT" worktree add --detach "$code" "${code##*/code-}"
  (cd "$STUDY" && PYTHONPATH=$code/src "$PY" -m sweep -m train.checkpoint_dir="$STUDY/ckpt" \
     hydra.sweep.dir="$STUDY/multirun/$name" "$@")
}
need() { [ -n "$2" ] || { echo "run.sh: set $1 (comma-separated agents, PPO first) from the main leaderboard" >&2; exit 2; }; }

case ${1:-} in
  import)      (cd "$STUDY" && "$PY" -m sweep.archive import "$ARCHIVE") ;;
  equivalence) sweep $PILOT_COMMIT equivalence experiment=equivalence train.total_timesteps=500000 "seed=$(seq -s, 0 19)" \
                 eval.every_timesteps=0 tracking.experiment=equivalence-20 ;;
  pilot)       sweep $PILOT_COMMIT pilot experiment=remedies train.total_timesteps=6000000 seed=0,1,2 tracking.experiment=remedies-pilot ;;
  main)        sweep $MAIN_COMMIT main experiment=remedies ;;
  control)     sweep $CONTROL_COMMIT control experiment=remedies agent=l2_lr_decay_8m ;;
  recheck)     sweep $RECHECK_COMMIT recheck experiment=remedies "seed=${SEEDS:-8,9,10,11,12,13,14,15}" "agent=$AGENTS_RECHECK" ;;
  none)        need AGENTS_NONE "$AGENTS_NONE"; sweep $MAIN_COMMIT none experiment=remedies wind=none "agent=$AGENTS_NONE" ${SEEDS:+"seed=$SEEDS"} ;;
  fast)        need AGENTS_FAST "$AGENTS_FAST"
               sweep $MAIN_COMMIT fast experiment=remedies env.n_envs=16 agent.ppo.n_steps=128 "agent=$AGENTS_FAST" ${SEEDS:+"seed=$SEEDS"} ;;
  export)      (cd "$STUDY" && "$PY" -m sweep.archive export --experiment remedies --where wind=none \
                  --artifacts 'config.yaml,eval_trajectories.npz,model*.zip' --out "$ARCHIVE/remedies")
               for exp in equivalence-20 remedies-pilot remedies; do
                 (cd "$STUDY" && "$PY" -m sweep.archive export --experiment "$exp" --out "$ARCHIVE/$exp") || true
               done ;;
  report)      out=$ROOT/docs/remedies_study
               (cd "$STUDY" && "$PY" -m sweep.report --experiment equivalence-20 --out "$out/equivalence" \
                  --by agent.learner --baseline agent.learner=sb3 --at 100000,250000,500000)
               (cd "$STUDY" && "$PY" -m sweep.report --experiment remedies-pilot --out "$out/pilot")
               (cd "$STUDY" && "$PY" -m sweep.report --experiment remedies --out "$out/main" --by env.n_envs \
                  --baseline agent=ppo --vs ppo,l2_lr_decay,l2_lr_decay_8m,ppo_target_kl)
               if [ -n "$AGENTS_TOP" ]; then  # curves of the top agents against PPO
                 (cd "$STUDY" && "$PY" -m sweep.report --experiment remedies --out "$out/top" --by env.n_envs \
                    --baseline agent=ppo --agents "$AGENTS_TOP")
               fi ;;
  still-air)   (cd "$STUDY" && "$PY" -m sweep.reevaluate --experiment remedies --where wind=none --name still_air --vs ppo \
                  --out "$ROOT/docs/remedies_study/none/still_air.md" eval.wind_speed=0) ;;
  *) sed -n 2,15p "$0"; exit 2 ;;
esac
