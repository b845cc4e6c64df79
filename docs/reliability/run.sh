#!/usr/bin/env bash
# The reliability study (issue 55; experiment=reliability; docs/reliability.md), row by row, resumable across sessions.
#
#   docs/reliability/run.sh ppo-13d        # PPO, 16 x 128 (JAX), the paper's 13-D observation and start
#   docs/reliability/run.sh ppo-obs        # the same + rotor speeds + the last 8 actions
#   docs/reliability/run.sh ppo-paper      # PPO on the paper's layout, 1 x 2048 (JAX)
#   docs/reliability/run.sh ppo-curriculum # PPO 16 x 128, 13-D, the start box widening from 0.2 m to 2 m over 500k
#   docs/reliability/run.sh td3-anchor     # TD3 (JAX) as the anchor trains it: replay ratio 0.1, rotor speeds and the last
#                                          # 32 actions, an alive bonus of 2 per step, the start-box curriculum
#   docs/reliability/run.sh sac-anchor     # SAC (JAX) with td3-anchor's settings (replay ratio, inputs, bonus, curriculum)
#   docs/reliability/run.sh hover-heldout  # experiment=hover itself on seeds 16-31 (experiment reliability-heldout): the
#                                          # preset, chosen on seeds 0-15, confirmed on seeds that chose nothing
#   docs/reliability/run.sh paper-heldout  # ppo-paper on seeds 16-31 beside it (its 3M tie with the preset, on new seeds)
#   docs/reliability/run.sh rows           # the rows above in that order (what a session resumes)
#   docs/reliability/run.sh stop           # pause: stop the running row and its jobs (they resume from their checkpoints)
#   docs/reliability/run.sh report         # the table and figure -> docs/reliability/main (held-out: .../heldout)
#   docs/reliability/run.sh pilot-report   # the pilot's tables (seeds 100-103, 1M) -> docs/reliability/pilot
#   docs/reliability/run.sh export         # FINISHED runs -> docs/reliability/runs (commit them; the pilot was exported from its own store)
#   docs/reliability/run.sh import         # the archive -> the store (re-make every table without training)
#
# PPO rows run 3M steps, the off-policy rows 1M (experiment=reliability's budget: the pilot's off-policy runs flew ~5k
# steps/s against PPO's ~20k). WIND=3 runs a row under a constant 3 m/s instead of still air (wind=paper
# wind.speeds=[3.0]); SEEDS=0,1 other seeds; BUDGET=N another budget (another job: its key has the budget). Store, checkpoints and sweep dirs live in $STUDY;
# each row runs the code of MAIN_COMMIT from a worktree there. The pilot (experiments reliability-pilot, -pilot2) ran
# from a worktree at PILOT_COMMITS, seeds 100-103, 1M steps; nothing the rows run was chosen on seeds 0-15.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
STUDY=${STUDY:-/work/studies/reliability}
MAIN_COMMIT=${MAIN_COMMIT:-4bce2ee}   # 8d10031 ran the PPO rows; 4bce2ee writes a replay checkpoint at its size
PILOT_COMMITS="3bb5d0a (reliability-pilot) d764b27 (reliability-pilot2)"
PY=${PYTHON:-$ROOT/.venv/bin/python}
ARCHIVE=$ROOT/docs/reliability/runs
# every env setting a row may change (a cell keeps one run per agent, learner, wind, seed and these values)
BY=env.n_envs,env.observe.rotor_speeds,env.observe.action_history,env.observe.critic_rotor_speeds,env.observe.critic_condition,env.start.tilt_deg,env.curriculum.start_bound_from,env.reward.alive_bonus
PILOT_BY=(env.n_envs,env.observe.rotor_speeds,env.observe.action_history,env.reward.alive_bonus  # pilot 1's code had no critic_*
          env.n_envs,env.observe.rotor_speeds,env.observe.action_history,env.observe.critic_rotor_speeds,env.curriculum.start_bound_from,env.reward.alive_bonus)
export MLFLOW_TRACKING_URI=sqlite:///$STUDY/mlflow.db
mkdir -p "$STUDY"

