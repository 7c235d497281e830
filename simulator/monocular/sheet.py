"""Rectangular sheet meshes with an exact element count, and their clamped boundary vertices.

The paper's Table 1 uses 256, 576, 1024 and 1600 elements. A grid of ``n x n`` square cells,
each split into four triangles around a centre vertex ("crossed" grid), has exactly ``4 n²``
triangles, so n = 8, 12, 16, 20 gives those counts with no preferred shear direction.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..mesh import MeshError, TriMesh

__all__ = ["crossed_grid", "edge_vertices", "element_count_to_cells"]


def element_count_to_cells(element_count: int) -> int:
    """Cells per side ``n`` of a crossed grid with ``4 n²`` triangles."""
    n = math.isqrt(max(int(element_count), 0) // 4)
    if n < 1 or 4 * n * n != element_count:
        raise MeshError(
            f"element_count must be 4 n² (e.g. 256, 576, 1024, 1600), got {element_count}"
        )
    return n


def crossed_grid(cells: int, *, size: float = 0.1, dtype: torch.dtype = torch.float64) -> TriMesh:
    """Flat square sheet in the z = 0 plane with ``4 cells²`` triangles.

    Corner vertex ``(i, j)`` is ``i + j (cells + 1)``; centre vertices follow. Material
    coordinates equal the rest (x, y) positions.

    Args:
        cells: cells per side, >= 1.
        size: side length [m], > 0.
        dtype: float dtype of the rest data.
    """
    if cells < 1:
        raise MeshError(f"cells must be >= 1, got {cells}")
    if not size > 0:
        raise MeshError(f"size must be a positive length in metres, got {size}")
    side = cells + 1
    lin = np.linspace(0.0, size, side)
    u, v = np.meshgrid(lin, lin, indexing="xy")
    corners = np.stack([u.ravel(), v.ravel()], 1)
    mid = (lin[:-1] + lin[1:]) / 2
    cu, cv = np.meshgrid(mid, mid, indexing="xy")
    centres = np.stack([cu.ravel(), cv.ravel()], 1)
    uv = np.concatenate([corners, centres])
    tris = []
    for j in range(cells):
        for i in range(cells):
            a, b = i + j * side, i + 1 + j * side
            c, d = i + (j + 1) * side, i + 1 + (j + 1) * side
            m = side * side + i + j * cells
            tris += [(a, b, m), (b, d, m), (d, c, m), (c, a, m)]
    pos = np.concatenate([uv, np.zeros((uv.shape[0], 1))], 1)
    return TriMesh.from_arrays(pos, np.asarray(tris), uv, dtype=dtype)


def edge_vertices(mesh: TriMesh, side: str, *, tol: float = 1e-9) -> torch.Tensor:
    """Vertices on one straight side of a rectangular sheet: ``left``/``right`` (min/max u).

    Returns:
        int64 vertex ids sorted by v, shape (P,).
    """
    uv = mesh.uv
    if side == "left":
        hit = uv[:, 0] <= uv[:, 0].min() + tol
    elif side == "right":
        hit = uv[:, 0] >= uv[:, 0].max() - tol
    else:
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    ids = torch.nonzero(hit).flatten()
    return ids[torch.argsort(uv[ids, 1])]
