"""BenchMARL's command line with the sidewalk's tasks: ``benchmarl/run.py``'s Hydra app on our config
(``conf/config.yaml``: BenchMARL's, with our task configs and tuned settings on its search path).

    python -m sidewalk.interop.benchmarl algorithm=mappo task=sidewalk/door_continuous
    python -m sidewalk.interop.benchmarl -m algorithm=iql,qmix task=sidewalk/door_discrete model=layers/cnn seed=0,1,2
"""

from __future__ import annotations

import difflib
import sys

from sidewalk.interop.benchmarl import CONFIG_DIR, ENV_NAME, SidewalkTask

USAGE = """\
usage: python -m sidewalk.interop.benchmarl algorithm=ALGORITHM task=TASK [OVERRIDE ...]
       python -m sidewalk.interop.benchmarl -m algorithm=A,B task=TASK seed=0,1,2 [OVERRIDE ...]

BenchMARL's run.py (Hydra) with the sidewalk's tasks. Where this package ships tuned settings for the task and
algorithm (conf/tuned/sidewalk/<task>/<algorithm>.yaml, as BenchMARL's fine_tuned/), they are loaded over
BenchMARL's defaults; tuned=default runs BenchMARL's defaults alone. Every BenchMARL override works
(experiment.max_n_frames=..., experiment.loggers=[csv] where wandb is not installed, model=layers/cnn, ...).

algorithms: {algorithms}
the sidewalk's tasks (task=sidewalk/<name>; BenchMARL's own tasks work too):
{tasks}

Hydra's own help: --hydra-help. Guide: docs/guide/benchmarl.md."""


def usage() -> str:
    from benchmarl.algorithms import algorithm_config_registry

    lines = []
    for task in SidewalkTask:
        tuned = task.tuned_algorithms()
        lines.append(f"  {ENV_NAME}/{task.name.lower()}" + (f"   (tuned: {', '.join(tuned)})" if tuned else ""))
    return USAGE.format(algorithms=", ".join(sorted(algorithm_config_registry)), tasks="\n".join(lines))


def check_choices(argv: list[str]) -> str | None:
    """The ``error:`` line for a ``task=`` or ``algorithm=`` override (each value of a ``-m`` list) that BenchMARL
    does not know, with the closest valid name and the sidewalk's tasks; None if every one is known."""
    from benchmarl.algorithms import algorithm_config_registry
    from benchmarl.environments import task_config_registry

    ours = [f"{ENV_NAME}/{task.name.lower()}" for task in SidewalkTask]
    valid = {"task": list(task_config_registry), "algorithm": sorted(algorithm_config_registry)}
    for arg in argv:
        key, _, values = arg.lstrip("+").partition("=")
        if key not in valid or not values:
            continue
        for value in values.split(","):
            if value in valid[key]:
                continue
            close = difflib.get_close_matches(value, ours if key == "task" else valid[key], n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            listed = f"the sidewalk's tasks: {', '.join(ours)} (and BenchMARL's own)" if key == "task" else (
                f"valid: {', '.join(valid[key])}")
            return f"error: {key}={value} is not a BenchMARL {key}{hint}; {listed}"
    return None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "-h" in argv or "--help" in argv:  # Hydra's --help composes the config, which needs a task and an algorithm
        print(usage())
        return 0
    error = check_choices(argv)
    if error:
        print(error, file=sys.stderr)
        return 2
    import hydra
    from benchmarl.hydra_config import load_experiment_from_hydra
    from hydra.core.hydra_config import HydraConfig

    @hydra.main(version_base=None, config_path=str(CONFIG_DIR), config_name="config")
    def run(cfg) -> None:  # benchmarl/run.py's body, on our config
        load_experiment_from_hydra(cfg, task_name=HydraConfig.get().runtime.choices.task).run()

    sys.argv = [sys.argv[0], *argv]
    run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
