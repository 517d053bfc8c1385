#!/usr/bin/env bash
# Every sweep of the paper's figures (conf/experiment/), then the report on all of them.
#
#   runners/reproduce.sh                       # the paper's budgets: days of CPU time
#   runners/reproduce.sh quick                 # smoke test: every sweep at scale=quick (minutes), then the report
#   runners/reproduce.sh full hydra/launcher=joblib hydra.launcher.n_jobs=4   # extra overrides go to every sweep
#
# Sweeps land in $REPRODUCE_DIR/<preset>/ and the report in $REPRODUCE_DIR/report/report.md; REPRODUCE_DIR defaults
# to results/sweeps/reproduce_<scale>_<time>. (Do not pass hydra.sweep.dir: each preset gets its own folder.)
# Fig. 7 is drawn from the Fig. 5 runs, so its alias presets are not run again. A sweep whose jobs fail does not stop
# the others: the report lists the failed run folders, and the script exits 1 at the end.
set -uo pipefail
cd "$(dirname "$0")/.."

scale="${1:-full}"
case "$scale" in
  full|quick) shift $(( $# > 0 ? 1 : 0 )) ;;
  *) echo "usage: $0 [full|quick] [hydra overrides...]; got scale '$scale'" >&2; exit 2 ;;
esac
root="${REPRODUCE_DIR:-results/sweeps/reproduce_${scale}_$(date +%Y-%m-%d_%H-%M-%S)}"
for arg in "$@"; do
  if [[ "$arg" == hydra.sweep.dir=* ]]; then
    echo "$0: do not pass hydra.sweep.dir (each preset gets a folder under \$REPRODUCE_DIR)" >&2; exit 2
  fi
done
presets=(fig5_discrete fig5_continuous fig6_discrete fig6_continuous fig8)

failed=()
for preset in "${presets[@]}"; do
  echo "== $preset (scale=$scale) -> $root/$preset" >&2
  if ! python runners/main.py -m "+experiment=$preset" "scale=$scale" "hydra.sweep.dir=$root/$preset" "$@"; then
    failed+=("$preset")
  fi
done

echo "== report -> $root/report" >&2
python runners/report.py "$root" --out "$root/report" || failed+=("report")

if (( ${#failed[@]} )); then
  echo "reproduce: failed: ${failed[*]} (see error.txt in the job folders and $root/report/report.md)" >&2
  exit 1
fi
echo "reproduce: done: $root/report/report.md" >&2
