"""BenchMARL's command line with the sidewalk's tasks: ``benchmarl/run.py``'s Hydra app on our config
(``conf/config.yaml``: BenchMARL's, with our task configs and tuned settings on its search path).

    python -m sidewalk.interop.benchmarl algorithm=mappo task=sidewalk/door_continuous
    python -m sidewalk.interop.benchmarl -m algorithm=iql,qmix task=sidewalk/door_discrete seed=0,1,2
    python -m sidewalk.interop.benchmarl algorithm=iql task=sidewalk/door_discrete tuned=default model=layers/cnn
"""

from __future__ import annotations

import difflib
import sys
from pathlib import Path

from sidewalk.interop.benchmarl import CONFIG_DIR, ENV_NAME, SidewalkTask

USAGE = """\
usage: python -m sidewalk.interop.benchmarl algorithm=ALGORITHM task=TASK [OVERRIDE ...]
       python -m sidewalk.interop.benchmarl -m algorithm=A,B task=TASK seed=0,1,2 [OVERRIDE ...]

BenchMARL's run.py (Hydra) with the sidewalk's tasks. Where this package ships tuned settings for the task and
algorithm (conf/tuned/sidewalk/<task>/<algorithm>.yaml, as BenchMARL's fine_tuned/), they are loaded over
BenchMARL's defaults; tuned=default runs BenchMARL's defaults alone. Every BenchMARL override works
(experiment.max_n_frames=..., experiment.loggers=[csv] where wandb is not installed, model=layers/cnn, ...).
The grid's tuned files choose this package's dueling Q-value model, model=layers/dueling_mlp.

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


def model_choices() -> list[str]:
    """The options of the ``model`` config group on the command line's search path: BenchMARL's
    (``benchmarl/conf/model``: ``layers/mlp``, ``layers/cnn``, ..., ``sequence``) and this package's
    (``layers/dueling_mlp``)."""
    import benchmarl

    roots = [Path(benchmarl.__file__).parent / "conf" / "model", CONFIG_DIR / "model"]
    return sorted(path.relative_to(root).with_suffix("").as_posix() for root in roots for path in root.rglob("*.yaml"))


def check_choices(argv: list[str]) -> str | None:
    """The ``error:`` line for a ``task=``, ``algorithm=``, ``model=`` or ``critic_model=`` override (each value of a
    ``-m`` list) that BenchMARL does not know, with the closest valid name and the sidewalk's tasks; None if every one
    is known."""
    from benchmarl.algorithms import algorithm_config_registry
    from benchmarl.environments import task_config_registry

    ours = [f"{ENV_NAME}/{task.name.lower()}" for task in SidewalkTask]
    valid = {"task": list(task_config_registry), "algorithm": sorted(algorithm_config_registry),
             "model": model_choices(), "critic_model": model_choices()}
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
            kind = "model" if key == "critic_model" else key
            return f"error: {key}={value} is not a BenchMARL {kind}{hint}; {listed}"
    return None


def check_tuned_models(argv: list[str]) -> str | None:
    """The ``error:`` line for a ``model=`` or ``critic_model=`` override that a task and algorithm's tuned settings
    would override in turn (Hydra merges the tuned file's model over the chosen one: ``layers/mlp`` would run as the
    tuned model, ``layers/cnn`` would fail with the two merged); None where none does, or under ``tuned=...``."""
    values = {}
    for arg in argv:
        key, _, value = arg.lstrip("+").partition("=")
        values[key] = value.split(",")
    if "tuned" in values:
        return None
    ours = {f"{ENV_NAME}/{task.name.lower()}": task for task in SidewalkTask}
    for section in ("model", "critic_model"):
        for task_name in values.get("task", []):
            for algorithm in values.get("algorithm", []):
                chosen = ours[task_name].tuned_models(algorithm).get(section) if task_name in ours else None
                asked = [value for value in values.get(section, []) if value != f"layers/{chosen}"]
                if chosen and asked:
                    return (f"error: {section}={asked[0]}: the tuned settings of {task_name} and {algorithm} choose "
                            f"{section} layers/{chosen}; add tuned=default to run BenchMARL's defaults with another")
    return None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "-h" in argv or "--help" in argv:  # Hydra's --help composes the config, which needs a task and an algorithm
        print(usage())
        return 0
    error = check_choices(argv) or check_tuned_models(argv)
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
