#!/usr/bin/env bash
# The exact commands that produced results/reference/safe/ (reference.json there gives the commit; report.md the date
# and each run's wall clock).
#
#   results/reference/safe/run.sh        # into results/sweeps/reference/safe/, two lanes of jobs on 2 CPU cores
#   REFERENCE_DIR=/tmp/safe REFERENCE_OUT=/tmp/safe/report results/reference/safe/run.sh iterations=2 eval_every=1
#                                        # a smoke test of the whole script
#
# Safe RL on the Sidewalk, seeds 0-2: the unconstrained learner (grid DQN vs Dijkstra, continuous TRPO vs PRM) and the
# same learner shielded (shield=true), each job training its seeds together (seed=0 replicas=3), and PPO-Lagrangian
# (algo=ppo_lagrangian at its default cost limit) one process per seed (the reference's commit could not train it in a
# group), at noise 0. Budgets: DQN at its default 200 iterations (102,400
# frames); TRPO at 200 iterations (409,600 frames); PPO-Lagrangian at the frames of the learner it is compared with: 50
# iterations in the grid (102,400 frames, minibatches of 512 images), 200 in the continuous world.
#
# To run every job on one code revision while the checkout moves on, run them in a worktree of that revision:
#   git worktree add ../ref <commit> && REFERENCE_TREE=../ref REFERENCE_DIR=$PWD/results/sweeps/reference/safe \
#     results/reference/safe/run.sh
# then copy the runs' small files into results/reference/safe/runs/ and rebuild the report from them:
#   python -m sidewalk.reference collect results/sweeps/reference/safe results/reference/safe/runs
#   python runners/report.py results/reference/safe/runs --out results/reference/safe \
#     --preamble results/reference/safe/notes.md
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"  # this folder, where the report goes
cd "${REFERENCE_TREE:-$here/../../..}"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"  # this tree's package, whatever is installed

root="$(realpath -m "${REFERENCE_DIR:-results/sweeps/reference/safe}")"
out="${REFERENCE_OUT:-$here}"  # the report's folder
extra=(logger=none "$@")  # extra overrides (a smoke test: iterations=2) go to every job
groups=(seed=0 replicas=3)
seeds=(seed=0,1,2)

# Each domain's sweeps share one folder, so that the report draws the unconstrained, shielded and constrained learners
# of a domain in one family (one cost figure, one table); their run folders' names (the overrides) differ.
sweep() {  # sweep NAME FOLDER OVERRIDES...: one multirun into $root/FOLDER, timed
  local name="$1" folder="$2" start
  shift 2
  start=$(date +%s)
  echo "== $name: python runners/main.py -m $* ($(date -Is))" >&2
  python runners/main.py -m "$@" "${extra[@]}" "hydra.sweep.dir=$root/$folder" || return 1
  echo "== $name: $(( $(date +%s) - start )) s" >&2
}

# Two lanes of about equal length: the continuous PPO-Lagrangian runs beside everything else.
(sweep continuous_ppo_lagrangian continuous +experiment=safe_continuous algo=ppo_lagrangian shield=false iterations=200 \
  "${seeds[@]}") & lane=$!
status=0
sweep discrete_ppo_lagrangian discrete +experiment=safe_discrete algo=ppo_lagrangian shield=false iterations=50 \
  eval_every=10 algo.minibatch_size=512 "${seeds[@]}" || status=1
sweep discrete_dqn discrete +experiment=safe_discrete algo=dqn shield=false,true "${groups[@]}" || status=1
sweep continuous_trpo continuous +experiment=safe_continuous algo=trpo iterations=200 shield=false,true "${groups[@]}" ||
  status=1
wait "$lane" || status=1

python runners/report.py "$root" --out "$out" --preamble "$here/notes.md" || status=1
exit $status
