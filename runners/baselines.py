"""Scripted baselines of every scenario: teams of random and of planner agents, evaluated like a learner.

    python runners/baselines.py                                     # every scenario, both domains, 3 seeds × 256
    python runners/baselines.py --scenarios door zipper --domains discrete --noise 0 0.1
    python runners/baselines.py --out results/reference/scenarios   # where the committed table lives

Each scenario is read from its preset (``conf/experiment/<scenario>_<domain>.yaml``; ``sidewalk``: the env's
defaults), so the table describes the worlds the learners train in. A *team* plays every agent: ``random``
(uniform random actions) or ``planner`` (Dijkstra in the grid, PRM in the continuous world; each agent plans
around every other one). Per seed, 256 worlds play one episode each (``sidewalk.evaluate``), and the table gives
mean ± standard error over seeds of: team success (every agent arrived), agent success, collision rate, deadlock
rate, makespan and wait steps (definitions: ``sidewalk.evaluate``). Writes ``baselines.csv`` (one row per
scenario, domain, team, noise and seed) and ``baselines.md`` (the table, and the command that made it) into
``--out``; files are written whole, then renamed, so an interrupted run leaves the previous table intact.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from sidewalk.envs.layouts import scenario_names
from sidewalk.paths import CONFIG_DIR

DOMAINS = ("discrete", "continuous")
TEAMS = ("random", "planner")
PLANNER = {"discrete": "dijkstra", "continuous": "prm"}
METRICS = {
    "team/success_rate": "team success",
    "success_rate": "agent success",
    "collision_rate": "collision",
    "deadlock_rate": "deadlock",
    "makespan": "makespan",
    "wait_steps": "wait steps",
}


def scenario_overrides(scenario: str, domain: str) -> list[str]:
    """The config overrides of a scenario: its preset where one exists, else the env group's defaults."""
    preset = CONFIG_DIR / "experiment" / f"{scenario}_{domain}.yaml"
    if preset.exists():
        return [f"+experiment={scenario}_{domain}"]
    if scenario != "sidewalk":
        raise ValueError(f"scenario {scenario!r} has no preset conf/experiment/{preset.name}")
    return [f"env={domain}", f"algo={'dqn' if domain == 'discrete' else 'trpo'}"]


def evaluate_team(scenario: str, domain: str, team: str, noise: float, seed: int, episodes: int) -> dict:
    """The metrics of one team of scripted agents in ``episodes`` worlds of one scenario, seeded with ``seed``."""
    from sidewalk.compose import compose_experiment
    from sidewalk.evaluate import evaluate
    from sidewalk.partners.team import ScriptedTeam

    experiment = compose_experiment([*scenario_overrides(scenario, domain), f"noise={noise}", f"seed={seed}"])
    core = experiment.world.core(episodes, seed=seed)
    name = "random" if team == "random" else PLANNER[domain]
    players = ScriptedTeam(core, name)
    metrics = evaluate(players.view, players, seed=seed, deterministic=False)
    return {"scenario": scenario, "domain": domain, "team": team, "agents": core.n_agents, "noise": noise,
            "seed": seed, **{key: metrics[key] for key in METRICS}, "episode_length": metrics["episode_length"]}


def table(rows: pd.DataFrame) -> str:
    """Mean ± standard error over seeds, one line per scenario, domain, team and noise."""
    from sidewalk.stats import mean_se

    lines = [
        "| scenario | domain | agents | team | noise | " + " | ".join(METRICS.values()) + " |",
        "|---" * (5 + len(METRICS)) + "|",
    ]
    keys = ["scenario", "domain", "agents", "team", "noise"]
    order = {name: i for i, name in enumerate(scenario_names())}
    grouped = sorted(
        rows.groupby(keys),
        key=lambda item: (DOMAINS.index(item[0][1]), order[item[0][0]], TEAMS.index(item[0][3]), item[0][4]),
    )
    for (scenario, domain, agents, team, noise), group in grouped:
        cells = []
        for key in METRICS:
            mean, se, count = mean_se(group[key].to_numpy())
            digits = 1 if key in ("makespan", "wait_steps") else 2
            cells.append("–" if count == 0 else f"{mean:.{digits}f} ± {se:.{digits}f}" if count > 1 else f"{mean:.{digits}f}")
        team_name = team if team == "random" else f"planner ({PLANNER[domain]})"
        lines.append(f"| {scenario} | {domain} | {agents} | {team_name} | {noise:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_whole(path: Path, text: str) -> None:
    partial = path.with_name(path.name + ".partial")
    partial.write_text(text)
    partial.replace(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="\n".join(__doc__.splitlines()[2:]),
    )
    parser.add_argument("--scenarios", nargs="+", default=scenario_names(), choices=scenario_names())
    parser.add_argument("--domains", nargs="+", default=list(DOMAINS), choices=DOMAINS)
    parser.add_argument("--teams", nargs="+", default=list(TEAMS), choices=TEAMS)
    parser.add_argument("--noise", nargs="+", type=float, default=[0.0], help="noise levels (grid: action noise)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=256, help="episodes (batched worlds) per seed")
    parser.add_argument("--out", type=Path, default=Path("results") / "reference" / "scenarios")
    args = parser.parse_args(argv)
    if args.episodes < 1 or any(seed < 0 for seed in args.seeds) or any(n < 0 for n in args.noise):
        parser.error(f"--episodes must be ≥ 1, --seeds and --noise ≥ 0; got {args.episodes}, {args.seeds}, {args.noise}")
    for domain in args.domains:  # a scenario without a preset fails here, before any evaluation
        for scenario in args.scenarios:
            scenario_overrides(scenario, domain)
    torch.set_num_threads(1)

    from tqdm import tqdm

    jobs = [
        (scenario, domain, team, noise, seed)
        for domain in args.domains
        for scenario in args.scenarios
        for team in args.teams
        for noise in args.noise
        for seed in args.seeds
    ]
    rows = []
    started = time.perf_counter()
    with tqdm(jobs, desc="baselines", unit="eval", file=sys.stderr) as progress:
        for scenario, domain, team, noise, seed in progress:
            progress.set_postfix_str(f"{scenario} {domain} {team} noise={noise:g} seed={seed}")
            rows.append(evaluate_team(scenario, domain, team, noise, seed, args.episodes))
    frame = pd.DataFrame(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    write_whole(args.out / "baselines.csv", frame.to_csv(index=False, float_format="%.6g"))
    command = "python runners/baselines.py " + shlex.join(sys.argv[1:] if argv is None else argv)
    write_whole(
        args.out / "baselines.md",
        "# Scripted baselines of the scenarios\n\n"
        f"Made by `{command.strip()}` ({len(args.seeds)} seeds × {args.episodes} episodes per row, mean ± standard "
        f"error over seeds; {time.perf_counter() - started:.0f} s). Every agent is scripted: `random` or the "
        "domain's planner. Definitions of the columns: `sidewalk/evaluate.py`.\n\n" + table(frame) + "\n",
    )
    print(table(frame))
    print(f"wrote {args.out / 'baselines.csv'} and {args.out / 'baselines.md'}", file=sys.stderr)
    return 0 if np.isfinite(frame["team/success_rate"]).all() else 1


if __name__ == "__main__":
    sys.exit(main())
