"""How a learner sees the Sidewalk game: against a scripted opponent, as one joint controller, or as all agents.

Three views of one batched core env (``DiscreteSidewalkEnv`` or ``ContinuousSidewalkEnv`` with B worlds):

- ``EgoView(env, opponent, ego)``: one learning agent; the others are played by a scripted opponent. Keys are
  flat single-agent ones, so stock single-agent TorchRL losses (``DQNLoss``, ``ClipPPOLoss``) work unchanged.
- ``CentralizedView(env)``: the learner plays every agent through one joint action and receives the team reward.
- ``SelfPlayView(env)``: every agent is the learner (``opponent=self``): TorchRL's multi-agent keys
  ``("agents", ...)`` as its VMAS wrapper gives them (the observation, and under ``("agents", "info")`` the outcome
  flags, cost and the mask of the steps that carry learning signal), a root ``state`` for centralised critics, each
  agent with its own life cycle (see the class), for the multi-agent learners (IPPO, MAPPO, IQL, VDN, QMIX);
- the all-agents view is the multi-agent core env itself (``make_view("all", env)`` returns it).

``view_for_opponent(env, opponent, ego)`` builds the view an experiment's ``opponent=`` names (``centralized``,
``self``, or an opponent playing every agent but the ego); ``make_view(kind, env)`` builds the view of a kind with it.

Every view takes ``shield=True``: before the core steps, the safety shield (the core's ``shield_action``, a one-step
look-ahead on the known dynamics) replaces the learner's actions that would collide -- the ego's in an ego view,
every agent's in the others -- with the nearest safe ones. The shield is part of the environment the learner sees:
the learner's own action stays in its data, and its evaluation runs shielded too.

The wrappers are thin ``EnvBase`` subclasses over the core's tensors: one step is a fixed sequence of tensor
operations for all B worlds, and the specs are built once. They carry the same ``"world"`` group for evaluation
and plots (every agent, in agent order, batch shape (B, N)):

- ``("world", "state")`` / ``("world", "goal")``: the true state and goal of every agent (no observation noise);
- ``("world", "present")``: the agent occupies space (moving, or parked at its goal; not crashed and removed);
- ``("world", "reward")``: every agent's own reward of the step, (B, N, 1), zero on reset;
- ``("world", "cost")``: every agent's safety cost of the step (the core's ``("agents", "cost")``), (B, N, 1);
- ``("world", "shield")`` (only with ``shield=True``): bool (B, N, 1), the shield replaced that agent's action in the
  step (``SidewalkEnvBase.shield_action``);
- ``("world", "info", k)`` for ``k`` in ``INFO_KEYS`` (``reached_goal``, ``collided_agent``, ``collided_wall``,
  ``timed_out``): the sticky per-episode outcome flags, (B, N, 1) bool.

The ego view adds ``("info", k)``, the ego agent's own flags, (B, 1) bool, so ``ego/success_rate`` reads
``("info", "reached_goal")`` and ``other/...`` reads ``("world", "info", k)`` at the other agents' indices.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from torchrl.envs import EnvBase

from sidewalk._checks import check_choice
from sidewalk.envs.base import SidewalkEnvBase
from sidewalk.opponents.base import Opponent
from sidewalk.views.base import MAX_JOINT_ACTIONS, WORLD
from sidewalk.views.centralized import CentralizedView
from sidewalk.views.ego import EgoView
from sidewalk.views.selfplay import SelfPlayView

VIEW_KINDS = ("ego", "centralized", "self", "all")
# What each kind of view takes beyond the env, ego and shield: the settings make_view passes on.
VIEW_SETTINGS = {"ego": ("end_on_ego_done", "opponent_kwargs"), "centralized": (), "self": ("other_play", "role_frame"), "all": ()}


def view_for_opponent(
    env: SidewalkEnvBase,
    opponent: str | Opponent,
    ego: int = 0,
    *,
    shield: bool = False,
    end_on_ego_done: bool = False,
    opponent_kwargs: Mapping[str, Any] | None = None,
    other_play: bool = False,
    role_frame: bool = False,
) -> EnvBase:
    """The view a learner plays ``env`` through, for ``opponent`` as an experiment names it (``opponent=``):
    ``"centralized"`` (``CentralizedView``), ``"self"`` (``SelfPlayView``, with ``other_play`` and ``role_frame``), or else an
    ``EgoView`` of agent ``ego`` (with ``end_on_ego_done``) against ``opponent`` -- a registered name, built with
    ``opponent_kwargs``, or an ``Opponent`` on ``env`` playing every other agent. ``shield=True`` shields the
    learner's actions.

    The ego's settings go unread where the learner plays every agent (a config carries them whatever its choice);
    ``other_play`` or ``role_frame`` for any view but self-play is an error.
    """
    for name, value in (("other_play", other_play), ("role_frame", role_frame)):
        if value and opponent != "self":
            raise ValueError(f"{name}=True trains self-play partners: use opponent='self', not opponent={opponent!r}")
    if opponent == "centralized":
        return CentralizedView(env, shield=shield)
    if opponent == "self":
        return SelfPlayView(env, shield=shield, other_play=other_play, role_frame=role_frame)
    return EgoView(
        env, opponent=opponent, ego=ego, end_on_ego_done=end_on_ego_done, opponent_kwargs=opponent_kwargs,
        shield=shield,
    )


def make_view(
    kind: str,
    env: SidewalkEnvBase,
    opponent: str | Opponent | None = None,
    ego: int | None = None,
    shield: bool = False,
    **settings: Any,
) -> EnvBase:
    """The view ``kind`` of ``env`` (``view_for_opponent`` builds it): ``"ego"`` (``EgoView``; ``opponent``
    defaults to ``"random"``; ``settings``: ``end_on_ego_done``, ``opponent_kwargs``), ``"centralized"``
    (``CentralizedView``), ``"self"`` (``SelfPlayView``; ``settings``: ``other_play``, ``role_frame``) or ``"all"`` (the
    multi-agent core env itself).

    ``opponent`` and ``ego`` (default 0) apply only to ``"ego"``; giving either to another view is an error, as is
    an opponent that does not play the env's domain, or a setting the view does not take. ``shield=True`` shields
    the learner's actions (every view but ``"all"``, the bare core, which has no learner to shield).
    """
    check_choice("kind", kind, VIEW_KINDS)
    if not isinstance(env, SidewalkEnvBase):
        raise TypeError(
            f"env={env!r} must be a Sidewalk core env (DiscreteSidewalkEnv or ContinuousSidewalkEnv)"
        )
    unexpected = [name for name in settings if name not in VIEW_SETTINGS[kind]]
    if unexpected:
        raise TypeError(f"unexpected argument(s) {', '.join(map(repr, unexpected))} for the {kind!r} view")
    if kind == "ego":
        opponent = "random" if opponent is None else opponent
        if isinstance(opponent, str) and opponent in ("centralized", "self"):
            raise ValueError(
                f"opponent={opponent!r} means the learner plays every agent: use make_view({opponent!r}, env)"
            )
        return view_for_opponent(env, opponent, 0 if ego is None else ego, shield=shield, **settings)
    if opponent is not None and not (kind == "centralized" and opponent == "centralized"):
        raise ValueError(
            f"the {kind!r} view has no opponent (the learner plays every agent); got opponent={opponent!r}"
        )
    if ego is not None:
        raise ValueError(
            f"the {kind!r} view has no ego agent (the learner plays every agent); got ego={ego!r}"
        )
    if kind != "all":
        return view_for_opponent(env, kind, shield=shield, **settings)
    if shield:
        raise ValueError(
            "shield=True: the 'all' view is the bare core env; call env.shield_action, or use kind='self'"
        )
    return env


__all__ = [
    "MAX_JOINT_ACTIONS", "VIEW_KINDS", "WORLD", "CentralizedView", "EgoView", "SelfPlayView", "make_view",
    "view_for_opponent",
]
