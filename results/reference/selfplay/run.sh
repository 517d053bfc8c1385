#!/usr/bin/env bash
# The commands that produced results/reference/selfplay/ (README.md there gives what ran where and when), into
# results/sweeps/. One torch thread a run; on the 2-core machine they ran two to four at a time.
set -euo pipefail
cd "$(dirname "$0")/../../.."
main() { OMP_NUM_THREADS=1 python runners/main.py "$@"; }

# Continuous sidewalk: IPPO and MAPPO self-play, 3 seeds, and IPPO with Other-Play (other_play=true), 3 seeds.
main -m +experiment=selfplay_continuous hydra.sweep.dir=results/sweeps/selfplay_continuous
main -m +experiment=selfplay_continuous algo=ippo other_play=true hydra.sweep.dir=results/sweeps/otherplay_continuous
# Beside them: the centralized TRPO on the same reward, and TRPO against the PRM planner (single-agent partners for
# the cross-play, and the check that the observation and head changes keep the safe reference's results).
main -m env=continuous opponent=centralized algo=trpo reward.c_progress=0.1 iterations=100 eval_every=5 seed=0,1,2 \
  hydra.sweep.dir=results/sweeps/centralized_continuous
main -m +experiment=safe_continuous algo=trpo shield=false iterations=200 seed=0,1,2 \
  hydra.sweep.dir=results/sweeps/check_trpo_prm
main -m +experiment=safe_continuous algo=ppo_lagrangian shield=false iterations=200 seed=0,1,2 \
  hydra.sweep.dir=results/sweeps/check_ppo_lagrangian

# Grid sidewalk: IQL, VDN (seeds 0, 1) and QMIX (seeds 0, 1; seed 2 stopped) self-play at the preset's settings.
main -m +experiment=selfplay_discrete algo=iql,vdn seed=0 hydra.sweep.dir=results/sweeps/selfplay_discrete
main -m +experiment=selfplay_discrete algo=qmix seed=0,1,2 hydra.sweep.dir=results/sweeps/selfplay_discrete_qmix
for algo in iql vdn; do  # seed 1 of IQL and VDN
  main +experiment=selfplay_discrete algo=$algo seed=1 hydra.run.dir=results/sweeps/selfplay_discrete_s1/${algo}_seed1
done

# Scenarios in self-play (continuous IPPO, seed 0): zipper, teams, circle, door; the same settings as the presets
# conf/experiment/selfplay_<scenario>_continuous.yaml (written after these runs). Door was stopped at 73 iterations.
for scenario in zipper teams circle door; do
  main +experiment=${scenario}_continuous opponent=self algo=ippo reward.c_progress=0.1 seed=0 iterations=100 \
    eval_every=10 hydra.run.dir=results/sweeps/selfplay_scenarios_continuous/${scenario}_ippo_seed0
done

# 2026-11-25: grid seed 2 of IQL, VDN and QMIX; the grid scenarios in self-play (IQL, seed 0); the continuous door
# with the progress shaping along the path around its wall (IPPO and MAPPO, 300 iterations) and teams with MAPPO.
for algo in iql vdn qmix; do
  main +experiment=selfplay_discrete algo=$algo seed=2 hydra.run.dir=results/sweeps/selfplay_discrete_s2/${algo}_seed2
done
for scenario in door zipper circle teams; do
  main +experiment=selfplay_${scenario}_discrete seed=0 hydra.run.dir=results/sweeps/selfplay_scenarios_discrete/${scenario}_iql_seed0
done
for algo in ippo mappo; do
  main +experiment=selfplay_door_continuous algo=$algo seed=0 iterations=300 eval_every=20 \
    hydra.run.dir=results/sweeps/selfplay_scenarios_geodesic/door_${algo}_seed0_300
done
# Grid IPPO on images (seed 0; stopped at the session's end after 61,440 frames): ~22-27 min for 500 k frames alone.
main +experiment=selfplay_discrete algo=ippo seed=0 iterations=245 eval_every=10 \
  hydra.run.dir=results/sweeps/selfplay_discrete_images/ippo_seed0
main +experiment=selfplay_teams_continuous algo=mappo seed=0 iterations=200 eval_every=20 \
  hydra.run.dir=results/sweeps/selfplay_scenarios_geodesic/teams_mappo_seed0

# The table of README.md, and the cross-play matrix of the continuous runs.
python results/reference/selfplay/table.py results/sweeps/selfplay_continuous results/sweeps/otherplay_continuous \
  results/sweeps/centralized_continuous results/sweeps/selfplay_discrete results/sweeps/selfplay_discrete_qmix \
  results/sweeps/selfplay_discrete_s1 results/sweeps/selfplay_scenarios_continuous results/sweeps/selfplay_discrete_s2
python results/reference/selfplay/table.py --target 0.8 results/sweeps/selfplay_scenarios_discrete \
  results/sweeps/selfplay_scenarios_geodesic
python runners/crossplay.py results/sweeps/selfplay_continuous results/sweeps/otherplay_continuous \
  results/sweeps/centralized_continuous results/sweeps/check_trpo_prm --out results/reference/selfplay/crossplay
