"""One game of ``sidewalk-play``: a person's keys drive the ego of a Gymnasium face against the configured partner,
and every episode is recorded as a Minari dataset (``sidewalk.datasets``).

The game holds the package's own env (``gymnasium.make("sidewalk/Discrete-v0" | "sidewalk/Continuous-v0", ...)``):
the page only sends keys and shows the frames the env's renderer draws, so there is one implementation of the
dynamics. Messages from the page are checked here (``GameError`` names what is wrong and what is valid).
"""

from __future__ import annotations

import base64
import io
import threading
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

from sidewalk.config import LEARNER_PLAYS_ALL
from sidewalk.envs.base import OUTCOME_WORDS
from sidewalk.interop.gymnasium import ENV_IDS, world_kwargs
from sidewalk.registry import OPPONENTS
from sidewalk.world import World

GRID_MOVES = ("up", "down", "left", "right")  # the grid's actions UP, DOWN, LEFT, RIGHT, in that order
DIRECTIONS = (-1, 0, 1)  # continuous: each key axis is released (0), or held one way (±1)
DRIVER = "a person (sidewalk-play)"
GRID_STEPS_PER_S = 4.0  # the grid has no dt: four moves a second is a walking pace a person can steer


def partners(domain: str) -> list[str]:
    """Whom a person can walk against in ``domain``: the opponents that declare it (the registry's); ``centralized``
    and ``self`` name how a learner sees the game, not partners."""
    return [name for name in OPPONENTS if domain in OPPONENTS[name].domains]


def check_partner(opponent: str, domain: str) -> None:
    """A ``ValueError`` naming the valid partners when ``opponent`` is not one a person can walk against in
    ``domain``."""
    valid = partners(domain)
    if opponent not in valid:
        what = "a learner's view, not a partner" if opponent in LEARNER_PLAYS_ALL else "not a partner"
        raise ValueError(f"opponent={opponent!r} is {what} in env={domain}; valid: {', '.join(valid)}")


class GameError(ValueError):
    """A message from the page that the game cannot take; the text names the field and its valid values."""


@dataclass(frozen=True)
class Recording:
    """Where played episodes go: Minari dataset ``dataset_id`` under the datasets root ``data_path``."""

    dataset_id: str
    data_path: str | None = None


def frame_png(frame: np.ndarray) -> str:
    """An RGB frame as a ``data:`` URL of a PNG the page shows as it is."""
    from matplotlib.image import imsave

    buffer = io.BytesIO()
    imsave(buffer, frame, format="png")
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


class Game:
    """The ego of one world, played by keys; ``reset`` and ``step`` return what the page shows (``state``)."""

    def __init__(self, world: World, recording: Recording | None = None, seed: int = 0) -> None:
        check_partner(world.opponent, world.domain)
        self.domain = world.domain
        # The person's episode ends with their own outcome (a grid ego at its goal could not move on); a person
        # walks unshielded.
        self.kwargs = world_kwargs(world.replace(end_on_ego_done=True, shield=False))
        self.env = gymnasium.make(ENV_IDS[self.domain], render_mode="rgb_array", **self.kwargs)
        self.recording = recording
        if recording is not None:
            from sidewalk.datasets import record

            self.env = record(self.env, data_path=recording.data_path)
        self.face = self.env.unwrapped
        self.seed = seed
        self.lock = threading.Lock()  # one game: the server's threads take turns
        high = self.face.action_space.high if self.domain == "continuous" else None
        self.action_scale = None if high is None else np.asarray(high, dtype=np.float32)
        dt_s = getattr(self.face.view.core.params, "dt_s", None)
        self.steps_per_s = 1.0 / dt_s if dt_s else GRID_STEPS_PER_S
        self.episodes, self.steps, self.done = 0, 0, True
        self.reset()

    def describe(self) -> dict[str, Any]:
        """What the page needs before the first frame: domain, partner, keys, step rate."""
        keys = ("arrows: one cell a press, or one a step while held; with no key the game waits" if self.domain == "discrete" else
                "up/down: accelerate/brake, left/right: turn; released keys coast")
        return {"domain": self.domain, "partner": self.kwargs["opponent"],
                "partner_settings": self.kwargs.get("opponent_kwargs", {}), "keys": keys,
                "steps_per_s": self.steps_per_s, "recording": self.recording.dataset_id if self.recording else None}

    def reset(self) -> dict[str, Any]:
        """A new episode in the next world (seeds ``seed``, ``seed + 1``, ...); an episode cut short is saved first."""
        self.save_unfinished()
        self._observation, info = self.env.reset(seed=self.seed + self.episodes)
        self.episodes += 1
        self.steps, self.total_return, self.done, self.info = 0, 0.0, False, info
        return self.state()

    def action(self, message: Any) -> Any:
        """The env action a page message asks for, or ``GameError``: ``{"move": "up"|...}`` in the grid,
        ``{"accelerate": -1|0|1, "turn": -1|0|1}`` in the continuous world."""
        if not isinstance(message, dict):
            raise GameError(f"a step message is a JSON object, not {type(message).__name__}")
        if self.domain == "discrete":
            move = message.get("move")
            if move not in GRID_MOVES:
                raise GameError(f"move={move!r} is not valid; valid: {', '.join(GRID_MOVES)}")
            return GRID_MOVES.index(move)
        axes = []
        for name in ("accelerate", "turn"):
            value = message.get(name, 0)
            if isinstance(value, bool) or value not in DIRECTIONS:
                raise GameError(f"{name}={value!r} is not valid; valid: -1, 0, 1")
            axes.append(value)
        return np.asarray(axes, dtype=np.float32) * self.action_scale

    def step(self, message: Any) -> dict[str, Any]:
        """One env step with the page's keys; the finished episode is saved to the dataset."""
        action = self.action(message)
        if self.done:
            raise GameError("the episode is over: restart it")
        self._observation, reward, terminated, truncated, self.info = self.env.step(action)
        self.steps += 1
        self.total_return += float(reward)
        self.done = bool(terminated or truncated)
        if self.done and self.recording is not None:
            self.save()
        return self.state()

    def save_unfinished(self) -> None:
        """Save the episode under way, if any step of it was played (it ends truncated): a restart or ``close``."""
        if self.recording is not None and self.steps and not self.done:
            self.save()
            self.done = True

    def close(self) -> None:
        """End the game (once; later calls do nothing): the episode under way is saved, the env closed."""
        if self.env is None:
            return
        self.save_unfinished()
        self.env.close()
        self.env = None

    def save(self) -> None:
        from sidewalk.datasets import save

        save(self.env, self.recording.dataset_id, env_config=self.kwargs, data_path=self.recording.data_path,
             driver=DRIVER, description="Episodes a person played by keyboard in sidewalk-play")

    def state(self) -> dict[str, Any]:
        return {"frame": frame_png(self.env.render()), "step": self.steps, "return": round(self.total_return, 4),
                "done": self.done, "outcome": self.outcome(), "episode": self.episodes}

    def outcome(self) -> str:
        """The ego's outcome in words (``OUTCOME_WORDS``), else running or episode over."""
        agents, ego = self.info["agents"], self.face.view.ego
        for flag, words in OUTCOME_WORDS.items():
            if bool(agents[flag][ego]):
                return words
        return "episode over" if self.done else "running"
