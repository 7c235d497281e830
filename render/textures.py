"""Fabric texture bank (thesis 7.6: random textures), generated procedurally, no downloads.

Modes (:class:`TextureMode`): ``grid`` is one fixed grey checkerboard (8 x 8 squares over the
cloth) that makes the deformation easy to read; ``color`` is one random solid colour per clip
(shading is then the only cue); ``random`` draws one kind uniformly from
:func:`available_texture_kinds`: ``stripes``, ``plaid``, ``dots``, ``noise`` (fractal value
noise, half of the time warped into marble-like veins) and ``checks``, each with random
palettes, scales and angles, plus ``photo`` (a random crop of a scikit-image sample
photograph used as a fabric print) when scikit-image is installed. The texture spans the
whole cloth once (the renderer maps the cloth's uv extent to [0, 1]), so pattern periods are
drawn log-uniformly between 1/16 and 1/4 of the texture, i.e. about 3-12 cm on the 0.5 m
cloth and 3-16 px in the 112 px presets; finer patterns would be mipmapped to a flat average.
Determinism: the same Generator state gives the same bytes for a given set of available
kinds; ``photo`` exists only with scikit-image, so pin ``kinds`` when clips must be
reproducible across environments with and without it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from enum import StrEnum

import numpy as np

from .patterns import (
    draw_kind,
    photos_available,
    random_color,
    random_photo,
    rotated_coords,
    to_uint8,
    value_noise,
)

__all__ = [
    "PROCEDURAL_TEXTURE_KINDS",
    "TextureMode",
    "available_texture_kinds",
    "make_texture",
]

PROCEDURAL_TEXTURE_KINDS: tuple[str, ...] = ("stripes", "plaid", "dots", "noise", "checks")
"""Kinds of ``random`` textures that need nothing beyond numpy and cv2."""


class TextureMode(StrEnum):
    """How a clip's cloth texture is chosen."""

    GRID = "grid"
    COLOR = "color"
    RANDOM = "random"


def available_texture_kinds() -> tuple[str, ...]:
    """Kinds ``random`` mode draws from here: the procedural ones, plus ``photo`` if possible."""
    return (*PROCEDURAL_TEXTURE_KINDS, "photo") if photos_available() else PROCEDURAL_TEXTURE_KINDS


