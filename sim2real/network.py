"""The trained network's layers as rungs of the representation ladder.

Forward hooks record, per clip, every block of each frame encoder's trunk (global-average
pooled per frame, then averaged over the clip's frames), fc6 (averaged over frames), the
LSTM's hidden state (mean over time and last step) and the logits. Layer names follow the
data flow (``enc.block1`` ... ``enc.fc6``, ``lstm``, ``logits``), so "the first layer where
the gap jumps" reads directly off the list.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn

__all__ = ["layer_features", "layer_names", "tap_points"]


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
    clips = np.asarray(clips)
    if clips.dtype != np.uint8 or clips.ndim != 5 or clips.shape[-1] != 3:
        raise ValueError(f"clips must be uint8 (N, T, H, W, 3), got {clips.dtype} {clips.shape}")
    to_input = to_input or (
        lambda x: torch.from_numpy(x).permute(0, 1, 4, 2, 3).float().div_(255.0)
    )
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
