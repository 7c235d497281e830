"""TetMesh validation, structured builder and gmsh-built tissue geometries."""

import math

import numpy as np
import pytest
import torch

from simulator.mesh import MeshError
from simulator.tetmesh import TetMesh, voxel_aggregates
from simulator.tissue.meshing import REGION_TISSUE, organ_scene, sphere_in_cube

UNIT_TET = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)


def test_box_volume_surface_and_lumping():
    mesh = TetMesh.box((3, 2, 2), (0.3, 0.2, 0.1))
    assert mesh.tet_count == 3 * 2 * 2 * 6
    assert math.isclose(float(mesh.tet_rest_volume.sum()), 0.006, rel_tol=1e-12)
    assert math.isclose(float(mesh.vert_volume.sum()), 0.006, rel_tol=1e-12)
    assert bool((mesh.tet_rest_volume > 0).all())
    x = mesh.vert_pos[mesh.surface_tri_indices]
    normal = 0.5 * torch.linalg.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], dim=-1)
    area = float(normal.norm(dim=1).sum())
    assert math.isclose(area, 2 * (0.06 + 0.03 + 0.02), rel_tol=1e-12)
    # Outward orientation: the divergence theorem gives the volume.
    centroid = x.mean(1)
    assert math.isclose(float((normal * centroid).sum() / 3.0), 0.006, rel_tol=1e-9)


def test_inverted_tet_is_rejected_naming_field():
    with pytest.raises(MeshError, match=r"tet_indices.*inverted"):
        TetMesh.from_arrays(UNIT_TET, np.array([[0, 2, 1, 3]]))


def test_degenerate_tet_is_rejected_naming_field():
    flat = UNIT_TET.copy()
    flat[3] = [0.3, 0.3, 0.0]
    with pytest.raises(MeshError, match=r"tet_indices.*degenerate"):
        TetMesh.from_arrays(flat, np.array([[0, 1, 2, 3]]))
    with pytest.raises(MeshError, match=r"tet_indices.*repeats"):
        TetMesh.from_arrays(UNIT_TET, np.array([[0, 1, 1, 3]]))


def test_region_labels_must_cover_the_mesh():
    box = TetMesh.box((1, 1, 1), (1.0, 1.0, 1.0))
    pos, tets = box.vert_pos.numpy(), box.tet_indices.numpy()
    with pytest.raises(MeshError, match=r"tet_region.*every tet"):
        TetMesh.from_arrays(pos, tets, np.zeros(5, dtype=int))
    labels = np.zeros(6, dtype=int)
    labels[2] = -1
    with pytest.raises(MeshError, match=r"tet_region.*tet 2"):
        TetMesh.from_arrays(pos, tets, labels)
    with pytest.raises(MeshError, match=r"tet_region.*no tets"):
        TetMesh.from_arrays(pos, tets, np.array([0, 0, 2, 2, 0, 0]))


def test_submesh_and_aggregates():
    box = TetMesh.box((2, 2, 2), (1.0, 1.0, 1.0))
    labels = (box.vert_pos[box.tet_indices].mean(1)[:, 0] > 0.5).long()
    mesh = TetMesh.from_arrays(box.vert_pos.numpy(), box.tet_indices.numpy(), labels.numpy())
    sub, ids = mesh.submesh(mesh.tet_region == 0)
    assert sub.tet_count == 24 and math.isclose(float(sub.tet_rest_volume.sum()), 0.5)
    torch.testing.assert_close(sub.vert_pos, mesh.vert_pos[ids])
    agg = voxel_aggregates(TetMesh.box((8, 8, 8), (1.0, 1.0, 1.0)).vert_pos, 3)
    assert int(agg.max()) + 1 == len(torch.unique(agg)) and 10 <= len(torch.unique(agg)) <= 40


def test_locate_reproduces_affine_fields_and_nested_vertices():
    coarse = TetMesh.box((2, 1, 1), (0.02, 0.01, 0.01))
    fine = TetMesh.box((4, 2, 2), (0.02, 0.01, 0.01))
    gen = torch.Generator().manual_seed(0)
    points = torch.rand(50, 3, generator=gen, dtype=torch.float64) * torch.tensor(
        [0.02, 0.01, 0.01], dtype=torch.float64
    )
    slope = torch.tensor([[1.0], [2.0], [0.5]], dtype=torch.float64)
    for query in (points, coarse.vert_pos):
        tet, weights = fine.locate(query)
        assert bool((weights > -1e-12).all()), "points inside get non-negative weights"
        got = ((fine.vert_pos @ slope)[fine.tet_indices[tet]] * weights[..., None]).sum(1)
        torch.testing.assert_close(got, query @ slope)
    outside = torch.tensor([[0.021, 0.005, 0.005]], dtype=torch.float64)
    tet, weights = fine.locate(outside)
    back = (fine.vert_pos[fine.tet_indices[tet]] * weights[..., None]).sum(1)
    torch.testing.assert_close(back, outside)  # extrapolated linearly


def test_sphere_in_cube_regions():
    mesh = sphere_in_cube(0.1, 0.025, 0.02)
    vol = mesh.tet_rest_volume
    sphere = float(vol[mesh.tet_region == 0].sum())
    assert math.isclose(sphere, 4 / 3 * math.pi * 0.025**3, rel_tol=0.08)
    assert math.isclose(float(vol.sum()), 1e-3, rel_tol=1e-9)


@pytest.mark.parametrize("ratio", [0.1, 0.6])
def test_organ_scene_tumour_ratio_and_regions(ratio):
    scene = organ_scene(ratio, tet_target=600)
    mesh = scene.mesh
    assert set(torch.unique(mesh.tet_region).tolist()) == {0, 1, REGION_TISSUE}
    assert abs(scene.tumour_ratio - ratio) < 0.06
    assert bool((mesh.tet_region[scene.tet_tumour] == 0).all())
    assert len(scene.base_verts) > 10 and len(scene.top_verts) > 10
    organ_tets = int((mesh.tet_region != REGION_TISSUE).sum())
    assert 450 < organ_tets < 800
    again = organ_scene(ratio, tet_target=600)
    assert again is scene  # cached


def test_organ_scene_bad_ratio():
    with pytest.raises(MeshError, match="tumour_ratio"):
        organ_scene(1.5)
