"""Cloth shapes shared by the render tests (plain functions; fixtures live in conftest)."""

import numpy as np

CLOTH_SIZE = 0.5  # m
CLOTH_CENTRE_Z = 0.75  # m
IMAGE_SIZE = 48  # px


def grid_cloth(n: int = 12, size: float = CLOTH_SIZE):
    """Flat square cloth hanging in the x-z plane (y = 0), centred at z = CLOTH_CENTRE_Z.

    Returns pos (V, 3) [m], tri_indices (F, 3), uv (V, 2) [m].
    """
    u, v = np.meshgrid(np.linspace(0.0, size, n), np.linspace(0.0, size, n))
    u, v = u.ravel(), v.ravel()
    pos = np.stack([u - size / 2, np.zeros_like(u), CLOTH_CENTRE_Z + size / 2 - v], -1)
    tris = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            tris += [[a, a + n, a + 1], [a + 1, a + n, a + n + 1]]
    return pos, np.asarray(tris, dtype=np.int64), np.stack([u, v], -1)


def blown(pos: np.ndarray, angle_deg: float) -> np.ndarray:
    """The hanging cloth rotated about its top edge towards +y by ``angle_deg``."""
    top = pos[:, 2].max()
    drop = top - pos[:, 2]
    angle = np.radians(angle_deg)
    out = pos.copy()
    out[:, 1] = drop * np.sin(angle)
    out[:, 2] = top - drop * np.cos(angle)
    return out


def crumpled(pos: np.ndarray, seed: int = 0, amplitude: float = 0.06) -> np.ndarray:
    """Smooth random out-of-plane folds (along y) of the hanging cloth."""
    rng = np.random.default_rng(seed)
    out = pos.copy()
    x, z = pos[:, 0], pos[:, 2]
    for _ in range(4):
        kx, kz, phase = rng.uniform(6, 18), rng.uniform(6, 18), rng.uniform(0, 2 * np.pi)
        out[:, 1] += amplitude / 2 * np.sin(kx * x + kz * z + phase)
    return out
