"""Tetrahedral meshes of the thesis's test geometries, generated with gmsh (OpenCASCADE).

* :func:`sphere_in_cube`: the sensitivity-study model of *thesis* §3.2.3 (Fig. 3.6), a
  sphere (region 0) embedded in a cube (region 1), meshed conformally.
* :func:`organ_scene`: the multi-region experiment of *thesis* §3.3.1 (Fig. 3.8): an
  ellipsoidal organ with a flat base, split by the plane x = 0 into the region that holds
  the tumour (region 0, x < 0) and the normal region (region 1); an embedded tumour of
  adjustable volume ratio (region 0 scaled about its centroid); and a box of surrounding
  tissue (region 2) whose base, shared with the organ's base, rests on bone.
* :func:`heart`: a biventricular heart for the Table 4.1-style experiment (*thesis* §4.3.1
  models the left and right ventricles): the union of two ellipsoidal shells, the left
  ventricle's cavity and the crescent-shaped right-ventricular cavity cut out, truncated
  at the base (valve) plane z = 0.

gmsh is imported inside the builders only (``simulator`` imports torch and numpy at
module level). Meshing is deterministic (one thread, fixed options) and results are cached
in-process, so a test or a table sweep pays for each mesh once.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import torch

from simulator.mesh import MeshError
from simulator.tetmesh import TetMesh

__all__ = [
    "HEART_ELLIPSOIDS",
    "REGION_NORMAL",
    "REGION_TISSUE",
    "REGION_TUMOUR_SIDE",
    "HeartBody",
    "OrganScene",
    "heart",
    "organ_scene",
    "sphere_in_cube",
]

REGION_TUMOUR_SIDE = 0
"""Organ region holding the tumour (x < 0)."""
REGION_NORMAL = 1
"""Organ region of normal tissue (x > 0)."""
REGION_TISSUE = 2
"""Surrounding soft tissue."""


@dataclasses.dataclass(frozen=True)
class OrganScene:
    """Organ + surrounding tissue mesh with the masks the tissue experiments need."""

    mesh: TetMesh
    """Whole domain; ``tet_region`` is REGION_TUMOUR_SIDE, REGION_NORMAL or REGION_TISSUE."""
    tet_tumour: torch.Tensor
    """Whether each tet belongs to the tumour (inside REGION_TUMOUR_SIDE), bool, (T,)."""
    base_verts: torch.Tensor
    """Vertices on the bone plane z = z_base (Dirichlet, fixed), int64, (Pb,)."""
    top_verts: torch.Tensor
    """Vertices on the tissue box's top face (moved to compress), int64, (Pt,)."""
    tumour_ratio: float
    """Tumour volume over the volume of REGION_TUMOUR_SIDE, from the meshed tets."""
    box_height: float
    """Height of the tissue box [m]."""


HEART_ELLIPSOIDS = {
    "lv_outer": ((0.0, 0.0, 0.0), (0.025, 0.025, 0.065)),
    "rv_outer": ((0.014, 0.0, 0.0), (0.036, 0.022, 0.05)),
    "lv_cavity": ((0.0, 0.0, 0.0), (0.016, 0.016, 0.056)),
    "rv_cavity": ((0.016, 0.0, 0.0), (0.029, 0.016, 0.044)),
}
"""Centre and semi-axes [m] of the heart's ellipsoids: left-ventricular wall ~9 mm, right
free wall ~5 mm, 65 mm base to apex, 75 mm wide (an adult heart's ventricles)."""


@dataclasses.dataclass(frozen=True)
class HeartBody:
    """Biventricular heart mesh with the surfaces its boundary conditions need."""

    mesh: TetMesh
    """Ventricle walls, one region."""
    base_verts: torch.Tensor
    """Vertices on the base (valve) plane z = 0 (Dirichlet, fixed), int64, (Pb,)."""
    epicardium_tris: torch.Tensor
    """Outer surface triangles (no base, no cavity), outward, int64, (S, 3)."""


