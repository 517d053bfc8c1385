"""A learned partner: the frozen policy of a finished run playing some agents of a Sidewalk env (``opponent=policy``).

``PolicyOpponent(env, controlled, ego, path=RUN_DIR)`` rebuilds the learner saved in ``RUN_DIR/policy.pt`` (written
by every run at each checkpoint and at the end: the networks plus the description of the world they were trained
on) and plays the ``controlled`` agents with its evaluation policy (greedy / the distribution's mode), or with its
collection policy (``sample=True``). Every learner can be a partner:

- a multi-agent (self-play) learner plays any agent: it was trained as every agent, on their ego-centric
  observations;
- a centralized learner plans the joint action from agent 0's observation (it shows every agent); the partner
  plays its plan for the agents it controls;
- a single-agent learner trained as agent ``e`` plays agent ``e`` as it was trained; it plays another agent ``j``
  where the scenario makes the two roles the same game: in a random layout every role is drawn alike (its
  ego-centric observation is all it needs), and in a two-agent layout that a half turn maps onto itself with
  agent ``e``'s start and goal onto agent ``j``'s (the paper's sidewalk) it sees ``j``'s observation turned by
  half a turn and its action is turned back (grid: UP↔DOWN, LEFT↔RIGHT; continuous: acceleration and turn rate
  are unchanged by a rotation).

``check_partner`` runs the checks before any compute (``sidewalk.config.validate`` calls it): the folder holds a
policy, and it was trained in this domain and scenario with the same observation (or one the env computes for it,
``PARTNER_OBSERVATIONS``: a grid partner trained on vectors plays in an image world); noise, rewards, the time limit,
what happens to crashed agents and how far starts and goals were moved may differ. Anything else raises ``PartnerMismatch`` naming the differences.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from sidewalk.envs.base import AGENT_GROUP, SidewalkEnvBase
from sidewalk.opponents.base import ACTION_KEY, Opponent, env_domain
from sidewalk.symmetry import turn_observation

OBSERVATION_KEY = (AGENT_GROUP, "observation")
# Settings a partner may have been trained under differently: they change the game's payoffs, noise or where its
# episodes start (the jitter of an evaluation protocol), not what an observation means or what an action does.
MAY_DIFFER = ("noise", "rewards", "max_steps", "remove_crashed", "check_actions", "start_jitter_rows",
              "goal_jitter_rows", "start_jitter_m", "goal_jitter_m", "heading_jitter_rad")
GRID_HALF_TURN_ACTIONS = (1, 0, 3, 2)  # UP, DOWN, LEFT, RIGHT turned by half a turn: DOWN, UP, RIGHT, LEFT


class PartnerMismatch(ValueError):
    """A partner run that cannot play in this world (the message names what differs)."""


@dataclass
class Partner:
    """What a run folder's ``policy.pt`` says about its learner: enough to rebuild it on its own world."""

    path: Path
    algo_name: str
    algo_config: Any  # the learner's Config dataclass
    domain: str
    env_params: Any  # DiscreteParams | ContinuousParams
    opponent: str  # what it trained against: a scripted opponent, "centralized", "self", "policy"
    ego: int | None  # the agent it played (single-agent learners); None: every agent
    state: dict[str, Any]  # the learner's policy state (``Algorithm.load_policy_state_dict``)

    @property
    def plays_every_agent(self) -> bool:
        return self.opponent in ("self", "centralized")

    @property
    def label(self) -> str:
        if self.opponent in ("self", "centralized"):
            return f"{self.algo_name} {'self-play' if self.opponent == 'self' else 'centralized'}"
        return f"{self.algo_name} vs {self.opponent}"


def policy_description(experiment: Any) -> dict[str, Any]:
    """The part of ``policy.pt`` that says which world its networks were trained on (see ``read_partner``)."""
    return {
        "algo_name": experiment.algo.name,
        "algo": dataclasses.asdict(experiment.algo),
        "domain": experiment.domain,
        "env_params": dataclasses.asdict(experiment.env_params),
        "opponent": experiment.opponent,
        "ego": experiment.ego,
    }


