"""Episodes played for pictures: a run's evaluation episode replayed with its final policy, or scripted agents in one
world, each as frames from the env's own ``render`` and its outcome in words."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from sidewalk.envs.base import INFO_KEYS


def rollout_run(run_dir: Path, episode: int) -> tuple[list[np.ndarray], str]:
    """Frames of evaluation episode ``episode`` of a run's final policy, and its outcome in words."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

    from sidewalk.experiment import EVAL_SEED_OFFSET, make_eval_view
    from sidewalk.report.checkpoints import load_experiment, load_policy

    experiment = load_experiment(run_dir)
    if not 0 <= episode < experiment.eval_episodes:
        raise ValueError(
            f"--episode={episode} is out of range; the run evaluates episodes 0..{experiment.eval_episodes - 1}"
        )
    seed = experiment.seed + EVAL_SEED_OFFSET
    env = make_eval_view(experiment)  # the evaluation's worlds (its protocol's), seeded as the evaluation seeds them
    policy = load_policy(run_dir, experiment, env)
    env.set_seed(seed)  # as sidewalk.evaluate.run_episodes does, so the episode is the evaluation's own
    td = env.reset()
    frames = [env.render(episode)]
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(env.core.params.max_steps + 1):
            td = env.step(policy(td))
            frames.append(env.render(episode))
            if bool(td.get(("next", "done"))[episode]):
                break
            td = step_mdp(td)
    info = td.get(("next", "world", "info"))
    return frames, outcome({key: info.get(key)[episode].squeeze(-1) for key in info.keys()})  # noqa: SIM118 (a TensorDict iterates rows)


class Episode(NamedTuple):
    """One episode of scripted agents: frames at each requested scale, where every agent was, the outcome."""

    frames: list[list[np.ndarray]]  # frames[scale][t]: RGB uint8, t = 0 is the reset
    positions: np.ndarray  # (T, N, 2) float, in agent widths (grid cells; continuous: diameters)
    present: np.ndarray  # (T, N) bool: the agent occupies space
    outcome: str
    setting: str  # the world in words: agents and size


def scripted_world(domain: str, opponent: str, seed: int, overrides: list[str]):
    """The validated World of scripted agents (``runners/main.py``'s config of ``overrides``), and one world of it
    (a core env)."""
    from sidewalk.compose import compose
    from sidewalk.config import validate_world

    world = validate_world(compose([f"env={domain}", f"opponent={opponent}", f"seed={seed}", *overrides]))
    return world, world.core(1, seed=seed)


def play_scripted(
    domain: str,
    opponent: str,
    ego: str,
    seed: int,
    overrides: list[str],
    scales: tuple[dict[str, int], ...] = ({},),
) -> Episode:
    """One episode of scripted agents in one world: ``ego`` plays agent 0, ``opponent`` every other agent.

    With ``ego == opponent`` both are the same class with the same parameters, so every agent is scripted
    alike (a planner plans for its own agents and treats all others as obstacles, whatever their number).
    ``scales`` are keyword arguments of the env's ``render`` (``pixels_per_cell`` or ``pixels_per_m``), one
    frame list each.
    """
    from torchrl.envs.utils import step_mdp

    from sidewalk.opponents.base import make_opponent
    from sidewalk.registry import OPPONENTS

    if "centralized" in (opponent, ego):
        raise ValueError(
            "'centralized' is a learner playing every agent: render a run folder trained with it instead"
        )
    if ego not in OPPONENTS:
        raise ValueError(f"--ego={ego!r} is not valid; valid: {', '.join(map(repr, OPPONENTS))}")
    world, core = scripted_world(domain, opponent, seed, overrides)
    others = tuple(agent for agent in range(core.n_agents) if agent != 0)
    # The configured parameters belong to the opponent's class; an ego of the same class gets them too.
    ego_params = world.opponent_params if ego == opponent else {}
    players = [
        make_opponent(ego, core, controlled=(0,), ego=others[0] if len(others) == 1 else None, **ego_params),
        make_opponent(opponent, core, controlled=others, ego=0, **world.opponent_params),
    ]
    # Grid positions are cells, one agent wide; continuous ones metres, an agent 2·radius wide.
    width = 1.0 if domain == "discrete" else 2 * core.params.agent_radius_m
    frames: list[list[np.ndarray]] = [[] for _ in scales]
    positions, present = [], []

    def record(agents) -> None:
        for scale, scale_frames in zip(scales, frames):
            scale_frames.append(core.render(0, **scale))
        positions.append(agents.get("state")[0, :, :2].numpy().astype(np.float64) / width)
        present.append(agents.get("present")[0, :, 0].numpy().copy())

    td = core.reset()
    record(td.get("agents"))
    for _ in range(core.params.max_steps + 1):
        for player in players:
            td = player(td)
        td = core.step(td)
        record(td.get(("next", "agents")))
        if bool(td.get(("next", "done")).all()):
            break
        td = step_mdp(td)
    info = td.get(("next", "agents", "info"))
    layout = core.layout
    size = (
        f"{layout.rows} × {layout.cols} cells"
        if domain == "discrete"
        else f"{layout.length_m:g} × {layout.width_m:g} m"
    )
    return Episode(
        frames=frames,
        positions=np.stack(positions),
        present=np.stack(present),
        outcome=outcome({key: info.get(key)[0].squeeze(-1) for key in info.keys()}),  # noqa: SIM118 (a TensorDict iterates rows)
        setting=f"{core.n_agents} agents, {size}",
    )


def rollout_scripted(
    domain: str, opponent: str, ego: str, seed: int, overrides: list[str]
) -> tuple[list[np.ndarray], str]:
    """Frames of one episode of scripted agents in one world (``play_scripted``), and its outcome in words."""
    episode = play_scripted(domain, opponent, ego, seed, overrides)
    return episode.frames[0], episode.outcome


def outcome(info: dict) -> str:
    """Each agent's outcome in words from its sticky info flags (one bool per agent)."""
    words = []
    for agent in range(len(next(iter(info.values())))):
        flags = [name for name in INFO_KEYS if bool(info[name][agent])]
        words.append(f"agent{agent}: {flags[0] if flags else 'running'}")
    return ", ".join(words)
