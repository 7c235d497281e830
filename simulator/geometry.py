"""Batched geometric kernels shared by the energies and forces.

Everything here is pure torch on tensors with a leading batch dimension B and
is differentiable, so autograd can serve as the test oracle for the analytic
derivatives written in the energies.
"""

from __future__ import annotations

import torch

__all__ = [
    "deformation_gradient",
    "dihedral_angle",
    "dihedral_angle_gradient",
    "flat_indices",
    "scatter_vertices",
    "vertex_area_normals",
]


def flat_indices(indices: torch.Tensor, batch: int, vert_count: int) -> torch.Tensor:
    """Element vertex indices offset per instance into a flattened (B*V) array.

    Args:
        indices: element vertex indices, shape (N, k).
        batch: B.
        vert_count: V.

    Returns:
        int64 indices into ``pos.reshape(B * V, 3)``, shape (B * N, k).
    """
    offset = torch.arange(batch, device=indices.device).mul_(vert_count).view(batch, 1, 1)
    return (indices.unsqueeze(0) + offset).reshape(-1, indices.shape[-1])


def scatter_vertices(values: torch.Tensor, indices: torch.Tensor, vert_count: int) -> torch.Tensor:
    """Sum per-element vertex vectors into per-vertex vectors.

    Args:
        values: per-element contributions, shape (B, N, k, 3).
        indices: element vertex indices shared by the batch, shape (N, k).
        vert_count: V.

    Returns:
        Summed vectors, shape (B, V, 3).
    """
    batch = values.shape[0]
    out = values.new_zeros(batch * vert_count, 3)
    out.index_add_(0, flat_indices(indices, batch, vert_count).reshape(-1), values.reshape(-1, 3))
    return out.view(batch, vert_count, 3)


def deformation_gradient(
    pos: torch.Tensor, tri_indices: torch.Tensor, tri_rest_inv: torch.Tensor
) -> torch.Tensor:
    """Deformation gradient of each triangle from material (2D) to world (3D).

    Args:
        pos: vertex positions [m], shape (B, V, 3).
        tri_indices: shape (F, 3).
        tri_rest_inv: inverse rest edge matrices [1/m], shape (F, 2, 2).

    Returns:
        F = [x1 - x0, x2 - x0] Dm^-1, shape (B, F, 3, 2).
    """
    x = pos[:, tri_indices]  # (B, F, 3, 3)
    ds = torch.stack([x[:, :, 1] - x[:, :, 0], x[:, :, 2] - x[:, :, 0]], dim=-1)
    return ds @ tri_rest_inv


def _hinge_normals(pos: torch.Tensor, edge_indices: torch.Tensor):
    """Unnormalised face normals and edge vector of each hinge ``[o0, o1, v1, v2]``."""
    x = pos[:, edge_indices]  # (B, E, 4, 3)
    o0, o1, v1, v2 = x.unbind(dim=2)
    n1 = torch.linalg.cross(v1 - o0, v2 - o0, dim=-1)
    n2 = torch.linalg.cross(v2 - o1, v1 - o1, dim=-1)
    return o0, o1, v1, v2, n1, n2


def dihedral_angle(pos: torch.Tensor, edge_indices: torch.Tensor) -> torch.Tensor:
    """Signed dihedral (bend) angle at each interior edge.

    Zero for a flat hinge; the sign follows ``sin(theta) = (n1 x n2) . e_hat``
    with n1, n2 the normals of the faces holding o0 and o1 and e = v2 - v1.

    Args:
        pos: vertex positions [m], shape (B, V, 3).
        edge_indices: ``[o0, o1, v1, v2]``, shape (E, 4).

    Returns:
        Angles in (-pi, pi] [rad], shape (B, E).
    """
    _, _, v1, v2, n1, n2 = _hinge_normals(pos, edge_indices)
    e = v2 - v1
    e_hat = e / torch.linalg.vector_norm(e, dim=-1, keepdim=True)
    n1_len = torch.linalg.vector_norm(n1, dim=-1)
    n2_len = torch.linalg.vector_norm(n2, dim=-1)
    sin = (torch.linalg.cross(n1, n2, dim=-1) * e_hat).sum(-1)
    cos = (n1 * n2).sum(-1)
    # atan2 is scale-invariant, so the unnormalised normals suffice.
    return torch.atan2(sin / (n1_len * n2_len), cos / (n1_len * n2_len))


def dihedral_angle_gradient(pos: torch.Tensor, edge_indices: torch.Tensor) -> torch.Tensor:
    """Analytic gradient of :func:`dihedral_angle` (Bridson et al. 2003 bending modes).

    Returns:
        d theta / d x for ``[o0, o1, v1, v2]`` [1/m], shape (B, E, 4, 3).
    """
    o0, o1, v1, v2, n1, n2 = _hinge_normals(pos, edge_indices)
    e = v2 - v1
    e_len = torch.linalg.vector_norm(e, dim=-1, keepdim=True)
    e_hat = e / e_len
    m1 = n1 / (n1 * n1).sum(-1, keepdim=True)
    m2 = n2 / (n2 * n2).sum(-1, keepdim=True)
    g_o0 = -e_len * m1
    g_o1 = -e_len * m2

    def along(d: torch.Tensor) -> torch.Tensor:
        return (d * e_hat).sum(-1, keepdim=True)

    g_v1 = -along(o0 - v2) * m1 - along(o1 - v2) * m2
    g_v2 = along(o0 - v1) * m1 + along(o1 - v1) * m2
    return torch.stack([g_o0, g_o1, g_v1, g_v2], dim=2)


def vertex_area_normals(pos: torch.Tensor, tri_indices: torch.Tensor) -> torch.Tensor:
    """Per-vertex area-weighted normal vectors (a third of each adjacent triangle).

    Args:
        pos: vertex positions [m], shape (B, V, 3).
        tri_indices: shape (F, 3).

    Returns:
        Vectors whose length is the vertex's share of the current area [m²] and
        whose direction is the area-weighted normal, shape (B, V, 3).
    """
    x = pos[:, tri_indices]
    area_vec = 0.5 * torch.linalg.cross(x[:, :, 1] - x[:, :, 0], x[:, :, 2] - x[:, :, 0], dim=-1)
    per_vert = (area_vec / 3.0).unsqueeze(2).expand(-1, -1, 3, -1)
    return scatter_vertices(per_vert, tri_indices, pos.shape[1])
