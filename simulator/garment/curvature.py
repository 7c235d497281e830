"""Wrinkle curvature of a draped garment (*thesis* Eq. 6.7) and its regional averages.

Eq. 6.7 reads the curvature at an edge from the bend between its two triangles. Here, per
interior edge ``e`` with bend (dihedral) angle ``theta`` and adjacent current areas
``A_1, A_2`` (heights ``h_i = 2 A_i / |e|``)::

    kappa_e = 2 sin(|theta| / 2) |e| / (A_1 + A_2) = 4 sin(|theta| / 2) / (h_1 + h_2)   [1/m]

the normal curvature across the edge (``1 / R`` on a cylinder of radius R, for edges along
its axis; the *thesis*'s ``sin(alpha / 2) (h_1 + h_2)^-1 |e|`` up to the factor that makes it a
curvature). The vertex value is the discrete mean curvature

    H_v = sum_{e at v} |theta_e| |e| / 4  /  A_v                                       [1/m]

(half of each edge's integrated mean curvature ``|theta_e| |e| / 2`` goes to each end, over
the vertex's lumped area ``A_v``), which is ``1 / (2R)`` on the cylinder: the mean curvature.
Absolute angles, because wrinkles alternate ridges and valleys whose signed curvatures cancel.
A region's average curvature K is the area-weighted mean of ``H_v`` over its vertices.
"""

from __future__ import annotations

import numpy as np
import torch

from simulator.geometry import dihedral_angle

__all__ = ["edge_curvature", "regional_curvature", "vertex_mean_curvature"]


def _edge_terms(pos: torch.Tensor, tri: torch.Tensor, edges: torch.Tensor):
    theta = dihedral_angle(pos, edges).abs()  # (B, E)
    x = pos[:, edges]  # (B, E, 4, 3)
    o0, o1, v1, v2 = x.unbind(2)
    e = v2 - v1
    length = torch.linalg.vector_norm(e, dim=-1)
    a1 = 0.5 * torch.linalg.vector_norm(torch.linalg.cross(v1 - o0, v2 - o0, dim=-1), dim=-1)
    a2 = 0.5 * torch.linalg.vector_norm(torch.linalg.cross(v1 - o1, v2 - o1, dim=-1), dim=-1)
    return theta, length, a1 + a2


def edge_curvature(pos: torch.Tensor, tri: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """Eq. 6.7 per interior edge [1/m], pos (B, V, 3), hinges ``edges`` (E, 4) -> (B, E)."""
    theta, length, area = _edge_terms(pos, tri, edges)
    return 2.0 * torch.sin(0.5 * theta) * length / area.clamp_min(1e-300)


def _vertex_area(pos: torch.Tensor, tri: torch.Tensor) -> torch.Tensor:
    x = pos[:, tri]
    area = 0.5 * torch.linalg.vector_norm(
        torch.linalg.cross(x[:, :, 1] - x[:, :, 0], x[:, :, 2] - x[:, :, 0], dim=-1), dim=-1
    )
    out = pos.new_zeros(pos.shape[:2])
    out.index_add_(1, tri.reshape(-1), (area / 3.0).repeat_interleave(3, dim=1))
    return out


def vertex_mean_curvature(
    pos: torch.Tensor, tri: torch.Tensor, edges: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Discrete mean curvature per vertex [1/m] and lumped vertex areas [m²], both (B, V)."""
    theta, length, _ = _edge_terms(pos, tri, edges)
    integrated = 0.25 * theta * length  # per end of each edge
    h = pos.new_zeros(pos.shape[:2])
    h.index_add_(1, edges[:, 2], integrated)
    h.index_add_(1, edges[:, 3], integrated)
    area = _vertex_area(pos, tri)
    return h / area.clamp_min(1e-300), area


def regional_curvature(
    pos: torch.Tensor,
    tri: torch.Tensor,
    edges: torch.Tensor,
    regions: np.ndarray | torch.Tensor,
    region_count: int,
) -> torch.Tensor:
    """Area-weighted mean curvature of each region [1/m], shape (B, R).

    Args:
        pos: vertex positions [m], shape (B, V, 3).
        tri: triangles, shape (F, 3).
        edges: interior hinges ``[o0, o1, v1, v2]``, shape (E, 4).
        regions: region id of each vertex, shape (V,) or (B, V); -1 leaves a vertex out.
        region_count: R.
    """
    h, area = vertex_mean_curvature(pos, tri, edges)
    reg = torch.as_tensor(np.asarray(regions), dtype=torch.int64, device=pos.device)
    reg = reg.expand(pos.shape[0], -1)
    onehot = torch.nn.functional.one_hot(reg.clamp_min(0), region_count).to(pos.dtype)
    onehot = onehot * (reg >= 0)[..., None]
    weight = area[..., None] * onehot  # (B, V, R)
    total = weight.sum(1)
    return (weight * h[..., None]).sum(1) / total.clamp_min(1e-300)
