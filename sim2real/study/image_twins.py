"""Image effects of sealed sets written apart from the renderer's (:mod:`render.effects`).

A validation whose sealed sets were made by the very code the candidates run could pass on a
match of implementations instead of an identification. These are second implementations of
the renderer's image effects, with the same parameters and physical meaning but another
model or library each, so a sealed set made with them differs from any candidate set in its
details the way footage from another camera would:

* defocus blur: a six-bladed (hexagonal) aperture, applied in the Fourier domain (the
  renderer: an anti-aliased disc by direct convolution);
* vignetting: the cos⁴ law of natural vignetting, with the field angle set so that the corners
  get the same gain ``1 - strength`` (the renderer: ``1 - strength r²``);
* sensor noise: Poisson shot noise in electrons plus Gaussian read noise, quantised (the
  renderer: one Gaussian of the summed variance);
* white balance: channel gains applied to linear light, between an sRGB decode and encode
  (the renderer: to the encoded values);
* compression: JPEG through Pillow with 4:2:0 chroma subsampling and an optimised Huffman
  table (the renderer: OpenCV's encoder).

The frame rate, motion blur, camera shake and rolling shutter are made by the renderer's
timing and geometry and stay the renderer's.
"""

from __future__ import annotations

import io
import math

import numpy as np

from render.effects import VisualEffects

__all__ = ["TWIN_EFFECTS", "apply_image_twins", "hexagon_kernel", "without_twinned"]

TWIN_EFFECTS = ("defocus_blur", "vignetting", "sensor_noise", "white_balance", "compression")
"""The renderer's image effects that have a second implementation here, in camera order."""


def without_twinned(effects: VisualEffects) -> VisualEffects:
    """``effects`` with the twinned switches off: what the renderer itself should apply."""
    import dataclasses

    return dataclasses.replace(effects, **dict.fromkeys(TWIN_EFFECTS, False))


def hexagon_kernel(radius: float, size: int) -> np.ndarray:
    """A six-bladed aperture's PSF of circumradius ``radius`` [px], centred in (size, size).

    Coverage of each pixel by the hexagon, estimated on a 6 x 6 sub-grid; sums to 1.
    """
    sub = (np.arange(6) + 0.5) / 6 - 0.5
    taps = np.arange(size) - size // 2
    x = (taps[:, None] + sub[None, :]).reshape(-1)
    xx, yy = np.meshgrid(x, x, indexing="xy")
    inside = np.ones_like(xx, dtype=bool)
    apothem = radius * math.cos(math.pi / 6)
    for k in range(3):  # three pairs of parallel edges
        angle = math.pi / 3 * k
        inside &= np.abs(xx * math.cos(angle) + yy * math.sin(angle)) <= apothem
    kernel = inside.reshape(size, 6, size, 6).mean(axis=(1, 3))
    return kernel / kernel.sum()


def _defocus(clip: np.ndarray, radius: float) -> np.ndarray:
    if radius < 0.5:
        return clip.astype(np.float64)
    h, w = clip.shape[1:3]
    pad = math.ceil(radius) + 1
    padded = np.pad(
        clip.astype(np.float64), ((0, 0), (pad, pad), (pad, pad), (0, 0)), mode="reflect"
    )
    ph, pw = padded.shape[1:3]
    kernel = hexagon_kernel(radius, 2 * pad + 1)
    spread = np.zeros((ph, pw))
    spread[: kernel.shape[0], : kernel.shape[1]] = kernel
    spread = np.roll(spread, (-pad, -pad), axis=(0, 1))  # centre the PSF at the origin
    transfer = np.fft.rfft2(spread)
    blurred = np.fft.irfft2(
        np.fft.rfft2(padded, axes=(1, 2)) * transfer[None, :, :, None], s=(ph, pw), axes=(1, 2)
    )
    return blurred[:, pad : pad + h, pad : pad + w]


def _vignetting(frames: np.ndarray, strength: float) -> np.ndarray:
    h, w = frames.shape[1:3]
    y = (np.arange(h) + 0.5 - h / 2) / (h / 2)
    x = (np.arange(w) + 0.5 - w / 2) / (w / 2)
    r = np.sqrt((y[:, None] ** 2 + x[None, :] ** 2) / 2.0)  # 1 at a corner
    corner_angle = math.acos((1.0 - strength) ** 0.25)  # cos⁴ = 1 - strength at a corner
    gain = np.cos(np.arctan(r * math.tan(corner_angle))) ** 4
    return frames * gain[None, :, :, None]


def _sensor_noise(
    frames: np.ndarray, rng: np.random.Generator, read_sigma: float, shot_gain: float
) -> np.ndarray:
    level = np.clip(frames, 0.0, 255.0)
    electrons = rng.poisson(level / shot_gain) if shot_gain > 0 else level
    return electrons * shot_gain + rng.normal(0.0, read_sigma, size=frames.shape)


def _to_linear(v: np.ndarray) -> np.ndarray:
    v = np.clip(v / 255.0, 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _to_srgb(v: np.ndarray) -> np.ndarray:
    v = np.clip(v, 0.0, 1.0)
    return 255.0 * np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)


def _white_balance(frames: np.ndarray, rng: np.random.Generator, shift: float) -> np.ndarray:
    gains = rng.uniform(1.0 - shift, 1.0 + shift, size=3)
    gains /= gains.mean()
    return _to_srgb(_to_linear(frames) * gains)


def _jpeg(clip: np.ndarray, quality: int) -> np.ndarray:
    from PIL import Image

    out = np.empty_like(clip)
    for k, frame in enumerate(clip):
        buffer = io.BytesIO()
        Image.fromarray(frame).save(
            buffer, format="JPEG", quality=int(quality), subsampling=2, optimize=True
        )
        out[k] = np.asarray(Image.open(io.BytesIO(buffer.getvalue())).convert("RGB"))
    return out


def _quantised(frames: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(frames), 0, 255).astype(np.uint8)


def apply_image_twins(
    clip: np.ndarray, effects: VisualEffects, rng: np.random.Generator
) -> np.ndarray:
    """Apply the enabled twinned effects of ``effects`` to ``clip`` (uint8 (K, H, W, 3)).

    In the renderer's camera order (defocus, vignetting, noise, white balance, compression),
    with the renderer's parameters; the defocus radius is drawn between its minimum and
    maximum as the renderer draws it, from ``rng``.
    """
    clip = np.asarray(clip)
    if clip.dtype != np.uint8 or clip.ndim != 4 or clip.shape[-1] != 3:
        raise ValueError(f"clip must be uint8 (K, H, W, 3), got {clip.dtype} {clip.shape}")
    frames = clip.astype(np.float64)
    if effects.defocus_blur:
        radius = rng.uniform(effects.defocus_radius_min_px, effects.defocus_radius_max_px)
        frames = _defocus(clip, radius)
    if effects.vignetting:
        frames = _vignetting(frames, effects.vignetting_strength)
    if effects.sensor_noise:
        frames = _sensor_noise(frames, rng, effects.noise_read_sigma, effects.noise_shot_gain)
    if effects.white_balance:
        frames = _white_balance(frames, rng, effects.white_balance_shift)
    out = _quantised(frames)
    if effects.compression:
        out = _jpeg(out, effects.jpeg_quality)
    return out
