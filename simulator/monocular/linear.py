"""Baseline sheet energies on the same mesh: small-strain (linear) FEM and mass-spring.

The paper compares its St Venant-Kirchhoff model with a linear stress/strain FEM and a
classic mass-spring model (§7.2.2). Linear FEM uses the infinitesimal strain
``eps = sym(T^T grad u)`` of the displacement ``u = x - X`` in the rest tangent plane ``T``:
a constant, PSD element stiffness ``K_e = A B^T D B``, so the energy is exactly quadratic and
not invariant under rotation (the reason it fails on large, rotating deformations).
"""

from __future__ import annotations

import dataclasses

import torch

from ..energies.base import ElementBlocks, Energy
from ..energies.springs import EnergyMassSpring
from ..geometry import flat_indices, scatter_vertices
from ..mesh import TriMesh
from .material import SheetMaterial, plane_stress_matrix

__all__ = ["EnergySheetLinear", "sheet_mass_spring"]


@dataclasses.dataclass(frozen=True)
class EnergySheetLinear(Energy):
    """Linear (small-strain) plane-stress membrane: ``E = 1/2 sum_f u_f^T K_f u_f``."""

    element_stiffness: torch.Tensor
    """``K_f`` in entry layout [N/m], shape (F, 3, 3, 3, 3)."""
    rest_pos: torch.Tensor
    """Rest positions X [m], shape (V, 3)."""

    @staticmethod
    def from_mesh(mesh: TriMesh, material: SheetMaterial) -> EnergySheetLinear:
        """Element stiffness from the rest shape (uv in-plane, vert_pos for the tangent plane)."""
        x = mesh.vert_pos[mesh.tri_indices]
        ds = torch.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]], -1)  # (F, 3, 2)
        tangent = ds @ mesh.tri_rest_inv  # (F, 3, 2): d X / d (u, v)
        c = torch.cat([-mesh.tri_rest_inv.sum(1, keepdim=True), mesh.tri_rest_inv], 1)  # (F,3,2)
        t0, t1 = tangent[..., 0][:, None], tangent[..., 1][:, None]  # (F, 1, 3)
        c0, c1 = c[..., 0, None], c[..., 1, None]  # (F, 3, 1)
        bmat = torch.stack([c0 * t0, c1 * t1, c1 * t0 + c0 * t1], 1)  # (F, 3voigt, 3vert, 3xyz)
        dmat = plane_stress_matrix(material, dtype=x.dtype).to(x.device)
        k = torch.einsum("fpax,pq,fqby->faxby", bmat, dmat, bmat)
        k = k * mesh.tri_rest_area[:, None, None, None, None]
        return EnergySheetLinear(k.permute(0, 1, 3, 2, 4).contiguous(), mesh.vert_pos)

    def _forces(self, model, pos):
        u = (pos - self.rest_pos)[:, model.mesh.tri_indices]  # (B, F, 3, 3)
        return torch.einsum("fabxy,zfby->zfax", self.element_stiffness, u), u

    def energy(self, model, pos):
        """Quadratic strain energy [J], shape (B,)."""
        f, u = self._forces(model, pos)
        return 0.5 * (f * u).sum(dim=(1, 2, 3))

    def gradient(self, model, pos):
        """``K u`` [N], shape (B, V, 3)."""
        f, _ = self._forces(model, pos)
        return scatter_vertices(f, model.mesh.tri_indices, pos.shape[1])

    def hessian_product(self, model, pos, dpos):
        """``K dpos`` (the energy is quadratic)."""
        return self.gradient(model, dpos + self.rest_pos)

    def hessian_blocks(self, model, pos):
        """The constant element stiffness, repeated per instance."""
        batch = pos.shape[0]
        blocks = self.element_stiffness[None].expand(batch, -1, -1, -1, -1, -1)
        return ElementBlocks(
            flat_indices(model.mesh.tri_indices, batch, pos.shape[1]),
            blocks.reshape(-1, 3, 3, 3, 3),
            model.mesh.tri_indices,
        )


def sheet_mass_spring(mesh: TriMesh, material: SheetMaterial) -> EnergyMassSpring:
    """The core's mass-spring model (edge + bend springs) with the sheet's plane-stress law."""
    rows = torch.tensor(material.stiffness_rows(), dtype=mesh.uv.dtype)
    stretching = rows.expand(1, 6, 4).contiguous()
    bending = torch.full((1, 3, 5), material.bending_rigidity, dtype=mesh.uv.dtype)
    return EnergyMassSpring.from_material(mesh, stretching, bending)
