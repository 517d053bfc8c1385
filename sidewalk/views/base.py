"""What every view shares: the core env, seeding, the ``"world"`` group and the fast reset path."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite
from torchrl.envs import EnvBase

from sidewalk._torchrl import new_tensordict_unchecked
from sidewalk.envs.actions import ActionCheck
from sidewalk.envs.base import AGENT_GROUP, SidewalkEnvBase, spec_lines, swap_in_reset
from sidewalk.opponents.base import env_domain

WORLD = "world"
# Beyond this many joint actions (5 grid agents) a Categorical head is impractical; the all-agents view scales.
MAX_JOINT_ACTIONS = 4**5


def _reset_rows(tensordict: TensorDictBase | None, batch_size: int, device: torch.device) -> torch.Tensor:
    """Bool (B,): the worlds a reset call asks for (``"_reset"`` of shape (B, 1)); all of them when absent."""
    if tensordict is not None:
        mask = tensordict.get("_reset", None)
        if mask is not None:
            return mask.reshape(batch_size, -1).any(-1)
    return torch.ones(batch_size, dtype=torch.bool, device=device)


class _SidewalkView(EnvBase):
    """What both wrappers share: the core env, seeding, the ``"world"`` group and the fast reset path.

    The core's ``_step``/``_reset`` are called directly (as ``TransformedEnv`` does with its base env), so a step
    costs one core step plus a few tensor selections. The core's last output is kept as ``self._last``: the core
    is stateful (its worlds live in its tensors), and an opponent reads the agents' state and done flags from it.
    """

    def __init__(self, env: SidewalkEnvBase, shield: bool = False) -> None:
        if not isinstance(env, SidewalkEnvBase):
            raise TypeError(
                f"env={env!r} must be a Sidewalk core env (DiscreteSidewalkEnv or ContinuousSidewalkEnv)"
            )
        if not isinstance(shield, bool):
            raise TypeError(f"shield={shield!r} must be a bool")
        super().__init__(device=env.device, batch_size=env.batch_size)
        self.shield = shield
        # The agents the shield guards: the learner's (every agent here; the ego view narrows it to the ego).
        self._shielded = torch.ones(env.n_agents, dtype=torch.bool, device=env.device)
        self._intervened: torch.Tensor | None = None
        # Every agent's reward in the last output, and the worlds the last reset reset: the worlds a partial reset
        # skips keep the last step's reward and shield flags, as a lone env of a replica's seed would.
        self._last_reward: torch.Tensor | None = None
        self._reset_worlds: torch.Tensor | None = None
        self.core = env
        self.n_agents = env.n_agents
        self.num_envs = env.num_envs
        self.domain = env_domain(env)
        self._agents_shape = torch.Size((*env.batch_size, env.n_agents))
        self._last: TensorDictBase | None = None
        self._view_action_key: str | tuple[str, str] = "action"
        self._check_action: ActionCheck | None = None  # built at the first step, from the view's action spec

    # ---- specs shared by the views -------------------------------------------------------------------------

    def _world_spec(self) -> Composite:
        core_agents = self.core.observation_spec[AGENT_GROUP]
        # The shield's flags are bool (B, N, 1), as the presence flags are.
        extra = {"shield": core_agents["present"].clone()} if self.shield else {}
        return Composite(
            **extra,
            state=core_agents["state"].clone(),
            goal=core_agents["goal"].clone(),
            present=core_agents["present"].clone(),
            reward=self.core.full_reward_spec[AGENT_GROUP, "reward"].clone(),
            cost=core_agents["cost"].clone(),
            info=core_agents["info"].clone(),
            shape=self._agents_shape,
            device=self.device,
        )

    def _global_done_spec(self) -> Composite:
        core_done = self.core.full_done_spec
        return Composite(
            {key: core_done[key].clone() for key in ("done", "terminated", "truncated")},
            shape=self.batch_size,
            device=self.device,
        )

    # ---- TorchRL interface ---------------------------------------------------------------------------------

    def _set_seed(self, seed: int | None) -> None:
        self.core._set_seed(seed)

    @property
    def generator(self) -> torch.Generator:
        """The core env's generator: the core, the opponent and the view all draw from it (with several replicas, the
        first replica's; per-world draws go through the core's ``rand``/``randint``)."""
        return self.core.generator

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        rows = _reset_rows(tensordict, self.num_envs, self.device)
        # The core reads the same root "_reset" mask and returns every world: reset ones fresh, the others as the
        # last step left them (observation noise included), so this view's output is complete too.
        core_out = self.core._reset(tensordict)
        self._on_reset(rows)
        if self._intervened is not None:
            self._intervened = self._intervened & ~rows.unsqueeze(-1)
        self._reset_worlds = rows
        self._last = core_out
        return self._output(core_out, reset=True)

    def _reset_proc_data(self, tensordict: TensorDictBase | None, tensordict_reset: TensorDictBase):
        # Like the core, _reset returns every world, so the reset output is swapped in rather than merged.
        return swap_in_reset(tensordict, tensordict_reset, self.reset_keys)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        last = self._last
        if last is None:
            raise RuntimeError(f"{type(self).__name__}.step() was called before reset()")
        action = tensordict.get(self._view_action_key, None)
        if self._check_action is None:
            self._check_action = ActionCheck(
                self.full_action_spec[self._view_action_key], self._view_action_key, type(self).__name__,
                labels=self._action_labels, check_finite=getattr(self.core.params, "check_actions", True),
            )
        # Checked against the view's own key and spec, before it is turned into the joint action (the core checks
        # that again, the opponent's part included).
        self._check_action(action, tensordict)
        last.set((AGENT_GROUP, "action"), self._joint_action(action))
        self._before_core_step(last)
        if self.shield:
            safe, self._intervened = self.core.shield_action(last.get((AGENT_GROUP, "action")), self._shielded)
            last.set((AGENT_GROUP, "action"), safe)
        core_out = self.core._step(last)
        self._last = core_out
        return self._output(core_out, reset=False)

    # ---- hooks for the views -------------------------------------------------------------------------------

    def _on_reset(self, rows: torch.Tensor) -> None:
        """Called with the bool (B,) mask of the worlds just reset."""

    def _joint_action(self, action: torch.Tensor) -> torch.Tensor:
        """The core's ("agents", "action") (B, N[, 2]) from the view's ``action``."""
        raise NotImplementedError

    @property
    def _action_labels(self) -> tuple[str, ...]:
        """The names of a discrete action's values, for error messages: the core's (an agent's action)."""
        return self.core.ACTION_LABELS

    def _before_core_step(self, core_in: TensorDictBase) -> None:
        """Last chance to fill in the core's input (the ego view's opponent writes its agents' actions)."""

    def _output(self, core_out: TensorDictBase, reset: bool) -> TensorDictBase:
        raise NotImplementedError

    def _world_reward(self, agents: TensorDictBase, reset: bool) -> torch.Tensor:
        """Every agent's reward (B, N, 1): the step's, or on a reset 0 in the worlds reset and the last output's in
        the others."""
        if not reset:
            reward = agents.get("reward")
        elif self._last_reward is None:
            reward = torch.zeros((*self._agents_shape, 1), device=self.device)
        else:
            reward = self._last_reward.masked_fill(self._reset_worlds.view(-1, 1, 1), 0.0)
        self._last_reward = reward
        return reward

    def _world(self, agents: TensorDictBase, reward: torch.Tensor) -> TensorDictBase:
        extra = {}
        if self.shield:
            intervened = self._intervened
            extra["shield"] = (
                intervened.unsqueeze(-1) if intervened is not None
                else torch.zeros((*self._agents_shape, 1), dtype=torch.bool, device=self.device)
            )
        return new_tensordict_unchecked(
            {
                **extra,
                "state": agents.get("state"),
                "goal": agents.get("goal"),
                "present": agents.get("present"),
                "reward": reward,
                "cost": agents.get("cost"),
                "info": agents.get("info"),
            },
            batch_size=self._agents_shape,
        )

    def extra_repr(self) -> str:
        # The view's own specs; nn.Module's repr adds its core env and opponent below them.
        return "\n".join([f"shield={self.shield}", *spec_lines(self)])

    def render(self, env_index: int = 0, **kwargs: Any):
        """The core's RGB rendering of world ``env_index`` (see the core env's ``render``; ``mode="rgb_array"``)."""
        return self.core.render(env_index, **kwargs)

    @property
    def max_steps(self) -> int:
        """The core's time limit (``SidewalkEnvBase.max_steps``)."""
        return self.core.max_steps
