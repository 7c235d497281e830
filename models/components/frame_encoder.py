"""Per-frame image encoders: the thesis's five-convolution AlexNet-like CNN, torchvision trunks.

Every encoder maps frames ``(N, 3, H, W)`` in [0, 1] to features ``(N, feature_dim)``; the
last layer is the fully connected "fc6" of thesis eq. 7.1 (``v = W CNN(I) + b``, then ReLU),
whose output feeds the LSTM (thesis 7.5.1, Fig. 7.5).

``alexnet5`` follows Fig. 7.5 (Krizhevsky et al. 2012): conv 11x11/4 - pool - conv 5x5 -
pool - three conv 3x3 - pool - fc6, with AlexNet's channel widths times ``width``. Two
deliberate changes: BatchNorm after each convolution instead of local response
normalisation (trains from scratch in minutes instead of hours; the thesis fine-tuned
ImageNet weights we cannot ship), and adaptive pooling so any frame size >= 64 works.

torchvision backbones (``resnet18``, ``mobilenet_v3_small``, ``alexnet``) are built without
weights. ``pretrained`` names a local state-dict file, or ``True`` to look in torch's
checkpoint cache (``$TORCH_HOME/hub/checkpoints``) for torchvision's file name. Nothing is
ever downloaded: when the file is absent a warning says so and training starts from scratch.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import torch
from torch import nn

__all__ = ["ENCODERS", "FrameEncoder", "torch_checkpoint_dir"]

log = logging.getLogger(__name__)

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

TORCHVISION_FILES = {
    "resnet18": "resnet18-f37072fd.pth",
    "mobilenet_v3_small": "mobilenet_v3_small-047dcff4.pth",
    "alexnet": "alexnet-owt-7be5be79.pth",
}
"""torchvision's own checkpoint file names, looked up (never fetched) in the torch cache."""

ALEXNET_WIDTHS = (64, 192, 384, 256, 256)


def torch_checkpoint_dir() -> Path:
    """Where torch keeps downloaded weights: ``$TORCH_HOME/hub/checkpoints``."""
    home = (
        os.environ.get("TORCH_HOME")
        or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "torch"
    )
    return Path(home) / "hub" / "checkpoints"


def _conv(cin: int, cout: int, kernel: int, stride: int = 1) -> list[nn.Module]:
    pad = kernel // 2 if stride == 1 else 2
    return [
        nn.Conv2d(cin, cout, kernel, stride=stride, padding=pad, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    ]


def _alexnet5(width: float) -> tuple[nn.Module, int]:
    c1, c2, c3, c4, c5 = (max(8, round(w * width)) for w in ALEXNET_WIDTHS)
    trunk = nn.Sequential(
        *_conv(3, c1, 11, stride=4),
        nn.MaxPool2d(3, 2),
        *_conv(c1, c2, 5),
        nn.MaxPool2d(3, 2),
        *_conv(c2, c3, 3),
        *_conv(c3, c4, 3),
        *_conv(c4, c5, 3),
        nn.AdaptiveMaxPool2d(3),
        nn.Flatten(),
    )
    return trunk, c5 * 9


def _torchvision(name: str) -> tuple[nn.Module, int]:
    from torchvision import models as tvm

    if name == "resnet18":
        net = tvm.resnet18(weights=None)
        dim = net.fc.in_features
        net.fc = nn.Identity()
    elif name == "mobilenet_v3_small":
        net = tvm.mobilenet_v3_small(weights=None)
        dim = net.classifier[0].in_features
        net.classifier = nn.Identity()
    else:
        net = tvm.alexnet(weights=None)
        dim = net.classifier[1].in_features
        net.classifier = nn.Identity()
    return net, dim


ENCODERS = ("alexnet5", "resnet18", "mobilenet_v3_small", "alexnet")
"""Encoder names accepted by :func:`build_frame_encoder`."""


class FrameEncoder(nn.Module):
    """A CNN trunk plus the fc6 layer: frames (N, 3, H, W) in [0, 1] -> (N, feature_dim).

    Args:
        name: One of :data:`ENCODERS`.
        feature_dim: fc6 width (the LSTM's input size).
        width: Channel multiplier of ``alexnet5`` (1.0 = AlexNet's 64-192-384-256-256).
        dropout: Dropout after fc6 while training.
        pretrained: ``False``; ``True`` (torchvision's file in the torch cache); or a path to
            a state dict of the trunk. Missing files fall back to random weights with a warning.
        fc6_norm: BatchNorm between fc6's linear map and its ReLU. Without it, most fc6 units
            of our trained models never fire (73-96 %, dead ReLUs), which starves the LSTM.
    """

    def __init__(
        self,
        name: str = "alexnet5",
        *,
        feature_dim: int = 256,
        width: float = 0.5,
        dropout: float = 0.3,
        pretrained: bool | str = False,
        fc6_norm: bool = False,
    ):
        super().__init__()
        if name not in ENCODERS:
            raise ValueError(f"encoder name must be one of {ENCODERS}, got {name!r}")
        if not isinstance(feature_dim, int) or feature_dim < 1:
            raise ValueError(f"encoder feature_dim must be an integer >= 1, got {feature_dim!r}")
        if not 0 < width <= 4:
            raise ValueError(f"encoder width must be in (0, 4], got {width!r}")
        if not 0 <= dropout < 1:
            raise ValueError(f"encoder dropout must be in [0, 1), got {dropout!r}")
        self.name = name
        self.trunk, trunk_dim = _alexnet5(width) if name == "alexnet5" else _torchvision(name)
        norm = [nn.BatchNorm1d(feature_dim)] if fc6_norm else []
        self.fc6 = nn.Sequential(
            nn.Linear(trunk_dim, feature_dim), *norm, nn.ReLU(inplace=True), nn.Dropout(dropout)
        )
        self.feature_dim = feature_dim
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), False)
        self.pretrained_from = self._load_pretrained(pretrained) if pretrained else None

    def _load_pretrained(self, pretrained: bool | str) -> str | None:
        if pretrained is True:
            if self.name not in TORCHVISION_FILES:
                log.warning("encoder %s has no pretrained file; training from scratch", self.name)
                return None
            path = torch_checkpoint_dir() / TORCHVISION_FILES[self.name]
        else:
            path = Path(str(pretrained))
        if not path.is_file():
            log.warning(
                "pretrained weights for encoder %s not found at %s (nothing is downloaded); "
                "training from scratch",
                self.name,
                path,
            )
            return None
        state = torch.load(path, map_location="cpu", weights_only=True)
        missing, unexpected = self.trunk.load_state_dict(state, strict=False)
        loaded = len(state) - len(unexpected)
        if loaded == 0:
            raise ValueError(f"pretrained file {path} holds no weights of encoder {self.name}")
        log.info(
            "encoder %s: %d tensors from %s (%d left random)", self.name, loaded, path, len(missing)
        )
        return str(path)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """Frames (N, 3, H, W) in [0, 1] -> fc6 features (N, feature_dim)."""
        if frames.ndim != 4 or frames.shape[1] != 3:
            raise ValueError(f"frames must have shape (N, 3, H, W), got {tuple(frames.shape)}")
        return self.fc6(self.trunk((frames - self.mean) / self.std))
