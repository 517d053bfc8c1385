#!/usr/bin/env bash
# The commands that produced results/reference/crossplay/ (README.md there gives the revision and what ran where).
#
# 1. The paper's DQN runs (rows "dqn vs random", "dqn vs dijkstra", "dqn centralized", seeds 0-2): the fig5_discrete
#    sweep of results/reference/run.sh (5000 iterations each), into results/sweeps/reference/fig5_discrete.
# 2. Self-play in the grid sidewalk (rows "iql/vdn/qmix self-play"): seed 0 of each at the learners' defaults
#    (300 iterations, 153,600 frames; seeds 1 and 2 did not fit the 2-core machine's budget for this issue):
#      python runners/main.py -m +experiment=selfplay_discrete algo=iql,vdn,qmix seed=0 logger=none \
#        hydra.sweep.dir=results/sweeps/selfplay_discrete
# 3. The matrix: every run with the grid's scripted opponents and every run, 256 seeded worlds per cell:
set -euo pipefail
cd "$(dirname "$0")/../../.."
python runners/crossplay.py results/sweeps/reference/fig5_discrete results/sweeps/selfplay_discrete \
  --out results/reference/crossplay "$@"