def _gmsh_session():
    import gmsh

    if gmsh.isInitialized():
        gmsh.finalize()
    gmsh.initialize(readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.Verbosity", 0)
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
    gmsh.option.setNumber("Mesh.Optimize", 1)
    gmsh.model.add("clothsense")
    return gmsh


def _volume_tets(gmsh, tag: int) -> tuple[np.ndarray, np.ndarray]:
    """Node tags of the linear tets of volume ``tag``, shape (n, 4)."""
    types, _, nodes = gmsh.model.mesh.getElements(3, tag)
    for etype, enodes in zip(types, nodes, strict=True):
        if etype == 4:  # 4-node tetrahedron
            return np.asarray(enodes, dtype=np.int64).reshape(-1, 4)
    return np.zeros((0, 4), dtype=np.int64)


def _collect(gmsh, labels: dict[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Positions, tets, region per tet and gmsh volume tag per tet for the labelled volumes."""
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    order = np.argsort(node_tags)
    node_tags = np.asarray(node_tags)[order]
    pos = np.asarray(coords).reshape(-1, 3)[order]
    tets, region, source = [], [], []
    for tag, label in labels.items():
        t = _volume_tets(gmsh, tag)
        tets.append(t)
        region.append(np.full(len(t), label, dtype=np.int64))
        source.append(np.full(len(t), tag, dtype=np.int64))
    tets = np.searchsorted(node_tags, np.concatenate(tets))
    used, tets = np.unique(tets, return_inverse=True)
    tets = tets.reshape(-1, 4)
    pos = pos[used]
    x = pos[tets]
    det = np.linalg.det(np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], 2))
    tets[det < 0] = tets[det < 0][:, [0, 2, 1, 3]]
    return pos, tets, np.concatenate(region), np.concatenate(source)


def _bbox_inside(inner, outer, tol) -> bool:
    return all(inner[i] >= outer[i] - tol for i in range(3)) and all(
        inner[i + 3] <= outer[i + 3] + tol for i in range(3)
    )


@functools.lru_cache(maxsize=8)
def sphere_in_cube(
    cube_size: float = 0.1,
    sphere_radius: float = 0.025,
    mesh_size: float = 0.008,
    *,
    sphere_mesh_size: float | None = None,
) -> TetMesh:
    """Sphere (region 0) centred in a cube (region 1), conforming at the interface.

    Args:
        cube_size: cube edge [m].
        sphere_radius: sphere radius [m], below half the cube edge.
        mesh_size: target element size in the cube [m].
        sphere_mesh_size: target element size on the sphere [m] (default ``mesh_size / 2``).
    """
    if not 0 < sphere_radius < 0.5 * cube_size:
        raise MeshError(
            f"sphere_radius must lie in (0, cube_size / 2) = (0, {0.5 * cube_size}), "
            f"got {sphere_radius}"
        )
    if mesh_size <= 0:
        raise MeshError(f"mesh_size must be > 0 m, got {mesh_size}")
    gmsh = _gmsh_session()
    try:
        occ = gmsh.model.occ
        h = 0.5 * cube_size
        box = occ.addBox(-h, -h, -h, cube_size, cube_size, cube_size)
        ball = occ.addSphere(0.0, 0.0, 0.0, sphere_radius)
        occ.fragment([(3, box)], [(3, ball)])
        occ.synchronize()
        fine = sphere_mesh_size or 0.5 * mesh_size
        labels = {}
        for _, tag in gmsh.model.getEntities(3):
            bb = gmsh.model.getBoundingBox(3, tag)
            labels[tag] = 0 if bb[3] - bb[0] < cube_size * 0.9 else 1
        _refine_near(gmsh, [t for t, lab in labels.items() if lab == 0], fine, mesh_size, h)
        gmsh.model.mesh.generate(3)
        pos, tets, region, _ = _collect(gmsh, labels)
    finally:
        gmsh.finalize()
    return TetMesh.from_arrays(pos, tets, region)


def _refine_near(gmsh, volumes: list[int], fine: float, coarse: float, reach: float) -> None:
    """Size ``fine`` inside the given volumes, growing to ``coarse`` over ``reach`` outside."""
    surfaces = [t for _, t in gmsh.model.getBoundary([(3, v) for v in volumes], oriented=False)]
    field = gmsh.model.mesh.field
    dist = field.add("Distance")
    field.setNumbers(dist, "SurfacesList", surfaces)
    ramp = field.add("Threshold")
    field.setNumber(ramp, "InField", dist)
    field.setNumber(ramp, "SizeMin", fine)
    field.setNumber(ramp, "SizeMax", coarse)
    field.setNumber(ramp, "DistMin", 0.0)
    field.setNumber(ramp, "DistMax", reach)
    const = field.add("MathEval")
    field.setString(const, "F", f"{fine!r}")
    inside = field.add("Restrict")
    field.setNumber(inside, "InField", const)
    field.setNumbers(inside, "VolumesList", volumes)
    both = field.add("Min")
    field.setNumbers(both, "FieldsList", [ramp, inside])
    field.setAsBackgroundMesh(both)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)


def _organ_geometry(gmsh, semi_axes, base_z, margin, tumour_ratio):
    occ = gmsh.model.occ
    a, b, c = semi_axes

    def organ():
        body = occ.addSphere(0.0, 0.0, 0.0, 1.0)
        # Poles on the x axis: the split plane x = 0 must not pass through a pole, and
        # the seam meridian must not lie in the split or base planes (degenerate curves).
        occ.rotate([(3, body)], 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.5 * math.pi)
        occ.rotate([(3, body)], 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.25 * math.pi)
        occ.dilate([(3, body)], 0.0, 0.0, 0.0, a, b, c)
        below = occ.addBox(-2 * a, -2 * b, base_z - 4 * c, 4 * a, 4 * b, 4 * c)
        cut, _ = occ.cut([(3, body)], [(3, below)])
        return cut

    def left_box():
        return [(3, occ.addBox(-2 * a, -2 * b, base_z - c, 2 * a, 4 * b, 4 * c))]

    left, _ = occ.intersect(organ(), left_box())
    right, _ = occ.cut(organ(), left_box())
    tools = left + right
    tumour = []
    if tumour_ratio > 0:
        # The tumour-side region is convex, so its copy scaled about its centroid by
        # ratio^(1/3) lies strictly inside it and has exactly ``ratio`` of its volume.
        tumour, _ = occ.intersect(organ(), left_box())
        occ.synchronize()
        centre = occ.getCenterOfMass(*tumour[0])
        scale = tumour_ratio ** (1.0 / 3.0)
        occ.dilate(tumour, *centre, scale, scale, scale)
        tools += tumour
    height = c - base_z + margin
    box = occ.addBox(-a - margin, -b - margin, base_z, 2 * (a + margin), 2 * (b + margin), height)
    _, children = occ.fragment([(3, box)], tools)
    occ.synchronize()
    kids = [{t for _, t in group} for group in children]
    left_tags = set().union(*kids[1 : 1 + len(left)])
    right_tags = set().union(*kids[1 + len(left) : 1 + len(left) + len(right)])
    tumour_tags = set().union(*kids[1 + len(left) + len(right) :]) if tumour else set()
    labels = dict.fromkeys(kids[0], REGION_TISSUE)
    labels.update(dict.fromkeys(left_tags, REGION_TUMOUR_SIDE))
    labels.update(dict.fromkeys(right_tags, REGION_NORMAL))
    return labels, tumour_tags


@functools.lru_cache(maxsize=16)
def organ_scene(
    tumour_ratio: float = 0.3,
    *,
    tet_target: int = 4000,
    semi_axes: tuple[float, float, float] = (0.03, 0.02, 0.02),
    base_fraction: float = 0.6,
    margin: float = 0.015,
    tissue_size_factor: float = 2.0,
) -> OrganScene:
    """Two-region organ with an embedded tumour inside a box of surrounding tissue.

    Args:
        tumour_ratio: tumour volume / volume of the tumour-side region, in [0, 0.95].
        tet_target: wanted number of organ tets (the mesh size is calibrated once; the
            result is within ~15 %).
        semi_axes: organ ellipsoid semi-axes (a, b, c) [m].
        base_fraction: the organ is cut flat at z = -base_fraction * c (its base on bone).
        margin: tissue thickness around the organ (sides and top) [m].
        tissue_size_factor: tissue elements are this many times larger than the organ's.
    """
    if not 0.0 <= tumour_ratio <= 0.95:
        raise MeshError(f"tumour_ratio must lie in [0, 0.95], got {tumour_ratio}")
    if tet_target < 50:
        raise MeshError(f"tet_target must be >= 50, got {tet_target}")
    a, b, c = semi_axes
    base_z = -base_fraction * c
    organ_volume_estimate = (4.0 / 3.0) * math.pi * a * b * c * 0.9
    size = (organ_volume_estimate / (tet_target * 0.15)) ** (1.0 / 3.0)
    for _attempt in range(2):
        mesh, tumour = _mesh_organ_retry(
            semi_axes, base_z, margin, tumour_ratio, size, tissue_size_factor
        )
        organ_tets = int((mesh.tet_region != REGION_TISSUE).sum())
        if abs(organ_tets / tet_target - 1.0) < 0.15:
            break
        size *= (organ_tets / tet_target) ** (1.0 / 3.0)
    pos = mesh.vert_pos
    base = torch.nonzero((pos[:, 2] - base_z).abs() < 1e-9 * a + 1e-12).reshape(-1)
    top = torch.nonzero((pos[:, 2] - (c + margin)).abs() < 1e-9 * a + 1e-12).reshape(-1)
    vol = mesh.tet_rest_volume
    side = mesh.tet_region == REGION_TUMOUR_SIDE
    ratio = float(vol[tumour].sum() / vol[side].sum())
    return OrganScene(mesh, tumour, base, top, ratio, c + margin - base_z)


def _mesh_organ_retry(*args):
    """Mesh, retrying with slightly different sizes if gmsh fails.

    gmsh's 3D Delaunay occasionally fails on thin slivers between close surfaces (tumour
    near the organ surface); a slightly different size settles it.
    """
    *geometry, size, factor = args
    last = None
    for shrink in (1.0, 0.93, 1.07, 0.87):
        try:
            return _mesh_organ(*geometry, size * shrink, factor)
        except Exception as err:  # gmsh raises a bare Exception
            last = err
    raise MeshError(f"gmsh could not mesh the organ scene: {last}")


def _mesh_organ(semi_axes, base_z, margin, tumour_ratio, size, tissue_factor):
    gmsh = _gmsh_session()
    try:
        labels, tumour_tags = _organ_geometry(gmsh, semi_axes, base_z, margin, tumour_ratio)
        organ_vols = [t for t, lab in labels.items() if lab != REGION_TISSUE]
        _refine_near(gmsh, organ_vols, size, size * tissue_factor, margin)
        gmsh.model.mesh.generate(3)
        pos, tets, region, source = _collect(gmsh, labels)
    finally:
        gmsh.finalize()
    mesh = TetMesh.from_arrays(pos, tets, region)
    tumour = torch.as_tensor(np.isin(source, list(tumour_tags)))
    return mesh, tumour


def _inside_ellipsoid(points: torch.Tensor, name: str, scale: float) -> torch.Tensor:
    centre, axes = HEART_ELLIPSOIDS[name]
    q = (points - points.new_tensor(centre)) / (scale * points.new_tensor(axes))
    return (q * q).sum(-1) <= 1.0


@functools.lru_cache(maxsize=4)
def heart(mesh_size: float = 0.007) -> HeartBody:
    """Left and right ventricle walls meshed with gmsh (see :data:`HEART_ELLIPSOIDS`).

    Args:
        mesh_size: target element edge [m], in [1, 20] mm (the walls are 5-9 mm thick).
    """
    if not 0.001 <= mesh_size <= 0.02:
        raise MeshError(f"mesh_size must lie in [0.001, 0.02] m, got {mesh_size}")
    gmsh = _gmsh_session()
    try:
        occ = gmsh.model.occ

        def ellipsoid(name):
            (cx, cy, cz), (a, b, c) = HEART_ELLIPSOIDS[name]
            tag = occ.addSphere(0.0, 0.0, 0.0, 1.0)
            occ.dilate([(3, tag)], 0.0, 0.0, 0.0, a, b, c)
            occ.translate([(3, tag)], cx, cy, cz)
            return [(3, tag)]

        # The septum belongs to the left ventricle: the right cavity stops at its wall.
        rv_cavity, _ = occ.cut(ellipsoid("rv_cavity"), ellipsoid("lv_outer"))
        walls, _ = occ.fuse(ellipsoid("lv_outer"), ellipsoid("rv_outer"))
        walls, _ = occ.cut(walls, ellipsoid("lv_cavity") + rv_cavity)
        above_base = occ.addBox(-0.1, -0.1, 0.0, 0.2, 0.2, 0.1)
        walls, _ = occ.cut(walls, [(3, above_base)])
        occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", mesh_size)
        gmsh.option.setNumber("Mesh.MeshSizeMin", 0.5 * mesh_size)
        gmsh.model.mesh.generate(3)
        pos, tets, region, _ = _collect(gmsh, {tag: 0 for _, tag in walls})
    finally:
        gmsh.finalize()
    mesh = TetMesh.from_arrays(pos, tets, region)
    x = mesh.vert_pos
    base = torch.nonzero(x[:, 2].abs() < 1e-9).reshape(-1)
    tris = mesh.surface_tri_indices
    centroid = x[tris].mean(1)
    on_base = (x[tris][..., 2].abs() < 1e-9).all(-1)
    in_cavity = _inside_ellipsoid(centroid, "lv_cavity", 1.1) | _inside_ellipsoid(
        centroid, "rv_cavity", 1.1
    )
    return HeartBody(mesh, base, tris[~on_base & ~in_cavity])
