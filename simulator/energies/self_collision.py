"""Cloth self-collision as a vertex-vertex repulsion penalty.

Candidate pairs are found once per step (vertices closer than ``2 * radius``
that are not also that close in material (uv) space) and kept for the Newton iterations of
that step; each pair closer than ``radius`` costs ``1/2 k (radius - d)²`` with
``k = stiffness * mean vertex area``. A vertex-vertex model needs a radius of
about the edge length to stop triangles passing through each other; it is the
cheap, composable variant (an edge-edge/vertex-face model is future work).
Candidate search is a brute-force distance matrix per instance: O(V²) memory
per instance, fine for the thesis's resolutions.
"""

from __future__ import annotations

import dataclasses

import torch

from .base import ElementBlocks, Energy

__all__ = ["EnergySelfCollision"]


@dataclasses.dataclass(frozen=True)
class EnergySelfCollision(Energy):
    """Repulsion between non-adjacent vertices closer than ``radius``."""

    radius: float = 0.01
    """Contact distance [m]."""
    stiffness: float = 2.0e6
    """Penalty stiffness per unit vertex area [N/m³]."""
    pairs: torch.Tensor | None = None
    """Flat vertex ids ``(b*V + i, b*V + j)`` of candidate pairs, int64, shape (N, 2)."""

    def bind(self, model, control, pos):
        """Find candidate pairs within ``2 * radius`` at the start of the step."""
        return dataclasses.replace(self, pairs=self.find_pairs(model, pos))

    def find_pairs(self, model, pos: torch.Tensor) -> torch.Tensor:
        """Flat ids of close vertex pairs that are not already close in the rest shape."""
        batch, verts = pos.shape[:2]
        rest = model.mesh.uv.to(pos)  # material-space distance: folded layers still collide
        rest_close = torch.cdist(rest, rest) <= 2.0 * self.radius
        found = []
        with torch.no_grad():
            for b in range(batch):
                close = (torch.cdist(pos[b], pos[b]) < 2.0 * self.radius) & ~rest_close
                found.append(close.triu_(diagonal=1).nonzero() + b * verts)
        return torch.cat(found)

    def _pair_terms(self, model, pos):
        pairs = self.pairs
        if pairs is None or pairs.numel() == 0:
            return None
        flat = pos.reshape(-1, 3)
        diff = flat[pairs[:, 0]] - flat[pairs[:, 1]]
        dist = torch.linalg.vector_norm(diff, dim=-1)
        depth = (self.radius - dist).clamp_min(0.0)
        k = self.stiffness * model.mesh.vert_area.mean()
        return pairs, diff / dist.clamp_min(1e-12)[:, None], depth, k

    def energy(self, model, pos):
        """Penalty energy [J], shape (B,)."""
        terms = self._pair_terms(model, pos)
        out = pos.new_zeros(pos.shape[0])
        if terms is None:
            return out
        pairs, _, depth, k = terms
        return out.index_add(0, pairs[:, 0] // pos.shape[1], 0.5 * k * depth * depth)

    def gradient(self, model, pos):
        """Minus the repulsion forces [N], shape (B, V, 3)."""
        terms = self._pair_terms(model, pos)
        grad = torch.zeros_like(pos).reshape(-1, 3)
        if terms is not None:
            pairs, normal, depth, k = terms
            f = (k * depth)[:, None] * normal
            grad.index_add_(0, pairs[:, 0], -f)
            grad.index_add_(0, pairs[:, 1], f)
        return grad.view_as(pos)

    def hessian_blocks(self, model, pos):
        """Gauss-Newton pair blocks ``k [n; -n][n; -n]^T`` for active pairs."""
        terms = self._pair_terms(model, pos)
        if terms is None:
            return None
        pairs, normal, depth, k = terms
        active = (depth > 0).to(pos.dtype)
        nn = (k * active)[:, None, None] * normal[:, :, None] * normal[:, None, :]
        blocks = torch.stack([torch.stack([nn, -nn], 1), torch.stack([-nn, nn], 1)], 1)
        return ElementBlocks(pairs, blocks)
