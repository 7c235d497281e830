"""Constant-rigidity discrete-shell bending, a lean version of the core's dihedral energy.

``E = sum_e 1/2 D l_e² / A_e (theta_e - theta_e^0)²`` with plate rigidity ``D`` [N·m], rest
edge length ``l_e`` and adjacent rest area ``A_e``: the core's
:class:`simulator.energies.bending.EnergyBendingDihedral` with a curvature-independent,
isotropic stiffness (equal energies, tested), without its measured-data interpolation,
which costs more than the membrane in the per-frame reconstruction loop.
"""

from __future__ import annotations

import dataclasses

import torch

from ..energies.base import ElementBlocks, Energy
from ..geometry import dihedral_angle, dihedral_angle_gradient, flat_indices, scatter_vertices
from ..mesh import TriMesh

__all__ = ["EnergyBendingQuadratic"]


@dataclasses.dataclass(frozen=True)
class EnergyBendingQuadratic(Energy):
    """Quadratic dihedral bending with per-edge stiffness ``D l² / A``."""

    edge_stiffness: torch.Tensor
    """``D l_e² / A_e`` [N·m], shape (E,)."""

    @staticmethod
    def from_mesh(mesh: TriMesh, rigidity: float) -> EnergyBendingQuadratic:
        """Per-edge stiffness from the rest mesh and the plate rigidity D [N·m] (>= 0)."""
        if not rigidity >= 0:
            raise ValueError(f"rigidity must be >= 0 N·m, got {rigidity}")
        return EnergyBendingQuadratic(rigidity * mesh.edge_rest_length**2 / mesh.edge_rest_area)

    def _delta(self, model, pos):
        return dihedral_angle(pos, model.mesh.edge_indices) - model.mesh.edge_rest_angle

    def energy(self, model, pos):
        """Bending energy [J], shape (B,)."""
        delta = self._delta(model, pos)
        return 0.5 * (self.edge_stiffness * delta * delta).sum(-1)

    def gradient(self, model, pos):
        """Analytic dE/dx [N], shape (B, V, 3)."""
        delta = self._delta(model, pos)
        grad_theta = dihedral_angle_gradient(pos, model.mesh.edge_indices)
        coef = (self.edge_stiffness * delta)[..., None, None]
        return scatter_vertices(coef * grad_theta, model.mesh.edge_indices, pos.shape[1])

    def hessian_blocks(self, model, pos):
        """Gauss-Newton blocks ``k grad(theta) grad(theta)^T`` (PSD)."""
        grad_theta = dihedral_angle_gradient(pos, model.mesh.edge_indices)
        g = grad_theta * self.edge_stiffness.sqrt()[None, :, None, None]
        blocks = g[:, :, :, None, :, None] * g[:, :, None, :, None, :]
        return ElementBlocks(
            flat_indices(model.mesh.edge_indices, pos.shape[0], pos.shape[1]),
            blocks.reshape(-1, 4, 4, 3, 3),
            model.mesh.edge_indices,
        )
