"""Capsule geometry for drawing the arm: meshes, poses from end points, and per-frame capsules.

Capsules arrive as rows ``[p0 (3), p1 (3), radius]`` [m], the layout of
``SimControl.capsules``. :func:`capsule_mesh` makes a z-aligned capsule centred at the
origin (trimesh) and :func:`capsule_pose` the rigid transform that places it between two end
points. The capsules of every recorded frame travel in the mesh sequence
(``MeshSequence.capsules``), so drawing the arm never rebuilds its scene.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

__all__ = ["capsule_mesh", "capsule_pose"]


def capsule_mesh(length: float, radius: float, *, segments: int = 24) -> trimesh.Trimesh:
    """Capsule along z centred at the origin.

    Args:
        length: Distance between the two hemisphere centres [m] (>= 0).
        radius: Radius [m] (> 0).
        segments: Segments around the axis (rings per hemisphere are half of it).

    Returns:
        The capsule mesh (smooth vertex normals available as ``vertex_normals``).
    """
    if not (math.isfinite(length) and length >= 0):
        raise ValueError(f"capsule length must be >= 0 m, got {length}")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"capsule radius must be > 0 m, got {radius}")
    return trimesh.creation.capsule(
        height=float(length), radius=float(radius), count=[segments, segments // 2]
    )


def capsule_pose(p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Rigid transform taking the z-axis capsule of :func:`capsule_mesh` onto p0 -> p1.

    Args:
        p0: First end point [m], shape (3,).
        p1: Second end point [m], shape (3,).

    Returns:
        Transform, float64, shape (4, 4): rotation z -> (p1 - p0) direction, translation to
        the midpoint. Coincident end points give the identity rotation.
    """
    p0, p1 = np.asarray(p0, np.float64), np.asarray(p1, np.float64)
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    pose = np.eye(4)
    pose[:3, 3] = 0.5 * (p0 + p1)
    if length < 1e-12:
        return pose
    d = axis / length
    z = np.array([0.0, 0.0, 1.0])
    cos = float(d @ z)
    if cos < -1.0 + 1e-12:
        pose[:3, :3] = np.diag([1.0, -1.0, -1.0])  # half turn about x
        return pose
    v = np.cross(z, d)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    pose[:3, :3] = np.eye(3) + vx + vx @ vx / (1.0 + cos)
    return pose
