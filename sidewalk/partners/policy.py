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

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from sidewalk.envs.base import AGENT_GROUP, SidewalkEnvBase
from sidewalk.opponents.base import ACTION_KEY, Opponent, env_domain
from sidewalk.symmetry import role_map, turn_action, turn_observation
from sidewalk.world import MAY_DIFFER, World

OBSERVATION_KEY = (AGENT_GROUP, "observation")


class PartnerMismatch(ValueError):
    """A partner run that cannot play in this world (the message names what differs)."""


@dataclass
class Partner:
    """What a run folder's ``policy.pt`` says about its learner: enough to rebuild it on its own world."""

    path: Path
    algo_name: str
    algo_config: Any  # the learner's Config dataclass
    world: World  # the world it trained in (its opponent: a scripted one, a partner, "centralized" or "self")
    state: dict[str, Any]  # the learner's policy state (``Algorithm.load_policy_state_dict``)

    @property
    def plays_every_agent(self) -> bool:
        return self.world.learner_plays_every_agent

    @property
    def ego(self) -> int | None:
        """The agent it played (single-agent learners; self-play in the role frame sees every game as agent 0);
        None: every agent."""
        if self.world.role_frame:
            return 0
        return None if self.plays_every_agent else self.world.ego

    @property
    def label(self) -> str:
        if self.plays_every_agent:
            return f"{self.algo_name} {'self-play' if self.world.opponent == 'self' else 'centralized'}"
        return f"{self.algo_name} vs {self.world.opponent}"


def read_partner(path: str | Path, map_location: str | torch.device = "cpu") -> Partner:
    """The learner saved in the run folder ``path`` (its ``policy.pt``; a folder from before ``policy.pt``
    described itself is read through its ``config.yaml``). Raises ``FileNotFoundError`` naming what is missing, and
    ``GroupFolderGiven`` naming the seeds' folders of a group folder."""
    from sidewalk.registry import LEARNERS
    from sidewalk.run_folder import POLICY, one_run_folder, policy_file, read_torch_file, saved_world

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
    algo_name, algo, world = saved_world(state.get("description"), run_dir)
    return Partner(path=run_dir, algo_name=algo_name, algo_config=LEARNERS[algo_name].Config(**algo), world=world,
                   state=state)


def check_partner(path: str | Path, world: World, controlled=None) -> Partner:
    """The partner in ``path``, checked to play the agents ``controlled`` (default: all but the world's ego) of
    ``world``; raises ``FileNotFoundError`` or ``PartnerMismatch`` naming what is wrong."""
    partner = read_partner(path)
    shown = f"opponent.path={str(path)!r}"
    domain, env_params = world.domain, world.env_params
    if partner.world.domain != domain:
        raise PartnerMismatch(
            f"{shown} was trained in the {partner.world.domain} domain (env={partner.world.domain}); this run is "
            f"env={domain}"
        )
    # The env computes a partner's own observation for it (PolicyOpponent): a partner trained on one may play here.
    own_observation = getattr(partner.world.env_params, "observation", None) in world.core_class.PARTNER_OBSERVATIONS
    ignoring = (*MAY_DIFFER, *(("observation",) if own_observation else ()))
    differ = [f"{name}={partner.world.value(name)!r} (this run: {world.value(name)!r})"
              for name in partner.world.differences(world, ignoring) if name.startswith("env.")]
    if differ:
        raise PartnerMismatch(
            f"{shown} was trained on another world: {', '.join(differ)}. A partner must share the domain, scenario "
            f"and observation (or have one the env computes for it: {world.core_class.PARTNER_OBSERVATIONS}); only "
            f"{', '.join(MAY_DIFFER)} may differ"
        )
    if controlled is None:
        controlled = [agent for agent in range(world.n_agents) if agent != world.ego]
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
    if experiment.world.opponent != "policy":
        return None
    return check_partner(experiment.world.opponent_params["path"], experiment.world)


def partner_policy(partner: Partner, device: str | torch.device = "cpu", sample: bool = False) -> tuple[Any, Any]:
    """The partner's policy module (its evaluation policy, or its collection policy with ``sample``), built on one
    world of its own (so every spec is the one training saw), and the joint-action decoder of a centralized grid
    partner (else None): a saved policy replayed is its World plus its learner."""
    from torchrl.envs import RewardSum, TransformedEnv

    from sidewalk.registry import LEARNERS

    view = partner.world.stand_in().make(1, seed=0, device=device)
    algo = LEARNERS[partner.algo_name](partner.algo_config, TransformedEnv(view, RewardSum()), device=device)
    algo.load_policy_state_dict(partner.state)
    policy = algo.collection_policy() if sample else algo.evaluation_policy()
    centralized_grid = partner.world.opponent == "centralized" and partner.world.domain == "discrete"
    return policy, view.decode_action if centralized_grid else None


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
        here = World(env_domain(env), env.params, self.name, ego=0 if ego is None else ego)
        self.partner = check_partner(path, here, self.controlled)
        self.sample = sample
        self.in_keys = [OBSERVATION_KEY]
        self._policy, self._decode = partner_policy(self.partner, env.device, sample)
        self._maps = [role_map(self.partner.world.domain, env.params, self.partner.ego, agent) if self.partner.ego is not None
                      else "same" for agent in self.controlled]
        # A partner trained on another observation kind (a grid vector in an image world) sees its own, from the env.
        own = getattr(self.partner.world.env_params, "observation", None)
        self._own_observation = own if own != getattr(env.params, "observation", None) else None
        if self._own_observation is not None:
            self.in_keys = list(type(env).PARTNER_OBSERVATION_KEYS)

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self._own_observation is None:
            observation = tensordict.get(OBSERVATION_KEY)  # (B, N, ...)
        else:
            observation = self.env.observe_as(self._own_observation, tensordict)
        batch = observation.shape[0]
        partner = self.partner
        if partner.world.opponent == "self":
            out = self._policy(TensorDict({OBSERVATION_KEY: observation}, batch_size=[batch]))
            action = out.get(ACTION_KEY).index_select(1, self._controlled_index)
        elif partner.world.opponent == "centralized":
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
        action = torch.where(turned.view(1, -1), turn_action(action, "discrete"), action)
    return action


def write_actions(opponent: Opponent, tensordict: TensorDictBase, action: torch.Tensor) -> TensorDictBase:
    """``tensordict`` with ``action`` (B, C[, 2]) written into the joint action's columns of ``opponent``'s
    controlled agents (the joint action made of zeros where there is none yet)."""
    joint = tensordict.get(ACTION_KEY, None)
    joint = opponent.env.full_action_spec[ACTION_KEY].zero() if joint is None else joint.clone()
    joint.index_copy_(1, opponent._controlled_index, action.to(joint.dtype))
    tensordict.set(ACTION_KEY, joint)
    return tensordict
