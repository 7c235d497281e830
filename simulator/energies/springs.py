"""Mass-spring cloth: stretch/shear springs on mesh edges and bend (flip) springs.

Every spring stores ``E = 1/2 K (|x_i - x_j| - L)²``.

* Stretch/shear springs lie on the mesh edges. A spring at angle ``a`` to the
  warp gets the directional membrane stiffness of the zero-strain row
  ``Y(a) = k0 c⁴ + k2 s⁴ + (2 k1 + k3) c² s²`` [N/m] (the orthotropic StVK law
  under uniaxial strain along the spring), so ``K = Y A_s / L²`` with ``A_s`` a
  third of the adjacent rest triangle areas: axis-aligned springs are stretch
  springs, diagonal ones shear springs.
* Bend springs join the two opposite vertices ``o0, o1`` of each interior edge.
  Their length changes only at second order in the fold angle, so they cannot
  reproduce a linear moment-curvature law: ``K`` is chosen so that a cylindrical
  fold of curvature ``BEND_SPRING_REFERENCE_CURVATURE`` stores the continuum
  energy ``1/2 D kappa² A`` (softer below that curvature, stiffer above).
"""

from __future__ import annotations

import dataclasses

import torch

from ..geometry import flat_indices, scatter_vertices
from ..mesh import TriMesh
from .base import ElementBlocks, Energy

__all__ = ["BEND_SPRING_REFERENCE_CURVATURE", "EnergyMassSpring"]

BEND_SPRING_REFERENCE_CURVATURE = 20.0
"""Curvature [1/m] at which bend springs match the continuum bending energy."""


def _spring_arrays(mesh: TriMesh, stretching: torch.Tensor, bending: torch.Tensor):
    """Spring vertex pairs (S, 2), rest lengths (S,) and stiffness (B, S) [N/m]."""
    seg = mesh.segment_indices
    d = mesh.uv[seg[:, 1]] - mesh.uv[seg[:, 0]]
    length = torch.linalg.vector_norm(d, dim=-1)
    c2 = (d[:, 0] / length) ** 2
    s2 = 1.0 - c2
    k0, k1, k2, k3 = stretching[:, 0, :].unbind(-1)  # (B,)
    young = k0[:, None] * c2 * c2 + k2[:, None] * s2 * s2 + (2 * k1 + k3)[:, None] * c2 * s2
    # Each triangle's area is shared by its three edges.
    tri = mesh.tri_indices
    edge_area = torch.zeros_like(length)
    key = seg[:, 0] * mesh.vert_count + seg[:, 1]
    order = torch.argsort(key)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        lo = torch.minimum(tri[:, a], tri[:, b])
        hi = torch.maximum(tri[:, a], tri[:, b])
        pos = torch.searchsorted(key[order], lo * mesh.vert_count + hi)
        edge_area.index_add_(0, order[pos], mesh.tri_rest_area / 3.0)
    k_stretch = young * edge_area / (length * length)

    e = mesh.edge_indices
    u = mesh.uv
    hinge = u[e[:, 3]] - u[e[:, 2]]
    hinge_len = torch.linalg.vector_norm(hinge, dim=-1)

    def height(o):
        rel = u[o] - u[e[:, 2]]
        return (rel[:, 0] * hinge[:, 1] - rel[:, 1] * hinge[:, 0]).abs() / hinge_len

    h1, h2 = height(e[:, 0]), height(e[:, 1])
    bend_len = torch.linalg.vector_norm(u[e[:, 0]] - u[e[:, 1]], dim=-1)
    stiffness_d = bending.mean(dim=(1, 2))  # (B,) N·m
    kappa = BEND_SPRING_REFERENCE_CURVATURE
    area = mesh.edge_rest_area / 3.0
    k_bend = 4.0 * stiffness_d[:, None] * area / (h1 * h1 * h2 * h2 * (h1 + h2) ** 2 * kappa**2)
    pairs = torch.cat([seg, e[:, :2]])
    return pairs, torch.cat([length, bend_len]), torch.cat([k_stretch, k_bend], dim=1)


@dataclasses.dataclass(frozen=True)
class EnergyMassSpring(Energy):
    """Sum of Hookean springs with per-instance stiffness."""

    spring_indices: torch.Tensor
    """Vertex pairs, int64, shape (S, 2)."""
    rest_length: torch.Tensor
    """Rest lengths [m], shape (S,)."""
    stiffness: torch.Tensor
    """Spring constants [N/m], shape (B, S)."""

    @staticmethod
    def from_material(mesh: TriMesh, stretching: torch.Tensor, bending: torch.Tensor):
        """Springs for a mesh and batched material tables (B, 6, 4) and (B, 3, 5)."""
        return EnergyMassSpring(*_spring_arrays(mesh, stretching, bending))

    def _vectors(self, pos):
        x = pos[:, self.spring_indices]
        diff = x[:, :, 1] - x[:, :, 0]
        length = torch.linalg.vector_norm(diff, dim=-1)
        return diff, length

    def energy(self, model, pos):
        """Spring energy [J], shape (B,)."""
        _, length = self._vectors(pos)
        return 0.5 * (self.stiffness * (length - self.rest_length) ** 2).sum(-1)

    def gradient(self, model, pos):
        """Analytic dE/dx [N], shape (B, V, 3)."""
        diff, length = self._vectors(pos)
        f = (self.stiffness * (length - self.rest_length) / length.clamp_min(1e-12))[
            ..., None
        ] * diff
        return scatter_vertices(torch.stack([-f, f], dim=2), self.spring_indices, pos.shape[1])

    def hessian_blocks(self, model, pos):
        """Spring Hessians with the transverse term clamped at zero (PSD)."""
        diff, length = self._vectors(pos)
        n = diff / length.clamp_min(1e-12)[..., None]
        nn = n[..., :, None] * n[..., None, :]
        eye = torch.eye(3, dtype=pos.dtype, device=pos.device)
        transverse = (1.0 - self.rest_length / length.clamp_min(1e-12)).clamp_min(0.0)
        h = self.stiffness[..., None, None] * (nn + transverse[..., None, None] * (eye - nn))
        blocks = torch.stack(
            [torch.stack([h, -h], 2), torch.stack([-h, h], 2)], 2
        )  # (B, S, 2, 2, 3, 3)
        batch = pos.shape[0]
        return ElementBlocks(
            flat_indices(self.spring_indices, batch, pos.shape[1]),
            blocks.reshape(-1, 2, 2, 3, 3),
            self.spring_indices,
        )
