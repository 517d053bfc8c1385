"""The report's runs as marl-eval files (Gorsane et al. 2022, github.com/instadeepai/marl-eval), laid out as BenchMARL's
``JsonWriter`` writes its runs, so that marl-eval's tools load each file whole and a BenchMARL user can merge it with
their own runs of our tasks.

One file per comparable set, ``marl_eval/<tasks>_<E>_evaluations_<F>_frames.json`` in the report's folder:
marl-eval's ``DiagnoseData`` and ``create_matrices_for_rliable`` take one environment's tasks to share the same
algorithms, the same runs and the same number of evaluations. The report's conditions are grouped by their runs'
evaluation frames (the same E evaluations at the same frames, the last at F; whether the runs have an absolute metric)
and seeds; within such a group, the tasks that hold the same algorithms make one file (``+`` joins them in the name; a
second file of the same name gets ``_2``). A condition whose seeds were evaluated at different frames lands in a file
of its own, which ``DiagnoseData`` then flags.

Layout: environment → task → algorithm → ``seed_<seed>`` (BenchMARL's run name) → ``step_<k>``, the k-th evaluation
from 1 (BenchMARL numbers its steps by frames ÷ evaluation interval: the same names where our evaluations fall every
interval, as they do but for a last iteration off the interval) with ``step_count`` the frames collected by then, and
``absolute_metrics``.

- environment: ``sidewalk``, BenchMARL's name for our tasks; task: ``<layout>_<domain>`` (``sidewalk_discrete``,
  ``door_continuous``), the names of our BenchMARL tasks. Only a condition whose learner plays every agent of the
  self-play presets' worlds plays what BenchMARL's task of that name plays; a learner against a scripted partner plays
  the same worlds with another agent in them, and another reward.
- algorithm: the condition's label without its domain, told apart from the other conditions of its task only (so one
  experiment run on several tasks has one name), commas replaced (marl-eval refuses them).
- metrics, the learner's (the ego's against a partner; where it plays every agent, the team's success and its agents'
  collisions and return), each a one-element list: ``success_rate``, ``collision_rate``, ``return`` (the mean over
  episodes and the learner's agents of an agent's undiscounted return) and, so that nobody reads a list's length or
  the world count as the sample size, ``episodes`` (worlds played) and ``distinct_episodes`` (different trajectories
  among them: at noise 0 many worlds replay one episode). An empty list where the run did not record it.
- BenchMARL writes, per evaluation, ``return`` as one value per episode (the mean over agent groups of the group's
  mean agent return) and ``<group>_return`` per group; our runs record an evaluation's means, not its episodes, and our
  learner is one group, so ``return`` is a one-element list of the same mean and there is no group key. marl-eval reads
  a list's mean, so both give the same aggregates.
- ``absolute_metrics``: ours is the run's best evaluation's policy re-evaluated on ten times the episodes
  (``summary.json``'s ``absolute``, ``sidewalk.experiment.Trial``), marl-eval's README's definition (Colas et al.
  2018). BenchMARL's is each metric's maximum over every episode of every evaluation. The two are not the same
  quantity; a run made before the absolute metric existed has none.

``merge_marl_eval`` puts our file and BenchMARL's files of a task in one dict that marl-eval loads whole: the metrics and
steps every run has (BenchMARL has no success, we have no ``<group>_return``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sidewalk.report.conditions import Condition, label

ENVIRONMENT = "sidewalk"
MARL_EVAL_DIR = "marl_eval"
ABSOLUTE = "absolute_metrics"
STEP_COUNT = "step_count"


@dataclass
class MarlEvalSet:
    """One marl-eval file: conditions marl-eval compares whole (see the module docstring)."""

    name: str  # the file's name without .json
    conditions: list[Condition]
    tasks: list[str]
    seeds: list[int]
    frames: list[int]  # the evaluations' frames, the same in every run
    data: dict[str, Any] = field(repr=False)


def learner_prefix(condition: Condition) -> str:
    """The metric prefix of the learner's outcomes: ``ego/`` against a partner, ``team/`` for the team's success where
    the learner plays every agent (its collisions and return: over all agents, no prefix)."""
    return "ego/" if condition.agents()[0][0] == "ego" else ""


def _one(value: Any, kind: type = float) -> list:
    """A value as a one-element list; empty where it is missing or NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return []
    return [kind(value)]


def evaluation_metrics(metrics: Mapping[str, Any], prefix: str) -> dict[str, list[float]]:
    """One evaluation's learner metrics as marl-eval lists (see the module docstring)."""
    success_key = "ego/success_rate" if prefix == "ego/" else "team/success_rate"
    return {
        "success_rate": _one(metrics.get(success_key)),
        "collision_rate": _one(metrics.get(f"{prefix}collision_rate")),
        "return": _one(metrics.get(f"{prefix}return")),
        "episodes": _one(metrics.get("episodes"), int),
        "distinct_episodes": _one(metrics.get("distinct_episodes"), int),
    }


def _evaluations(run: Any) -> list[dict[str, Any]]:
    """The run's evaluation rows of ``metrics.csv``: ``frames`` and each ``eval/`` metric without its prefix."""
    metrics = run.metrics
    if "eval/episodes" not in metrics.columns:
        return []
    rows = metrics[metrics["eval/episodes"].notna()]
    return [
        {"frames": int(row["frames"]),
         **{str(key)[len("eval/"):]: value for key, value in row.items() if str(key).startswith("eval/")}}
        for _, row in rows.iterrows()
    ]


