"""The window of the faces' ``render_mode="human"``: the env's RGB frames shown as they come, through matplotlib's
interactive backend (matplotlib is a dependency; pygame, which gymnasium's own ``HumanRendering`` needs, is not).

Where no window can open (no display, or no GUI toolkit for matplotlib), building one warns once
(``NoWindowWarning``) saying why and what to do, and the env runs without one: a script, or Gymnasium's
``check_env`` (which builds the env in every render mode it advertises), still runs on a headless machine.
"""

from __future__ import annotations

import os
import sys
import warnings

import numpy as np


class NoWindowWarning(UserWarning):
    """``render_mode="human"`` where no window can open (the message says why and what to do instead); make it an
    error with ``warnings.simplefilter("error", NoWindowWarning)``."""


def _interactive_backends() -> list[str]:
    try:
        from matplotlib.backends import BackendFilter, backend_registry
    except ImportError:  # matplotlib < 3.9
        from matplotlib.rcsetup import interactive_bk

        return [name.lower() for name in interactive_bk]
    return backend_registry.list_builtin(BackendFilter.INTERACTIVE)


def window_problem() -> str | None:
    """Why no window can open here, or None. matplotlib picks its backend at first use: an interactive one where
    a display and a GUI toolkit exist, else the non-interactive ``agg`` (as it does for an unusable ``MPLBACKEND``)."""
    import matplotlib

    backend = matplotlib.get_backend().lower()
    if backend.startswith("module://") or backend in _interactive_backends():
        return None
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return (f"this machine has no display ($DISPLAY and $WAYLAND_DISPLAY are unset: a headless machine, or ssh "
                f"without -X), so matplotlib runs its non-interactive {backend!r} backend")
    return (f"matplotlib's backend is {backend!r}, which draws no window: it found no GUI toolkit (install one, e.g. "
            "`apt install python3-tk` or `pip install PyQt6`), or MPLBACKEND or a matplotlibrc chose it")


class FrameWindow:
    """A window titled ``title`` that shows each RGB frame given to ``show`` and waits ``1 / fps`` s (the window's
    event loop runs meanwhile); closed by ``close``, and opened again by ``show`` if the user closed it. Where no
    window can open, building it warns (``NoWindowWarning``) and ``show`` does nothing."""

    def __init__(self, title: str, fps: float) -> None:
        self.title, self.fps = title, fps
        self._figure = None
        self._image = None
        problem = window_problem()
        self.opens = problem is None
        if problem is not None:
            warnings.warn(
                NoWindowWarning(
                    f"render_mode='human' shows no window: {problem}. The env runs without one; to see episodes "
                    "here, record them: render_mode='rgb_array' (gymnasium.wrappers.RecordVideo), or python "
                    "runners/render.py"
                ),
                stacklevel=3,
            )

    def show(self, frame: np.ndarray) -> None:
        if not self.opens:
            return
        import matplotlib.pyplot as plt

        if self._figure is None or not plt.fignum_exists(self._figure.number):
            self._figure, axes = plt.subplots(num=self.title)
            axes.set_axis_off()
            self._image = axes.imshow(frame)
            self._figure.tight_layout(pad=0)
            self._figure.show()
        else:
            self._image.set_data(frame)
        canvas = self._figure.canvas
        canvas.draw_idle()
        canvas.start_event_loop(1.0 / self.fps)  # draws the frame and keeps the window responsive meanwhile

    def close(self) -> None:
        if self._figure is not None:
            import matplotlib.pyplot as plt

            plt.close(self._figure)
            self._figure = self._image = None
