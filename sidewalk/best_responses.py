"""Best responses to the held-out partners: the denominators of BR-Prox (ZSC-Eval's normalised ad-hoc score).

For each held-out member of a domain (``sidewalk.partners.population``) our learner that the domain's reference
trains against a scripted partner (``RECIPES``: PPO in the continuous world, DQN in the grid) is trained against that
member alone, then evaluated with it under the cross-play protocol (``sidewalk.crossplay.arena.evaluate_cell``: greedy, one
episode in each of ``episodes`` worlds seeded ``seed + EVAL_SEED_OFFSET``, the matrix's own worlds). Its team success
is cached in ``best_responses.csv`` (``BEST_RESPONSE_COLUMNS``) beside the matrix, which
``sidewalk.report.crossplay.adhoc_table`` reads; the policies stay in their run folders.

``train_best_responses`` skips members the cache already holds (and trains no seed whose run folder finished), so
an interrupted job is continued by running it again.
"""

from __future__ import annotations

import logging
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from sidewalk._checks import check_choice, check_int
from sidewalk.crossplay.arena import evaluate_cell
from sidewalk.crossplay.pairings import evaluation_world
from sidewalk.crossplay.players import heldout_column, load_player
from sidewalk.partners.population import Member, population
from sidewalk.report.crossplay import BEST_RESPONSES_CSV, best_response_warning
from sidewalk.stats import interval_estimate

log = logging.getLogger(__name__)

# The learner each domain's reference trains against a scripted partner, with that reference's settings:
# the continuous population learner (docs/guide/adhoc.md) and the grid's default learner (conf/algo/dqn.yaml) at the
# 300 iterations the committed best responses were made with (its default is 400 since; a recipe pins its budget so
# that moving a learner's default does not move BR-Prox).
RECIPES: dict[str, tuple[str, ...]] = {
    "continuous": ("env=continuous", "algo=ppo", "iterations=200", "eval_every=20", "reward.c_progress=0.1"),
    "discrete": ("env=discrete", "algo=dqn", "iterations=300"),
}
BEST_RESPONSE_COLUMNS = ("member", "command", "budget", "reference_budget", "seeds", "success", "low", "high", "note",
                         "episodes", "distinct_low", "distinct_high", "run_folders")


def reference_budget(domain: str) -> int:
    """The iterations ``RECIPES[domain]`` trains for: the budget a best response is meant to have (``iterations`` or
    ``--override`` may give it less, and the report then warns that BR-Prox rests on it)."""
    from sidewalk.compose import compose

    return int(compose(list(RECIPES[domain]))["iterations"])


def member_overrides(domain: str, member: Member) -> list[str]:
    """The config overrides that make ``member`` the opponent: its registered name and settings, a shipped learned
    member as ``opponent=policy opponent.path=<its folder>``."""
    if member.opponent == "policy":
        path = Path(member.kwargs(domain)["path"])
        if path.is_relative_to(Path.cwd()):  # a clone's command reads the same on every machine
            path = path.relative_to(Path.cwd())
        return ["opponent=policy", f"opponent.path={path}"]
    return [f"opponent={member.opponent}"] + [f"opponent.params.{key}={value}" for key, value in member.params.items()]


def best_response_overrides(
    domain: str, name: str, seeds: int = 1, iterations: int | None = None, extra: Sequence[str] = ()
) -> list[str]:
    """The overrides of ``runners/main.py`` that train the best response to held-out member ``name`` of ``domain``:
    ``RECIPES[domain]`` against that member, seeds 0..``seeds``-1 as one group, ``iterations`` where given, then
    ``extra`` (any other override)."""
    members = check_members(domain, [name])
    overrides = [*RECIPES[domain], *member_overrides(domain, members[name]), "plots=false"]
    if iterations is not None:
        overrides.append(f"iterations={iterations}")
    return overrides + ["seed=0", f"replicas={seeds}", *extra]


def check_members(domain: str, names: Sequence[str] | None) -> dict[str, Member]:
    """The held-out members named (all of ``domain``'s when None); raises ``ValueError`` naming an unknown one and
    the valid ones, before anything is trained."""
    check_choice("domain", domain, RECIPES)
    heldout = population(domain, "heldout")
    for name in names or []:
        check_choice("held-out member", name, heldout)
    return {name: heldout[name] for name in (names or heldout)}


def evaluate_best_response(
    domain: str, name: str, run_folders: Sequence[Path], episodes: int = 256, seed: int = 0
) -> dict[str, Any]:
    """One cache row: each seed's policy (``run_folders``) with member ``name`` under the cross-play protocol, its
    team success the mean over seeds with a 95 % bootstrap interval over them (none with one seed)."""
    column = heldout_column(domain, name, check_members(domain, [name])[name])
    scores, distinct = [], []
    for folder in run_folders:
        player = load_player(folder)
        metrics = evaluate_cell(player, column, evaluation_world([player], None), episodes, seed)
        scores.append(float(metrics["team/success_rate"]))
        distinct.append(int(metrics["distinct_episodes"]))
    interval = interval_estimate(np.array(scores), "mean")
    return {"member": name, "seeds": len(scores), "success": interval.point, "low": interval.low,
            "high": interval.high, "note": interval.note, "episodes": episodes * len(scores),
            "distinct_low": min(distinct), "distinct_high": max(distinct),
            "run_folders": " ".join(str(folder) for folder in run_folders)}


def read_cache(out: str | Path) -> pd.DataFrame:
    """``out/best_responses.csv`` (``BEST_RESPONSE_COLUMNS``), empty where there is none."""
    path = Path(out) / BEST_RESPONSES_CSV
    if not path.exists():
        return pd.DataFrame(columns=list(BEST_RESPONSE_COLUMNS))
    return pd.read_csv(path, keep_default_na=False, na_values=[""])


