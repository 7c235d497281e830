"""Garment energies on the solver core: seams, and cloth energies with per-instance rest shapes.

* :class:`EnergySeam` sews: zero-rest-length springs between paired seam vertices,
  ``E = 1/2 sum_i k_i |x_a - x_b|²`` with ``k_i = seam_stiffness * l_i`` (``l_i`` the length
  of seam this pair stands for), so the closing force per unit seam length does not depend on
  the mesh resolution. Quadratic, so its gradient and Hessian are exact and the Hessian
  blocks ``k [[I, -I], [-I, I]]`` are positive semi-definite. A seam carrying a tension ``T``
  [N/m] stays open by ``T / seam_stiffness`` [m] (:data:`SEAM_TOLERANCE` is the stated bound).
* :class:`EnergyMembranePattern` and :class:`EnergyBendingPattern` are the core's
  :class:`~simulator.energies.EnergyMembraneWang` and
  :class:`~simulator.energies.EnergyBendingDihedral` with rest data per instance, shape
  (B, F, ...) / (B, E), instead of the shared mesh's: a swarm of particles with different
  sizing G (different flat panels on one topology) runs as one batch. They override only the
  core's ``rest_data``, so with equal rest shapes they equal the core terms (the tests'
  reference); the compiled kernels take only the core types, so these stay on the torch path.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from simulator.energies import EnergyBendingDihedral, EnergyMembraneWang
from simulator.energies.base import ElementBlocks, Energy
from simulator.geometry import flat_indices, scatter_vertices

__all__ = [
    "SEAM_STIFFNESS",
    "SEAM_TOLERANCE",
    "EnergyBendingPattern",
    "EnergyMembranePattern",
    "EnergySeam",
    "PatternRest",
    "seam_pair_lengths",
]

SEAM_STIFFNESS = 5.0e4
"""Seam stiffness per unit seam length [N/m²]."""
SEAM_TOLERANCE = 2.0e-3
"""Largest seam gap accepted after sewing [m] (a drape's tension of 10 N/m leaves 0.2 mm)."""


def seam_pair_lengths(coords: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Seam length each vertex pair stands for [m], shape (n,): half its neighbouring edges.

    Averaged over the two sides of the seam (``coords`` (V, 2) panel coordinates).
    """
    out = np.zeros(len(pairs))
    for side in (0, 1):
        pts = coords[pairs[:, side]]
        edge = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        out[:-1] += 0.25 * edge
        out[1:] += 0.25 * edge
    return out


@dataclasses.dataclass(frozen=True)
class EnergySeam(Energy):
    """Zero-rest-length springs that sew paired vertices (see the module docstring)."""

    pairs: torch.Tensor
    """Vertex pairs, int64, shape (S, 2)."""
    stiffness: torch.Tensor
    """Spring constants [N/m], shape (S,) or (B, S)."""

    def _diff(self, pos):
        return pos[:, self.pairs[:, 1]] - pos[:, self.pairs[:, 0]]

    def energy(self, model, pos):
        """Seam energy [J], shape (B,)."""
        d = self._diff(pos)
        return 0.5 * (self.stiffness * (d * d).sum(-1)).sum(-1)

    def gradient(self, model, pos):
        """Exact dE/dx [N], shape (B, V, 3)."""
        f = self.stiffness[..., None] * self._diff(pos)
        return scatter_vertices(torch.stack([-f, f], dim=2), self.pairs, pos.shape[1])

    def hessian_product(self, model, pos, dpos):
        """Exact d²E/dx² · dpos (the energy is quadratic), shape (B, V, 3)."""
        return self.gradient(model, dpos)

    def hessian_blocks(self, model, pos):
        """Exact blocks ``k [[I, -I], [-I, I]]`` per pair (PSD)."""
        batch, verts = pos.shape[:2]
        k = self.stiffness.expand(batch, -1)
        eye = torch.eye(3, dtype=pos.dtype, device=pos.device)
        h = k[..., None, None] * eye
        blocks = torch.stack([torch.stack([h, -h], 2), torch.stack([-h, h], 2)], 2)
        return ElementBlocks(
            flat_indices(self.pairs, batch, verts), blocks.reshape(-1, 2, 2, 3, 3), self.pairs
        )

    def gaps(self, pos: torch.Tensor) -> torch.Tensor:
        """Distance between the two vertices of every pair [m], shape (B, S)."""
        return torch.linalg.vector_norm(self._diff(pos), dim=-1)


@dataclasses.dataclass(frozen=True)
class PatternRest:
    """Rest data of a batch of flat patterns sharing one topology."""

    tri_rest_inv: torch.Tensor
    """Inverse rest edge matrices [1/m], shape (B, F, 2, 2)."""
    tri_rest_area: torch.Tensor
    """Rest triangle areas [m²], shape (B, F)."""
    edge_rest_length: torch.Tensor
    """Rest lengths of the bending edges [m], shape (B, E)."""
    edge_rest_area: torch.Tensor
    """Sum of the two adjacent rest triangle areas [m²], shape (B, E)."""
    vert_area: torch.Tensor
    """Lumped rest area per vertex [m²], shape (B, V)."""

    @staticmethod
    def from_coords(coords: torch.Tensor, tri: torch.Tensor, edges: torch.Tensor) -> PatternRest:
        """Rest data of panel coordinates (B, V, 2) [m] on triangles (F, 3) and hinges (E, 4).

        The formulas are :meth:`simulator.mesh.TriMesh.from_arrays`'s; triangles must be
        counter-clockwise (positive area) in every instance.
        """
        d1 = coords[:, tri[:, 1]] - coords[:, tri[:, 0]]
        d2 = coords[:, tri[:, 2]] - coords[:, tri[:, 0]]
        signed = 0.5 * (d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0])
        if not bool((signed > 1e-12).all()):
            raise ValueError("pattern: a triangle is degenerate or inverted in some instance")
        rest = torch.stack([d1, d2], dim=-1)
        area = signed.abs()
        # The hinge's two triangles: found once from the shared topology.
        t0, t1 = _hinge_triangles(tri, edges)
        e = coords[:, edges[:, 3]] - coords[:, edges[:, 2]]
        verts = coords.shape[1]
        vert_area = coords.new_zeros(coords.shape[0], verts)
        vert_area.index_add_(1, tri.reshape(-1), (area / 3.0).repeat_interleave(3, dim=1))
        return PatternRest(
            torch.linalg.inv(rest),
            area,
            torch.linalg.vector_norm(e, dim=-1),
            area[:, t0] + area[:, t1],
            vert_area,
        )


def _hinge_triangles(tri: torch.Tensor, edges: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The two triangles of each hinge ``[o0, o1, v1, v2]``: those holding (v1, v2, o0/o1)."""
    tri_np = tri.cpu().numpy()
    index = {}
    for t, row in enumerate(tri_np.tolist()):
        index[frozenset(row)] = t
    e = edges.cpu().numpy()
    t0 = [index[frozenset((a, c, d))] for a, _, c, d in e.tolist()]
    t1 = [index[frozenset((b, c, d))] for _, b, c, d in e.tolist()]
    return (
        torch.as_tensor(t0, dtype=torch.int64, device=tri.device),
        torch.as_tensor(t1, dtype=torch.int64, device=tri.device),
    )


@dataclasses.dataclass(frozen=True)
class EnergyMembranePattern(EnergyMembraneWang):
    """:class:`EnergyMembraneWang` with per-instance rest shapes (B, F, ...)."""

    rest_inv: torch.Tensor
    """Inverse rest edge matrices [1/m], shape (B, F, 2, 2)."""
    rest_area: torch.Tensor
    """Rest triangle areas [m²], shape (B, F)."""

    @staticmethod
    def from_rest(
        stretching: torch.Tensor,
        rest: PatternRest,
        *,
        strain_dependent: bool = True,
        anisotropic: bool = True,
    ) -> EnergyMembranePattern:
        """From stabilised stiffness rows (B, 6, 4) [N/m] and the patterns' rest data."""
        core = EnergyMembraneWang.from_material(
            stretching, strain_dependent=strain_dependent, anisotropic=anisotropic
        )
        return EnergyMembranePattern(core.row0, core.fibres, rest.tri_rest_inv, rest.tri_rest_area)

    def rest_data(self, model) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-instance inverse rest edge matrices [1/m], (B, F, 2, 2), and areas [m²], (B, F)."""
        return self.rest_inv, self.rest_area


@dataclasses.dataclass(frozen=True)
class EnergyBendingPattern(EnergyBendingDihedral):
    """:class:`EnergyBendingDihedral` with per-instance hinge rest lengths and areas (B, E)."""

    rest_length: torch.Tensor
    """Rest lengths of the hinges [m], shape (B, E)."""
    rest_area: torch.Tensor
    """Adjacent rest areas of the hinges [m²], shape (B, E)."""

    @staticmethod
    def from_rest(
        mesh,
        bending: torch.Tensor,
        rest: PatternRest,
        *,
        curvature_dependent: bool = True,
        anisotropic: bool = True,
    ) -> EnergyBendingPattern:
        """From material rows (B, 3, 5) [N·m]; hinge directions from the shared mesh."""
        core = EnergyBendingDihedral.from_material(
            mesh, bending, curvature_dependent=curvature_dependent, anisotropic=anisotropic
        )
        return EnergyBendingPattern(core.edge_stiffness, rest.edge_rest_length, rest.edge_rest_area)

    def rest_data(self, model) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-instance hinge rest lengths [m] and adjacent rest areas [m²], shape (B, E)."""
        return self.rest_length, self.rest_area
