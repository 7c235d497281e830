"""Multi-region elasticity recovery (*thesis* §3.2.2.4-3.2.2.6, Algorithm 1).

The objective (*thesis* eq. 3.13) sums, over regions ``m``, the squared distances from the
deformed surface vertices of region ``m`` to the target surface of region ``m``, leaving
out the vertices shared with another region (*thesis* Fig. 3.5). The forward model is a
batched static solve of the organ (:class:`simulator.tissue.scenes.OrganForwardModel`), so the
whole PSO swarm is one batch of instances.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import torch

from simulator.calibrate.pso import pso_minimize
from simulator.tissue.scenes import OrganForwardModel

__all__ = ["MultiRegionObjective", "point_triangle_distance_sq", "recover_regions"]


def point_triangle_distance_sq(points: torch.Tensor, tris: torch.Tensor) -> torch.Tensor:
    """Squared distance from each point to the nearest of the triangles.

    Args:
        points: query points [m], shape (N, 3).
        tris: triangle corners [m], shape (M, 3, 3).

    Returns:
        Squared distances [m²], shape (N,).
    """
    p = points[:, None, :]  # (N, 1, 3)
    a, b, c = tris[None, :, 0], tris[None, :, 1], tris[None, :, 2]
    ab, ac = b - a, c - a
    normal = torch.linalg.cross(ab, ac, dim=-1)
    nn = (normal * normal).sum(-1).clamp_min(1e-300)
    ap = p - a
    # Barycentric coordinates of the projection onto the plane.
    v = (torch.linalg.cross(ap, ac, dim=-1) * normal).sum(-1) / nn
    w = (torch.linalg.cross(ab, ap, dim=-1) * normal).sum(-1) / nn
    inside = (v >= 0) & (w >= 0) & (v + w <= 1)
    plane = (ap * normal).sum(-1) ** 2 / nn

    def seg(p0, p1):
        d = p1 - p0
        t = (((p - p0) * d).sum(-1) / (d * d).sum(-1).clamp_min(1e-300)).clamp(0.0, 1.0)
        diff = p - (p0 + t[..., None] * d)
        return (diff * diff).sum(-1)

    edge = torch.minimum(torch.minimum(seg(a, b), seg(b, c)), seg(c, a))
    return torch.where(inside, plane, edge).amin(-1)


@dataclasses.dataclass
class MultiRegionObjective:
    """``Phi(mu) = sum_m sum_{v in S_m,l} d(v, S_m,t)²`` for a batch of per-region moduli."""

    forward: OrganForwardModel
    target_pos: torch.Tensor
    """Target (observed) organ vertex positions [m], shape (Vo, 3); the target surface of
    each region is made of its boundary triangles at these positions."""
    query_verts: list = dataclasses.field(init=False)
    target_tris: list = dataclasses.field(init=False)
    call_count: int = 0

    def __post_init__(self):
        mesh = self.forward.case.mesh
        target = torch.as_tensor(self.target_pos, dtype=mesh.vert_pos.dtype)
        if target.shape != (mesh.vert_count, 3):
            raise ValueError(
                f"target_pos must have shape ({mesh.vert_count}, 3), got {tuple(target.shape)}"
            )
        self.target_pos = target
        incidence = mesh.vert_regions()  # (V, R)
        shared = incidence.sum(-1) > 1
        region_of_tri = mesh.surface_tri_region
        self.query_verts, self.target_tris = [], []
        for r in range(mesh.region_count):
            tris = mesh.surface_tri_indices[region_of_tri == r]
            verts = torch.unique(tris)
            verts = verts[~shared[verts]]
            if tris.shape[0] == 0 or verts.numel() == 0:
                raise ValueError(
                    f"target_surface: region {r} has no surface vertices outside the shared "
                    "interface (nothing to compare)"
                )
            self.query_verts.append(verts)
            self.target_tris.append(tris)

    def distances(self, pos: torch.Tensor) -> torch.Tensor:
        """Objective per instance [m²] for deformed positions (B, Vo, 3), shape (B,)."""
        out = pos.new_zeros(pos.shape[0])
        for verts, tris in zip(self.query_verts, self.target_tris, strict=True):
            corners = self.target_pos.to(pos)[tris]
            for b in range(pos.shape[0]):
                out[b] = out[b] + point_triangle_distance_sq(pos[b, verts], corners).sum()
        return out

    def __call__(self, region_mu: np.ndarray | torch.Tensor) -> torch.Tensor:
        """Objective for per-region moduli (B, R) [Pa], shape (B,)."""
        mu = torch.as_tensor(np.asarray(region_mu), dtype=self.target_pos.dtype)
        self.call_count += 1
        return self.distances(self.forward.solve_regions(mu))


def recover_regions(
    objective: MultiRegionObjective,
    lower: list[float],
    upper: list[float],
    *,
    swarm_size: int = 40,
    seed: int = 0,
    max_iters: int = 60,
    x_tol: float = 2e-3,
    patience: int = 15,
) -> dict:
    """Run the PSO on ``objective`` and report the recovered per-region moduli.

    Stops at ``max_iters``, when every personal best lies within ``x_tol`` (relative to the
    search range) of the best one, or after ``patience`` iterations without improvement.

    Returns:
        ``best_mu`` (R,) [Pa], ``best_f``, ``iterations``, ``evaluations``, ``seconds``,
        ``history`` (best objective per iteration).
    """
    start = time.perf_counter()
    res = pso_minimize(
        objective,
        lower,
        upper,
        swarm_size=swarm_size,
        seed=seed,
        max_iters=max_iters,
        x_tol=x_tol,
        patience=patience,
    )
    return {
        "best_mu": res.best_x,
        "best_f": res.best_f,
        "iterations": res.iterations,
        "evaluations": res.evaluations,
        "seconds": time.perf_counter() - start,
        "history": res.history,
    }
