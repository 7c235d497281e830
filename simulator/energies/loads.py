"""Dead loads: prescribed nodal forces and surface tractions as linear potential energies."""

from __future__ import annotations

import dataclasses

import torch

from .base import Energy

__all__ = ["EnergyNodalForce", "surface_traction_forces"]


@dataclasses.dataclass(frozen=True)
class EnergyNodalForce(Energy):
    """``E = -sum_i f_i . x_i`` for fixed (dead) nodal forces, e.g. contact tractions."""

    linear = True

    force: torch.Tensor
    """Nodal forces [N], shape (B, V, 3) or (1, V, 3) shared by the batch."""

    def energy(self, model, pos):
        """Potential of the loads [J], shape (B,)."""
        return -(self.force * pos).sum(dim=(1, 2))

    def gradient(self, model, pos):
        """Minus the forces [N], shape (B, V, 3)."""
        return (-self.force).expand_as(pos)

    def hessian_product(self, model, pos, dpos):
        """Zero: the energy is linear."""
        return torch.zeros_like(dpos)


def surface_traction_forces(
    vert_pos: torch.Tensor, tri_indices: torch.Tensor, traction: torch.Tensor
) -> torch.Tensor:
    """Lump a traction per boundary triangle to its vertices (a third of the force each).

    Args:
        vert_pos: rest positions [m], shape (V, 3).
        tri_indices: boundary triangles, shape (S, 3).
        traction: force per rest area [Pa], shape (S, 3) or (B, S, 3).

    Returns:
        Nodal forces [N], shape (B, V, 3) (B = 1 for a shared traction).
    """
    x = vert_pos[tri_indices]
    area = 0.5 * torch.linalg.vector_norm(
        torch.linalg.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], dim=-1), dim=-1
    )
    trac = traction if traction.dim() == 3 else traction[None]
    per_tri = trac * (area / 3.0)[None, :, None]
    out = trac.new_zeros(trac.shape[0], vert_pos.shape[0], 3)
    for k in range(3):
        out.index_add_(1, tri_indices[:, k], per_tri)
    return out