def saved_description(run_dir: str | Path) -> dict[str, Any]:
    """``policy_description`` of a run folder from before ``policy.pt`` described its world, from its ``config.yaml``."""
    from omegaconf import OmegaConf

    from sidewalk.run_folder import read_saved_config
    from sidewalk.schema import env_params_of

    cfg = read_saved_config(run_dir)
    return {
        "algo_name": cfg.algo.name,
        "algo": dataclasses.asdict(OmegaConf.to_object(cfg.algo)),
        "domain": cfg.env.domain,
        "env_params": dataclasses.asdict(env_params_of(cfg)),
        "opponent": cfg.opponent.name,
        "ego": cfg.opponent.ego,
    }


def read_partner(path: str | Path, map_location: str | torch.device = "cpu") -> Partner:
    """The learner saved in the run folder ``path`` (its ``policy.pt``; a folder from before ``policy.pt``
    described itself is read through its ``config.yaml``). Raises ``FileNotFoundError`` naming what is missing, and
    ``GroupFolderGiven`` naming the seeds' folders of a group folder."""
    from sidewalk.envs.grid import DiscreteParams
    from sidewalk.envs.rewards import RewardParams
    from sidewalk.envs.unicycle import ContinuousParams
    from sidewalk.registry import LEARNERS
    from sidewalk.run_folder import POLICY, one_run_folder, policy_file, read_torch_file

    run_dir = Path(path)
    if not str(path):
        raise FileNotFoundError("opponent=policy needs opponent.path=RUN_DIR: the run folder of the partner's policy")
    if not run_dir.is_dir():
        raise FileNotFoundError(f"opponent.path={str(path)!r} is not a folder; give a run folder with a {POLICY}")
    one_run_folder(run_dir, f"opponent.path={str(path)!r}")  # a partner is one policy: a group folder names its seeds'
    file = policy_file(run_dir)
    if file is None:
        raise FileNotFoundError(
            f"opponent.path={str(path)!r} has no {POLICY}: the run has not written one yet (it does at its first "
            "checkpoint and at the end)"
        )
    state = read_torch_file(file, map_location=map_location, mmap=file.name != POLICY)
    if file.name != POLICY:  # a run from before policy.pt was written at checkpoints: its checkpoint's learner
        state = state["algorithm"]
    described = state.get("description")
    if described is None:  # written before policy.pt described its world: the folder's config.yaml does
        described = saved_description(run_dir)
    algo_cls = LEARNERS[described["algo_name"]]
    algo_config = algo_cls.Config(**described["algo"])
    params = dict(described["env_params"])
    params["rewards"] = RewardParams(**params["rewards"])
    params_cls = DiscreteParams if described["domain"] == "discrete" else ContinuousParams
    return Partner(
        path=run_dir,
        algo_name=described["algo_name"],
        algo_config=algo_config,
        domain=described["domain"],
        env_params=params_cls(**params),
        opponent=described["opponent"],
        ego=None if described["opponent"] in ("self", "centralized") else described["ego"],
        state=state,
    )


def _env_class(domain: str) -> type[SidewalkEnvBase]:
    from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv

    return DiscreteSidewalkEnv if domain == "discrete" else ContinuousSidewalkEnv


def check_partner(path: str | Path, domain: str, env_params: Any, ego: int | None, controlled=None) -> Partner:
    """The partner in ``path``, checked to play the agents ``controlled`` (default: all but ``ego``) of a world of
    ``domain`` with ``env_params``; raises ``FileNotFoundError`` or ``PartnerMismatch`` naming what is wrong."""
    partner = read_partner(path)
    shown = f"opponent.path={str(path)!r}"
    if partner.domain != domain:
        raise PartnerMismatch(
            f"{shown} was trained in the {partner.domain} domain (env={partner.domain}); this run is env={domain}"
        )
    differ = []
    for f in dataclasses.fields(env_params):
        if f.name in MAY_DIFFER:
            continue
        theirs, ours = getattr(partner.env_params, f.name), getattr(env_params, f.name)
        if f.name == "observation" and theirs in _env_class(domain).PARTNER_OBSERVATIONS:
            continue  # the env computes the partner's own observation for it (PolicyOpponent)
        if theirs != ours:
            differ.append(f"env.{f.name}={theirs!r} (this run: {ours!r})")
    if differ:
        raise PartnerMismatch(
            f"{shown} was trained on another world: {', '.join(differ)}. A partner must share the domain, scenario "
            f"and observation (or have one the env computes for it: {_env_class(domain).PARTNER_OBSERVATIONS}); only "
            f"{', '.join(MAY_DIFFER)} may differ"
        )
    n_agents = _env_class(domain).layout_for(env_params).n_agents
    if controlled is None:
        controlled = [agent for agent in range(n_agents) if agent != ego]
    if not partner.plays_every_agent:
        for agent in controlled:
            if agent != partner.ego and role_map(domain, env_params, partner.ego, agent) is None:
                raise PartnerMismatch(
                    f"{shown} was trained as agent {partner.ego} (opponent.ego={partner.ego}) and cannot play agent "
                    f"{agent} in env.layout={env_params.layout!r}: no symmetry of that scenario maps one role onto "
                    f"the other. Train the partner with opponent.ego={agent}, or use a self-play partner (opponent=self)"
                )
    return partner


