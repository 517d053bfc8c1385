"""The check of the action a step is given, against the env's action spec: its key, dtype, shape and values.

Built once per env from the spec, so a step pays a few attribute comparisons and, for the values, one reduction: a
discrete action's least and largest index (``aminmax``), a continuous action's sum (finite exactly when every entry
is). TorchRL's ``spec.is_in`` says only yes or no, and refuses a continuous action beyond its bounds, which the
Sidewalk clamps (SPEC §1); this check names what is wrong instead.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import Categorical, TensorSpec

SHOWN_BAD = 3  # bad entries named in a message; the rest are counted


class InvalidActionError(ValueError):
    """An action of the wrong key, dtype, shape or value handed to a Sidewalk env's step (the message names what
    was expected and what came)."""


def _key_text(key: str | tuple[str, ...]) -> str:
    return repr(key) if isinstance(key, str) else "(" + ", ".join(map(repr, key)) + ")"


def _preview(value: torch.Tensor) -> str:
    """The first few entries of ``value`` on one line."""
    flat = value.detach().reshape(-1)
    more = ", ..." if flat.numel() > 6 else ""
    return "[" + ", ".join(repr(x) for x in flat[:6].tolist()) + more + "]"


class ActionCheck:
    """The check of the action under ``key`` against ``spec`` (a ``Categorical`` or a floating ``Bounded``) for the
    env ``owner`` names; ``labels`` name a discrete action's values (``UP``, ``DOWN``, ...). Calling it with the
    action (None when absent) and the step's tensordict returns nothing or raises ``InvalidActionError`` naming the
    key, the dtype, shape and values expected, and the bad action (its first bad entries, by index). A discrete
    action must be an index in [0, n); a continuous one finite (``check_finite``): beyond the bounds it is clamped."""

    def __init__(self, spec: TensorSpec, key: str | tuple[str, ...], owner: str, *,
                 labels: Sequence[str] = (), check_finite: bool = True) -> None:
        self.key, self.owner = key, owner
        self.shape, self.dtype = spec.shape, spec.dtype
        self.n = int(spec.space.n) if isinstance(spec, Categorical) else None
        self.check_finite = check_finite
        dtype = str(self.dtype).removeprefix("torch.")
        if self.n is not None:
            named = f" ({', '.join(labels)})" if labels else ""
            values = f"indices in [0, {self.n}){named}"
        else:
            low, high = (", ".join(f"{x:.4g}" for x in bound.reshape(-1, self.shape[-1])[0].tolist())
                         for bound in (spec.space.low, spec.space.high))
            values = f"finite values (clamped to low [{low}], high [{high}] along the last axis)"
        self.expected = f"{_key_text(key)}: {dtype} of shape {tuple(self.shape)}, {values}"

    def __call__(self, action: Any, tensordict: TensorDictBase) -> None:
        if not isinstance(action, torch.Tensor) or action.shape != self.shape or action.dtype != self.dtype:
            raise InvalidActionError(self._kind_problem(action, tensordict))
        if self.n is not None:
            bounds = torch.aminmax(action.reshape(-1))
            if bounds.min.item() < 0 or bounds.max.item() >= self.n:
                self._refuse((action < 0) | (action >= self.n), action, "out-of-range")
        elif self.check_finite and not math.isfinite(action.sum().item()):
            bad = ~torch.isfinite(action).all(-1)
            if bad.any():  # else finite entries whose sum overflowed (large actions, later clamped)
                self._refuse(bad, action, "non-finite")

    def _refuse(self, bad: torch.Tensor, action: torch.Tensor, what: str) -> None:
        """Raise naming the first bad actions of ``bad`` (bool over the world[, agent] axes) by world and agent."""
        where = bad.nonzero()
        shown = "; ".join(
            " ".join(f"{axis} {i}" for axis, i in zip(("world", "agent"), index)) + f": {action[tuple(index)].tolist()!r}"
            for index in where[:SHOWN_BAD].tolist()
        )
        more = f"; and {len(where) - SHOWN_BAD} more" if len(where) > SHOWN_BAD else ""
        worlds = int(bad.reshape(bad.shape[0], -1).any(-1).sum())
        hint = ("; the policy that chose it has diverged or is fed NaN (env.check_actions=false skips this check)"
                if self.n is None else "")
        raise InvalidActionError(
            f"{self.owner}.step: {what} action in {worlds} of {bad.shape[0]} worlds ({shown}{more}); expected "
            f"{self.expected}{hint}"
        )

    def _kind_problem(self, action: Any, tensordict: TensorDictBase) -> str:
        start = f"{self.owner}.step: "
        if action is None:
            elsewhere = [key for key in tensordict.keys(True, True)
                         if (key if isinstance(key, str) else key[-1]) == "action"]
            found = (f"; found {', '.join(map(_key_text, elsewhere))}: put it under {_key_text(self.key)}"
                     if elsewhere else "")
            return f"{start}no action under {_key_text(self.key)}{found}; expected {self.expected}"
        if not isinstance(action, torch.Tensor):
            return f"{start}the action is a {type(action).__name__}, not a tensor; expected {self.expected}"
        dtype = str(action.dtype).removeprefix("torch.")
        return (f"{start}got {dtype} of shape {tuple(action.shape)} {_preview(action)}; expected {self.expected}")
