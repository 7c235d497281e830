"""Re-texturing rendered cloth from stored render passes, without rendering again.

Why: with the ``random`` texture every simulation wears its own print, and a network can name
a training clip's class from the print instead of from how the cloth moves (the texture's
counterpart of the background shortcut that :class:`datasets.augment.BackgroundSwap`
removes). Given two extra passes per frame, training can dress the same simulated cloth in a
new texture every epoch.

The passes (:meth:`render.renderer.ClothRenderer.render_clip` with ``passes=True``), uint8,
premultiplied by coverage like the frames:

* ``grey`` and ``black``: the frame rendered with a mid-grey (:data:`GREY_TEXEL`, linear
  albedo 0.5) and with a black cloth (same lights, shadows, arm);
* ``uvm``: unlit, the cloth drawn with :func:`uv_ramp_texture` (red = texel column, green =
  texel row, blue = 255) and the arm black: red / blue and green / blue are the texture
  coordinates each pixel saw.

Why two lit passes reproduce the render: pyrender's shader outputs ``min(c, 1) ** (1 / 2.2)``
with ``c = srgb_to_linear(texel) * diffuse + specular`` (a dielectric's specular does not
depend on its albedo), so in linear light (``x ** 2.2`` undoes the output gamma) a texel's
colour is ``black + albedo / 0.5 * (grey - black)``, clipped at 1 as the render clips it.
The grey pass (rather than a white one) keeps ``diffuse`` unclipped up to twice the light a
white cloth could show. Texture lookups follow GL's trilinear mipmapping (level of detail from
the pixel's footprint in texels), so prints are as blurred as in a render. The arm is the
same in both passes, so its pixels keep their colour; pixels shared by cloth and arm (its
silhouette over the cloth) are only approximately right. Measured against renders: mean
error 0.7-2.5 / 255, plain colours within 2 / 255 wherever the arm is not
(``tests/render/test_passes.py``).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "PASS_NAMES",
    "RAMP_SIZE",
    "TEXEL_ALBEDO",
    "retexture",
    "srgb_to_linear",
    "uv_ramp_texture",
]

PASS_NAMES = ("grey", "black", "uvm")
"""The stored passes, in the order the renderer returns them."""

RAMP_SIZE = 256
"""Side of the uv ramp texture: one 8-bit step per texel."""


def srgb_to_linear(x) -> np.ndarray:
    """The sRGB decoding pyrender's shader applies to colours in [0, 1]."""
    x = np.asarray(x, np.float64) if not isinstance(x, np.ndarray) else x
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


TEXEL_ALBEDO = srgb_to_linear(np.arange(256) / 255.0).astype(np.float32)
"""Linear albedo of each uint8 texel value, as pyrender's shader decodes it."""

GREY_TEXEL = 188
"""Texel value of the grey pass: linear albedo 0.503."""

OUTPUT_GAMMA = 2.2
"""pyrender's shader writes ``colour ** (1 / 2.2)``."""


def uv_ramp_texture() -> np.ndarray:
    """RGBA uint8 (256, 256, 4): red = column, green = row, blue and alpha = 255."""
    index = np.arange(RAMP_SIZE, dtype=np.uint8)
    ramp = np.empty((RAMP_SIZE, RAMP_SIZE, 4), np.uint8)
    ramp[..., 0] = index[None, :]
    ramp[..., 1] = index[:, None]
    ramp[..., 2:] = 255
    return ramp


def _check(name: str, array: np.ndarray, shape: tuple) -> np.ndarray:
    array = np.asarray(array)
    if array.dtype != np.uint8 or array.shape != shape:
        raise ValueError(
            f"{name} must be uint8 with shape {shape}, got {array.dtype} {array.shape}"
        )
    return array


