"""BenchMARL's command line with the sidewalk's tasks: ``benchmarl/run.py``'s Hydra app, our task configs on its
search path.

    python -m sidewalk.interop.benchmarl algorithm=mappo task=sidewalk/door_continuous
    python -m sidewalk.interop.benchmarl -m algorithm=iql,qmix task=sidewalk/door_discrete model=layers/cnn seed=0,1,2
"""

from __future__ import annotations

import sys

from sidewalk.interop.benchmarl import CONFIG_DIR


def main() -> None:
    from benchmarl.run import hydra_experiment

    sys.argv.append(f"hydra.searchpath=[file://{CONFIG_DIR}]")
    hydra_experiment()


if __name__ == "__main__":
    main()
