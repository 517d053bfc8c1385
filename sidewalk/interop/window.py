"""The window of the faces' ``render_mode="human"``: the env's RGB frames shown as they come, through matplotlib's
interactive backend (matplotlib is a dependency; pygame, which gymnasium's own ``HumanRendering`` needs, is not).

Where no window can open (no display, or no GUI toolkit for matplotlib), building one raises ``NoWindowError``
saying why and what to do, before any step runs.
"""

from __future__ import annotations

import os
import sys

import numpy as np


class NoWindowError(RuntimeError):
    """``render_mode="human"`` where no window can open (the message says why and what to do instead)."""


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
    event loop runs meanwhile); closed by ``close``, and opened again by ``show`` if the user closed it."""

    def __init__(self, title: str, fps: float) -> None:
        problem = window_problem()
        if problem is not None:
            raise NoWindowError(
                f"render_mode='human' cannot open a window: {problem}. To see episodes here, record them instead: "
                "render_mode='rgb_array' (gymnasium.wrappers.RecordVideo), or python runners/render.py"
            )
        self.title, self.fps = title, fps
        self._figure = None
        self._image = None

    def show(self, frame: np.ndarray) -> None:
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