sweep() {  # sweep NAME OVERRIDES...: MAIN_COMMIT's code, the study's store and checkpoints; output under $STUDY
  local commit code status=0 name=$1; shift
  commit=$(git -C "$ROOT" rev-parse --short "$MAIN_COMMIT")
  code=$STUDY/code-$commit
  [ -d "$code" ] || git -C "$ROOT" worktree add --detach "$code" "$commit"
  local wind=()
  [ -z "${WIND:-}" ] || wind=(wind=paper "wind.speeds=[${WIND}.0]" wind.segment_steps=100000000)
  (cd "$STUDY" && PYTHONPATH=$code/src "$PY" -m sweep -m "experiment=${PRESET:-reliability}" train.checkpoint_dir="$STUDY/ckpt" \
     hydra.sweep.dir="$STUDY/multirun/$name${WIND:+-wind$WIND}" "seed=${SEEDS:-0,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15}" \
     "${wind[@]}" "$@" ${BUDGET:+"train.total_timesteps=$BUDGET"}) || status=$?
  prune
  return $status
}
prune() {  # a FINISHED job is skipped on resume, so its last checkpoint is dead weight: an off-policy run's is its replay
           # buffer (1.2 GB at 1M steps of the 145-column observation; 16 of them filled this disk on 12-07)
  local job
  for job in "$STUDY"/ckpt/*/; do
    if grep -q '"status": "FINISHED"' "$job/job.json" 2>/dev/null; then rm -f "$job/checkpoint.pt"; fi
  done
}
ppo() {  # ppo NAME OVERRIDES...: a PPO row, 3M steps (the last of the table's budgets) unless BUDGET says otherwise
  sweep "$@" train.total_timesteps=3000000
}
PPO16=(agent=ppo agent.learner=jax env.n_envs=16 agent.ppo.n_steps=128)
CURRICULUM=(env.curriculum.start_bound_from=0.2 env.curriculum.steps=500000)
TD3=(agent=td3 agent.learner=jax agent.td3.learning_starts=15000 agent.td3.train_freq=10 agent.td3.gradient_steps=1
     env.reward.alive_bonus=2.0)
SAC=(agent=sac agent.learner=jax agent.sac.learning_starts=15000 agent.sac.train_freq=10 agent.sac.gradient_steps=1
     env.reward.alive_bonus=2.0)
ANCHOR_INPUTS=(env.observe.rotor_speeds=true env.observe.action_history=32)

main() {  # the whole script is parsed before it runs (the last line), so editing it under a running row is safe
case ${1:-} in
  ppo-13d)        ppo ppo-13d "${PPO16[@]}" ;;
  ppo-obs)        ppo ppo-obs "${PPO16[@]}" env.observe.rotor_speeds=true env.observe.action_history=8 ;;
  ppo-paper)      ppo ppo-paper agent=ppo agent.learner=jax ;;
  ppo-curriculum) ppo ppo-curriculum "${PPO16[@]}" "${CURRICULUM[@]}" ;;
  td3-anchor)     sweep td3-anchor "${TD3[@]}" "${CURRICULUM[@]}" "${ANCHOR_INPUTS[@]}" ;;
  sac-anchor)     sweep sac-anchor "${SAC[@]}" "${CURRICULUM[@]}" "${ANCHOR_INPUTS[@]}" ;;
  hover-heldout)  PRESET=hover SEEDS=${SEEDS:-16,17,18,19,20,21,22,23,24,25,26,27,28,29,30,31} \
                    sweep hover-heldout tracking.experiment=reliability-heldout ;;
  paper-heldout)  SEEDS=${SEEDS:-16,17,18,19,20,21,22,23,24,25,26,27,28,29,30,31} \
                    ppo paper-heldout agent=ppo agent.learner=jax tracking.experiment=reliability-heldout ;;
  rows)           for row in ppo-13d ppo-obs td3-anchor ppo-curriculum ppo-paper sac-anchor hover-heldout paper-heldout; do
                    "$0" "$row"; done ;;
  stop)           drivers=$(pgrep -f "reliability/run.sh" | grep -v $$ || true)
                  sweeps=$(pgrep -f "hydra.sweep.dir=$STUDY/multirun/" || true)
                  workers=$(for p in $sweeps; do pgrep -P "$p" || true; done)
                  kill $drivers $sweeps 2>/dev/null || true; sleep 2
                  kill $workers 2>/dev/null || true
                  echo "stopped: drivers" $drivers "| sweeps" $sweeps "| jobs" $workers ;;
  report)         (cd "$STUDY" && "$PY" -m sweep.report.reliability --experiment reliability --by "$BY" \
                     --out "$ROOT/docs/reliability/main")
                  (cd "$STUDY" && "$PY" -m sweep.report.reliability --experiment reliability-heldout --by env.n_envs \
                     --out "$ROOT/docs/reliability/heldout") || echo "(no held-out runs yet: run.sh hover-heldout)" ;;
  pilot-report)   exps=(reliability-pilot reliability-pilot2)
                  for i in 0 1; do
                    (cd "$STUDY" && "$PY" -m sweep.report.reliability --experiment "${exps[$i]}" \
                       --by "${PILOT_BY[$i]}" --out "$ROOT/docs/reliability/pilot/${exps[$i]}")
                  done ;;
  export)         for exp in reliability-pilot reliability-pilot2 reliability reliability-heldout; do
                    (cd "$STUDY" && "$PY" -m sweep.archive export --experiment "$exp" --out "$ARCHIVE/$exp") || true
                  done ;;
  import)         for dir in "$ARCHIVE"/*/; do (cd "$STUDY" && "$PY" -m sweep.archive import "$dir"); done ;;
  *) sed -n 2,24p "$0"; exit 2 ;;
esac
}
main "$@"; exit $?
