"""Penalty contact between cloth vertices and capsule obstacles (the arm).

Each vertex keeps a distance ``radius + thickness`` from every capsule axis
segment; penetration ``p`` costs ``E = 1/2 k_i p²`` with ``k_i = stiffness * A_i``
(``A_i`` the vertex's rest area), so the contact pressure does not depend on the
mesh resolution. Friction is a separate, velocity-dependent force
(:class:`simulator.forces.FrictionCapsule`) that reads the normal force from here.
"""

from __future__ import annotations

import dataclasses

import torch

from .base import ElementBlocks, Energy

__all__ = ["EnergyContactCapsule", "capsule_penetration"]


def capsule_penetration(pos: torch.Tensor, capsules: torch.Tensor, thickness: float):
    """Penetration depth and outward normal of every vertex against every capsule.

    Args:
        pos: vertex positions [m], shape (B, V, 3).
        capsules: ``[p0, p1, radius]`` [m], shape (B, C, 7).
        thickness: extra clearance (cloth half-thickness) [m].

    Returns:
        ``(depth (B, V, C) >= 0 [m], normal (B, V, C, 3))``.
    """
    p0 = capsules[:, None, :, 0:3]
    axis = capsules[:, None, :, 3:6] - p0
    radius = capsules[:, None, :, 6]
    rel = pos[:, :, None, :] - p0
    t = ((rel * axis).sum(-1) / (axis * axis).sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)
    diff = rel - t[..., None] * axis
    dist = torch.linalg.vector_norm(diff, dim=-1)
    normal = diff / dist.clamp_min(1e-12)[..., None]
    depth = (radius + thickness - dist).clamp_min(0.0)
    return depth, normal


@dataclasses.dataclass(frozen=True)
class EnergyContactCapsule(Energy):
    """Penalty energy of cloth vertices inside capsules."""

    stiffness: float = 2.0e6
    """Penalty stiffness per unit vertex area [N/m³]."""
    thickness: float = 2.0e-3
    """Clearance kept from the capsule surface [m]."""
    capsules: torch.Tensor | None = None
    """Capsules of the current step ``[p0, p1, radius]`` [m], shape (B, C, 7)."""

    def bind(self, model, control, pos):
        """Take this step's capsule positions from ``control``."""
        return dataclasses.replace(self, capsules=control.capsules)

    def _vert_stiffness(self, model):
        return self.stiffness * model.mesh.vert_area  # (V,)

    def energy(self, model, pos):
        """Penalty energy [J], shape (B,)."""
        if self.capsules is None:
            return pos.new_zeros(pos.shape[0])
        depth, _ = capsule_penetration(pos, self.capsules, self.thickness)
        return 0.5 * (self._vert_stiffness(model)[None, :, None] * depth * depth).sum(dim=(1, 2))

    def gradient(self, model, pos):
        """Minus the contact forces [N], shape (B, V, 3)."""
        if self.capsules is None:
            return torch.zeros_like(pos)
        depth, normal = capsule_penetration(pos, self.capsules, self.thickness)
        k = self._vert_stiffness(model)[None, :, None]
        return -(k * depth)[..., None].mul(normal).sum(dim=2)

    def normal_force(self, model, pos) -> torch.Tensor:
        """Magnitude of the contact force on each vertex [N], shape (B, V, C)."""
        depth, _ = capsule_penetration(pos, self.capsules, self.thickness)
        return self._vert_stiffness(model)[None, :, None] * depth

    def hessian_blocks(self, model, pos):
        """Per-vertex ``k n n^T`` for active contacts (PSD; curvature term dropped)."""
        if self.capsules is None:
            return None
        depth, normal = capsule_penetration(pos, self.capsules, self.thickness)
        active = (depth > 0).to(pos.dtype)
        k = self._vert_stiffness(model)[None, :, None] * active
        blocks = (k[..., None, None] * normal[..., :, None] * normal[..., None, :]).sum(dim=2)
        batch, verts = pos.shape[:2]
        idx = torch.arange(batch * verts, device=pos.device).unsqueeze(1)
        return ElementBlocks(idx, blocks.reshape(-1, 1, 1, 3, 3))