def check_partner_of(experiment: Any) -> Partner | None:
    """For ``opponent=policy``, the partner of a validated experiment, checked (``check_partner``) before any compute:
    the runner calls it beside ``validate``, which opens no file. None for any other opponent."""
    if experiment.opponent != "policy":
        return None
    return check_partner(experiment.opponent_params["path"], experiment.domain, experiment.env_params, experiment.ego)


def role_map(domain: str, env_params: Any, trained: int, plays: int) -> str | None:
    """How a learner trained as agent ``trained`` sees the game of agent ``plays``: ``"same"`` (the roles are drawn
    alike: a random layout, or the same agent), ``"half_turn"`` (a two-agent layout a half turn maps onto itself
    and ``trained``'s start and goal onto ``plays``'s), or None (no map)."""
    if trained == plays:
        return "same"
    layout = _env_class(domain).layout_for(env_params)
    layout = getattr(layout, "nominal", layout)  # jittered starts: their symmetry is the nominal layout's
    if not layout.fixed:
        return "same"
    if layout.n_agents != 2:
        return None
    if domain == "discrete":
        def turn(cell):
            return (layout.rows - 1 - cell[0], layout.cols - 1 - cell[1])

        symmetric = {turn(cell) for cell in layout.blocked} == set(layout.blocked)
        maps = turn(layout.starts[trained]) == layout.starts[plays] and turn(layout.goals[trained]) == layout.goals[plays]
    else:
        def turn(point):
            return (layout.length_m - point[0], layout.width_m - point[1])

        def close(a, b):
            return all(math.isclose(x, y, abs_tol=1e-9) for x, y in zip(a, b))

        boxes = {(round(x0, 9), round(y0, 9), round(x1, 9), round(y1, 9)) for x0, y0, x1, y1 in layout.boxes}
        turned = {
            (round(layout.length_m - x1, 9), round(layout.width_m - y1, 9),
             round(layout.length_m - x0, 9), round(layout.width_m - y0, 9))
            for x0, y0, x1, y1 in layout.boxes
        }
        heading_gap = (layout.headings[trained] + math.pi - layout.headings[plays]) % (2 * math.pi)
        symmetric = boxes == turned
        maps = (
            close(turn(layout.starts[trained]), layout.starts[plays])
            and close(turn(layout.goals[trained]), layout.goals[plays])
            and min(heading_gap, 2 * math.pi - heading_gap) < 1e-9
        )
    return "half_turn" if symmetric and maps else None


