#!/usr/bin/env bash
# The continuous ad-hoc table at 10 seeds a condition (issue 62: "the ad-hoc table at >= 10 seeds a condition"):
# self-play (IPPO, 200 iterations), Other-Play (IPPO, 100 iterations) and the population learner (PPO against
# opponent=population, 200 iterations), seeds 0-9 each as one group of 10 replicas, then the matrix with the 10
# held-out partners and its report. The committed table (results/reference/adhoc/continuous) rests on 3 seeds a
# condition, made at 9ecba67, which cannot separate anything (3 against 3: the smallest p is 0.1).
#
# Run it from a worktree of a pinned commit (git worktree add ../adhoc10 <commit>), in two lanes on a 2-core machine:
#   results/reference/adhoc/run.sh train selfplay            # lane 1 (the longest: about 41 min for 3 seeds at 9ecba67)
#   results/reference/adhoc/run.sh train otherplay population # lane 2 (28 and 8.5 min for 3 seeds)
#   results/reference/adhoc/run.sh matrix                     # when all three are done: the matrix and report.md
# A job stopped mid-way resumes from its checkpoint: the same command again (resume=true is passed when its folder
# already holds a checkpoint). Sweeps go under ADHOC_DIR (default results/sweeps/adhoc10).
set -euo pipefail
cd "$(dirname "$0")/../../.."
root="${ADHOC_DIR:-results/sweeps/adhoc10}"
export OMP_NUM_THREADS=1

train() {  # name, then the job's overrides
  local name=$1 dir="$root/$1"
  shift
  local resume=()
  [ -f "$dir/.group/checkpoint.pt" ] && resume=(resume=true)  # a group keeps its checkpoint in .group/
  python runners/main.py env=continuous seed=0 replicas=10 logger=none "$@" "hydra.run.dir=$dir" "${resume[@]}"
}

case "${1:-}" in
  train)
    shift
    for condition in "$@"; do
      case "$condition" in
        selfplay) train selfplay opponent=self algo=ippo ;;
        otherplay) train otherplay opponent=self algo=ippo other_play=true iterations=100 ;;
        population) train population algo=ppo opponent=population iterations=200 eval_every=20 reward.c_progress=0.1 ;;
        *) echo "error: condition=$condition is not one of selfplay, otherplay, population" >&2; exit 2 ;;
      esac
    done
    ;;
  matrix)
    python runners/crossplay.py "$root/selfplay" "$root/otherplay" "$root/population" --partners heldout \
      --out results/reference/adhoc/continuous --no-progress
    ;;
  *)
    echo "error: command=${1:-<none>} is not one of train, matrix" >&2
    exit 2
    ;;
esac
