"""Procedural image primitives shared by the texture and background banks (numpy + cv2).

Everything here is deterministic given a ``numpy.random.Generator`` and returns float
images in [0, 1] of shape (H, W, 3) or (H, W) unless stated; :func:`to_uint8` converts.
Optional photographs come from scikit-image's bundled sample data (``skimage.data``, shipped
inside the wheel, no download) when scikit-image is installed: :func:`photos_available`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence

import cv2
import numpy as np

__all__ = [
    "PHOTO_NAMES",
    "draw_kind",
    "hsv_to_rgb",
    "load_photo",
    "photos_available",
    "random_color",
    "random_crop",
    "random_photo",
    "rotated_coords",
    "to_uint8",
    "value_noise",
]

PHOTO_NAMES: tuple[str, ...] = ("astronaut", "coffee", "chelsea", "rocket")
"""Colour photographs of ``skimage.data`` used when scikit-image is installed."""


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Float image in [0, 1] (clipped) -> uint8, same shape."""
    return np.clip(np.rint(np.asarray(image) * 255.0), 0, 255).astype(np.uint8)


def hsv_to_rgb(hue, saturation, value) -> np.ndarray:
    """HSV in [0, 1] (broadcastable arrays) -> RGB in [0, 1], shape (..., 3)."""
    hue, saturation, value = np.broadcast_arrays(
        np.asarray(hue, np.float64),
        np.asarray(saturation, np.float64),
        np.asarray(value, np.float64),
    )
    sector = np.floor(hue * 6.0)
    frac = hue * 6.0 - sector
    p = value * (1.0 - saturation)
    q = value * (1.0 - saturation * frac)
    t = value * (1.0 - saturation * (1.0 - frac))
    sector = sector.astype(np.int64) % 6
    r = np.choose(sector, [value, q, p, p, t, value])
    g = np.choose(sector, [t, value, value, q, p, p])
    b = np.choose(sector, [p, p, t, value, value, q])
    return np.stack([r, g, b], -1)


def random_color(
    rng: np.random.Generator,
    *,
    saturation: tuple[float, float] = (0.0, 0.9),
    value: tuple[float, float] = (0.2, 0.95),
) -> np.ndarray:
    """One colour with uniform hue and uniform saturation/value in the given ranges, (3,)."""
    h, s, v = rng.uniform(0, 1), rng.uniform(*saturation), rng.uniform(*value)
    return hsv_to_rgb(h, s, v)


def rotated_coords(height: int, width: int, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates rotated by ``angle`` [rad], in units of ``height``.

    Returns:
        ``(u, v)``, each shape (H, W): the coordinates along the rotated x and y axes,
        so ``floor(u / period)`` gives stripes perpendicular to the rotated x axis.
    """
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    x = (x + 0.5) / height
    y = (y + 0.5) / height
    c, s = math.cos(angle), math.sin(angle)
    return c * x + s * y, -s * x + c * y


def value_noise(
    rng: np.random.Generator, height: int, width: int, *, cells: int = 4, octaves: int = 4
) -> np.ndarray:
    """Smooth fractal value noise normalised to [0, 1], shape (H, W).

    Octave ``o`` is a ``cells * 2**o`` lattice of uniform values upsampled bicubically,
    weighted by ``0.5**o``.
    """
    total = np.zeros((height, width), np.float64)
    for octave in range(octaves):
        n = cells * 2**octave
        grid = rng.uniform(0, 1, size=(n + 1, n + 1)).astype(np.float32)
        total += 0.5**octave * cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC)
    lo, hi = total.min(), total.max()
    return (total - lo) / max(hi - lo, 1e-12)


@functools.cache
def photos_available() -> bool:
    """Whether scikit-image (and so its bundled sample photographs) is importable."""
    try:
        import skimage.data  # noqa: F401
    except ImportError:
        return False
    return True


@functools.cache
def _load_photo_cached(name: str) -> np.ndarray:
    import skimage.data

    image = np.asarray(getattr(skimage.data, name)())
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=-1)
    image = image[..., :3]
    if image.dtype != np.uint8:
        image = to_uint8(image.astype(np.float64) / max(float(image.max()), 1e-12))
    image.setflags(write=False)
    return image


def load_photo(name: str) -> np.ndarray:
    """A ``skimage.data`` photograph as read-only uint8 RGB, shape (H, W, 3).

    Raises:
        ValueError: for a name outside :data:`PHOTO_NAMES`.
        ImportError: when scikit-image is not installed.
    """
    if name not in PHOTO_NAMES:
        raise ValueError(f"photo must be one of {PHOTO_NAMES}, got {name!r}")
    return _load_photo_cached(name)


def random_crop(
    rng: np.random.Generator,
    image: np.ndarray,
    height: int,
    width: int,
    *,
    min_fraction: float = 0.4,
    allow_flips: bool = True,
) -> np.ndarray:
    """Random crop with the output's aspect ratio, resized (INTER_AREA) to (height, width, 3).

    The crop's side is a fraction in ``[min_fraction, 1]`` of the largest crop that fits;
    with ``allow_flips`` it is also mirrored horizontally with probability 1/2.
    """
    src_h, src_w = image.shape[:2]
    aspect = width / height
    full_h = min(src_h, src_w / aspect)
    crop_h = full_h * rng.uniform(min_fraction, 1.0)
    crop_w = crop_h * aspect
    ch, cw = max(1, round(crop_h)), max(1, round(crop_w))
    top = int(rng.integers(0, src_h - ch + 1))
    left = int(rng.integers(0, src_w - cw + 1))
    crop = np.ascontiguousarray(image[top : top + ch, left : left + cw])
    flip = bool(rng.integers(0, 2)) if allow_flips else False
    if flip:
        crop = crop[:, ::-1]
    interpolation = cv2.INTER_AREA if ch >= height else cv2.INTER_LINEAR
    return cv2.resize(np.ascontiguousarray(crop), (width, height), interpolation=interpolation)


def random_photo(
    rng: np.random.Generator, height: int, width: int, *, min_fraction: float
) -> np.ndarray:
    """A random crop (:func:`random_crop`) of a random sample photograph, shape (H, W, 3)."""
    name = PHOTO_NAMES[int(rng.integers(len(PHOTO_NAMES)))]
    crop = random_crop(rng, load_photo(name), height, width, min_fraction=min_fraction)
    return crop.astype(np.float64) / 255.0


def draw_kind(
    rng: np.random.Generator,
    kinds: Sequence[str],
    generators: Mapping[str, object],
    what: str,
    *,
    photos: bool,
) -> str:
    """One of ``kinds`` drawn uniformly, once they are checked against ``generators``.

    ``what`` names the bank in the messages; ``photos`` says whether ``photo`` can be drawn.

    Raises:
        ValueError: for no kinds, a kind outside ``generators``, or ``photo`` without photos.
    """
    unknown = [k for k in kinds if k not in generators]
    if unknown or not kinds:
        raise ValueError(
            f"{what} kinds must be a non-empty subset of {tuple(generators)}, got {kinds}"
        )
    if "photo" in kinds and not photos:
        raise ValueError(f"{what} kind 'photo' needs scikit-image, which is not installed")
    return kinds[int(rng.integers(len(kinds)))]