class PolicyOpponent(Opponent):
    """The frozen policy of the run folder ``path`` playing the ``controlled`` agents (see the module docstring).

    It reads the agents' observations, ``("agents", "observation")``, from the env's last output (the views pass
    the core's) and writes their actions to ``("agents", "action")``.
    """

    name = "policy"
    scripted = False
    per_replica = False  # a frozen network, built from the run folder, not from the env's seed

    def __init__(
        self,
        env: SidewalkEnvBase,
        controlled=(1,),
        ego: int | None = 0,
        path: str | Path = "",
        sample: bool = False,
    ) -> None:
        super().__init__(env, controlled=controlled, ego=ego)
        if not isinstance(sample, bool):
            raise TypeError(f"sample={sample!r} must be a bool")
        self.partner = check_partner(path, env_domain(env), env.params, ego, self.controlled)
        self.sample = sample
        self.in_keys = [OBSERVATION_KEY]
        self._policy, self._decode = self._rebuild(self.partner, env, sample)
        self._maps = [role_map(self.partner.domain, env.params, self.partner.ego, agent) if self.partner.ego is not None
                      else "same" for agent in self.controlled]
        # A partner trained on another observation kind (a grid vector in an image world) sees its own, from the env.
        own = getattr(self.partner.env_params, "observation", None)
        self._own_observation = own if own != getattr(env.params, "observation", None) else None
        if self._own_observation is not None:
            self.in_keys = list(type(env).PARTNER_OBSERVATION_KEYS)

    @staticmethod
    def _rebuild(partner: Partner, env: SidewalkEnvBase, sample: bool):
        """The partner's policy module, built on a one-world view of the world it trained on (so every spec is
        the one training saw), and the joint-action decoder of a centralized partner."""
        from torchrl.envs import RewardSum, TransformedEnv

        from sidewalk.registry import LEARNERS
        from sidewalk.views import view_for_opponent

        core = _env_class(partner.domain)(1, device=env.device, seed=0, params=partner.env_params)
        # The networks need only the view's specs: a random opponent stands in for whom an ego learner trained against.
        view = view_for_opponent(core, partner.opponent if partner.plays_every_agent else "random", partner.ego or 0)
        algo = LEARNERS[partner.algo_name](partner.algo_config, TransformedEnv(view, RewardSum()), device=env.device)
        algo.load_policy_state_dict(partner.state)
        policy = algo.collection_policy() if sample else algo.evaluation_policy()
        decode = view.decode_action if partner.opponent == "centralized" and partner.domain == "discrete" else None
        return policy, decode

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self._own_observation is None:
            observation = tensordict.get(OBSERVATION_KEY)  # (B, N, ...)
        else:
            observation = self.env.observe_as(self._own_observation, tensordict)
        batch = observation.shape[0]
        partner = self.partner
        if partner.opponent == "self":
            out = self._policy(TensorDict({OBSERVATION_KEY: observation}, batch_size=[batch]))
            action = out.get(ACTION_KEY).index_select(1, self._controlled_index)
        elif partner.opponent == "centralized":
            joint = self._policy(TensorDict({"observation": observation.select(1, 0)}, batch_size=[batch])).get("action")
            per_agent = self._decode(joint) if self._decode is not None else joint.unflatten(-1, (self.env.n_agents, -1))
            action = per_agent.index_select(1, self._controlled_index)
        else:
            action = play_roles(self._policy, observation, self._controlled_index, self._maps, self.env.layout)
        return write_actions(self, tensordict, action)


def play_roles(
    policy: Any, observation: torch.Tensor, controlled: torch.Tensor, maps: list[str], layout: Any
) -> torch.Tensor:
    """The actions (B, C[, 2]) of the agents ``controlled`` (int64 (C,)) of a one-agent ``policy`` (a TensorDict
    module from ``"observation"`` to ``"action"``) trained as another agent: each agent's observation from
    ``observation`` (B, N, ...), turned by half a turn where its ``maps`` entry (``role_map``) says ``"half_turn"``,
    and a grid action turned back (UP↔DOWN, LEFT↔RIGHT; a continuous action is unchanged by a rotation)."""
    seen = observation.index_select(1, controlled)  # (B, C, ...)
    turned = torch.tensor([m == "half_turn" for m in maps], device=observation.device)
    if bool(turned.any()):
        shape = (1, -1, *[1] * (seen.dim() - 2))
        seen = torch.where(turned.view(shape), turn_observation(seen, layout), seen)
    flat = seen.flatten(0, 1)
    action = policy(TensorDict({"observation": flat}, batch_size=[flat.shape[0]])).get("action")
    action = action.unflatten(0, seen.shape[:2])
    if hasattr(layout, "rows") and bool(turned.any()):
        half_turn = torch.tensor(GRID_HALF_TURN_ACTIONS, device=action.device)
        action = torch.where(turned.view(1, -1), half_turn[action], action)
    return action


def write_actions(opponent: Opponent, tensordict: TensorDictBase, action: torch.Tensor) -> TensorDictBase:
    """``tensordict`` with ``action`` (B, C[, 2]) written into the joint action's columns of ``opponent``'s
    controlled agents (the joint action made of zeros where there is none yet)."""
    joint = tensordict.get(ACTION_KEY, None)
    joint = opponent.env.full_action_spec[ACTION_KEY].zero() if joint is None else joint.clone()
    joint.index_copy_(1, opponent._controlled_index, action.to(joint.dtype))
    tensordict.set(ACTION_KEY, joint)
    return tensordict
