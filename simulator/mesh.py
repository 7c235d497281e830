"""Triangle-mesh topology and rest geometry shared by every instance of a batch.

A :class:`TriMesh` is static data (integer topology, rest shape in material
coordinates, element arrays derived from them); the batch dimension lives in
:class:`simulator.model.SimState`. Builders validate their input and raise
:class:`MeshError` naming the offending field, so a bad mesh never reaches the
solver.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from common.errors import user_error

__all__ = ["MeshError", "TriMesh", "tensor_fields_to"]

_DEGENERATE_AREA = 1e-12  # m², smallest rest triangle area accepted


@user_error
class MeshError(ValueError):
    """Raised for a mesh that the simulator cannot use (names the field at fault)."""


def tensor_fields_to(
    obj, device: torch.device | str | None = None, dtype: torch.dtype | None = None
):
    """Copy of the frozen dataclass ``obj`` with every tensor field moved to ``device``.

    Float tensors are also cast to ``dtype`` (kept when ``None``); integer tensors keep theirs
    and other fields are left as they are.
    """
    changes = {}
    for field in dataclasses.fields(obj):
        value = getattr(obj, field.name)
        if isinstance(value, torch.Tensor):
            fdtype = dtype if value.is_floating_point() else None
            changes[field.name] = value.to(device=device, dtype=fdtype)
    return dataclasses.replace(obj, **changes)


@dataclasses.dataclass(frozen=True)
class TriMesh:
    """A triangle mesh with rest geometry, ready for the cloth energies.

    Rest shape: the cloth is flat in its material frame, so in-plane rest data
    comes from ``uv`` (warp along u, weft along v), while ``vert_pos`` is the 3D
    placement used as initial state and for rest dihedral angles.
    """

    vert_pos: torch.Tensor
    """Reference 3D vertex positions [m], shape (V, 3)."""
    uv: torch.Tensor
    """Material (warp, weft) coordinates of the vertices [m], shape (V, 2)."""
    tri_indices: torch.Tensor
    """Vertex indices of the triangles, int64, shape (F, 3)."""
    tri_rest_inv: torch.Tensor
    """Inverse of the rest edge matrix in material coordinates [1/m], shape (F, 2, 2)."""
    tri_rest_area: torch.Tensor
    """Rest triangle areas [m²], shape (F,)."""
    edge_indices: torch.Tensor
    """Interior (bending) edges ``[o0, o1, v1, v2]``, int64, shape (E, 4)."""
    edge_rest_angle: torch.Tensor
    """Rest dihedral angles [rad], shape (E,)."""
    edge_rest_length: torch.Tensor
    """Rest lengths of the bending edges [m], shape (E,)."""
    edge_rest_area: torch.Tensor
    """Sum of the two adjacent rest triangle areas [m²], shape (E,)."""
    edge_material_angle: torch.Tensor
    """Angle of each bending edge to the warp (u) axis, folded into [0, pi/2] [rad], shape (E,)."""
    segment_indices: torch.Tensor
    """All unique mesh edges (for stretch springs), int64, shape (S, 2)."""
    vert_area: torch.Tensor
    """Lumped rest area per vertex (one third of adjacent triangles) [m²], shape (V,)."""

    @property
    def vert_count(self) -> int:
        """Number of vertices V."""
        return int(self.vert_pos.shape[0])

    @property
    def tri_count(self) -> int:
        """Number of triangles F."""
        return int(self.tri_indices.shape[0])

    @property
    def edge_count(self) -> int:
        """Number of interior bending edges E."""
        return int(self.edge_indices.shape[0])

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None):
        """Return a copy on ``device`` with float fields cast to ``dtype``."""
        return tensor_fields_to(self, device, dtype)

    @staticmethod
    def grid(
        vert_per_side_u: int,
        vert_per_side_v: int | None = None,
        *,
        size_u: float = 0.5,
        size_v: float | None = None,
        dtype: torch.dtype = torch.float64,
    ) -> TriMesh:
        """Build a flat rectangular cloth in the z = 0 plane.

        Diagonals alternate in a checkerboard pattern so that the triangulation
        has no preferred shear direction. Vertex ``i + j * nu`` sits at
        ``(u_i, v_j)``; the material frame coincides with x (warp) and y (weft).

        Args:
            vert_per_side_u: vertices along u (warp), at least 2.
            vert_per_side_v: vertices along v (weft); defaults to ``vert_per_side_u``.
            size_u: side length along u [m], positive.
            size_v: side length along v [m]; defaults to ``size_u``.
            dtype: float dtype of the rest data.
        """
        nu = int(vert_per_side_u)
        nv = int(vert_per_side_v if vert_per_side_v is not None else nu)
        su = float(size_u)
        sv = float(size_v if size_v is not None else su)
        for name, count in (("vert_per_side_u", nu), ("vert_per_side_v", nv)):
            if count < 2:
                raise MeshError(f"{name} must be >= 2, got {count}")
        for name, size in (("size_u", su), ("size_v", sv)):
            if not np.isfinite(size) or size <= 0:
                raise MeshError(f"{name} must be a positive length in metres, got {size}")
        u, v = np.meshgrid(np.linspace(0.0, su, nu), np.linspace(0.0, sv, nv), indexing="xy")
        uv = np.stack([u.ravel(), v.ravel()], axis=1)
        tris = []
        for j in range(nv - 1):
            for i in range(nu - 1):
                a, b = i + j * nu, i + 1 + j * nu
                c, d = i + (j + 1) * nu, i + 1 + (j + 1) * nu
                if (i + j) % 2 == 0:
                    tris += [(a, b, d), (a, d, c)]
                else:
                    tris += [(a, b, c), (b, d, c)]
        pos = np.concatenate([uv, np.zeros((uv.shape[0], 1))], axis=1)
        return TriMesh.from_arrays(pos, np.asarray(tris), uv, dtype=dtype)

    @staticmethod
    def from_trimesh(mesh, uv: np.ndarray | None = None, *, dtype=torch.float64) -> TriMesh:
        """Build from a ``trimesh.Trimesh``; ``uv`` defaults to its texture coordinates.

        The texture coordinates must be in metres of material (warp, weft) length.
        """
        if uv is None:
            visual_uv = getattr(getattr(mesh, "visual", None), "uv", None)
            if visual_uv is None:
                raise MeshError("uv: the trimesh has no texture coordinates; pass uv explicitly")
            uv = np.asarray(visual_uv)
        return TriMesh.from_arrays(
            np.asarray(mesh.vertices), np.asarray(mesh.faces), uv, dtype=dtype
        )

    @staticmethod
    def from_arrays(
        vert_pos: np.ndarray, tri_indices: np.ndarray, uv: np.ndarray, *, dtype=torch.float64
    ) -> TriMesh:
        """Validate raw arrays and derive every element array.

        Raises:
            MeshError: on wrong shapes, out-of-range or repeated indices,
                non-finite coordinates, degenerate triangles (rest area below
                1e-12 m²), non-manifold edges (shared by more than two
                triangles) or inconsistently oriented neighbours.
        """
        pos = np.asarray(vert_pos, dtype=np.float64)
        tris = np.asarray(tri_indices)
        uv = np.asarray(uv, dtype=np.float64)
        if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] < 3:
            raise MeshError(f"vert_pos must have shape (V>=3, 3), got {pos.shape}")
        if uv.shape != (pos.shape[0], 2):
            raise MeshError(f"uv must have shape (V, 2) = ({pos.shape[0]}, 2), got {uv.shape}")
        if tris.ndim != 2 or tris.shape[1] != 3 or tris.shape[0] < 1:
            raise MeshError(f"tri_indices must have shape (F>=1, 3), got {tris.shape}")
        if not np.issubdtype(tris.dtype, np.integer):
            raise MeshError(f"tri_indices must be integers, got dtype {tris.dtype}")
        if not (np.isfinite(pos).all() and np.isfinite(uv).all()):
            raise MeshError("vert_pos/uv contain non-finite values")
        vert_count = pos.shape[0]
        if tris.min() < 0 or tris.max() >= vert_count:
            raise MeshError(f"tri_indices must lie in [0, {vert_count - 1}]")
        if np.any(
            (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
        ):
            raise MeshError("tri_indices: a triangle repeats a vertex (degenerate)")
        tris = tris.astype(np.int64)

        d1 = uv[tris[:, 1]] - uv[tris[:, 0]]
        d2 = uv[tris[:, 2]] - uv[tris[:, 0]]
        signed = 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
        area = np.abs(signed)
        if np.any(area < _DEGENERATE_AREA):
            bad = int(np.argmin(area))
            raise MeshError(
                f"uv: triangle {bad} is degenerate (rest area {area[bad]:.3e} m² < "
                f"{_DEGENERATE_AREA:.0e} m²)"
            )
        rest = np.stack([d1, d2], axis=2)  # (F, 2, 2), columns are edge vectors
        rest_inv = np.linalg.inv(rest)

        edges = _edge_table(tris)
        seg = np.array(sorted(edges.keys()), dtype=np.int64).reshape(-1, 2)
        bend = []
        for (a, b), owners in edges.items():
            if len(owners) > 2:
                raise MeshError(
                    f"tri_indices: edge ({a}, {b}) is shared by {len(owners)} triangles "
                    "(non-manifold; at most 2 allowed)"
                )
            if len(owners) == 2:
                (t0, dir0), (t1, dir1) = owners
                if dir0 == dir1:
                    raise MeshError(
                        f"tri_indices: triangles {t0} and {t1} have inconsistent orientation "
                        f"across edge ({a}, {b})"
                    )
                # v1 -> v2 follows triangle t0's winding, so t0 is the "left" face.
                v1, v2 = (a, b) if dir0 else (b, a)
                o0 = int(tris[t0][~np.isin(tris[t0], (a, b))][0])
                o1 = int(tris[t1][~np.isin(tris[t1], (a, b))][0])
                bend.append((o0, o1, v1, v2, t0, t1))
        bend_arr = np.array(bend, dtype=np.int64).reshape(-1, 6)
        edge_idx = bend_arr[:, :4]
        e_uv = uv[edge_idx[:, 3]] - uv[edge_idx[:, 2]]
        edge_len = np.linalg.norm(e_uv, axis=1)
        ang = np.abs(np.arctan2(e_uv[:, 1], e_uv[:, 0]))  # [0, pi]
        ang = np.where(ang > np.pi / 2, np.pi - ang, ang)
        edge_area = area[bend_arr[:, 4]] + area[bend_arr[:, 5]]
        vert_area = np.zeros(vert_count)
        np.add.at(vert_area, tris.ravel(), np.repeat(area / 3.0, 3))
        if np.any(vert_area == 0):
            raise MeshError("tri_indices: some vertices belong to no triangle (isolated vertices)")
        rest_angle = _dihedral_numpy(pos, edge_idx)
        t = lambda a: torch.as_tensor(a, dtype=dtype)  # noqa: E731
        i = lambda a: torch.as_tensor(a, dtype=torch.int64)  # noqa: E731
        return TriMesh(
            vert_pos=t(pos),
            uv=t(uv),
            tri_indices=i(tris),
            tri_rest_inv=t(rest_inv),
            tri_rest_area=t(area),
            edge_indices=i(edge_idx),
            edge_rest_angle=t(rest_angle),
            edge_rest_length=t(edge_len),
            edge_rest_area=t(edge_area),
            edge_material_angle=t(ang),
            segment_indices=i(seg),
            vert_area=t(vert_area),
        )


def _edge_table(tris: np.ndarray) -> dict[tuple[int, int], list[tuple[int, bool]]]:
    """Map each undirected edge (a<b) to [(triangle, follows_winding)]."""
    edges: dict[tuple[int, int], list[tuple[int, bool]]] = {}
    for t, (a, b, c) in enumerate(tris.tolist()):
        for p, q in ((a, b), (b, c), (c, a)):
            key = (p, q) if p < q else (q, p)
            edges.setdefault(key, []).append((t, p < q))
    return edges


def _dihedral_numpy(pos: np.ndarray, edge_idx: np.ndarray) -> np.ndarray:
    """Signed dihedral angles of ``[o0, o1, v1, v2]`` edges (same convention as the energy)."""
    from .geometry import dihedral_angle

    with torch.no_grad():
        return dihedral_angle(torch.as_tensor(pos)[None], torch.as_tensor(edge_idx))[0].numpy()
