"""Rasterise one world to an RGB array with numpy: no display, no plotting backend, fast enough for videos."""

from __future__ import annotations

import numpy as np

BACKGROUND = (236, 236, 228)
WALL = (60, 60, 60)
CELL_LINE = (205, 205, 198)
TICK = (255, 255, 255)
# A goal's outline is drawn over the agents' edges (a goal under an agent still shows), GOAL_RIM of the star's radius
# thick (2 px at least) and just outside the star; an agent's middle, AGENT_CORE of its radius, stays on top.
GOAL_RIM, AGENT_CORE = 0.13, 0.6
# One colour per agent (and its goal): the first six are matplotlib's tab10, the other ten were picked
# greedily for the largest least CIELAB distance to every colour before them and to the background, walls
# and ticks, so 16 agents stay apart (least ΔE76 ≈ 34). Larger teams cycle.
AGENT_COLOURS = (
    (214, 39, 40),  # red
    (31, 119, 180),  # blue
    (44, 160, 44),  # green
    (255, 127, 14),  # orange
    (148, 103, 189),  # purple
    (140, 86, 75),  # brown
    (220, 211, 0),  # yellow
    (240, 50, 230),  # magenta
    (0, 0, 128),  # navy
    (70, 240, 240),  # cyan
    (255, 105, 180),  # hot pink
    (128, 128, 0),  # olive
    (0, 128, 128),  # teal
    (255, 152, 150),  # salmon
    (170, 255, 195),  # mint
    (220, 190, 255),  # lavender
)


def colour(agent: int) -> tuple[int, int, int]:
    """The RGB colour of ``agent`` and of its goal (distinct for up to ``len(AGENT_COLOURS)`` agents)."""
    return AGENT_COLOURS[agent % len(AGENT_COLOURS)]


def _window(image: np.ndarray, centre_xy: tuple[float, float], radius_px: float):
    """The part of ``image`` a shape of ``radius_px`` around ``centre_xy`` can touch, and pixel-centre offsets
    (dx right, dy down) from the centre: drawing only there keeps a frame cheap whatever the agent count."""
    height, width, _ = image.shape
    x0, x1 = max(int(centre_xy[0] - radius_px) - 1, 0), min(int(centre_xy[0] + radius_px) + 2, width)
    y0, y1 = max(int(centre_xy[1] - radius_px) - 1, 0), min(int(centre_xy[1] + radius_px) + 2, height)
    ys, xs = np.ogrid[y0:y1, x0:x1]
    return image[y0:y1, x0:x1], xs + 0.5 - centre_xy[0], ys + 0.5 - centre_xy[1]


def _disc(image: np.ndarray, centre_xy: tuple[float, float], radius_px: float, rgb: tuple[int, int, int]) -> None:
    patch, dx, dy = _window(image, centre_xy, radius_px)
    patch[dx**2 + dy**2 <= radius_px**2] = rgb


def _agent(
    image: np.ndarray, centre_xy: tuple[float, float], radius_px: float, rgb: tuple[int, int, int]
) -> None:
    """A disc with a thin dark rim: pale colours, and an agent on a goal of its colour, stay visible."""
    rim_px = 0.12 * radius_px if radius_px >= 5 else 0.0
    if rim_px:
        _disc(image, centre_xy, radius_px, WALL)
    _disc(image, centre_xy, radius_px - rim_px, rgb)


def _star(
    image: np.ndarray, centre_xy: tuple[float, float], radius_px: float, rgb: tuple[int, int, int], rim: bool = False
) -> None:
    """A five-pointed star, or with ``rim`` a line just outside its outline: a point is inside when its radius is
    below the star's outline at its angle."""
    rim_px = max(2.0, GOAL_RIM * radius_px) if rim else 0.0
    patch, dx, dy = _window(image, centre_xy, radius_px + rim_px)
    dy = -dy
    angle = np.arctan2(dy, dx) - np.pi / 2
    sector = np.abs(((angle % (2 * np.pi / 5)) / (2 * np.pi / 5)) - 0.5) * 2  # 1 at the tips, 0 between them
    outline = radius_px * (0.45 + 0.55 * sector)
    distance = np.hypot(dx, dy)
    inside = distance <= outline + rim_px
    patch[inside & (distance > outline) if rim else inside] = rgb


