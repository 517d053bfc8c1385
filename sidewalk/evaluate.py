"""Evaluation: one episode in each of B batched worlds, and every metric below per agent and overall.

Metric names (every tool reads these keys): ``success_rate``, ``collision_rate`` (any), ``agent_collision_rate``,
``wall_collision_rate``, ``timeout_rate``, ``return``, ``episode_length``, ``path_efficiency``,
``min_separation``, ``wait_steps``, ``cost``, ``shield_rate`` (shielded views: the share of the agents' moving steps
whose action the shield replaced); per agent as ``agent0/success_rate``...; in an ego view also ``ego/...`` and
``other/...``; and for the whole team ``team/success_rate`` (every agent reached its goal), ``makespan`` and
``deadlock_rate``; in two-agent worlds the social measures of the pass, ``social/...`` (``sidewalk.social``).

Definitions: rates are fractions of episodes (per agent, or of agent-episodes for the overall figure); ``return``
is an agent's undiscounted episode return (its own reward, cooperative term included); ``cost`` its episode cost
(the sum of its safety cost ``("world", "cost")`` over the episode: with ``env.cost=collision`` 1 if it collided,
else 0; near misses add to it with ``env.cost=near_miss``); ``episode_length`` is
the world's episode length in steps (per agent: steps until that agent was done); ``path_efficiency`` is the
shortest distance from start to goal over the distance travelled, over agents that reached their goal (grid:
Manhattan cells, the shortest grid path; continuous: metres to the edge of the goal radius); ``min_separation`` is the smallest distance
between two agents in the world during the episode (grid: cells, Euclidean; continuous: centre to centre, m),
averaged over episodes, counting only agents present in the world (``("world", "present")``). ``episodes`` is the
number of worlds, ``distinct_episodes`` how many different trajectories they played: at noise 0 in a fixed layout
every world plays the same episode, so a rate is one episode's 0 or 1 and only seeds give it a spread. Such an
evaluation plays that episode once, in one world, and counts it for every world (``run_episodes``'s ``one_world``):
the same record, for the compute of one world.

The scenarios' coordination metrics (paper §7): ``makespan`` is the steps until the last agent arrived, over
episodes where every agent did (NaN if none did); ``deadlock_rate`` the fraction of episodes that timed out while no
unfinished agent moved more than ``DEADLOCK_CELLS`` cell (grid, Manhattan) / ``DEADLOCK_M`` m (continuous) from
where it ended, over its last ``DEADLOCK_WINDOW`` steps -- agents stuck, or stepping back and forth, in front of
each other; ``wait_steps`` the steps an agent stood still before it was done, where standing still means ending a
step where it was two steps before (grid: the same cell -- the grid has no stay action, so an agent waits by
stepping aside and back; continuous: within ``WAIT_M`` m).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from sidewalk.envs.base import INFO_KEYS, crashed
from sidewalk.social import SocialTally

DEADLOCK_WINDOW = 30  # steps
DEADLOCK_CELLS = 1
DEADLOCK_M = 0.5
WAIT_M = 0.1

RATE_OF = {
    "success_rate": "reached_goal",
    "agent_collision_rate": "collided_agent",
    "wall_collision_rate": "collided_wall",
    "timeout_rate": "timed_out",
}


@dataclass
class EpisodeRecord:
    """Raw per-episode outcomes of one evaluation, arrays of shape (episodes, N) unless stated."""

    info: dict[str, np.ndarray]
    returns: np.ndarray
    costs: np.ndarray  # (episodes, N): each agent's episode cost
    agent_length: np.ndarray
    world_length: np.ndarray  # (episodes,)
    travelled: np.ndarray
    shortest: np.ndarray
    min_separation: np.ndarray  # (episodes,), inf with a single agent
    wait_steps: np.ndarray | None = None  # (episodes, N)
    shielded: np.ndarray | None = None  # (episodes, N): steps whose action the shield replaced (shield=true views)
    deadlocked: np.ndarray | None = None  # (episodes,) bool
    trajectories: np.ndarray | None = None  # (T, k, N, 2) positions of the first k worlds, NaN once finished
    ego: int | None = None
    distinct_episodes: int | None = None  # how many different trajectories the worlds played
    social: dict[str, float] | None = None  # two-agent worlds: the social measures (sidewalk.social)
    extras: dict = field(default_factory=dict)


@torch.no_grad()
def run_episodes(
    env: EnvBase,
    policy: TensorDictModuleBase | None,
    *,
    seed: int | None = None,
    record_trajectories: int = 0,
    deterministic: bool = True,
    one_world: Callable[[], EnvBase] | None = None,
    epsilon: float = 0.0,
) -> EpisodeRecord:
    """Play one episode in every world of ``env`` (an ego or centralized view, B worlds = B episodes).

    ``policy`` acts deterministically (greedy / distribution mode), so it runs once per distinct input
    (``act_on_distinct``); a policy that samples whatever the context (a collection policy) needs
    ``deterministic=False``, so that every world draws its own action. ``None`` plays uniformly random actions.
    ``seed`` reseeds the env first, so repeated evaluations see the same noise and opponent draws.

    ``one_world`` builds ``env`` with one world (the same config and seed). Where every world of ``env`` starts
    alike and ``policy`` is deterministic, that world plays the episode alone, and if neither its reset nor a step
    drew a random number, every world of ``env`` plays it too: it is counted for all of them (the record is the one
    the B worlds give). At the first draw the B worlds play instead, as without ``one_world``.

    ``epsilon`` > 0 (an evaluation protocol's ``eval.epsilon``): at every step each entry of the learner's action (each
    agent's, in a self-play view; the joint action in a centralized one) is replaced by a uniform random action with
    this probability, drawn from a generator seeded by ``seed``, as the DQN literature evaluates (Mnih et al. 2015 at
    0.05): a greedy pair of one policy otherwise mirrors itself in a standoff to the time limit.
    """
    if not 0.0 <= epsilon < 1.0:
        raise ValueError(f"epsilon={epsilon!r} is out of range; valid: [0, 1)")
    if seed is not None:
        env.set_seed(seed)
    td = env.reset()
    explore = _Exploration(env, epsilon, seed) if epsilon > 0 and policy is not None else None
    if (one_world is not None and seed is not None and deterministic and policy is not None and explore is None
            and _worlds_alike(td)):
        record = _played_once(one_world, policy, seed, td, record_trajectories, env.device)
        if record is not None:
            return record
    tally = _EpisodeTally.begin(env, td.get("world"), record_trajectories)
    _play(env, policy, td, tally, deterministic, explore=explore)
    return tally.record(ego=getattr(env, "ego", None))


class _Exploration:
    """``epsilon``-greedy on the learner's action key of ``env``: each entry replaced by a uniform random action with
    probability ``epsilon``, drawn from its own generator (seeded by the evaluation's seed), so the env's draws stay
    the same as a greedy evaluation's."""

    def __init__(self, env: EnvBase, epsilon: float, seed: int | None) -> None:
        self.epsilon = epsilon
        self.key = env.action_key
        self.spec = env.full_action_spec[self.key]
        self.generator = torch.Generator(device=env.device)
        self.generator.manual_seed(0 if seed is None else seed)

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        action = td.get(self.key)
        continuous = action.dtype.is_floating_point  # an action is its last axis (acceleration, turn rate)
        chosen = action.shape[:-1] if continuous else action.shape
        explore = torch.rand(chosen, generator=self.generator, device=action.device) < self.epsilon
        if continuous:  # uniform within the bounds
            low, high = self.spec.space.low, self.spec.space.high
            uniform = low + (high - low) * torch.rand(action.shape, generator=self.generator, device=action.device)
            explore = explore.unsqueeze(-1)
        else:
            uniform = torch.randint(0, self.spec.space.n, action.shape, generator=self.generator, device=action.device)
        td.set(self.key, torch.where(explore, uniform, action))
        return td


def _play(
    env: EnvBase,
    policy: TensorDictModuleBase | None,
    td: TensorDictBase,
    tally: _EpisodeTally,
    deterministic: bool,
    draws: _RandomDraws | None = None,
    explore: _Exploration | None = None,
) -> bool:
    """Step ``env`` from its reset ``td`` until every world's episode has ended, each step added to ``tally``; with
    ``draws``, stop at the first step that drew a random number and return False."""
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for step in range(env.core.params.max_steps + 1):
            if policy is None:
                td = env.rand_action(td)
            else:
                td = act_on_distinct(policy, td, ~tally.finished) if deterministic else policy(td)
                if explore is not None:
                    td = explore(td)
            td = env.step(td)
            if draws is not None and draws.happened():
                return False
            nxt = td.get("next")
            tally.add_step(step, nxt.get("world"), nxt.get("done").squeeze(-1))
            if bool(tally.finished.all()):
                break
            td = step_mdp(td)
    return True


def _worlds_alike(td: TensorDictBase) -> bool:
    """Whether the worlds of ``td`` (batch (B,), B > 1) all hold what the first one does, entry for entry."""
    values = list(td.values(include_nested=True, leaves_only=True))
    return td.batch_size[0] > 1 and all(torch.is_tensor(value) and bool((value == value[:1]).all()) for value in values)


class _RandomDraws:
    """Whether a random number was drawn since it was made: from ``env``'s generators, through which the envs, views
    and opponents draw everything, or from torch's global ones (a policy that samples)."""

    def __init__(self, env: EnvBase) -> None:
        self.generators = [*env.core.generators, *_global_generators(env.device)]
        self.states = [generator.get_state() for generator in self.generators]

    def happened(self) -> bool:
        return any(not torch.equal(g.get_state(), state) for g, state in zip(self.generators, self.states))


def _global_generators(device: torch.device | str) -> list[torch.Generator]:
    """torch's global generators a computation on ``device`` may draw from."""
    device = torch.device(device)
    if device.type == "cuda":
        return [torch.default_generator, torch.cuda.default_generators[device.index or torch.cuda.current_device()]]
    return [torch.default_generator]


def _played_once(
    one_world: Callable[[], EnvBase],
    policy: TensorDictModuleBase,
    seed: int,
    td: TensorDictBase,
    record_trajectories: int,
    device: torch.device | str,
) -> EpisodeRecord | None:
    """The record of the B worlds (on ``device``) whose alike reset is ``td``, from one world's episode; None where
    that world resets otherwise or draws a random number. torch's global generators are left as they were."""
    kept = [(generator, generator.get_state()) for generator in _global_generators(device)]
    try:
        env = one_world()
        env.set_seed(seed)
        draws = _RandomDraws(env)
        alone = env.reset()
        if draws.happened() or not _same_world(alone, td):
            return None
        tally = _EpisodeTally.begin(env, alone.get("world"), min(record_trajectories, 1))
        if not _play(env, policy, alone, tally, deterministic=True, draws=draws):
            return None
        return _for_every_world(tally.record(ego=getattr(env, "ego", None)), td.batch_size[0], record_trajectories)
    finally:
        for generator, state in kept:
            generator.set_state(state)


def _same_world(alone: TensorDictBase, td: TensorDictBase) -> bool:
    """Whether ``alone`` (one world) holds what the first world of ``td`` does, entry for entry."""
    keys = set(alone.keys(include_nested=True, leaves_only=True))
    if keys != set(td.keys(include_nested=True, leaves_only=True)):
        return False
    return all(torch.equal(alone.get(key), td.get(key)[:1]) for key in keys)


def _for_every_world(record: EpisodeRecord, worlds: int, record_trajectories: int) -> EpisodeRecord:
    """``record`` of one world's episode as the record of ``worlds`` worlds that all played it."""
    changes: dict = {"info": {key: np.repeat(value, worlds, axis=0) for key, value in record.info.items()}}
    for entry in dataclasses.fields(record):
        value = getattr(record, entry.name)
        if entry.name == "trajectories" and value is not None:  # (T, k, N, 2): the first k worlds
            changes[entry.name] = np.repeat(value, min(record_trajectories, worlds), axis=1)
        elif entry.name != "trajectories" and isinstance(value, np.ndarray):  # (episodes, ...)
            changes[entry.name] = np.repeat(value, worlds, axis=0)
    return dataclasses.replace(record, **changes)


def _positions(world: TensorDictBase) -> torch.Tensor:
    """Float (B, N, 2): the agents' positions (grid: row, col; continuous: x, y)."""
    return world.get("state")[..., :2].to(torch.float32)


@dataclass
class _EpisodeTally:
    """What ``run_episodes`` adds up as the episodes run, per world (B,) or per agent (B, N); ``record`` turns it
    into an ``EpisodeRecord``."""

    grid: bool
    shortest: torch.Tensor
    finished: torch.Tensor  # (B,): the world's episode has ended
    returns: torch.Tensor
    costs: torch.Tensor
    shielded: torch.Tensor | None  # None: the view has no shield
    travelled: torch.Tensor
    agent_length: torch.Tensor
    world_length: torch.Tensor
    min_separation: torch.Tensor
    final_info: dict[str, torch.Tensor]
    previous: torch.Tensor  # positions one step back
    two_back: torch.Tensor  # positions two steps back (waiting)
    recent: torch.Tensor  # the last ``DEADLOCK_WINDOW`` positions, as a ring (deadlocks)
    wait_steps: torch.Tensor
    deadlocked: torch.Tensor
    pair: torch.Tensor  # (N, N): two different agents
    record_trajectories: int
    trajectory: list[np.ndarray]
    episode_class: torch.Tensor  # (B,): worlds with one class have played the same trajectory so far
    social: SocialTally | None  # two-agent worlds only

    @classmethod
    def begin(cls, env: EnvBase, world: TensorDictBase, record_trajectories: int) -> _EpisodeTally:
        """Nothing added yet, for ``env`` just reset to ``world`` (the reset's ``"world"`` entry)."""
        core = env.core
        n_worlds, n_agents, device = core.num_envs, core.n_agents, env.device
        grid = not torch.is_floating_point(core.observation_spec["agents", "state"].zero())
        start = _positions(world)
        goal = world.get("goal").to(torch.float32)
        # The continuous agent arrives anywhere within the goal radius, so its shortest path is that much shorter.
        shortest = (
            (goal - start).abs().sum(-1) if grid
            else ((goal - start).norm(dim=-1) - core.params.goal_radius_m).clamp(min=0)
        )

        def per_agent() -> torch.Tensor:
            return torch.zeros(n_worlds, n_agents, device=device)

        return cls(
            grid=grid,
            shortest=shortest,
            finished=torch.zeros(n_worlds, dtype=torch.bool, device=device),
            returns=per_agent(),
            costs=per_agent(),
            shielded=per_agent() if getattr(env, "shield", False) else None,
            travelled=per_agent(),
            agent_length=per_agent(),
            world_length=torch.zeros(n_worlds, device=device),
            min_separation=torch.full((n_worlds,), math.inf, device=device),
            final_info={key: torch.zeros(n_worlds, n_agents, dtype=torch.bool, device=device) for key in INFO_KEYS},
            previous=start,
            two_back=start,
            recent=start.unsqueeze(0).repeat(min(DEADLOCK_WINDOW, core.params.max_steps), 1, 1, 1),
            wait_steps=per_agent(),
            deadlocked=torch.zeros(n_worlds, dtype=torch.bool, device=device),
            pair=~torch.eye(n_agents, dtype=torch.bool, device=device),
            record_trajectories=record_trajectories,
            trajectory=[start[:record_trajectories].cpu().numpy()] if record_trajectories else [],
            episode_class=distinct_rows(start.flatten(1))[1],
            social=SocialTally.begin(world.get("state"), goal, grid, getattr(core.params, "dt_s", 1.0),
                                     getattr(core.params, "agent_radius_m", 0.5)) if n_agents == 2 else None,
        )

    def add_step(self, step: int, world: TensorDictBase, done: torch.Tensor) -> None:
        """Add step ``step`` (from 0), whose ``"world"`` entry is ``world`` and whose worlds ``done`` (B,) ended."""
        running = ~self.finished
        was_active = ~(self.final_info["reached_goal"] | crashed(self.final_info))
        now = _positions(world)
        live = running.unsqueeze(-1)
        info = {key: world.get(("info", key)).squeeze(-1) for key in INFO_KEYS}
        self._add_totals(world, now, running, was_active)
        self._add_waiting(step, now, was_active & live & ~info["reached_goal"])
        if self.pair.shape[0] > 1:
            self._add_separation(now, world.get("present").squeeze(-1), running)
        if self.social is not None:
            present = world.get("present").squeeze(-1).bool()
            # The pair's first collision: an agent-agent collision flag that was not set before this step.
            collided = (info["collided_agent"] & ~self.final_info["collided_agent"]).any(-1) & running
            self.social.add_step(world.get("state"), was_active & live & present, collided)
        for key in INFO_KEYS:
            self.final_info[key] = torch.where(live, info[key], self.final_info[key])
        if self.record_trajectories:
            frame = now[: self.record_trajectories].clone()
            frame[self.finished[: self.record_trajectories]] = float("nan")
            self.trajectory.append(frame.cpu().numpy())
        self.previous = now
        # A world's class: its class so far and where its agents are now (a finished world's trajectory is over).
        key = torch.cat([self.episode_class.unsqueeze(-1).to(now.dtype), now.flatten(1) * live], dim=-1)
        self.episode_class = distinct_rows(key)[1]
        ending = running & done
        if bool(ending.any()):
            self._add_deadlocks(step, now, ending, info["timed_out"])
        self.finished = self.finished | done

    def _add_totals(
        self, world: TensorDictBase, now: torch.Tensor, running: torch.Tensor, was_active: torch.Tensor
    ) -> None:
        """Each running world's rewards, costs, shield interventions, distance travelled and steps."""
        live = running.unsqueeze(-1)
        self.returns += world.get("reward").squeeze(-1) * live
        self.costs += world.get("cost").squeeze(-1) * live
        if self.shielded is not None:
            self.shielded += world.get("shield").squeeze(-1) * live
        self.travelled += _distance(now, self.previous, self.grid) * live
        self.agent_length += (was_active & live).float()
        self.world_length += running.float()

    def _add_waiting(self, step: int, now: torch.Tensor, counted: torch.Tensor) -> None:
        """A wait step for the ``counted`` agents that ended the step where they were two steps before; the
        positions two steps back and in the deadlock ring move on."""
        stood = _distance(now, self.two_back, self.grid) <= (0.0 if self.grid else WAIT_M)
        self.wait_steps += (stood & counted).float()
        self.two_back, self.recent[step % self.recent.shape[0]] = self.previous, now

    def _add_separation(self, now: torch.Tensor, in_world: torch.Tensor, running: torch.Tensor) -> None:
        """The smallest distance between two agents in each running world so far."""
        gaps = torch.cdist(now, now)
        both = in_world.unsqueeze(-1) & in_world.unsqueeze(-2) & self.pair
        closest = torch.where(both, gaps, torch.full_like(gaps, math.inf)).flatten(1).min(-1).values
        self.min_separation = torch.where(running, torch.minimum(self.min_separation, closest), self.min_separation)

    def _add_deadlocks(self, step: int, now: torch.Tensor, ending: torch.Tensor, timed_out: torch.Tensor) -> None:
        """Deadlocked: the world timed out while every unfinished agent stayed near where it ended."""
        still_within = DEADLOCK_CELLS if self.grid else DEADLOCK_M
        spread = _distance(self.recent, now.unsqueeze(0), self.grid).amax(0)  # (B, N)
        stuck = ((spread <= still_within) | ~timed_out).all(-1) & timed_out.any(-1)
        self.deadlocked |= ending & stuck & (step + 1 >= self.recent.shape[0])

    def record(self, ego: int | None) -> EpisodeRecord:
        """The episodes' outcomes as NumPy arrays."""
        return EpisodeRecord(
            info={key: value.cpu().numpy() for key, value in self.final_info.items()},
            returns=self.returns.cpu().numpy(),
            costs=self.costs.cpu().numpy(),
            agent_length=self.agent_length.cpu().numpy(),
            world_length=self.world_length.cpu().numpy(),
            travelled=self.travelled.cpu().numpy(),
            shortest=self.shortest.cpu().numpy(),
            min_separation=self.min_separation.cpu().numpy(),
            wait_steps=self.wait_steps.cpu().numpy(),
            shielded=self.shielded.cpu().numpy() if self.shielded is not None else None,
            deadlocked=self.deadlocked.cpu().numpy(),
            trajectories=np.stack(self.trajectory) if self.record_trajectories else None,
            ego=ego,
            distinct_episodes=int(self.episode_class.max()) + 1,
            social=self.social.summary(ego) if self.social is not None else None,
        )


def _distance(a: torch.Tensor, b: torch.Tensor, grid: bool) -> torch.Tensor:
    """Manhattan cells in the grid, metres in the continuous world, over the last axis (x, y)."""
    return (a - b).abs().sum(-1) if grid else (a - b).norm(dim=-1)


def act_on_distinct(policy: TensorDictModuleBase, td: TensorDictBase, running: torch.Tensor) -> TensorDictBase:
    """Write ``policy``'s deterministic outputs for the ``running`` worlds of ``td``, computed once per distinct
    input: an evaluation costs what its distinct episodes cost, not what its batch size does.

    Finished worlds (still stepped by the batched env, their outcome already recorded) get the outputs of the first
    running world, a valid action that is never scored. At noise 0 the 256 evaluation worlds of the grid play one
    episode, so the policy runs on one image instead of 256 (the conv stack is most of an evaluation step); with
    distinct inputs it costs a ``torch.unique`` more. A deterministic policy gives equal
    outputs for equal inputs, so this changes no result beyond floating-point differences between batch sizes.
    """
    in_keys = list(policy.in_keys)
    if not in_keys:  # reads no input (a fixed action): nothing to share
        return policy(td)
    rows = running.nonzero().squeeze(-1)
    if rows.numel() == 0:
        rows = torch.zeros(1, dtype=torch.long, device=running.device)
    inputs = td.select(*in_keys)[rows]
    flat = torch.cat([inputs.get(key).reshape(rows.numel(), -1).to(torch.float64) for key in in_keys], dim=-1)
    first_of, inverse = distinct_rows(flat)
    outputs = policy(inputs[first_of])
    # Every world gets the output of its distinct row; finished worlds that of the first running world.
    of_world = torch.zeros(td.batch_size[0], dtype=torch.long, device=running.device)
    of_world[rows] = inverse
    for key in policy.out_keys:
        td.set(key, outputs.get(key)[of_world])
    return td


def distinct_rows(flat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(the first row of each distinct row of ``flat`` (B, D), the distinct row of every row), exactly: the distinct
    rows in ``torch.unique(dim=0)``'s order, and ``inverse.max() + 1`` of them. Evaluation counts its distinct
    episodes and inputs with it, cross-play its players' distinct observations (``sidewalk.crossplay``)."""
    if bool((flat == flat[:1]).all()):  # noise 0, deterministic players: every world plays the same episode
        return torch.zeros(1, dtype=torch.long, device=flat.device), flat.new_zeros(flat.shape[0], dtype=torch.long)
    distinct, inverse = torch.unique(flat, dim=0, return_inverse=True)
    first_of = torch.full((distinct.shape[0],), flat.shape[0], dtype=torch.long, device=flat.device)
    first_of.scatter_reduce_(0, inverse, torch.arange(flat.shape[0], device=flat.device), reduce="amin")
    return first_of, inverse


def _group_metrics(record: EpisodeRecord, agents: list[int]) -> dict[str, float]:
    """Rates and means over the given agents' episodes."""
    out = {name: float(record.info[key][:, agents].mean()) for name, key in RATE_OF.items()}
    collided = crashed(record.info)[:, agents]
    out["collision_rate"] = float(collided.mean())
    out["return"] = float(record.returns[:, agents].mean())
    out["cost"] = float(record.costs[:, agents].mean())
    out["episode_length"] = float(record.agent_length[:, agents].mean())
    reached = record.info["reached_goal"][:, agents]
    efficiency = record.shortest[:, agents] / np.maximum(record.travelled[:, agents], 1e-9)
    out["path_efficiency"] = float(efficiency[reached].mean()) if reached.any() else float("nan")
    if record.wait_steps is not None:
        out["wait_steps"] = float(record.wait_steps[:, agents].mean())
    if record.shielded is not None:  # of the steps the agents moved, the share the shield corrected
        out["shield_rate"] = float(record.shielded[:, agents].sum() / max(record.agent_length[:, agents].sum(), 1.0))
    return out


def summarize(record: EpisodeRecord) -> dict[str, float]:
    """Every metric of the module docstring as flat keys: overall, ``agent{i}/``, ``ego/`` and ``other/`` (ego views),
    ``team/success_rate``, and ``episodes``."""
    n_agents = record.returns.shape[1]
    metrics = _group_metrics(record, list(range(n_agents)))
    metrics["episode_length"] = float(record.world_length.mean())
    finite = record.min_separation[np.isfinite(record.min_separation)]
    metrics["min_separation"] = float(finite.mean()) if finite.size else float("nan")
    team_success = record.info["reached_goal"].all(1)
    metrics["team/success_rate"] = float(team_success.mean())
    metrics["makespan"] = float(record.agent_length[team_success].max(1).mean()) if team_success.any() else float("nan")
    if record.deadlocked is not None:
        metrics["deadlock_rate"] = float(record.deadlocked.mean())
    metrics["episodes"] = float(record.returns.shape[0])
    if record.distinct_episodes is not None:
        metrics["distinct_episodes"] = float(record.distinct_episodes)
    metrics.update(record.social or {})
    for agent in range(n_agents):
        for name, value in _group_metrics(record, [agent]).items():
            metrics[f"agent{agent}/{name}"] = value
    if record.ego is not None:
        others = [a for a in range(n_agents) if a != record.ego]
        for prefix, agents in (("ego", [record.ego]), ("other", others)):
            if not agents:  # a scenario of one agent has no other
                continue
            for name, value in _group_metrics(record, agents).items():
                metrics[f"{prefix}/{name}"] = value
    return metrics


def evaluate(
    env: EnvBase,
    policy: TensorDictModuleBase | None,
    *,
    seed: int | None = None,
    deterministic: bool = True,
    one_world: Callable[[], EnvBase] | None = None,
    epsilon: float = 0.0,
) -> dict[str, float]:
    """Metrics of one episode in each of ``env``'s worlds under ``policy`` (see ``summarize``; ``deterministic``,
    ``one_world`` and ``epsilon`` as in ``run_episodes``)."""
    return summarize(run_episodes(env, policy, seed=seed, deterministic=deterministic, one_world=one_world,
                                  epsilon=epsilon))


def train_metrics(batch: TensorDictBase, ego: int | None) -> dict[str, float]:
    """Outcomes of the episodes that ended inside one collected batch, and the safety cost the learner paid in it.

    ``train/cost`` counts every step of the batch, finished episodes or not: the cost the learner's agents (the ego
    in an ego view, every agent otherwise) paid while learning -- the numerator of Safety Gym's training cost rate.
    """
    cost = batch.get(("next", "world", "cost"))  # (..., N, 1)
    learner_cost = cost.select(-2, ego) if ego is not None else cost
    done = batch.get(("next", "done")).squeeze(-1)
    episodes = int(done.sum())
    metrics: dict[str, float] = {"train/episodes": float(episodes), "train/cost": float(learner_cost.sum())}
    shielded = batch.get(("next", "world", "shield"), None)
    if shielded is not None:  # shield=true: the fraction of the learner's steps whose action the shield replaced
        learner_shielded = shielded.select(-2, ego) if ego is not None else shielded
        metrics["train/shield_rate"] = float(learner_shielded.float().mean())
    if episodes == 0:
        return metrics
    reached = batch.get(("next", "world", "info", "reached_goal")).squeeze(-1)[done]  # (episodes, N)
    collided = crashed(batch.get(("next", "world", "info"))).squeeze(-1)[done]
    episode_reward = batch.get(("next", "episode_reward"), None)
    if episode_reward is None:  # self-play: every agent's own return, averaged over the agents
        episode_reward = batch.get(("next", "agents", "episode_reward")).mean(-2)
    metrics["train/return"] = float(episode_reward.squeeze(-1)[done].mean())
    metrics["train/success_rate"] = float(reached.float().mean())
    metrics["train/team_success_rate"] = float(reached.all(-1).float().mean())
    if ego is not None:
        metrics["train/ego_success_rate"] = float(reached[:, ego].float().mean())
        metrics["train/ego_collision_rate"] = float(collided[:, ego].float().mean())
    return metrics
