"""The trained network's layers as rungs of the representation ladder.

Forward hooks record, per clip, every block of each frame encoder's trunk (global-average
pooled per frame, then averaged over the clip's frames), fc6 (averaged over frames), the
LSTM's hidden state (mean over time and last step) and the logits. Layer names follow the
data flow (``enc.block1`` ... ``enc.fc6``, ``lstm``, ``logits``), so "the first layer where
the gap jumps" reads directly off the list.

:func:`adapt_batchnorm` gives the counterfactual "the same network with its batch-norm
statistics re-estimated on the real clips" (AdaBN, Li et al. 2018): what is left of a layer's
gap after it is the part that a per-channel shift and scale cannot explain.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import numpy as np
import torch
from torch import nn

__all__ = ["adapt_batchnorm", "clip_logits", "layer_features", "layer_names", "tap_points"]


def _encoders(net: nn.Module) -> list[tuple[str, nn.Module]]:
    out = []
    for prefix, attr in (("enc", "encoder"), ("motion", "motion_encoder")):
        encoder = getattr(net, attr, None)
        if isinstance(encoder, nn.Module) and hasattr(encoder, "trunk"):
            out.append((prefix, encoder))
    return out


def tap_points(net: nn.Module) -> list[tuple[str, nn.Module, str]]:
    """``(layer name, module, kind)`` of every recorded layer, in data-flow order.

    Kinds: ``frames`` (per-frame maps or vectors, first dimension B*T), ``sequence`` (an
    LSTM's output) and ``clip`` (one vector per clip: the logits).
    """
    points = []
    for prefix, encoder in _encoders(net):
        trunk = encoder.trunk
        children = list(trunk.children()) if isinstance(trunk, nn.Sequential) else [trunk]
        blocks = [m for m in children if isinstance(m, nn.ReLU | nn.Sequential)]
        points += [(f"{prefix}.block{i + 1}", m, "frames") for i, m in enumerate(blocks)]
        if hasattr(encoder, "fc6"):
            points.append((f"{prefix}.fc6", encoder.fc6, "frames"))
    lstm = getattr(net, "lstm", None)
    if isinstance(lstm, nn.LSTM):
        points.append(("lstm", lstm, "sequence"))
    points.append(("logits", net, "clip"))
    return points


def layer_names(net: nn.Module) -> list[str]:
    """Names of the recorded layers, in data-flow order."""
    return [name for name, _, _ in tap_points(net)]


def _summarise(output, kind: str, batch: int) -> torch.Tensor:
    if kind == "sequence":
        hidden = output[0]  # (B, T, H)
        return torch.cat([hidden.mean(1), hidden[:, -1]], dim=1)
    if kind == "clip":
        return output
    value = output.float()
    if value.ndim == 4:
        value = value.mean(dim=(2, 3))  # global average pool per frame
    return value.reshape(batch, -1, value.shape[-1]).mean(1)


def _default_input(x: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(x).permute(0, 1, 4, 2, 3).float().div_(255.0)


def _check_clips(clips) -> np.ndarray:
    clips = np.asarray(clips)
    if clips.dtype != np.uint8 or clips.ndim != 5 or clips.shape[-1] != 3:
        raise ValueError(f"clips must be uint8 (N, T, H, W, 3), got {clips.dtype} {clips.shape}")
    return clips


@torch.no_grad()
def adapt_batchnorm(
    net: nn.Module,
    clips: np.ndarray,
    *,
    batch_size: int = 16,
    device: torch.device | str = "cpu",
    to_input: Callable[[np.ndarray], torch.Tensor] | None = None,
) -> nn.Module | None:
    """A copy of ``net`` whose batch-norm running statistics are re-estimated on ``clips``.

    Every ``BatchNorm`` layer's running mean and variance are reset and replaced by the
    cumulative average over forward passes of ``clips`` (each layer in training mode, so it
    normalises with the statistics of its own input, as AdaBN does); learned scales and
    shifts, and every other weight, stay. ``net`` itself is not changed.

    Args:
        net: A video net taking ``(B, T, 3, H, W)`` in [0, 1].
        clips: The target domain's frames, uint8, shape (N, T, H, W, 3), N >= 2.
        batch_size: Clips per forward pass (>= 2: a batch of one has no variance).
        device: Where to run.
        to_input: uint8 clips -> the net's input (default: scale to [0, 1]).

    Returns:
        The adapted copy in eval mode, or ``None`` when ``net`` has no batch-norm layer.
    """
    clips = _check_clips(clips)
    if len(clips) < 2 or batch_size < 2:
        raise ValueError(
            f"adapt_batchnorm needs >= 2 clips and batch_size >= 2, got "
            f"{len(clips)} clips, batch_size {batch_size}"
        )
    adapted = copy.deepcopy(net).to(device).eval()
    norms = [m for m in adapted.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    if not norms:
        return None
    for module in norms:
        module.reset_running_stats()
        module.momentum = None  # cumulative average over the passes
        module.train()
    to_input = to_input or _default_input
    starts = list(range(0, len(clips), batch_size))
    if len(clips) - starts[-1] < 2:  # a last batch of one clip: fold it into the one before
        starts.pop()
    for i, start in enumerate(starts):
        stop = starts[i + 1] if i + 1 < len(starts) else len(clips)
        adapted(to_input(clips[start:stop]).to(device))
    return adapted.eval()


@torch.no_grad()
def clip_logits(
    net: nn.Module,
    clips: np.ndarray,
    *,
    batch_size: int = 16,
    device: torch.device | str = "cpu",
) -> np.ndarray:
    """Class logits of ``net`` (eval mode) on uint8 clips (N, T, H, W, 3), float64 (N, C)."""
    clips = _check_clips(clips)
    net = net.to(device).eval()
    out = [
        net(_default_input(clips[start : start + batch_size]).to(device)).double().cpu()
        for start in range(0, len(clips), batch_size)
    ]
    return torch.cat(out).numpy()


@torch.no_grad()
def layer_features(
    net: nn.Module,
    clips: np.ndarray,
    *,
    batch_size: int = 16,
    device: torch.device | str = "cpu",
    to_input: Callable[[np.ndarray], torch.Tensor] | None = None,
) -> dict[str, np.ndarray]:
    """Per-layer clip features of ``net`` (eval mode) on uint8 clips (N, T, H, W, 3).

    Args:
        net: A video net taking ``(B, T, 3, H, W)`` in [0, 1].
        clips: Frames, uint8, shape (N, T, H, W, 3).
        batch_size: Clips per forward pass.
        device: Where to run.
        to_input: uint8 clips (B, T, H, W, 3) -> the net's input (default: scale to [0, 1]).

    Returns:
        ``{layer name: float64 (N, C_layer)}`` in data-flow order.
    """
    clips = _check_clips(clips)
    to_input = to_input or _default_input
    net = net.to(device).eval()
    points = tap_points(net)
    store: dict[str, list[torch.Tensor]] = {name: [] for name, _, _ in points}
    current = {"batch": 0}
    handles = []
    for name, module, kind in points:
        if kind == "clip":
            continue

        def hook(_module, _inputs, output, name=name, kind=kind):
            store[name].append(_summarise(output, kind, current["batch"]).cpu())

        handles.append(module.register_forward_hook(hook))
    try:
        for start in range(0, len(clips), batch_size):
            chunk = clips[start : start + batch_size]
            current["batch"] = len(chunk)
            logits = net(to_input(chunk).to(device))
            store["logits"].append(logits.float().cpu())
    finally:
        for handle in handles:
            handle.remove()
    return {name: torch.cat(store[name]).double().numpy() for name, _, _ in points}