def _run_data(condition: Condition, run: Any) -> dict[str, Any]:
    prefix = learner_prefix(condition)
    data: dict[str, Any] = {
        f"step_{k}": {STEP_COUNT: row["frames"], **evaluation_metrics(row, prefix)}
        for k, row in enumerate(_evaluations(run), 1)
    }
    absolute = run.summary.get("absolute")
    if isinstance(absolute, dict):
        data[ABSOLUTE] = evaluation_metrics(absolute, prefix)
    return data


def task_name(condition: Condition) -> str:
    return f"{condition.flat.get('env.layout', 'sidewalk')}_{condition.domain}"


def algorithm_name(condition: Condition, conditions: Sequence[Condition]) -> str:
    """The condition's label among the conditions of its task, without its domain (the task says it) and without
    commas (marl-eval refuses them)."""
    peers = [other for other in conditions if task_name(other) == task_name(condition)]
    text = label(condition, peers).split(": ", 1)[-1]
    return text.replace(", ", "; ").replace(",", ";")


def _schedule(run: Any) -> tuple:
    """What marl-eval needs alike in every run of a file: the evaluations' frames, and whether there is an absolute
    metric."""
    return tuple(row["frames"] for row in _evaluations(run)), isinstance(run.summary.get("absolute"), dict)


def marl_eval_sets(conditions: Sequence[Condition]) -> list[MarlEvalSet]:
    """The conditions as marl-eval files, one per comparable set (see the module docstring), in the conditions'
    order."""
    names: dict[int, str] = {}
    for task in dict.fromkeys(map(task_name, conditions)):
        in_task = [c for c in conditions if task_name(c) == task]
        chosen = {id(c): algorithm_name(c, conditions) for c in in_task}
        for condition in in_task:  # alike but for keys the label leaves out: keep them apart
            if [name.lower() for name in chosen.values()].count(chosen[id(condition)].lower()) > 1:
                chosen[id(condition)] += f" ({condition.ident})"
        names.update(chosen)
    groups: dict[tuple, list[Condition]] = {}
    for condition in conditions:
        schedules = tuple(sorted({_schedule(run) for run in condition.runs}))
        groups.setdefault((schedules, tuple(condition.seeds)), []).append(condition)
    sets: list[MarlEvalSet] = []
    taken: set[str] = set()
    for (schedules, seeds), grouped in groups.items():
        by_task: dict[str, list[Condition]] = {}
        for condition in grouped:
            by_task.setdefault(task_name(condition), []).append(condition)
        by_algorithms: dict[frozenset, list[str]] = {}
        for task, in_task in by_task.items():
            by_algorithms.setdefault(frozenset(names[id(c)] for c in in_task), []).append(task)
        for tasks in by_algorithms.values():
            frames = list(schedules[0][0])
            name = f"{'+'.join(tasks)}_{len(frames)}_evaluations_{frames[-1] if frames else 0}_frames"
            suffix = 2
            while name in taken:
                name, suffix = f"{name.rsplit('_frames', 1)[0]}_frames_{suffix}", suffix + 1
            taken.add(name)
            members = [c for task in tasks for c in by_task[task]]
            data = {ENVIRONMENT: {task: {names[id(c)]: {f"seed_{run.seed}": _run_data(c, run) for run in c.runs}
                                         for c in by_task[task]} for task in tasks}}
            sets.append(MarlEvalSet(name, members, list(tasks), list(seeds), frames, data))
    return sets


def write_marl_eval(conditions: Sequence[Condition], out: Path) -> list[tuple[Path, MarlEvalSet]]:
    """Write each set's file into ``out/marl_eval/`` (files of an earlier report there are removed first); returns
    each file with its set."""
    folder = out / MARL_EVAL_DIR
    for stale in folder.glob("*.json"):
        stale.unlink()
    written = []
    for marl_set in marl_eval_sets(conditions):
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{marl_set.name}.json"
        path.write_text(json.dumps(marl_set.data, separators=(",", ":")) + "\n")
        written.append((path, marl_set))
    return written


def merge_marl_eval(*files: Mapping[str, Any]) -> dict[str, Any]:
    """marl-eval files (environment → task → algorithm → run → step → metric) as one, keeping the steps that every run
    has and, in them, the metrics that every step has (``step_count`` always): what marl-eval's ``DiagnoseData``
    asks of one file. Raises ``ValueError`` for a run that two files hold."""
    merged: dict[str, Any] = {}
    runs: list[dict[str, Any]] = []
    for data in files:
        for environment, tasks in data.items():
            for task, algorithms in tasks.items():
                for algorithm, algorithm_runs in algorithms.items():
                    into = merged.setdefault(environment, {}).setdefault(task, {}).setdefault(algorithm, {})
                    for run, steps in algorithm_runs.items():
                        if run in into:
                            raise ValueError(f"{environment}/{task}/{algorithm}/{run} is in two files")
                        into[run] = steps
                        runs.append(steps)
    if not runs:
        return merged
    steps = set.intersection(*(set(steps) for steps in runs))
    metrics = set.intersection(*(set(run[step]) - {STEP_COUNT} for run in runs for step in steps))
    for environment, tasks in merged.items():
        for task, algorithms in tasks.items():
            for algorithm, algorithm_runs in algorithms.items():
                for run, run_steps in algorithm_runs.items():
                    algorithm_runs[run] = {
                        step: {key: value for key, value in values.items() if key in metrics or key == STEP_COUNT}
                        for step, values in run_steps.items() if step in steps
                    }
    return merged