def _palette(rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` colours whose first two differ clearly in brightness, shape (count, 3)."""
    dark = random_color(rng, saturation=(0.0, 0.9), value=(0.12, 0.5))
    light = random_color(rng, saturation=(0.0, 0.7), value=(0.6, 0.97))
    colours = [dark, light] if rng.uniform() < 0.5 else [light, dark]
    colours += [random_color(rng) for _ in range(count - 2)]
    return np.stack(colours)


def _period(rng: np.random.Generator) -> float:
    # Log-uniform between 1/16 and 1/4 of the texture side (see the module docstring).
    return math.exp(rng.uniform(math.log(1 / 16), math.log(1 / 4)))


def _stripes(rng: np.random.Generator, size: int) -> np.ndarray:
    count = int(rng.integers(2, 4))
    colours = _palette(rng, count)
    period, angle = _period(rng), rng.uniform(0, math.pi)
    widths = rng.uniform(0.3, 1.0, size=count)
    edges = np.cumsum(widths) / widths.sum()
    u, _ = rotated_coords(size, size, angle)
    phase = np.mod(u / period, 1.0)
    index = np.minimum(np.searchsorted(edges, phase, side="right"), count - 1)
    return colours[index]


def _plaid(rng: np.random.Generator, size: int) -> np.ndarray:
    colours = _palette(rng, 4)
    angle = rng.uniform(0, math.pi / 2)
    u, v = rotated_coords(size, size, angle)
    period_u, period_v = _period(rng), _period(rng)
    duty_u, duty_v = rng.uniform(0.25, 0.6, size=2)
    band_u = np.mod(u / period_u, 1.0) < duty_u
    band_v = np.mod(v / period_v, 1.0) < duty_v
    image = np.broadcast_to(colours[0], (size, size, 3)).copy()
    image[band_u] = colours[1]
    image[band_v] = colours[2]
    image[band_u & band_v] = 0.5 * (colours[1] + colours[2])
    # Thin over-check lines in a fourth colour, as in tartans.
    line_u = np.mod(u / period_u + 0.5 * duty_u, 1.0) < 0.08
    line_v = np.mod(v / period_v + 0.5 * duty_v, 1.0) < 0.08
    if rng.uniform() < 0.5:
        image[line_u | line_v] = colours[3]
    return image


def _dots(rng: np.random.Generator, size: int) -> np.ndarray:
    background, dot = _palette(rng, 2)
    period = _period(rng)
    radius = rng.uniform(0.15, 0.4) * period
    u, v = rotated_coords(size, size, rng.uniform(0, math.pi / 2))
    row = np.floor(v / period)
    if rng.uniform() < 0.5:  # hexagonal packing: every other row shifted by half a period
        u = u + 0.5 * period * np.mod(row, 2)
    du = np.mod(u, period) - 0.5 * period
    dv = np.mod(v, period) - 0.5 * period
    inside = du * du + dv * dv < radius * radius
    return np.where(inside[..., None], dot, background)


def _noise(rng: np.random.Generator, size: int) -> np.ndarray:
    colours = _palette(rng, int(rng.integers(2, 4)))
    noise = value_noise(rng, size, size, cells=int(rng.integers(2, 7)), octaves=4)
    if rng.uniform() < 0.5:  # marble: noise-warped sinusoidal veins
        u, _ = rotated_coords(size, size, rng.uniform(0, math.pi))
        noise = 0.5 + 0.5 * np.sin(2 * math.pi * (u / _period(rng) + 2.0 * noise))
    stops = np.linspace(0.0, 1.0, len(colours))
    return np.stack([np.interp(noise, stops, colours[:, c]) for c in range(3)], -1)


def _checks(rng: np.random.Generator, size: int) -> np.ndarray:
    first, second = _palette(rng, 2)
    period = _period(rng)
    u, v = rotated_coords(size, size, rng.uniform(0, math.pi / 2))
    parity = (np.floor(u / period) + np.floor(v / period)) % 2 == 0
    return np.where(parity[..., None], first, second)


def _photo(rng: np.random.Generator, size: int) -> np.ndarray:
    return random_photo(rng, size, size, min_fraction=0.35)


_GENERATORS = {
    "stripes": _stripes,
    "plaid": _plaid,
    "dots": _dots,
    "noise": _noise,
    "checks": _checks,
    "photo": _photo,
}


def _grid(size: int) -> np.ndarray:
    index = np.arange(size) * 8 // size
    parity = (index[:, None] + index[None, :]) % 2 == 0
    return np.where(parity[..., None], 0.85, 0.25) * np.ones(3)


def make_texture(
    mode: TextureMode | str,
    rng: np.random.Generator,
    size: int = 256,
    *,
    kinds: Sequence[str] | None = None,
) -> np.ndarray:
    """One cloth texture.

    Args:
        mode: ``grid``, ``color`` or ``random`` (see the module docstring).
        rng: Source of randomness; ``grid`` does not draw from it.
        size: Side of the square texture [texels].
        kinds: For ``random``: the kinds to draw from (default
            :func:`available_texture_kinds`).

    Returns:
        RGB texture, uint8, shape (size, size, 3); row 0 is the cloth's v = 0 edge and
        column 0 its u = 0 edge.

    Raises:
        ValueError: for an unknown mode or kind, a size below 8, or ``photo`` requested
            without scikit-image.
    """
    try:
        mode = TextureMode(mode)
    except ValueError:
        raise ValueError(
            f"texture mode must be one of {[m.value for m in TextureMode]}, got {mode!r}"
        ) from None
    if isinstance(size, bool) or not isinstance(size, int | np.integer) or size < 8:
        raise ValueError(f"texture size must be an integer >= 8, got {size!r}")
    size = int(size)
    if mode is TextureMode.GRID:
        return to_uint8(_grid(size))
    if mode is TextureMode.COLOR:
        colour = random_color(rng, saturation=(0.0, 0.9), value=(0.2, 0.95))
        return np.broadcast_to(to_uint8(colour), (size, size, 3)).copy()
    kinds = available_texture_kinds() if kinds is None else tuple(kinds)
    kind = draw_kind(rng, kinds, _GENERATORS, "texture", photos=photos_available())
    return to_uint8(_GENERATORS[kind](rng, size))
