"""Training augmentation applied identically to every frame of a clip.

Only changes a material cannot cause: a random crop-and-resize (framing), a horizontal
flip (wind from the other side), small brightness/contrast/saturation changes
(:class:`ClipAugment`), a new print on the cloth (:class:`TextureSwap`) and a new background
behind it (:class:`BackgroundSwap`).
Random draws use torch's global generator, which Lightning seeds per data-loader worker.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from torchvision.transforms.v2 import functional as tvf

from render.backgrounds import make_background
from render.passes import PASS_NAMES, retexture
from render.textures import TextureMode, make_texture

__all__ = ["BackgroundSwap", "ClipAugment", "TextureSwap"]

_SWAP_STREAM = 23
"""Keeps the swapped-in backgrounds apart from the generator's (seeded by simulation)."""
_TEXTURE_SWAP_STREAM = 29
"""Keeps the swapped-in textures apart from the generator's and the background swap's."""


@dataclasses.dataclass(frozen=True)
class BackgroundSwap:
    """Re-composite a training clip's cloth over a freshly drawn background.

    Why: every simulation is rendered over its own background, so a network can name a
    training clip's class from its background alone, and the RGB models do (they fit their
    training clips and stay at chance on held-out simulations). With a new background for
    every sample and epoch (one per clip, the same for all its frames, drawn from the same
    procedural bank as the generator's, :func:`render.backgrounds.make_background`) the
    background carries no label. Needs the coverage the generator stores
    (``render.store_coverage``): ``frame' = a * frame + (1 - a) * background`` with ``a``
    the cloth's coverage, exact wherever ``a`` is 0 or 1 (the silhouette's antialiased
    pixels keep a trace of the old background).
    """

    prob: float = 0.0
    """Chance that a training sample gets a new background; 0 = off."""

    def __post_init__(self):
        if not 0 <= self.prob <= 1:
            raise ValueError(f"data.background_swap.prob must be in [0, 1], got {self.prob}")

    @property
    def enabled(self) -> bool:
        """Whether any sample is ever changed (only then is coverage needed)."""
        return self.prob > 0

    def __call__(self, video: torch.Tensor, coverage: torch.Tensor) -> torch.Tensor:
        """``video`` float (T, 3, H, W) in [0, 1], ``coverage`` uint8 (T, H, W)."""
        if coverage.shape != (video.shape[0], *video.shape[-2:]):
            raise ValueError(
                f"coverage must have shape {(video.shape[0], *video.shape[-2:])}, "
                f"got {tuple(coverage.shape)}"
            )
        if not float(torch.rand(())) < self.prob:
            return video
        seed = int(torch.randint(0, 2**62, ()))
        height, width = video.shape[-2:]
        background = make_background(np.random.default_rng([seed, _SWAP_STREAM]), width, height)
        background = torch.from_numpy(background).permute(2, 0, 1).to(video) / 255.0
        alpha = coverage[:, None].to(video) / 255.0
        return alpha * video + (1.0 - alpha) * background


@dataclasses.dataclass(frozen=True)
class TextureSwap:
    """Re-texture a training clip's cloth with a freshly drawn texture.

    Why: with the ``random`` texture every simulation wears its own print, so a network can
    name a training clip's class from the print, as it can from the background (which
    :class:`BackgroundSwap` removes). With a new texture for every sample and epoch (one per
    clip, from the generator's bank, :func:`render.textures.make_texture`) the print carries
    no label. Needs the render passes the generator stores (``render.store_passes``);
    the re-texturing is :func:`render.passes.retexture` (mean error about 2/255 against a
    render with the same texture). Image effects that the generator applied after rendering
    (noise, compression, defocus, white balance) are not in the passes and so are absent from
    swapped clips.
    """

    prob: float = 0.0
    """Chance that a training sample gets a new texture; 0 = off."""
    mode: str = "random"
    """Texture mode to draw from (``grid``, ``color``, ``random``)."""
    size: int = 256
    """Side of the drawn textures [texels] (the generator's ``texture_size``)."""

    def __post_init__(self):
        if not 0 <= self.prob <= 1:
            raise ValueError(f"data.texture_swap.prob must be in [0, 1], got {self.prob}")
        try:
            TextureMode(self.mode)
        except ValueError:
            raise ValueError(
                f"data.texture_swap.mode must be one of {[m.value for m in TextureMode]}, "
                f"got {self.mode!r}"
            ) from None
        if isinstance(self.size, bool) or not isinstance(self.size, int) or self.size < 8:
            raise ValueError(f"data.texture_swap.size must be an integer >= 8, got {self.size!r}")

    @property
    def enabled(self) -> bool:
        """Whether any sample is ever changed (only then are the passes needed)."""
        return self.prob > 0

    def __call__(self, layers: dict[str, np.ndarray], coverage: np.ndarray) -> np.ndarray | None:
        """New uint8 frames (T, H, W, 3), or ``None`` when this sample keeps its texture.

        ``layers``: the clip's ``grey``, ``black``, ``uvm`` passes (T, H, W, 3) and its
        ``background`` (1, H, W, 3); ``coverage`` uint8 (T, H, W).
        """
        if not float(torch.rand(())) < self.prob:
            return None
        seed = int(torch.randint(0, 2**62, ()))
        texture = make_texture(
            self.mode, np.random.default_rng([seed, _TEXTURE_SWAP_STREAM]), self.size
        )
        return retexture(
            *(layers[name] for name in PASS_NAMES),
            coverage,
            layers["background"][0],
            texture,
        )


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
