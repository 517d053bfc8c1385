#!/usr/bin/env bash
# The exact commands that produced results/reference/safe/ (report.md there gives the revision, date and wall clock).
#
#   results/reference/safe/run.sh          # into results/sweeps/reference/safe/, two runs at a time on 2 CPU cores
#
# Safe RL on the Sidewalk, 3 seeds each: the unconstrained learner (grid DQN vs Dijkstra, continuous TRPO vs PRM), the
# same learner shielded (shield=true) and PPO-Lagrangian (algo=ppo_lagrangian at its default cost limit), at noise 0.
# Budgets: DQN at its default 200 iterations (102,400 frames); TRPO at 200 iterations (409,600 frames: it succeeds
# from iteration 50 in the Fig. 6 reference runs); PPO-Lagrangian at the frames of the learner it is compared with:
# 50 iterations in the grid (102,400 frames, minibatches of 512 images: 64 made an iteration of the conv nets ~30 s
# here), 200 in the continuous world.
#
# To keep every run on one code revision while the checkout moves on, run it from a worktree of that revision:
#   git worktree add ../ref <commit> && REFERENCE_DIR=$PWD/results/sweeps/reference/safe PYTHONPATH=../ref \
#     ../ref/results/reference/safe/run.sh
set -uo pipefail
cd "$(dirname "$0")/../../.."

root="${REFERENCE_DIR:-results/sweeps/reference/safe}"
launcher=(hydra/launcher=joblib hydra.launcher.n_jobs=2)
only="${ONLY:-}"  # ONLY=name runs one sweep of the list below
failed=()

# Each domain's sweeps share one folder, so that the report draws the unconstrained, shielded and constrained learners
# of a domain in one family (one cost figure, one table); their run folders' names (the overrides) differ.
sweep() {  # sweep NAME FOLDER OVERRIDES...: one multirun into $root/FOLDER, timed
  local name="$1" folder="$2" start
  shift 2
  [[ -n "$only" && "$only" != "$name" ]] && return
  start=$(date +%s)
  echo "== $name: python runners/main.py -m $* ($(date -Is))" >&2
  if ! python runners/main.py -m "$@" logger=none "hydra.sweep.dir=$root/$folder" "${launcher[@]}"; then
    failed+=("$name")
  fi
  echo "== $name: $(( $(date +%s) - start )) s" >&2
}

sweep discrete_dqn discrete +experiment=safe_discrete algo=dqn shield=false,true seed=0,1,2
sweep continuous_trpo continuous +experiment=safe_continuous algo=trpo iterations=200 shield=false,true seed=0,1,2
sweep discrete_ppo_lagrangian discrete +experiment=safe_discrete algo=ppo_lagrangian shield=false seed=0,1,2 \
  iterations=50 eval_every=10 algo.minibatch_size=512
sweep continuous_ppo_lagrangian continuous +experiment=safe_continuous algo=ppo_lagrangian shield=false iterations=200 seed=0,1,2

python runners/report.py "$root" --out results/reference/safe --preamble results/reference/safe/notes.md
if ((${#failed[@]})); then
  echo "failed sweeps: ${failed[*]}" >&2
  exit 1
fi
