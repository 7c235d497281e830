"""Tetrahedral-mesh topology, rest geometry and region labels shared by a batch.

A :class:`TetMesh` is static data for the tissue FEM (thesis ch. 3): linear tetrahedra,
their inverse rest edge matrices and volumes, one region label per element (the regions
whose moduli the multi-region recovery estimates), the outward surface triangles and
lumped vertex volumes. :meth:`TetMesh.from_arrays` validates everything and raises
:class:`simulator.mesh.MeshError` naming the field at fault. :meth:`TetMesh.box` is a
structured builder for analytic tests; real geometry comes from gmsh
(:mod:`simulator.tissue.meshing`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from .mesh import MeshError, tensor_fields_to

__all__ = ["TetMesh", "voxel_aggregates"]

DEGENERATE_VOLUME_RATIO = 1e-9
"""A tet whose volume is below this fraction of (mean edge length)³ is degenerate."""

# Outward faces of a positively oriented tet (a, b, c, d), det[b-a, c-a, d-a] > 0.
_TET_FACES = ((0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3))


@dataclasses.dataclass(frozen=True)
class TetMesh:
    """A linear tetrahedral mesh with rest geometry and per-element region labels."""

    vert_pos: torch.Tensor
    """Rest vertex positions [m], shape (V, 3)."""
    tet_indices: torch.Tensor
    """Vertex indices of the tets, positively oriented, int64, shape (T, 4)."""
    tet_rest_inv: torch.Tensor
    """Inverse rest edge matrix ``[x1-x0, x2-x0, x3-x0]^-1`` [1/m], shape (T, 3, 3)."""
    tet_rest_volume: torch.Tensor
    """Rest volumes [m³], shape (T,)."""
    tet_region: torch.Tensor
    """Region label of each tet in [0, R), int64, shape (T,)."""
    surface_tri_indices: torch.Tensor
    """Boundary triangles, outward counter-clockwise, int64, shape (S, 3)."""
    surface_tri_tet: torch.Tensor
    """Tet owning each boundary triangle, int64, shape (S,)."""
    vert_volume: torch.Tensor
    """Lumped rest volume per vertex (a quarter of each adjacent tet) [m³], shape (V,)."""

    @property
    def vert_count(self) -> int:
        """Number of vertices V."""
        return int(self.vert_pos.shape[0])

    @property
    def tet_count(self) -> int:
        """Number of tets T."""
        return int(self.tet_indices.shape[0])

    @property
    def region_count(self) -> int:
        """Number of regions R (largest label + 1)."""
        return int(self.tet_region.max()) + 1

    @property
    def surface_tri_region(self) -> torch.Tensor:
        """Region of the tet owning each boundary triangle, int64, shape (S,)."""
        return self.tet_region[self.surface_tri_tet]

    def surface_vertices(self) -> torch.Tensor:
        """Sorted ids of the vertices on the boundary, int64, shape (Vs,)."""
        return torch.unique(self.surface_tri_indices)

    def vert_regions(self) -> torch.Tensor:
        """Boolean incidence of vertices and regions (vertex touches a tet of region r), (V, R)."""
        out = torch.zeros(self.vert_count, self.region_count, dtype=torch.bool)
        rows = self.tet_indices.cpu().reshape(-1)
        cols = self.tet_region.cpu()[:, None].expand(-1, 4).reshape(-1)
        out[rows, cols] = True
        return out.to(self.tet_indices.device)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None):
        """Return a copy on ``device`` with float fields cast to ``dtype``."""
        return tensor_fields_to(self, device, dtype)

    def locate(self, points: torch.Tensor, *, chunk: int = 64) -> tuple[torch.Tensor, torch.Tensor]:
        """Tet containing each rest-space point and its barycentric weights there.

        A point outside the mesh (e.g. on a curved surface that the facets cut) gets the
        tet it lies least outside of, with weights that extrapolate linearly.

        Args:
            points: query points [m], shape (N, 3).
            chunk: points per batch (memory is chunk x T x 4).

        Returns:
            ``(tet, weights)``: tet ids, int64 (N,), and weights summing to 1, shape (N, 4).
        """
        origin = self.vert_pos[self.tet_indices[:, 0]]  # (T, 3)
        tets, weights = [], []
        for part in points.to(self.vert_pos).split(chunk):
            rel = part[:, None, :] - origin[None]  # (n, T, 3)
            lam = torch.einsum("tij,ntj->nti", self.tet_rest_inv, rel)
            bary = torch.cat([1.0 - lam.sum(-1, keepdim=True), lam], -1)  # (n, T, 4)
            best = bary.amin(-1).argmax(-1)
            tets.append(best)
            weights.append(bary[torch.arange(part.shape[0]), best])
        return torch.cat(tets), torch.cat(weights)

    def submesh(self, tet_mask: torch.Tensor) -> tuple[TetMesh, torch.Tensor]:
        """The mesh made of the tets where ``tet_mask`` (T,) holds, and its vertex ids here.

        Returns:
            ``(mesh, vert_ids)``: the submesh, whose vertex ``i`` is vertex ``vert_ids[i]`` of
            this mesh (int64, shape (V',)). Region labels are kept as they are.
        """
        mask = torch.as_tensor(tet_mask, dtype=torch.bool).cpu()
        if mask.shape != (self.tet_count,):
            raise MeshError(
                f"tet_mask must have shape ({self.tet_count},), got {tuple(mask.shape)}"
            )
        tets = self.tet_indices.cpu()[mask]
        vert_ids, local = torch.unique(tets, return_inverse=True)
        sub = TetMesh.from_arrays(
            self.vert_pos.cpu().double().numpy()[vert_ids.numpy()],
            local.numpy(),
            self.tet_region.cpu()[mask].numpy(),
            dtype=self.vert_pos.dtype,
        )
        return sub, vert_ids

    @staticmethod
    def from_arrays(
        vert_pos: np.ndarray,
        tet_indices: np.ndarray,
        tet_region: np.ndarray | None = None,
        *,
        dtype: torch.dtype = torch.float64,
    ) -> TetMesh:
        """Validate raw arrays and derive every element array.

        Args:
            vert_pos: rest positions [m], shape (V, 3).
            tet_indices: vertex ids, shape (T, 4); must be positively oriented.
            tet_region: region label per tet, integers >= 0, shape (T,); default all 0.
            dtype: float dtype of the rest data.

        Raises:
            MeshError: on wrong shapes, out-of-range or repeated indices, non-finite
                positions, inverted (negative volume) or degenerate tets, region labels that
                do not cover every tet or leave a region empty, isolated vertices.
        """
        pos = np.asarray(vert_pos, dtype=np.float64)
        tets = np.asarray(tet_indices)
        if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] < 4:
            raise MeshError(f"vert_pos must have shape (V>=4, 3), got {pos.shape}")
        if not np.isfinite(pos).all():
            raise MeshError("vert_pos contains non-finite values")
        if tets.ndim != 2 or tets.shape[1] != 4 or tets.shape[0] < 1:
            raise MeshError(f"tet_indices must have shape (T>=1, 4), got {tets.shape}")
        if not np.issubdtype(tets.dtype, np.integer):
            raise MeshError(f"tet_indices must be integers, got dtype {tets.dtype}")
        vert_count, tet_count = pos.shape[0], tets.shape[0]
        if tets.min() < 0 or tets.max() >= vert_count:
            raise MeshError(f"tet_indices must lie in [0, {vert_count - 1}]")
        tets = tets.astype(np.int64)
        srt = np.sort(tets, axis=1)
        if np.any(srt[:, 1:] == srt[:, :-1]):
            bad = int(np.nonzero(np.any(srt[:, 1:] == srt[:, :-1], axis=1))[0][0])
            raise MeshError(f"tet_indices: tet {bad} repeats a vertex (degenerate)")
        if tet_region is None:
            region = np.zeros(tet_count, dtype=np.int64)
        else:
            region = np.asarray(tet_region)
            if region.shape != (tet_count,):
                raise MeshError(
                    f"tet_region must label every tet: shape ({tet_count},), got {region.shape}"
                )
            if not np.issubdtype(region.dtype, np.integer):
                raise MeshError(f"tet_region must be integers, got dtype {region.dtype}")
            if region.min() < 0:
                bad = int(np.argmin(region))
                raise MeshError(
                    f"tet_region: tet {bad} has label {int(region[bad])}; labels must be >= 0 "
                    "(every tet must belong to a region)"
                )
            used = np.bincount(region, minlength=int(region.max()) + 1)
            if np.any(used == 0):
                missing = np.nonzero(used == 0)[0].tolist()
                raise MeshError(
                    f"tet_region: regions {missing} have no tets (labels must be 0..R-1)"
                )
            region = region.astype(np.int64)

        x = pos[tets]
        edges = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
        signed = np.linalg.det(edges) / 6.0
        mean_edge = np.linalg.norm(edges, axis=1).mean()
        tol = DEGENERATE_VOLUME_RATIO * mean_edge**3
        if np.any(np.abs(signed) <= tol):
            bad = int(np.argmin(np.abs(signed)))
            raise MeshError(
                f"tet_indices: tet {bad} is degenerate (rest volume {signed[bad]:.3e} m³, "
                f"|volume| must exceed {tol:.1e} m³)"
            )
        if np.any(signed < 0):
            bad = int(np.argmin(signed))
            raise MeshError(
                f"tet_indices: tet {bad} is inverted (signed rest volume {signed[bad]:.3e} m³ "
                "< 0); order each tet so that det[x1-x0, x2-x0, x3-x0] > 0"
            )
        vert_volume = np.zeros(vert_count)
        np.add.at(vert_volume, tets.ravel(), np.repeat(signed / 4.0, 4))
        if np.any(vert_volume == 0):
            raise MeshError("tet_indices: some vertices belong to no tet (isolated vertices)")

        faces = tets[:, list(_TET_FACES)]  # (T, 4, 3)
        flat = faces.reshape(-1, 3)
        keys = np.sort(flat, axis=1)
        _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        inverse = inverse.reshape(-1)
        if np.any(counts > 2):
            raise MeshError(
                "tet_indices: a triangle is shared by more than two tets (non-manifold)"
            )
        boundary = counts[inverse] == 1
        surface = flat[boundary]
        surface_tet = np.repeat(np.arange(tet_count), 4)[boundary]
        t = lambda a: torch.as_tensor(a, dtype=dtype)  # noqa: E731
        i = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.int64)  # noqa: E731
        return TetMesh(
            vert_pos=t(pos),
            tet_indices=i(tets),
            tet_rest_inv=t(np.linalg.inv(edges)),
            tet_rest_volume=t(signed),
            tet_region=i(region),
            surface_tri_indices=i(surface),
            surface_tri_tet=i(surface_tet),
            vert_volume=t(vert_volume),
        )

    @staticmethod
    def box(
        cells: tuple[int, int, int],
        size: tuple[float, float, float],
        *,
        origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
        dtype: torch.dtype = torch.float64,
    ) -> TetMesh:
        """Structured box of ``nx x ny x nz`` cubes, each split into six tets (Kuhn).

        Every cube uses the same main diagonal, so the mesh is conforming. Vertex
        ``i + (nx+1) * (j + (ny+1) * k)`` sits at ``origin + (i, j, k) * size / cells``.
        """
        nx, ny, nz = (int(c) for c in cells)
        if min(nx, ny, nz) < 1:
            raise MeshError(f"cells must all be >= 1, got {cells}")
        if min(size) <= 0 or not all(math.isfinite(s) for s in size):
            raise MeshError(f"size must be positive lengths [m], got {size}")
        counts = (nx, ny, nz)
        axes = [np.linspace(o, o + s, n + 1) for o, s, n in zip(origin, size, counts, strict=True)]
        gx, gy, gz = np.meshgrid(*axes, indexing="ij")
        pos = np.stack([gx.ravel(order="F"), gy.ravel(order="F"), gz.ravel(order="F")], 1)

        def vid(i, j, k):
            return i + (nx + 1) * (j + (ny + 1) * k)

        # Six tets of the unit cube along the 0 -> 7 diagonal (vertex bit order x, y, z).
        kuhn = ((0, 1, 3, 7), (0, 3, 2, 7), (0, 2, 6, 7), (0, 6, 4, 7), (0, 4, 5, 7), (0, 5, 1, 7))
        ii, jj, kk = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
        ii, jj, kk = ii.ravel(), jj.ravel(), kk.ravel()
        corners = np.stack(
            [vid(ii + (c & 1), jj + ((c >> 1) & 1), kk + ((c >> 2) & 1)) for c in range(8)], 1
        )
        tets = np.concatenate([corners[:, list(t)] for t in kuhn], 0)
        x = pos[tets]
        det = np.linalg.det(np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], 2))
        tets[det < 0] = tets[det < 0][:, [0, 2, 1, 3]]
        return TetMesh.from_arrays(pos, tets, dtype=dtype)


def voxel_aggregates(pos: torch.Tensor, patch: int) -> torch.Tensor:
    """Group 3D vertices into voxel cells holding about ``patch³`` vertices each.

    The 3D analogue of :func:`simulator.solvers.coarse.grid_aggregates`, for the two-level
    preconditioner on tet meshes: the cell edge is rescaled a few times until the number
    of non-empty cells is within ~1.3x of ``V / patch³``; ids are renumbered densely.

    Args:
        pos: rest positions [m], shape (V, 3).
        patch: target aggregate width in vertices (>= 1).

    Returns:
        Aggregate id of each vertex, int64 in [0, A), shape (V,).
    """
    if patch < 1:
        raise ValueError(f"patch must be >= 1, got {patch}")
    pts = pos.detach().to(torch.float64).cpu()
    verts = pts.shape[0]
    lo = pts.amin(0)
    extent = (pts.amax(0) - lo).clamp_min(1e-12)
    target = max(verts / float(patch**3), 1.0)
    cell = float(extent.prod() / target) ** (1.0 / 3.0)
    best, best_err = None, math.inf
    for _ in range(10):
        counts = torch.ceil(extent / cell - 1e-9).clamp_min(1).long()
        ijk = torch.minimum(((pts - lo) / cell).floor().long(), counts - 1)
        key = (ijk[:, 0] * counts[1] + ijk[:, 1]) * counts[2] + ijk[:, 2]
        ids = torch.unique(key, return_inverse=True)[1]
        found = int(ids.max()) + 1
        err = abs(math.log(found / target))
        if err < best_err:
            best, best_err = ids, err
        if err <= math.log(1.3):
            break
        cell *= (found / target) ** (1.0 / 3.0)
    return best.to(pos.device)
