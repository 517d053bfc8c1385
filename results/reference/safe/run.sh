#!/usr/bin/env bash
# The exact commands that produced results/reference/safe/, at the 10-seed paper reference's commit (reference.json
# gives it), on the 2-core machine the paper reference ran on.
#
#   REFERENCE_TREE=../ref10 results/reference/safe/run.sh     # into results/sweeps/reference/safe/
#   REFERENCE_TREE=../ref10 REFERENCE_DIR=/tmp/safe REFERENCE_OUT=/tmp/safe/report \
#     results/reference/safe/run.sh iterations=2 eval_every=1   # a smoke test of the whole script
#
# Safe RL on the Sidewalk, seeds 0-4 trained as one group per job (seed=0 replicas=5), at the presets' defaults (the
# perturbed evaluation protocol, noise 0): the unconstrained learner (grid DQN vs Dijkstra, continuous TRPO vs PRM),
# the same learner shielded (shield=true) and PPO-Lagrangian (algo=ppo_lagrangian at its default cost limit). Budgets:
# DQN at 200 iterations (102,400 frames; its default is 300), as the reference before; TRPO at 200 iterations
# (409,600 frames); PPO-Lagrangian at the frames of the learner it is compared with: 50 iterations in the grid
# (102,400 frames, at its own minibatches of 64 images: at 512, an eighth of the gradient steps, it walked its start
# row; results/who-yields/README.md), 200 in the continuous world.
#
# A sweep that finished is not run again (a marker in the output folder), so after a kill run the same command: the
# unfinished sweeps start over. Then copy the runs' small files into results/reference/safe/runs/ and rebuild its
# report from them:
#   python -m sidewalk.reference collect results/sweeps/reference/safe results/reference/safe/runs
#   python runners/report.py results/reference/safe/runs --out results/reference/safe \
#     --preamble results/reference/safe/notes.md
set -uo pipefail
safe="$(cd "$(dirname "$0")" && pwd)"  # the safe reference's folder, where the report goes
cd "${REFERENCE_TREE:-$safe/../../..}"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"  # this tree's package, whatever is installed

root="$(realpath -m "${REFERENCE_DIR:-results/sweeps/reference/safe}")"
out="${REFERENCE_OUT:-$safe}"  # the report's folder
extra=(logger=none "$@")  # extra overrides (a smoke test: iterations=2) go to every job
group=(seed=0 replicas=5)

# Each domain's sweeps share one folder, so that the report draws the unconstrained, shielded and constrained learners
# of a domain in one family (one cost figure, one table); their run folders' names (the overrides) differ.
sweep() {  # sweep NAME FOLDER OVERRIDES...: one multirun into $root/FOLDER, timed; skipped once it has finished
  local name="$1" folder="$2" start
  shift 2
  if [[ -e "$root/.finished-$name" ]]; then
    echo "== $name: finished before, skipped" >&2
    return 0
  fi
  start=$(date +%s)
  echo "== $name: python runners/main.py -m $* ($(date -Is))" >&2
  python runners/main.py -m "$@" "${extra[@]}" "${group[@]}" "hydra.sweep.dir=$root/$folder" || return 1
  echo "== $name: $(( $(date +%s) - start )) s" >&2
  touch "$root/.finished-$name"
}

# Two lanes of about equal length: the continuous PPO-Lagrangian runs beside everything else.
mkdir -p "$root"
(sweep continuous_ppo_lagrangian continuous +experiment=safe_continuous algo=ppo_lagrangian shield=false \
  iterations=200) & lane=$!
status=0
sweep discrete_ppo_lagrangian discrete +experiment=safe_discrete algo=ppo_lagrangian shield=false iterations=50 \
  eval_every=10 || status=1
sweep discrete_dqn discrete +experiment=safe_discrete algo=dqn iterations=200 shield=false,true || status=1
sweep continuous_trpo continuous +experiment=safe_continuous algo=trpo iterations=200 shield=false,true || status=1
wait "$lane" || status=1

python runners/report.py "$root" --out "$out" --preamble "$safe/notes.md" || status=1
exit $status
