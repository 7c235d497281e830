"""St Venant-Kirchhoff sheet energy in the edge-based form of Kikuuwe et al. (the paper §4).

For a linear element the deformation gradient is constant, so for every edge
``l_e^T E l_e = 1/2 (|l_e|² - |l_e^0|²)`` holds exactly (paper eq. 7). Writing the rest edge
in Voigt form ``q_e = (dx², dy², dx dy)`` and stacking the three edges of a triangle gives
``Q eps = 1/2 L`` (eqs. 9-10), so the Green strain ``eps = (exx, eyy, 2 exy)`` is a *fixed*
linear map of the squared-length changes ``L_e = |l_e|² - |l_e^0|²`` (eq. 11). The energy
``W = A/2 eps^T D eps`` (eq. 12, plane stress times thickness on our sheet) is then the
quadratic form ``1/2 L^T C L`` with a per-triangle 3 x 3 matrix ``C = A M^T D M``,
``M = 1/2 Q^-1``, precomputed once: no deformation gradient is needed at run time. It equals
the deformation-gradient StVK (tested against the core's membrane with the same law).

Hessian blocks for Newton: the material part ``J^T C J`` is PSD; the geometric part
``sum_e 2 sigma_e (a_e a_e^T) x I`` (edge tensions ``sigma = C L``) equals
``A c S c^T x I`` with the second Piola-Kirchhoff stress ``S``; we clamp the eigenvalues of
the 2 x 2 ``S`` at zero, which keeps the blocks PSD and exact wherever the element is in
tension.
"""

from __future__ import annotations

import dataclasses

import torch

from ..energies.base import ElementBlocks, Energy, psd_project_sym2
from ..geometry import flat_indices, scatter_vertices
from ..mesh import TriMesh
from .material import SheetMaterial, plane_stress_matrix

__all__ = ["TRI_EDGES", "EnergySheetStVK"]

TRI_EDGES = ((1, 2), (2, 0), (0, 1))
"""Local vertex pairs (i, j) of the three edges, ``l_e = x_j - x_i``."""


def _incidence(dtype, device) -> torch.Tensor:
    """s[e, a] = d l_e / d x_a (scalar), shape (3, 3)."""
    s = torch.zeros(3, 3, dtype=dtype, device=device)
    for e, (i, j) in enumerate(TRI_EDGES):
        s[e, i], s[e, j] = -1.0, 1.0
    return s


def _edges(pos: torch.Tensor, tri_indices: torch.Tensor) -> torch.Tensor:
    """Edge vectors ``l_e`` per triangle, shape (B, F, 3, 3)."""
    x = pos[:, tri_indices]
    return torch.stack([x[:, :, j] - x[:, :, i] for i, j in TRI_EDGES], dim=2)


@dataclasses.dataclass(frozen=True)
class EnergySheetStVK(Energy):
    """Isotropic plane-stress St Venant-Kirchhoff membrane, edge-based (Kikuuwe et al.)."""

    edge_stiffness: torch.Tensor
    """``C = A M^T D M`` of each triangle [N/m³], shape (F, 3, 3)."""
    strain_map: torch.Tensor
    """``M = 1/2 Q^-1`` mapping squared-length changes to Voigt strain [1/m²], shape (F, 3, 3)."""
    stress_matrix: torch.Tensor
    """Plane-stress Voigt matrix times thickness [N/m], shape (3, 3)."""
    rest_sq_length: torch.Tensor
    """Rest squared edge lengths ``|l_e^0|²`` [m²], shape (F, 3)."""

    @staticmethod
    def from_mesh(mesh: TriMesh, material: SheetMaterial) -> EnergySheetStVK:
        """Precompute ``Q``, ``M`` and ``C`` from the mesh's material (uv) rest shape."""
        uv = mesh.uv[mesh.tri_indices]  # (F, 3, 2)
        d = torch.stack([uv[:, j] - uv[:, i] for i, j in TRI_EDGES], dim=1)  # (F, 3, 2)
        q = torch.stack([d[..., 0] ** 2, d[..., 1] ** 2, d[..., 0] * d[..., 1]], dim=-1)
        strain_map = 0.5 * torch.linalg.inv(q)
        dmat = plane_stress_matrix(material, dtype=uv.dtype).to(uv.device)
        area = mesh.tri_rest_area[:, None, None]
        stiff = area * strain_map.transpose(1, 2) @ dmat @ strain_map
        return EnergySheetStVK(
            0.5 * (stiff + stiff.transpose(1, 2)), strain_map, dmat, (d * d).sum(-1)
        )

    def _tensions(self, model, pos):
        edges = _edges(pos, model.mesh.tri_indices)
        dsq = (edges * edges).sum(-1) - self.rest_sq_length  # (B, F, 3)
        sigma = torch.einsum("fgh,bfh->bfg", self.edge_stiffness, dsq)
        return edges, dsq, sigma

    def energy(self, model, pos):
        """Strain energy [J], shape (B,)."""
        _, dsq, sigma = self._tensions(model, pos)
        return 0.5 * (dsq * sigma).sum(dim=(1, 2))

    def strain(self, model, pos) -> torch.Tensor:
        """Green strain ``(exx, eyy, 2 exy)`` per triangle, shape (B, F, 3)."""
        _, dsq, _ = self._tensions(model, pos)
        return torch.einsum("fgh,bfh->bfg", self.strain_map, dsq)

    def gradient(self, model, pos):
        """Analytic dE/dx [N], shape (B, V, 3): ``sum_e sigma_e 2 l_e (+-1)``."""
        edges, _, sigma = self._tensions(model, pos)
        force = 2.0 * sigma[..., None] * edges  # d/dx_j of edge e, (B, F, 3, 3)
        s = _incidence(pos.dtype, pos.device)
        per_vert = torch.einsum("ea,bfex->bfax", s, force)
        return scatter_vertices(per_vert, model.mesh.tri_indices, pos.shape[1])

    def hessian_blocks(self, model, pos):
        """PSD blocks: exact material term plus the stress-clamped geometric term."""
        mesh = model.mesh
        edges, dsq, _ = self._tensions(model, pos)
        s = _incidence(pos.dtype, pos.device)
        jac = 2.0 * torch.einsum("ea,bfex->bfeax", s, edges)  # d L_e / d x_a, (B, F, 3, 3, 3)
        cj = torch.einsum("fgh,bfhcy->bfgcy", self.edge_stiffness, jac)
        blocks = torch.einsum("bfeax,bfecy->bfacxy", jac, cj)
        eps = torch.einsum("fgh,bfh->bfg", self.strain_map, dsq)
        stress = eps @ self.stress_matrix  # (B, F, 3) = (Sxx, Syy, Sxy) times thickness
        smat = torch.stack(
            [
                torch.stack([stress[..., 0], stress[..., 2]], -1),
                torch.stack([stress[..., 2], stress[..., 1]], -1),
            ],
            dim=-2,
        )
        smat = psd_project_sym2(smat) * mesh.tri_rest_area[None, :, None, None]
        c = torch.cat([-mesh.tri_rest_inv.sum(dim=1, keepdim=True), mesh.tri_rest_inv], dim=1)
        geo = torch.einsum("fia,bfac,fjc->bfij", c, smat, c)
        blocks.diagonal(dim1=-2, dim2=-1).add_(geo[..., None])
        return ElementBlocks(
            flat_indices(mesh.tri_indices, pos.shape[0], pos.shape[1]),
            blocks.reshape(-1, 3, 3, 3, 3),
            mesh.tri_indices,
        )
