"""Offscreen rendering of simulated cloth (thesis 7.6): cameras, lights, textures, effects.

Public API: :class:`CameraSpec` (view and image size, presets ``wind()`` / ``arm()``),
:class:`LightSpec` (key + ambient light), :func:`make_texture` (``grid`` / ``color`` /
``random``), :func:`make_background`, :class:`VisualEffects` (named switches) and
:class:`ClothRenderer` (pyrender over EGL; ``render_clip`` -> uint8 (K, H, W, 3)).
Shapes follow the legend of :mod:`simulator`: K frames, V verts, F tris, C capsules, H x W
image. ``import render`` stays light: pyrender (and the ``PYOPENGL_PLATFORM=egl`` default)
is only loaded when :class:`ClothRenderer` is first accessed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .backgrounds import available_background_kinds, make_background
from .camera import DEFAULT_RESOLUTION, CameraSpec
from .effects import EFFECT_NAMES, IMAGE_EFFECT_ORDER, VisualEffects, apply_image_effects
from .lights import LightFrame, LightSpec
from .textures import TextureMode, available_texture_kinds, make_texture

if TYPE_CHECKING:
    from .renderer import ClothRenderer

__all__ = [
    "DEFAULT_RESOLUTION",
    "EFFECT_NAMES",
    "IMAGE_EFFECT_ORDER",
    "CameraSpec",
    "ClothRenderer",
    "LightFrame",
    "LightSpec",
    "TextureMode",
    "VisualEffects",
    "apply_image_effects",
    "available_background_kinds",
    "available_texture_kinds",
    "make_background",
    "make_texture",
]


def __getattr__(name: str):
    if name == "ClothRenderer":
        from .renderer import ClothRenderer

        return ClothRenderer
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
