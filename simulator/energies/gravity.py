"""Uniform gravity as a linear potential energy."""

from __future__ import annotations

import dataclasses

import torch

from .base import Energy

__all__ = ["EnergyGravity"]


@dataclasses.dataclass(frozen=True)
class EnergyGravity(Energy):
    """``E = -sum_i m_i g . x_i`` with the model's lumped masses."""

    linear = True

    acceleration: torch.Tensor
    """Gravitational acceleration [m/s²], shape (3,)."""

    def energy(self, model, pos):
        """Potential energy [J], shape (B,)."""
        return -(model.vert_mass[..., None] * pos * self.acceleration).sum(dim=(1, 2))

    def gradient(self, model, pos):
        """Minus the weight of each vertex [N], shape (B, V, 3)."""
        return -(model.vert_mass[..., None] * self.acceleration).expand_as(pos)

    def hessian_product(self, model, pos, dpos):
        """Zero: the energy is linear."""
        return torch.zeros_like(dpos)
