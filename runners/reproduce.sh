#!/usr/bin/env bash
# Every sweep of the paper's figures (conf/experiment/) as one pool of jobs, then the report on all of them.
#
#   runners/reproduce.sh                          # the paper's budgets, 2 jobs at a time (runners/bench.py reproduce
#                                                 #   estimates how long on this machine)
#   runners/reproduce.sh quick                    # smoke test: every sweep at scale=quick (minutes), then the report
#   runners/reproduce.sh full --processes 4 replicas=5 --out results/sweeps/mine   # overrides go to every job
#   runners/reproduce.sh --list                   # the jobs, in the order the pool takes them
#
# Run the same command again after Ctrl-C or a kill: it continues the newest unfinished reproduction of the same
# arguments (finished jobs are skipped, the others resume or start); a stopped pool prints that command with --out.
# Jobs land in --out (or $REPRODUCE_DIR; default results/sweeps/reproduce_<scale>_<time>), the report in report/ there.
# The pool itself is sidewalk.reproduce (python -m sidewalk.reproduce --help).
set -euo pipefail
cd "$(dirname "$0")/.."
exec python -m sidewalk.reproduce "$@"
