"""Image features attached to the mesh: barycentric anchoring (eq. 17) and selection (eq. 21).

At initialisation each tracked feature is associated with a point on the rest surface
(the paper intersects its line of sight with the surface; on our flat template this is the
point's material position) and stored as barycentric coordinates of one triangle, assumed
valid throughout the deformation. For self-occlusion the paper keeps, highest detection
score first, only features at least ``tau`` apart on the rest surface (eq. 21), which spreads
the image forces evenly instead of letting dense, possibly erroneous clusters dominate.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..mesh import TriMesh

__all__ = ["FeatureSet", "locate_features", "select_features"]


@dataclasses.dataclass(frozen=True)
class FeatureSet:
    """Features anchored to a triangle mesh (shared by the batch)."""

    tri: torch.Tensor
    """Triangle holding each feature, int64, shape (N,)."""
    bary: torch.Tensor
    """Barycentric coordinates in that triangle, shape (N, 3), rows sum to 1."""

    def __post_init__(self):
        if self.tri.dim() != 1 or self.tri.numel() == 0:
            raise ValueError(
                f"features: tri must be a non-empty (N,) tensor, got {tuple(self.tri.shape)}"
            )
        if tuple(self.bary.shape) != (self.tri.shape[0], 3):
            raise ValueError(
                f"features: bary must have shape (N, 3) = ({self.tri.shape[0]}, 3), "
                f"got {tuple(self.bary.shape)}"
            )

    @property
    def count(self) -> int:
        """N."""
        return int(self.tri.shape[0])

    def vertices(self, mesh: TriMesh) -> torch.Tensor:
        """Vertex ids of each feature's triangle, int64, shape (N, 3)."""
        return mesh.tri_indices[self.tri]

    def points(self, mesh: TriMesh, pos: torch.Tensor) -> torch.Tensor:
        """3D feature positions ``sum_j b_j x_j`` [m], shape (B, N, 3), for pos (B, V, 3)."""
        return (pos[:, self.vertices(mesh)] * self.bary[None, :, :, None].to(pos)).sum(2)

    def subset(self, keep: torch.Tensor) -> FeatureSet:
        """The features at indices ``keep`` (int64 (M,))."""
        return FeatureSet(self.tri[keep], self.bary[keep])


def locate_features(mesh: TriMesh, uv: torch.Tensor, *, tol: float = 1e-9) -> FeatureSet:
    """Anchor material points uv [m] (N, 2) in the mesh (brute force over triangles).

    Raises:
        ValueError: if ``uv`` is empty or a point lies outside the mesh.
    """
    uv = torch.as_tensor(uv, dtype=mesh.uv.dtype)
    if uv.dim() != 2 or uv.shape[1] != 2 or uv.shape[0] == 0:
        raise ValueError(f"features: uv must have shape (N>0, 2), got {tuple(uv.shape)}")
    corners = mesh.uv[mesh.tri_indices]  # (F, 3, 2)
    a, b, c = corners.unbind(1)
    v0, v1 = b - a, c - a
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]  # (F,)
    rel = uv[:, None, :] - a[None]  # (N, F, 2)
    l1 = (rel[..., 0] * v1[:, 1] - rel[..., 1] * v1[:, 0]) / det
    l2 = (v0[:, 0] * rel[..., 1] - v0[:, 1] * rel[..., 0]) / det
    l0 = 1.0 - l1 - l2
    worst = torch.minimum(torch.minimum(l0, l1), l2)  # (N, F)
    best, tri = worst.max(dim=1)
    if bool((best < -tol).any()):
        bad = int(torch.argmin(best))
        raise ValueError(f"features: point {bad} at uv {uv[bad].tolist()} lies outside the mesh")
    idx = torch.arange(uv.shape[0])
    bary = torch.stack([l0[idx, tri], l1[idx, tri], l2[idx, tri]], 1).clamp_min(0.0)
    return FeatureSet(tri, bary / bary.sum(1, keepdim=True))


def select_features(points: torch.Tensor, scores: torch.Tensor, tau: float) -> torch.Tensor:
    """Greedy eq. 21: highest score first, keep a feature if >= ``tau`` from all kept ones.

    Args:
        points: rest (3D or 2D) positions of the candidate features [m], shape (N, D).
        scores: detection scores, higher is better, shape (N,).
        tau: minimum spacing [m], >= 0 (the paper: the longest rest edge of the largest element).

    Returns:
        Indices of the kept features in decreasing score order, int64, shape (M,).
    """
    pts = np.asarray(torch.as_tensor(points, dtype=torch.float64))
    sc = np.asarray(torch.as_tensor(scores, dtype=torch.float64))
    if pts.ndim != 2 or pts.shape[0] == 0:
        raise ValueError(f"features: points must have shape (N>0, D), got {pts.shape}")
    if sc.shape != (pts.shape[0],) or not np.isfinite(sc).all():
        raise ValueError(f"features: scores must be finite with shape ({pts.shape[0]},)")
    if not (np.isfinite(tau) and tau >= 0):
        raise ValueError(f"tau must be a finite spacing >= 0 m, got {tau}")
    order = np.argsort(-sc, kind="stable")
    kept: list[int] = []
    nearest = np.full(pts.shape[0], np.inf)
    for i in order:
        if nearest[i] >= tau:
            kept.append(int(i))
            nearest = np.minimum(nearest, np.linalg.norm(pts - pts[i], axis=1))
    return torch.as_tensor(kept, dtype=torch.int64)
