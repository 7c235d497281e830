"""Training augmentation applied identically to every frame of a clip.

Only changes a material cannot cause: a random crop-and-resize (framing), a horizontal
flip (wind from the other side) and small brightness/contrast/saturation changes. Random
draws use torch's global generator, which Lightning seeds per data-loader worker.
"""

from __future__ import annotations

import dataclasses

import torch
from torchvision.transforms.v2 import functional as tvf

__all__ = ["ClipAugment"]


@dataclasses.dataclass(frozen=True)
class ClipAugment:
    """Callable on a float clip (T, 3, H, W) in [0, 1]; returns the same shape."""

    crop_scale: tuple[float, float] = (0.8, 1.0)
    """Range of the crop's side as a fraction of the frame's."""
    flip_prob: float = 0.5
    brightness: float = 0.15
    contrast: float = 0.15
    saturation: float = 0.15

    def __post_init__(self):
        lo, hi = self.crop_scale
        if not 0 < lo <= hi <= 1:
            raise ValueError(f"crop_scale must satisfy 0 < min <= max <= 1, got {self.crop_scale}")
        if not 0 <= self.flip_prob <= 1:
            raise ValueError(f"flip_prob must be in [0, 1], got {self.flip_prob}")
        for name in ("brightness", "contrast", "saturation"):
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"{name} must be in [0, 1), got {getattr(self, name)}")

    @staticmethod
    def _uniform(lo: float, hi: float) -> float:
        return lo + (hi - lo) * float(torch.rand(()))

    def __call__(self, clip: torch.Tensor) -> torch.Tensor:
        """Augment one clip (the same crop, flip and colour change for every frame)."""
        height, width = clip.shape[-2:]
        side = self._uniform(*self.crop_scale)
        ch, cw = max(1, round(height * side)), max(1, round(width * side))
        top = int(torch.randint(0, height - ch + 1, ()))
        left = int(torch.randint(0, width - cw + 1, ()))
        clip = tvf.resized_crop(clip, top, left, ch, cw, [height, width], antialias=True)
        if float(torch.rand(())) < self.flip_prob:
            clip = tvf.horizontal_flip(clip)
        clip = tvf.adjust_brightness(clip, self._uniform(1 - self.brightness, 1 + self.brightness))
        clip = tvf.adjust_contrast(clip, self._uniform(1 - self.contrast, 1 + self.contrast))
        clip = tvf.adjust_saturation(clip, self._uniform(1 - self.saturation, 1 + self.saturation))
        return clip.clamp(0.0, 1.0)
