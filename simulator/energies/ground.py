"""Penalty contact with a horizontal ground plane ``z = height`` (frictionless)."""

from __future__ import annotations

import dataclasses

import torch

from ..geometry import flat_indices
from .base import ElementBlocks, Energy

__all__ = ["EnergyGroundPlane"]


@dataclasses.dataclass(frozen=True)
class EnergyGroundPlane(Energy):
    """``E = 1/2 k sum_i min(z_i - height, 0)²``: a stiff one-sided spring per vertex."""

    stiffness: float
    """Penalty stiffness per vertex [N/m], > 0."""
    height: float = 0.0
    """Ground level [m]."""

    def __post_init__(self):
        if not self.stiffness > 0:
            raise ValueError(f"stiffness must be > 0 N/m, got {self.stiffness}")

    def _depth(self, pos):
        return (pos[..., 2] - self.height).clamp_max(0.0)

    def energy(self, model, pos):
        """Penalty energy [J], shape (B,)."""
        return 0.5 * self.stiffness * self._depth(pos).square().sum(-1)

    def gradient(self, model, pos):
        """Minus the contact force [N], shape (B, V, 3)."""
        grad = torch.zeros_like(pos)
        grad[..., 2] = self.stiffness * self._depth(pos)
        return grad

    def hessian_blocks(self, model, pos):
        """``k e_z e_z^T`` at penetrating vertices, one 1-vertex block each."""
        batch, verts = pos.shape[:2]
        active = (pos[..., 2] < self.height).to(pos.dtype)
        blocks = pos.new_zeros(batch, verts, 1, 1, 3, 3)
        blocks[..., 0, 0, 2, 2] = self.stiffness * active
        topology = torch.arange(verts, device=pos.device)[:, None]
        return ElementBlocks(
            flat_indices(topology, batch, verts), blocks.reshape(-1, 1, 1, 3, 3), topology
        )