def _mip_pyramid(texture: np.ndarray) -> list[np.ndarray]:
    """Texture levels as ``glGenerateMipmap`` builds them (2 x 2 box averages), float [0, 1]."""
    levels = [texture.astype(np.float32) / 255.0]
    while min(levels[-1].shape[:2]) > 1:
        image = levels[-1]
        h, w = image.shape[0] // 2 * 2, image.shape[1] // 2 * 2
        levels.append(cv2.resize(image[:h, :w], (w // 2, h // 2), interpolation=cv2.INTER_AREA))
    return levels


def _sample_trilinear(pyramid: list[np.ndarray], map_x: np.ndarray, map_y: np.ndarray):
    """Texture lookup with GL's LINEAR_MIPMAP_LINEAR filter at texel coordinates (H, W).

    The level of detail is log2 of the larger screen-space footprint of a pixel in texels
    (the maps' finite differences along x and y); levels are blended linearly.
    """
    dxx, dxy = np.gradient(map_x, axis=1), np.gradient(map_y, axis=1)
    dyx, dyy = np.gradient(map_x, axis=0), np.gradient(map_y, axis=0)
    footprint = np.maximum(np.hypot(dxx, dxy), np.hypot(dyx, dyy))
    lod = np.clip(np.log2(np.maximum(footprint, 1e-6)), 0.0, len(pyramid) - 1.0)
    low = np.floor(lod).astype(int)
    out = np.zeros((*map_x.shape, 3), np.float32)
    for level in range(int(low.min()), min(int(low.max()) + 2, len(pyramid))):
        weight = np.where(low == level, 1.0 - (lod - low), 0.0)
        weight += np.where(low + 1 == level, lod - low, 0.0)
        if not weight.any():
            continue
        scale = 2.0**-level
        mx = ((map_x + 0.5) * scale - 0.5).astype(np.float32)
        my = ((map_y + 0.5) * scale - 0.5).astype(np.float32)
        sample = cv2.remap(
            pyramid[level], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )
        out += weight[..., None].astype(np.float32) * sample
    return out


def retexture(
    grey: np.ndarray,
    black: np.ndarray,
    uvm: np.ndarray,
    coverage: np.ndarray,
    background: np.ndarray,
    texture: np.ndarray,
) -> np.ndarray:
    """A clip's frames as if its cloth had been rendered with ``texture``.

    Args:
        grey: Grey-cloth pass, uint8 (T, H, W, 3).
        black: Black-cloth pass, uint8 (T, H, W, 3).
        uvm: uv ramp pass, uint8 (T, H, W, 3).
        coverage: Coverage of cloth and arm together (the frames' alpha), uint8 (T, H, W).
        background: What lies behind, uint8 (H, W, 3) or (T, H, W, 3).
        texture: New cloth texture, uint8 (h, w, 3), laid out as the renderer's
            (row 0 along the cloth's smallest v).

    Returns:
        Frames, uint8 (T, H, W, 3).
    """
    grey = np.asarray(grey)
    if grey.dtype != np.uint8 or grey.ndim != 4 or grey.shape[-1] != 3:
        raise ValueError(f"grey must be uint8 (T, H, W, 3), got {grey.dtype} {grey.shape}")
    black = _check("black", black, grey.shape)
    uvm = _check("uvm", uvm, grey.shape)
    coverage = _check("coverage", coverage, grey.shape[:3])
    background = np.asarray(background)
    if background.shape == grey.shape[1:]:
        background = np.broadcast_to(background, grey.shape)
    background = _check("background", background, grey.shape)
    texture = np.asarray(texture)
    if texture.dtype != np.uint8 or texture.ndim != 3 or texture.shape[-1] != 3:
        raise ValueError(f"texture must be uint8 (h, w, 3), got {texture.dtype} {texture.shape}")

    alpha = coverage.astype(np.float32)[..., None] / 255.0
    inverse = np.where(alpha > 0, 1.0 / np.maximum(alpha, 1e-6), 0.0) / 255.0
    lit = np.minimum(grey * inverse, 1.0) ** OUTPUT_GAMMA  # unpremultiplied, linear light
    dark = np.minimum(black * inverse, 1.0) ** OUTPUT_GAMMA
    uvm = uvm.astype(np.float32)
    blue = np.maximum(uvm[..., 2], 1.0)
    # Ramp texel (value v at texture coordinate (v + 0.5) / 256) -> the new texture's texel.
    height, width = texture.shape[:2]
    map_x = (uvm[..., 0] / blue * 255.0 + 0.5) * (width / RAMP_SIZE) - 0.5
    map_y = (uvm[..., 1] / blue * 255.0 + 0.5) * (height / RAMP_SIZE) - 0.5
    pyramid = _mip_pyramid(texture)
    albedo = np.stack(
        [_sample_trilinear(pyramid, mx, my) for mx, my in zip(map_x, map_y, strict=True)]
    )
    albedo = srgb_to_linear(albedo)  # GL filters the stored (sRGB) texels, the shader decodes
    diffuse = np.maximum(lit - dark, 0.0) / TEXEL_ALBEDO[GREY_TEXEL]
    colour = np.minimum(dark + albedo * diffuse, 1.0) ** (1.0 / OUTPUT_GAMMA)
    out = 255.0 * alpha * colour + (1.0 - alpha) * background.astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
