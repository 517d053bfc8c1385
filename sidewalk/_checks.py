"""Argument checks shared by every public constructor: a bad value is named with what would have been valid."""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Iterable, Mapping
from typing import Any


def check_range(
    name: str, value: Any, low: float | None = None, high: float | None = None, *, low_open: bool = False
) -> None:
    """Raise ``ValueError`` naming ``name=value`` and the valid interval unless ``value`` lies in it."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{name}={value!r} must be a number")
    too_low = low is not None and (value <= low if low_open else value < low)
    too_high = high is not None and value > high
    if too_low or too_high or math.isnan(value):
        lo = "(-inf" if low is None else f"({low}" if low_open else f"[{low}"
        hi = "+inf)" if high is None else f"{high}]"
        raise ValueError(f"{name}={value!r} is out of range; valid: {lo}, {hi}")


def check_int(name: str, value: Any, low: int | None = None, high: int | None = None) -> None:
    """Raise unless ``value`` is an int (not a bool) within [low, high]."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name}={value!r} must be an integer")
    check_range(name, value, low, high)


def check_choice(name: str, value: Any, choices: Iterable[Any]) -> None:
    """Raise ``ValueError`` naming ``value`` and listing the valid ``choices``."""
    choices = list(choices)
    if value not in choices:
        raise ValueError(f"{name}={value!r} is not valid; valid: {', '.join(map(repr, choices))}")


def replace_checked(params: Any, overrides: Mapping[str, Any], owner: str) -> Any:
    """Return ``dataclasses.replace(params, **overrides)`` after checking every key is a field of ``params``.

    Unknown names are an error that lists the valid ones (and the closest match), so a typo never falls back
    to a silent default.
    """
    check_keys(owner, overrides, [f.name for f in dataclasses.fields(params)], kind="parameter", error=TypeError)
    return dataclasses.replace(params, **overrides)


def check_keys(
    owner: str, keys: Iterable[str], valid: Iterable[str], *, kind: str = "key", error: type[Exception] = ValueError
) -> None:
    """Raise ``error`` naming every key of ``keys`` not in ``valid``, with the closest valid name ("did you mean")
    and the full list, so a typo never falls back to a silent default."""
    valid = list(valid)
    unknown = [key for key in keys if key not in valid]
    if unknown:
        hints = []
        for key in unknown:
            close = difflib.get_close_matches(key, valid, n=1)
            hints.append(f"{key!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        raise error(f"unknown {kind} {', '.join(hints)} for {owner}; valid: {', '.join(valid) or 'none'}")
