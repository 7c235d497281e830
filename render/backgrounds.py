"""Background bank (thesis 7.6: random backgrounds), generated procedurally, no downloads.

The thesis composites its cloth renders over photographs of the MIT indoor-scene dataset
(Quattoni & Torralba 2009, "Recognizing indoor scenes"), which cannot be downloaded here;
this bank substitutes indoor-like images of the same role: clutter with low-frequency
structure, muted colours and edges the network must learn to ignore. Kinds
(:func:`available_background_kinds`, drawn uniformly): ``gradient`` (two muted colours
along a random direction, with a vignette), ``room`` (a wall above a floor at a random
horizon, with a skirting board, a lit window or a picture frame and a wooden-plank or
carpet floor), ``shapes`` (a wall with blurred rectangles and ellipses like out-of-focus
furniture) and, when scikit-image is installed, ``photo`` (a random crop of its sample
photographs). Every kind ends with a random Gaussian blur (depth of field) and a mild
noise grain. Determinism: as for textures, same Generator state -> same bytes for a given
set of available kinds; pin ``kinds`` to be independent of scikit-image.

Backdrops (:data:`BACKDROPS`, a dataset's ``backdrop``) say which kinds a dataset draws from:
``bank`` the whole bank above (the training data's rooms), ``plain`` one muted uniform colour,
``dark`` a dark studio backdrop, ``gradient`` the gradient kind only. ``plain`` and ``dark``
are kinds of their own that the bank never draws, so the bank's bytes are those of before.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
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
    "BACKDROPS",
    "PROCEDURAL_BACKGROUND_KINDS",
    "available_background_kinds",
    "backdrop_kinds",
    "make_background",
]

PROCEDURAL_BACKGROUND_KINDS: tuple[str, ...] = ("gradient", "room", "shapes")
"""Background kinds of the bank that need nothing beyond numpy and cv2."""

BACKDROPS: dict[str, tuple[str, ...] | None] = {
    "bank": None,
    "plain": ("plain",),
    "dark": ("dark",),
    "gradient": ("gradient",),
}
"""Backdrop name -> the kinds :func:`make_background` draws from (``None``: the whole bank,
:func:`available_background_kinds`)."""


def available_background_kinds() -> tuple[str, ...]:
    """Kinds :func:`make_background` draws from here (``photo`` only with scikit-image)."""
    if photos_available():
        return (*PROCEDURAL_BACKGROUND_KINDS, "photo")
    return PROCEDURAL_BACKGROUND_KINDS


def backdrop_kinds(backdrop: str) -> tuple[str, ...] | None:
    """The kinds of ``backdrop`` (:data:`BACKDROPS`); a ValueError names the allowed ones."""
    if backdrop not in BACKDROPS:
        raise ValueError(f"backdrop must be one of {list(BACKDROPS)}, got {backdrop!r}")
    return BACKDROPS[backdrop]


def _muted(rng: np.random.Generator, lo: float = 0.3, hi: float = 0.9) -> np.ndarray:
    return random_color(rng, saturation=(0.0, 0.45), value=(lo, hi))


def _fill(colour: np.ndarray, height: int, width: int) -> np.ndarray:
    return np.broadcast_to(colour, (height, width, 3)).copy()


def _gradient(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    first, second = _muted(rng), _muted(rng)
    u, _ = rotated_coords(height, width, rng.uniform(0, 2 * math.pi))
    u = (u - u.min()) / max(float(np.ptp(u)), 1e-12)
    image = first + u[..., None] * (second - first)
    y, x = np.mgrid[0:height, 0:width]
    r2 = ((x - width / 2) / width) ** 2 + ((y - height / 2) / height) ** 2
    return image * (1.0 - rng.uniform(0.0, 0.8) * r2)[..., None]


def _room(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    horizon = round(rng.uniform(0.35, 0.8) * height)
    wall = _muted(rng, 0.45, 0.95)
    image = _fill(wall, height, width)
    # Light falls off down the wall and towards one side.
    y, x = np.mgrid[0:height, 0:width] / np.array([height, width])[:, None, None]
    side = rng.uniform(-0.25, 0.25)
    image *= (1.0 - 0.25 * y + side * (x - 0.5))[..., None]
    feature = rng.uniform()
    if feature < 0.35:  # lit window
        w, h = rng.uniform(0.2, 0.45) * width, rng.uniform(0.25, 0.5) * horizon
        x0, y0 = rng.uniform(0, width - w), rng.uniform(0.05, 0.5) * max(horizon - h, 1)
        sky = random_color(rng, saturation=(0.0, 0.3), value=(0.85, 1.0))
        image[int(y0) : int(y0 + h), int(x0) : int(x0 + w)] = sky
        frame = max(1, round(0.02 * width))
        image[int(y0) : int(y0 + h), int(x0 + w / 2) : int(x0 + w / 2) + frame] = 0.9 * wall
    elif feature < 0.7:  # picture frame
        w, h = rng.uniform(0.15, 0.35) * width, rng.uniform(0.15, 0.35) * horizon
        x0, y0 = rng.uniform(0, width - w), rng.uniform(0.05, 0.6) * max(horizon - h, 1)
        border = max(1, round(0.015 * width))
        image[int(y0) : int(y0 + h), int(x0) : int(x0 + w)] = random_color(rng, value=(0.1, 0.4))
        image[int(y0) + border : int(y0 + h) - border, int(x0) + border : int(x0 + w) - border] = (
            random_color(rng)
        )
    floor = random_color(rng, saturation=(0.1, 0.6), value=(0.2, 0.65))
    rows = height - horizon
    if rows > 0:
        grain = value_noise(rng, rows, width, cells=int(rng.integers(3, 8)), octaves=3)
        floor_img = floor * (0.8 + 0.4 * grain)[..., None]
        if rng.uniform() < 0.5:  # planks: seams whose spacing grows towards the camera
            depth = np.linspace(0.0, 1.0, rows) ** 1.6
            seams = np.mod(depth * rng.uniform(4, 10), 1.0) < 0.08
            floor_img[seams] *= 0.7
        image[horizon:] = floor_img
        skirting = max(1, round(rng.uniform(0.01, 0.04) * height))
        image[horizon : horizon + skirting] = _muted(rng, 0.6, 1.0)
    return image


def _shapes(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    image = _fill(_muted(rng, 0.4, 0.9), height, width)
    for _ in range(int(rng.integers(3, 9))):
        colour = random_color(rng, saturation=(0.0, 0.7), value=(0.15, 0.95))
        cx, cy = rng.uniform(0, width), rng.uniform(0, height)
        sx, sy = rng.uniform(0.08, 0.4) * width, rng.uniform(0.08, 0.5) * height
        if rng.uniform() < 0.5:
            x0, x1 = int(max(cx - sx / 2, 0)), int(min(cx + sx / 2, width))
            y0, y1 = int(max(cy - sy / 2, 0)), int(min(cy + sy / 2, height))
            image[y0:y1, x0:x1] = colour
        else:
            y, x = np.mgrid[0:height, 0:width]
            inside = ((x - cx) / (sx / 2)) ** 2 + ((y - cy) / (sy / 2)) ** 2 < 1.0
            image[inside] = colour
    sigma = rng.uniform(0.015, 0.05) * max(height, width)
    return cv2.GaussianBlur(image, (0, 0), sigmaX=sigma)


def _photo(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    return random_photo(rng, height, width, min_fraction=0.5)


def _plain(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    return _fill(_muted(rng), height, width)


def _dark(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    # A black or dark-grey studio cloth, lit a little.
    return _fill(_muted(rng, 0.02, 0.12), height, width)


_GENERATORS = {
    "gradient": _gradient,
    "room": _room,
    "shapes": _shapes,
    "photo": _photo,
    "plain": _plain,
    "dark": _dark,
}


def make_background(
    rng: np.random.Generator,
    width: int,
    height: int,
    *,
    kinds: Sequence[str] | None = None,
) -> np.ndarray:
    """One random background image.

    Args:
        rng: Source of randomness.
        width: Image width [px].
        height: Image height [px].
        kinds: Kinds to draw from (default :func:`available_background_kinds`).

    Returns:
        RGB image, uint8, shape (height, width, 3).

    Raises:
        ValueError: for a non-positive size, an unknown kind, or ``photo`` without
            scikit-image.
    """
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
            raise ValueError(f"background {name} must be a positive integer [px], got {value!r}")
    width, height = int(width), int(height)
    kinds = available_background_kinds() if kinds is None else tuple(kinds)
    kind = draw_kind(rng, kinds, _GENERATORS, "background", photos=photos_available())
    image = _GENERATORS[kind](rng, height, width).astype(np.float32)
    sigma = rng.uniform(0.0, 0.01) * max(height, width)
    if sigma > 0.3:
        image = cv2.GaussianBlur(image, (0, 0), sigmaX=sigma)
    image += rng.normal(0.0, 0.01, size=image.shape).astype(np.float32)
    return to_uint8(image)
