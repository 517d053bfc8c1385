"""The report's runs in marl-eval's JSON layout (Gorsane et al. 2022, github.com/instadeepai/marl-eval), the file
BenchMARL writes, so a BenchMARL user can aggregate and plot our runs beside theirs with marl-eval's tools.

Layout: environment → task → algorithm → ``run_<seed>`` → ``step_<k>`` (one per evaluation, in order:
``step_count`` the frames collected by then, and each metric as a list over the evaluation's episodes), plus
``absolute_metrics``: the run's best evaluation's policy re-evaluated on ten times the episodes (``summary.json``'s
``absolute``, written by ``sidewalk.experiment.Trial``).

- environment: ``sidewalk``; task: ``<layout>_<domain>`` (``sidewalk_discrete``, ``door_continuous``: the names of
  our BenchMARL tasks); algorithm: the condition's label (its learner, partner and what sets it apart), with commas
  replaced, which marl-eval refuses in algorithm names.
- metrics (the learner's: the ego's against a partner, the team's where it plays every agent): ``success_rate`` and
  ``collision_rate``, each episode's 0 or 1 -- a rate over E episodes fixes how many of them are 1, so the lists are
  exact, in no particular order; ``return``: a one-element list holding the evaluation's mean return (episodes'
  returns are not recorded; marl-eval's aggregation reads each list's mean).
- A run written before the absolute metric existed has no ``absolute_metrics``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sidewalk.report.conditions import Condition

ENVIRONMENT = "sidewalk"
MARL_EVAL_FILE = "marl_eval.json"
ABSOLUTE = "absolute_metrics"


def learner_prefix(condition: Condition) -> str:
    """The metric prefix of the learner's outcomes: ``ego/`` against a partner, ``team/`` for the team's success where
    the learner plays every agent (its collisions and return: over all agents, no prefix)."""
    return "ego/" if condition.agents()[0][0] == "ego" else ""


def _binary(rate: Any, episodes: int) -> list[int]:
    """The episodes' 0/1 outcomes that a ``rate`` over ``episodes`` episodes stands for (ones first)."""
    if rate is None or (isinstance(rate, float) and math.isnan(rate)) or episodes <= 0:
        return []
    ones = round(float(rate) * episodes)
    return [1] * ones + [0] * (episodes - ones)


def episode_metrics(metrics: dict[str, Any], prefix: str) -> dict[str, list]:
    """One evaluation's learner metrics as marl-eval lists (see the module docstring)."""
    episodes = int(metrics.get("episodes", 0) or 0)
    success_key = "ego/success_rate" if prefix == "ego/" else "team/success_rate"
    mean_return = metrics.get(f"{prefix}return")
    return {
        "success_rate": _binary(metrics.get(success_key), episodes),
        "collision_rate": _binary(metrics.get(f"{prefix}collision_rate"), episodes),
        "return": [] if mean_return is None or math.isnan(float(mean_return)) else [float(mean_return)],
    }


def _run_data(condition: Condition, run: Any) -> dict[str, Any]:
    prefix = learner_prefix(condition)
    metrics = run.metrics
    evaluations = metrics[metrics["eval/episodes"].notna()] if "eval/episodes" in metrics.columns else metrics[:0]
    data: dict[str, Any] = {}
    for index, (_, row) in enumerate(evaluations.iterrows()):
        values = {key[len("eval/"):]: value for key, value in row.items() if str(key).startswith("eval/")}
        data[f"step_{index}"] = {"step_count": int(row["frames"]), **episode_metrics(values, prefix)}
    absolute = run.summary.get("absolute")
    if isinstance(absolute, dict):
        data[ABSOLUTE] = episode_metrics(absolute, prefix)
    return data


def task_name(condition: Condition) -> str:
    return f"{condition.flat.get('env.layout', 'sidewalk')}_{condition.domain}"


def algorithm_name(condition: Condition) -> str:
    """The condition's label without its domain (the task says it) and without commas (marl-eval refuses them)."""
    label = condition.label.split(": ", 1)[-1] if ": " in condition.label else condition.label
    return label.replace(", ", "; ").replace(",", ";")


def marl_eval_data(conditions: Sequence[Condition]) -> dict[str, Any]:
    """Every condition's runs in marl-eval's layout (see the module docstring)."""
    tasks: dict[str, dict[str, Any]] = {}
    for condition in conditions:
        algorithms = tasks.setdefault(task_name(condition), {})
        name = algorithm_name(condition)
        if name in algorithms:  # two conditions alike but for a hidden key: keep both apart
            name = f"{name} ({condition.ident})"
        algorithms[name] = {f"run_{run.seed}": _run_data(condition, run) for run in condition.runs}
    return {ENVIRONMENT: tasks} if tasks else {}


def write_marl_eval(conditions: Sequence[Condition], out: Path) -> Path | None:
    """Write ``marl_eval.json`` into ``out``; None (and no file) without conditions."""
    data = marl_eval_data(conditions)
    if not data:
        return None
    path = out / MARL_EVAL_FILE
    path.write_text(json.dumps(data))
    return path
