"""Carry a draped garment from one mesh resolution of its pattern to another.

A recovery can fit the sizing on a coarse mesh (the silhouette needs few vertices) and the
material on a fine one (wrinkles need more). Both meshes are cut from the same panels, so a
vertex of one mesh lies in a triangle of the other in the panel's flat frame; its 3D position
is that triangle's, interpolated with the barycentric weights of the flat frame. A vertex on a
curved outline can fall just outside the other mesh's polygonal outline; it takes the nearest
triangle's weights, clamped to the triangle.
"""

from __future__ import annotations

import numpy as np

from .patterns import PatternTopology

__all__ = ["resample_positions"]


def _barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Weights of every point (N, 2) in every triangle (F, 3, 2), shape (N, F, 3)."""
    a = corners[:, 0]
    e1 = corners[:, 1] - a
    e2 = corners[:, 2] - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # (F,), > 0 for counter-clockwise
    d = points[:, None, :] - a[None]
    w1 = (d[..., 0] * e2[None, :, 1] - d[..., 1] * e2[None, :, 0]) / det[None]
    w2 = (e1[None, :, 0] * d[..., 1] - e1[None, :, 1] * d[..., 0]) / det[None]
    return np.stack([1.0 - w1 - w2, w1, w2], axis=-1)


def resample_positions(
    src: PatternTopology,
    src_coords: np.ndarray,
    src_pos: np.ndarray,
    dst: PatternTopology,
    dst_coords: np.ndarray,
) -> np.ndarray:
    """Positions of ``dst``'s vertices interpolated from a garment meshed as ``src``.

    Args:
        src: the topology the positions belong to.
        src_coords: its panel coordinates for the garment's G [m], shape (Vs, 2).
        src_pos: its vertex positions [m], shape (Vs, 3).
        dst: the topology to carry them to (same garment type, any edge length).
        dst_coords: its panel coordinates for the same G [m], shape (Vd, 2).

    Returns:
        Positions [m], shape (Vd, 3).
    """
    if src.garment != dst.garment:
        raise ValueError(f"cannot resample a {src.garment.value} onto a {dst.garment.value}")
    if src is dst:
        return np.array(src_pos, dtype=np.float64, copy=True)
    src_coords = np.asarray(src_coords, dtype=np.float64)
    src_pos = np.asarray(src_pos, dtype=np.float64)
    tri_panel = src.vert_panel[src.tri_indices[:, 0]]
    out = np.empty((dst.vert_count, 3))
    for panel in range(len(dst.panel_names)):
        tri = src.tri_indices[tri_panel == panel]
        ids = np.flatnonzero(dst.vert_panel == panel)
        weights = _barycentric(dst_coords[ids], src_coords[tri])  # (N, F, 3)
        best = np.argmax(weights.min(axis=-1), axis=1)  # inside: min >= 0
        w = np.clip(weights[np.arange(len(ids)), best], 0.0, None)
        w /= w.sum(axis=1, keepdims=True)
        out[ids] = np.einsum("nk,nkd->nd", w, src_pos[tri[best]])
    return out
