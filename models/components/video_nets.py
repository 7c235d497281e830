"""Clip classifiers over a per-frame encoder: the thesis's CNN+LSTM and its two baselines.

All take clips ``(B, T, 3, H, W)`` in [0, 1] and return class logits ``(B, num_classes)``;
``num_classes`` is the data's (its material set's class count, which ``train.py`` reads from
the datamodule), never a constant of the simulator.

* :class:`CNNLSTMNet` (thesis 7.5.1, LRCN of Donahue et al. 2015): fc6 features of every
  frame feed an LSTM; a linear layer reads each step's hidden state and, as in LRCN, the
  clip's logits are the mean over the steps (``readout="mean"``) or the last step's.
  With ``freeze_encoder`` and ``encoder_checkpoint`` it is baseline 2 (thesis 7.7.2.1):
  baseline 1's CNN, frozen, with only the LSTM and classifier trained.
* :class:`FramePoolNet` (baseline 1): the encoder plus a linear classifier applied to every
  frame; a clip's logits are the mean of its frames' logits. It also accepts single frames
  ``(B, 3, H, W)``, which is how it is trained ("on all frames").

``CNNLSTMNet(inputs="frame_diff")`` is our fourth method (not in the thesis): the LSTM reads
the encoder's features of the clip's T - 1 frame differences instead of its T frames, so a
static texture and background give no signal and only the cloth's motion does (see
:func:`frame_differences`). ``inputs="two_stream"`` (our fifth) gives the LSTM both: at every
step the ``encoder``'s features of frame t + 1 (the cloth's shape, what a per-frame CNN
reads) beside a second ``motion_encoder``'s features of the difference t -> t + 1 (its
motion), the two streams of Simonyan and Zisserman (2014) with frame differences standing in
for optical flow. On the simulated meshes both carry class information that the other lacks
(``python -m benchmarks.thesis.feature_probe``).
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch
from torch import nn

from .frame_encoder import FrameEncoder

__all__ = ["CNNLSTMNet", "FramePoolNet", "frame_differences", "load_encoder_state"]

log = logging.getLogger(__name__)

READOUTS = ("mean", "last")
INPUTS = ("rgb", "frame_diff", "two_stream")
"""What the encoder sees: the frames, the differences of consecutive frames, or both (the
frames through ``encoder``, the differences through ``motion_encoder``)."""


def frame_differences(video: torch.Tensor) -> torch.Tensor:
    """Clips (B, T, 3, H, W) in [0, 1] -> (B, T - 1, 3, H, W) in [0, 1]: signed-sqrt differences.

    ``0.5 + 0.5 sign(d) sqrt(|d|)`` with ``d = frame[t + 1] - frame[t]``: zero motion maps to
    mid-grey and the square root lifts the small differences of slow cloth against strong texture
    edges. On the full wind preset the motion reference of ``benchmarks.thesis.geometry_oracle``
    (1-NN on 16 x 16 grey sqrt|d|) names 33.1 % of held-out clips' classes, mean frames 3.5 %.
    """
    _check_clips(video)
    if video.shape[1] < 2:
        raise ValueError(f"frame_diff input needs clips of >= 2 frames, got {video.shape[1]}")
    d = video[:, 1:] - video[:, :-1]
    return 0.5 + 0.5 * torch.sign(d) * d.abs().sqrt()


def _check_clips(video: torch.Tensor) -> None:
    if video.ndim != 5 or video.shape[2] != 3:
        raise ValueError(f"video must have shape (B, T, 3, H, W), got {tuple(video.shape)}")


def _encode_frames(encoder: FrameEncoder, video: torch.Tensor) -> torch.Tensor:
    """(B, T, 3, H, W) -> (B, T, feature_dim), every frame through the encoder at once."""
    batch, steps = video.shape[:2]
    return encoder(video.flatten(0, 1)).view(batch, steps, -1)


def load_encoder_state(encoder: FrameEncoder, checkpoint: str | Path) -> None:
    """Copy the encoder weights of a trained clip model's checkpoint into ``encoder``.

    Accepts a Lightning checkpoint (``state_dict`` with ``net.encoder.*`` keys) or a plain
    state dict of a net (``encoder.*``) or of an encoder.
    """
    from models.checkpoint import read_checkpoint

    path = Path(checkpoint)
    if not path.is_file():
        raise FileNotFoundError(
            f"encoder_checkpoint {path} does not exist (baseline 2 needs baseline 1's "
            "checkpoint: train the frame model first)"
        )
    raw = read_checkpoint(path, "encoder_checkpoint")
    state = raw.get("state_dict", raw)
    if not isinstance(state, dict):
        state = {}
    wanted = set(encoder.state_dict())
    for prefix in ("net.encoder.", "encoder.", ""):
        picked = {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}
        if set(picked) == wanted:  # exactly: a subset would drop e.g. fc6's BatchNorm silently
            encoder.load_state_dict(picked)
            log.info("encoder weights from %s", path)
            return
    raise ValueError(
        f"encoder_checkpoint {path} holds no weights matching this encoder (the encoder config "
        "must be the one it was trained with, encoder.fc6_norm included)"
    )


class CNNLSTMNet(nn.Module):
    """Frame encoder -> LSTM -> per-step linear classifier, averaged (LRCN).

    Args:
        encoder: Per-frame encoder giving fc6 features.
        hidden_size: LSTM hidden units.
        num_layers: Stacked LSTM layers.
        num_classes: Output classes (the data's material classes; 54 for the thesis's set).
        readout: ``mean`` of the per-step logits (LRCN) or the ``last`` step's.
        freeze_encoder: Keep the encoder fixed (baseline 2); it also stays in eval mode.
        encoder_checkpoint: Load encoder weights from this checkpoint first (baseline 2).
        inputs: ``rgb`` (the frames; the thesis), ``frame_diff`` (:func:`frame_differences`)
            or ``two_stream`` (frames 2..T through ``encoder`` beside their differences
            through ``motion_encoder``, features concatenated per step).
        motion_encoder: The difference stream's encoder (``two_stream`` only).
        motion_encoder_checkpoint: Load ``motion_encoder``'s weights from this checkpoint
            first (e.g. a ``frame_diff`` model's); ``freeze_encoder`` does not freeze it.
    """

    def __init__(
        self,
        encoder: FrameEncoder,
        *,
        hidden_size: int = 256,
        num_layers: int = 1,
        num_classes: int,
        readout: str = "mean",
        freeze_encoder: bool = False,
        encoder_checkpoint: str | None = None,
        inputs: str = "rgb",
        motion_encoder: FrameEncoder | None = None,
        motion_encoder_checkpoint: str | None = None,
    ):
        super().__init__()
        if readout not in READOUTS:
            raise ValueError(f"readout must be one of {READOUTS}, got {readout!r}")
        if inputs not in INPUTS:
            raise ValueError(f"inputs must be one of {INPUTS}, got {inputs!r}")
        if (inputs == "two_stream") != (motion_encoder is not None):
            raise ValueError(
                "motion_encoder is needed by inputs='two_stream' and only by it "
                f"(inputs={inputs!r}, motion_encoder {'given' if motion_encoder else 'None'})"
            )
        if motion_encoder_checkpoint and motion_encoder is None:
            raise ValueError("motion_encoder_checkpoint needs a motion_encoder")
        self.inputs = inputs
        for name, value in (
            ("hidden_size", hidden_size),
            ("num_layers", num_layers),
            ("num_classes", num_classes),
        ):
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        self.encoder = encoder
        if encoder_checkpoint:
            load_encoder_state(encoder, encoder_checkpoint)
        self.freeze_encoder = freeze_encoder
        if freeze_encoder:
            encoder.requires_grad_(False)
        self.motion_encoder = motion_encoder
        if motion_encoder_checkpoint:
            load_encoder_state(motion_encoder, motion_encoder_checkpoint)
        width = encoder.feature_dim + (motion_encoder.feature_dim if motion_encoder else 0)
        self.lstm = nn.LSTM(width, hidden_size, num_layers, batch_first=True)
        self.classifier = nn.Linear(hidden_size, num_classes)
        self.readout = readout

    def train(self, mode: bool = True) -> CNNLSTMNet:
        """Like :meth:`nn.Module.train`, but a frozen encoder stays in eval mode."""
        super().train(mode)
        if self.freeze_encoder:
            self.encoder.eval()
        return self

    def forward(self, video: torch.Tensor) -> torch.Tensor:
        """Clips (B, T, 3, H, W) -> logits (B, num_classes)."""
        _check_clips(video)
        motion = None
        if self.inputs == "frame_diff":
            video = frame_differences(video)
        elif self.inputs == "two_stream":
            motion = _encode_frames(self.motion_encoder, frame_differences(video))
            video = video[:, 1:]  # frame t + 1 beside the difference t -> t + 1
        if self.freeze_encoder:
            if self.encoder.training:  # trainers may set modes module by module
                self.encoder.eval()
            with torch.no_grad():
                features = _encode_frames(self.encoder, video)
        else:
            features = _encode_frames(self.encoder, video)
        if motion is not None:
            features = torch.cat([features, motion], dim=-1)
        hidden, _ = self.lstm(features)
        if self.readout == "last":
            return self.classifier(hidden[:, -1])
        return self.classifier(hidden).mean(dim=1)


class FramePoolNet(nn.Module):
    """Per-frame classifier; a clip's logits are the mean of its frames' logits (baseline 1).

    Args:
        encoder: Per-frame encoder giving fc6 features.
        num_classes: Output classes (the data's material classes).
    """

    def __init__(self, encoder: FrameEncoder, *, num_classes: int):
        super().__init__()
        if not isinstance(num_classes, int) or num_classes < 1:
            raise ValueError(f"num_classes must be an integer >= 1, got {num_classes!r}")
        self.encoder = encoder
        self.classifier = nn.Linear(encoder.feature_dim, num_classes)

    def forward(self, video: torch.Tensor) -> torch.Tensor:
        """Clips (B, T, 3, H, W) or frames (B, 3, H, W) -> logits (B, num_classes)."""
        if video.ndim == 4:
            return self.classifier(self.encoder(video))
        _check_clips(video)
        return self.classifier(_encode_frames(self.encoder, video)).mean(dim=1)