def _crashed(
    image: np.ndarray, centre_xy: tuple[float, float], radius_px: float, colours: list[tuple[int, int, int]]
) -> None:
    """Crashed agents where they crashed (several in one place share the disc, a slice each), crossed out."""
    _disc(image, centre_xy, radius_px, WALL)
    patch, dx, dy = _window(image, centre_xy, radius_px)
    inside = dx**2 + dy**2 <= (0.88 * radius_px) ** 2
    slice_of = np.floor((np.arctan2(dy, dx) + np.pi) / (2 * np.pi) * len(colours)).astype(int) % len(colours)
    for index, rgb in enumerate(colours):
        patch[inside & (slice_of == index)] = rgb
    half_width = max(1.0, 0.12 * radius_px)
    patch[inside & ((np.abs(dx - dy) <= half_width) | (np.abs(dx + dy) <= half_width))] = WALL


def draw_grid(
    rows: int,
    cols: int,
    blocked: np.ndarray,
    positions: np.ndarray,
    goals: np.ndarray,
    present: np.ndarray,
    pixels_per_cell: int,
) -> np.ndarray:
    """Grid world, (rows·k, cols·k, 3) uint8: interior walls dark, each goal a star (outlined over the agents) and
    each present agent a disc in the agent's ``colour`` (agent 0 red, agent 1 blue, ...), a crashed one (not present)
    crossed out where it crashed; any number of agents."""
    k = pixels_per_cell
    image = np.empty((rows * k, cols * k, 3), dtype=np.uint8)
    image[:] = BACKGROUND
    image[::k, :] = CELL_LINE
    image[:, ::k] = CELL_LINE
    for row, col in zip(*np.nonzero(blocked)):
        image[row * k : (row + 1) * k, col * k : (col + 1) * k] = WALL

    def centre(row: int, col: int) -> tuple[float, float]:
        return (col + 0.5) * k, (row + 0.5) * k

    for agent, (row, col) in enumerate(goals):
        _star(image, centre(row, col), 0.45 * k, colour(agent))
    crashed: dict[tuple[int, int], list] = {}  # two agents that collide in a cell share it
    for agent, (row, col) in enumerate(positions):
        if not present[agent]:
            crashed.setdefault((int(row), int(col)), []).append(colour(agent))
    for cell, colours in crashed.items():
        _crashed(image, centre(*cell), 0.35 * k, colours)
    shown = [(agent, centre(row, col)) for agent, (row, col) in enumerate(positions) if present[agent]]
    for agent, xy in shown:
        _agent(image, xy, 0.35 * k, colour(agent))
    for agent, (row, col) in enumerate(goals):  # over the agents: a goal under an agent (each start) still shows
        _star(image, centre(row, col), 0.45 * k, colour(agent), rim=True)
    for agent, xy in shown:
        _disc(image, xy, AGENT_CORE * 0.35 * k, colour(agent))
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
    """Continuous world seen from above (x to the right, y up), an array (round(width_m·ppm) + 8,
    round(length_m·ppm) + 8, 3) uint8: walls as a dark border and dark interior boxes, goals as stars (outlined
    over the agents) and agents as discs with a heading tick, each in the agent's ``colour``, a crashed one (not
    present) crossed out where it crashed; any number of agents."""
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
    radius_px = radius_m * pixels_per_m
    for agent, (x, y) in enumerate(goals):
        # A little larger than an agent, so the tips show around an agent standing on the goal.
        _star(image, to_px(x, y), 1.25 * radius_px, colour(agent))
    for agent, (x, y) in enumerate(positions):
        if not present[agent]:
            _crashed(image, to_px(x, y), radius_px, [colour(agent)])
    shown = [(agent, x, y, theta) for agent, ((x, y), theta) in enumerate(zip(positions, headings)) if present[agent]]
    for agent, x, y, _ in shown:
        _agent(image, to_px(x, y), radius_px, colour(agent))
    for agent, (x, y) in enumerate(goals):  # over the agents: a goal under an agent (each start) still shows
        _star(image, to_px(x, y), 1.25 * radius_px, colour(agent), rim=True)
    for agent, x, y, theta in shown:
        _disc(image, to_px(x, y), AGENT_CORE * radius_px, colour(agent))
        for fraction in np.linspace(0.0, 0.85, 10):  # heading tick from the centre to the rim
            tx, ty = to_px(x + fraction * radius_m * np.cos(theta), y + fraction * radius_m * np.sin(theta))
            _disc(image, (tx, ty), max(1.5, 0.08 * radius_px), TICK)
    return image
