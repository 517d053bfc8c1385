"""Rasterise one world to an RGB array with numpy: no display, no plotting backend, fast enough for videos."""

from __future__ import annotations

import numpy as np

BACKGROUND = (236, 236, 228)
WALL = (60, 60, 60)
# One colour per agent (and its goal), cycling for larger teams.
AGENT_COLOURS = ((214, 39, 40), (31, 119, 180), (44, 160, 44), (255, 127, 14), (148, 103, 189), (140, 86, 75))


def colour(agent: int) -> tuple[int, int, int]:
    return AGENT_COLOURS[agent % len(AGENT_COLOURS)]


def _disc(image: np.ndarray, centre_xy: tuple[float, float], radius_px: float, rgb: tuple[int, int, int]) -> None:
    height, width, _ = image.shape
    ys, xs = np.ogrid[:height, :width]
    inside = (xs + 0.5 - centre_xy[0]) ** 2 + (ys + 0.5 - centre_xy[1]) ** 2 <= radius_px**2
    image[inside] = rgb


def _star(image: np.ndarray, centre_xy: tuple[float, float], radius_px: float, rgb: tuple[int, int, int]) -> None:
    """A five-pointed star: a point is inside when its radius is below the star's outline at its angle."""
    height, width, _ = image.shape
    ys, xs = np.mgrid[:height, :width]
    dx, dy = xs + 0.5 - centre_xy[0], -(ys + 0.5 - centre_xy[1])
    angle = np.arctan2(dy, dx) - np.pi / 2
    sector = np.abs(((angle % (2 * np.pi / 5)) / (2 * np.pi / 5)) - 0.5) * 2  # 1 at the tips, 0 between them
    outline = radius_px * (0.45 + 0.55 * sector)
    image[np.hypot(dx, dy) <= outline] = rgb


def draw_grid(
    rows: int,
    cols: int,
    blocked: np.ndarray,
    positions: np.ndarray,
    goals: np.ndarray,
    present: np.ndarray,
    pixels_per_cell: int,
) -> np.ndarray:
    """Grid world: walls dark, goals as coloured stars, agents as coloured discs; agent 0 red, agent 1 blue."""
    k = pixels_per_cell
    image = np.empty((rows * k, cols * k, 3), dtype=np.uint8)
    image[:] = BACKGROUND
    image[:: k, :] = (205, 205, 198)  # faint cell lines
    image[:, :: k] = (205, 205, 198)
    for row, col in zip(*np.nonzero(blocked)):
        image[row * k : (row + 1) * k, col * k : (col + 1) * k] = WALL
    for agent, (row, col) in enumerate(goals):
        _star(image, ((col + 0.5) * k, (row + 0.5) * k), 0.45 * k, colour(agent))
    for agent, (row, col) in enumerate(positions):
        if present[agent]:
            _disc(image, ((col + 0.5) * k, (row + 0.5) * k), 0.35 * k, colour(agent))
    return image


def draw_plane(
    length_m: float,
    width_m: float,
    boxes: np.ndarray,
    positions: np.ndarray,
    headings: np.ndarray,
    goals: np.ndarray,
    present: np.ndarray,
    radius_m: float,
    pixels_per_m: int,
) -> np.ndarray:
    """Continuous world seen from above (x to the right, y up): walls as a dark border, agents with heading ticks."""
    border = 4
    width_px, height_px = round(length_m * pixels_per_m), round(width_m * pixels_per_m)
    image = np.empty((height_px + 2 * border, width_px + 2 * border, 3), dtype=np.uint8)
    image[:] = WALL
    image[border:-border, border:-border] = BACKGROUND

    def to_px(x: float, y: float) -> tuple[float, float]:
        return border + x * pixels_per_m, border + (width_m - y) * pixels_per_m

    for x0, y0, x1, y1 in boxes:
        (c0, r1), (c1, r0) = to_px(x0, y0), to_px(x1, y1)
        image[int(r0) : int(np.ceil(r1)), int(c0) : int(np.ceil(c1))] = WALL
    for agent, (x, y) in enumerate(goals):
        _star(image, to_px(x, y), radius_m * pixels_per_m, colour(agent))
    for agent, ((x, y), theta) in enumerate(zip(positions, headings)):
        if not present[agent]:
            continue
        _disc(image, to_px(x, y), radius_m * pixels_per_m, colour(agent))
        for fraction in np.linspace(0.0, 1.0, 12):  # heading tick from the centre to the rim
            tx, ty = to_px(x + fraction * radius_m * np.cos(theta), y + fraction * radius_m * np.sin(theta))
            _disc(image, (tx, ty), max(1.5, 0.08 * radius_m * pixels_per_m), (255, 255, 255))
    return image