def write_cache(out: str | Path, rows: Sequence[dict[str, Any]]) -> Path:
    """``rows`` merged into ``out/best_responses.csv`` (a member's new row replaces its old one), in member order."""
    from sidewalk.run_folder import atomic_write

    old = read_cache(out)
    new = pd.DataFrame(list(rows), columns=list(BEST_RESPONSE_COLUMNS))
    table = pd.concat([old[~old["member"].isin(new["member"])], new] if len(old) else [new], ignore_index=True)
    path = Path(out) / BEST_RESPONSES_CSV
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: table[list(BEST_RESPONSE_COLUMNS)].to_csv(tmp, index=False))
    return path


def train_one(
    domain: str, name: str, runs_dir: Path, seeds: int, iterations: int | None, extra: Sequence[str] = ()
) -> tuple[list[Path], str]:
    """Train the best response to ``name`` in ``runs_dir/<domain>/<name>``, continuing a run stopped there and
    skipping one that finished; return its seeds' run folders and the command that trains it."""
    import contextlib

    from sidewalk.compose import compose
    from sidewalk.experiment import Trial
    from sidewalk.hydra_callbacks import planned
    from sidewalk.trial_state import seed_dirs

    run_dir = Path(runs_dir) / domain / name
    overrides = best_response_overrides(domain, name, seeds, iterations, extra)
    with contextlib.ExitStack() as held:  # the start sequence of runners/main.py, continuing what an earlier job began
        experiment, config, plan = planned(compose(overrides), run_dir, held, continue_started=True)
        if plan != "finished":
            Trial(experiment, run_dir, config).run(progress=False)
    folders = seed_dirs(run_dir, experiment)
    command = shlex.join(["python", "runners/main.py", *overrides, f"hydra.run.dir={run_dir}"])
    return folders, command


def train_best_responses(
    domain: str,
    out: str | Path,
    runs_dir: str | Path,
    members: Sequence[str] | None = None,
    seeds: int = 1,
    iterations: int | None = None,
    episodes: int = 256,
    seed: int = 0,
    show_progress: bool = True,
    extra: Sequence[str] = (),
) -> Path:
    """Train and evaluate the best response to each held-out member of ``domain`` (``members``, default all) that
    ``out/best_responses.csv`` does not hold yet, writing each row as it is done; return the CSV's path. ``extra``:
    config overrides added to ``RECIPES[domain]``'s. Unknown members, domains or counts raise ``ValueError`` before
    anything is trained; a tqdm bar counts the members. Best responses trained now that BR-Prox should not rest on
    (``best_response_warning``: below the reference budget, or weak with their partner) are logged as a warning."""
    from tqdm import tqdm

    table = check_members(domain, members)
    check_int("seeds", seeds, 1)
    check_int("episodes", episodes, 1)
    if iterations is not None:
        check_int("iterations", iterations, 1)
    done = set(read_cache(out)["member"].astype(str))
    reference, trained = reference_budget(domain), []
    with tqdm(total=len(table), desc="best responses", unit="member", disable=not show_progress) as bar:
        for name in table:
            bar.set_postfix_str(name + (" (cached)" if name in done else ""))
            if name not in done:
                folders, command = train_one(domain, name, Path(runs_dir), seeds, iterations, extra)
                row = evaluate_best_response(domain, name, folders, episodes, seed)
                write_cache(out, [{**row, "command": command, "budget": _iterations(folders[0]),
                                   "reference_budget": reference}])
                trained.append(name)
            bar.update(1)
    warning = best_response_warning(read_cache(out), trained)
    if warning:
        log.warning(warning)
    return Path(out) / BEST_RESPONSES_CSV


def _iterations(folder: Path) -> int:
    from omegaconf import OmegaConf

    from sidewalk.run_folder import CONFIG

    return int(OmegaConf.load(Path(folder) / CONFIG)["iterations"])


def best_responses_from_runs(
    paths: Sequence[str | Path], episodes: int = 256, seed: int = 0
) -> list[dict[str, Any]]:
    """Cache rows from run folders trained against held-out members by hand (``paths``: runs or sweeps): each run's
    partner matched to the member of its domain's held-out population whose opponent and settings it trained with,
    the member's runs evaluated together (``evaluate_best_response``). A run that matches no held-out member raises
    ``ValueError`` naming it."""
    from sidewalk.report.runs import find_run_folders, load_run

    found: dict[tuple[str, str], list[Path]] = {}
    for folder in find_run_folders(paths):
        run = load_run(folder)
        domain = run.flat["env.domain"]
        member = heldout_member(run.flat, population(domain, "heldout"))
        if member is None:
            raise ValueError(f"{folder} trained against opponent={run.flat.get('opponent.name')!r} with settings "
                             "that match no held-out partner")
        found.setdefault((domain, member), []).append(Path(folder))
    return [{**evaluate_best_response(domain, member, folders, episodes, seed), "command": "",
             "budget": _iterations(folders[0]), "reference_budget": reference_budget(domain)}
            for (domain, member), folders in found.items()]


def heldout_member(flat: dict[str, Any], members: dict[str, Member]) -> str | None:
    """The held-out member whose opponent and settings (its defaults but where it says otherwise) a run's flat
    ``opponent.*`` config holds; None when none does."""
    from sidewalk.opponents.base import opponent_config

    for name, member in members.items():
        if flat.get("opponent.name") != member.opponent:
            continue
        if member.opponent == "policy":
            if Path(str(flat.get("opponent.path", ""))).name == member.params["partner"]:
                return name
        elif all(flat.get(f"opponent.params.{key}") == value
                 for key, value in opponent_config(member.opponent, member.params).items()):
            return name
    return None
