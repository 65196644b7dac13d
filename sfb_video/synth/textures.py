"""Procedural texture images for the synthetic objects, deterministic from a random generator.

Convention:
    A texture is an (S, S, 3) uint8 RGB image, indexed [row, column]; texture coordinate
    (u, v) = (0, 0) is its top-left corner, u along the width (see ``geometry/mesh.py``).
    Textures are quantised to 8 bit when made, so what is rendered is exactly what a saved
    PNG holds.

Every style has strong, saturated contrast at several scales: a fitter can only recover a
rotation from the motion of texture detail, and a flat colour would hide it.
"""

from __future__ import annotations

import numpy as np

from sfb_video.errors import SfbError

TEXTURE_STYLES = ("stripes", "checker", "patches", "mixed")
"""The styles "random" draws from (kept as they are: every seeded set's draws depend on them)."""

OBJECT_STYLES = ("plain", "seam", "spokes")
"""Styles named only, for the looks real objects have that the random ones lack: one colour, a
tennis ball's seam, a flying disc's spokes."""


def random_palette(rng: np.random.Generator, count: int) -> np.ndarray:
    """(count, 3) float colours in [0, 1] with well-spread hues and strong saturation."""
    # Hues on a jittered circle keep neighbours in the palette distinguishable.
    hue = (rng.uniform() + np.arange(count) / count + rng.uniform(-0.15, 0.15, count) / count) % 1.0
    sat = rng.uniform(0.55, 1.0, count)
    val = rng.uniform(0.35, 1.0, count)
    return _hsv_to_rgb(np.stack((hue, sat, val), -1))


def _hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """(*, 3) HSV in [0, 1] -> (*, 3) RGB in [0, 1]."""
    h, s, v = hsv[..., 0] * 6.0, hsv[..., 1], hsv[..., 2]
    sector = np.floor(h).astype(np.int64) % 6
    f = h - np.floor(h)
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    table = np.stack(
        (
            np.stack((v, t, p), -1),
            np.stack((q, v, p), -1),
            np.stack((p, v, t), -1),
            np.stack((p, q, v), -1),
            np.stack((t, p, v), -1),
            np.stack((v, p, q), -1),
        ),
        0,
    )
    return np.take_along_axis(table, sector[None, ..., None].repeat(3, -1), 0)[0]


def _grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Texel-centre coordinates (u, v) in [0, 1], each (size, size)."""
    c = (np.arange(size) + 0.5) / size
    v, u = np.meshgrid(c, c, indexing="ij")
    return u, v


def stripes(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, size, 3) float: bands of 3-5 colours at a random angle and frequency."""
    u, v = _grid(size)
    colours = random_palette(rng, int(rng.integers(3, 6)))
    angle = rng.uniform(0, np.pi)
    # An integer number of periods along u keeps a u-wrapping seam (sphere, torus) invisible
    # when the stripes run across it.
    periods = int(rng.integers(4, 10))
    phase = (u * np.cos(angle) + v * np.sin(angle)) * periods * len(colours)
    return colours[np.floor(phase).astype(np.int64) % len(colours)]


def checker(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, size, 3) float: a two-colour checkerboard of 4-12 cells per side."""
    u, v = _grid(size)
    colours = random_palette(rng, 2)
    cells = int(rng.integers(2, 7)) * 2
    parity = (np.floor(u * cells) + np.floor(v * cells)).astype(np.int64) % 2
    return colours[parity]


def patches(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, size, 3) float: Voronoi patches of 8-24 colours, periodic in u (no seam)."""
    u, v = _grid(size)
    count = int(rng.integers(8, 25))
    centres = rng.uniform(0, 1, (count, 2))
    colours = random_palette(rng, count)
    du = np.abs(u[..., None] - centres[:, 0])
    du = np.minimum(du, 1 - du)
    dist = du**2 + (v[..., None] - centres[:, 1]) ** 2
    return colours[np.argmin(dist, axis=-1)]


def mixed(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, size, 3) float: patches overlaid with thin dark stripes (fine and coarse detail)."""
    base = patches(rng, size)
    u, v = _grid(size)
    angle = rng.uniform(0, np.pi)
    periods = int(rng.integers(6, 14))
    phase = ((u * np.cos(angle) + v * np.sin(angle)) * periods) % 1.0
    line = phase < rng.uniform(0.12, 0.25)
    return np.where(line[..., None], base * 0.25, base)


def plain(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, size, 3) float: one colour (a plain ball or box; its rotation cannot be seen)."""
    return np.broadcast_to(random_palette(rng, 1)[0], (size, size, 3)).copy()


def seam(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, size, 3) float: a tennis ball's look on a sphere's (longitude, latitude) map: one
    colour crossed by a pale band that swings twice around the ball, the seam's curve."""
    u, v = _grid(size)
    base, line = random_palette(rng, 1)[0], np.array([0.95, 0.95, 0.9])
    swing = rng.uniform(0.18, 0.26)
    curve = 0.5 + swing * np.sin(4 * np.pi * (u + rng.uniform()))
    band = np.abs(v - curve) < rng.uniform(0.025, 0.04)
    return np.where(band[..., None], line, base)


def spokes(rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, size, 3) float: on a planar map centred at (0.5, 0.5) (a disc's face), 4-8 dark
    spokes from the centre over a light colour, and a dark rim."""
    u, v = _grid(size)
    base = random_palette(rng, 1)[0]
    dark = base * 0.2
    count = int(rng.integers(4, 9))
    angle = (np.arctan2(v - 0.5, u - 0.5) + rng.uniform(0, np.pi)) % (2 * np.pi / count)
    radius = np.hypot(u - 0.5, v - 0.5)
    spoke = (angle < rng.uniform(0.15, 0.3) * 2 * np.pi / count) & (radius > 0.06)
    rim = (radius > 0.42) & (radius < 0.5)
    return np.where((spoke | rim)[..., None], dark, base)


_MAKERS = {
    "stripes": stripes,
    "checker": checker,
    "patches": patches,
    "mixed": mixed,
    "plain": plain,
    "seam": seam,
    "spokes": spokes,
}


def procedural_texture(rng: np.random.Generator, size: int, style: str) -> np.ndarray:
    """An (size, size, 3) uint8 texture of ``style`` (one of ``TEXTURE_STYLES`` or
    ``OBJECT_STYLES``, or "random").

    "random" draws the style from ``rng``, so the texture is still a function of the seed.
    """
    if size < 4:
        raise SfbError(f"texture size must be at least 4 texels, got {size}")
    if style == "random":
        style = TEXTURE_STYLES[int(rng.integers(len(TEXTURE_STYLES)))]
    if style not in _MAKERS:
        raise SfbError(f"unknown texture style {style!r}; choose one of {', '.join(_MAKERS)}")
    image = _MAKERS[style](rng, size)
    return np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)
