"""Mesh building/validation and measured-material loading, including bad input."""

import json

import numpy as np
import pytest
import torch

from simulator.cloth.material import (
    BEND_MULTIPLIERS,
    CLASS_COUNT,
    STRETCH_MULTIPLIERS,
    ClothMaterial,
    MaterialError,
    class_from_multipliers,
    class_summary,
    load_wang_material,
    multipliers_from_class,
    nearest_class,
    stabilize_stretching,
    wang_material_names,
)
from simulator.mesh import MeshError, TriMesh


def test_grid_counts_and_flat_rest_angles():
    mesh = TriMesh.grid(5, 4, size_u=0.4, size_v=0.3)
    assert mesh.vert_count == 20
    assert mesh.tri_count == 2 * 4 * 3
    # interior edges = all edges - boundary edges
    assert mesh.edge_count == mesh.segment_indices.shape[0] - 2 * (4 + 3)
    assert torch.allclose(mesh.edge_rest_angle, torch.zeros(mesh.edge_count, dtype=torch.float64))
    assert torch.isclose(mesh.tri_rest_area.sum(), torch.tensor(0.12, dtype=torch.float64))
    assert torch.isclose(mesh.vert_area.sum(), torch.tensor(0.12, dtype=torch.float64))


def test_from_trimesh_round_trip():
    trimesh = pytest.importorskip("trimesh")
    grid = TriMesh.grid(3)
    tm = trimesh.Trimesh(grid.vert_pos.numpy(), grid.tri_indices.numpy(), process=False)
    mesh = TriMesh.from_trimesh(tm, uv=grid.uv.numpy())
    assert torch.equal(mesh.tri_indices, grid.tri_indices)
    with pytest.raises(MeshError, match="uv"):
        TriMesh.from_trimesh(tm)


@pytest.mark.parametrize(
    ("pos", "tris", "uv", "field"),
    [
        ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], [[0, 0], [1, 0], [2, 0]], "degenerate"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]], [[0, 0], [1, 0], [0, 1]], "tri_indices"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 1]], [[0, 0], [1, 0], [0, 1]], "repeats"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], [[0, 0], [1, 0]], "uv"),
        ([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], [[0, 0], [1, 0], [0, 1]], "finite"),
    ],
)
def test_bad_meshes_raise_naming_the_problem(pos, tris, uv, field):
    with pytest.raises(MeshError, match=field):
        TriMesh.from_arrays(np.array(pos, float), np.array(tris), np.array(uv, float))


def test_non_manifold_and_inconsistent_orientation():
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1.0]])
    uv = pos[:, :2] + np.array([[0, 0], [0, 0], [0, 0], [0, 0], [0.5, 0.5]])
    fan = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(MeshError, match="non-manifold"):
        TriMesh.from_arrays(pos, fan, uv)
    flipped = np.array([[0, 1, 2], [0, 1, 3]])
    with pytest.raises(MeshError, match="orientation"):
        TriMesh.from_arrays(pos[:4], flipped, uv[:4])


def test_all_ten_fabrics_load_and_stabilise():
    names = wang_material_names()
    assert len(names) == 10
    for name in names:
        mat = load_wang_material(name)
        rows = stabilize_stretching(mat.stretching)
        for k0, k1, k2, k3 in rows:
            c = np.array([[k0, k1, 0], [k1, k2, 0], [0, 0, k3]])
            assert np.linalg.eigvalsh(c).min() > 0, name


@pytest.mark.parametrize(
    ("content", "field"),
    [
        ("{not json", "cannot read JSON"),
        (json.dumps({"stretching": [[1, 2, 3, 4]] * 6, "bending": [[1] * 5] * 3}), "density"),
        (json.dumps({"density": 0.2, "bending": [[1] * 5] * 3}), "stretching"),
        (
            json.dumps({"density": 0.2, "stretching": [[1, 2, 3]] * 6, "bending": [[1] * 5] * 3}),
            "stretching",
        ),
        (
            json.dumps({"density": -1, "stretching": [[1, 2, 3, 4]] * 6, "bending": [[1] * 5] * 3}),
            "density",
        ),
        (
            json.dumps(
                {"density": 0.2, "stretching": [[1, 2, 3, 4]] * 6, "bending": [["a"] * 5] * 3}
            ),
            "bending",
        ),
        ("[1, 2]", "object"),
    ],
)
def test_malformed_material_json_names_the_field(tmp_path, content, field):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(MaterialError, match=field):
        load_wang_material(path)


def test_unknown_material_and_class_ids():
    with pytest.raises(MaterialError, match="unknown name"):
        load_wang_material("silk")
    for bad in (-1, 54, 3.5, "2"):
        with pytest.raises(MaterialError, match="class_id"):
            multipliers_from_class(bad)
    with pytest.raises(MaterialError, match="not in the subspace"):
        class_from_multipliers(7, 1)
    # A batch of classes refuses a non-integer id instead of truncating it (1.7 is not class 1).
    for bad in ([0, 1.7], [np.float64(26.5)]):
        with pytest.raises(MaterialError, match=r"class_id must be an integer in \[0, 53\]"):
            ClothMaterial.from_classes(bad)
    assert ClothMaterial.from_classes([0.0, 53.0]).batch_size == 2


def test_class_ids_round_trip_and_order():
    assert CLASS_COUNT == len(STRETCH_MULTIPLIERS) * len(BEND_MULTIPLIERS) == 54
    ids = [class_from_multipliers(*multipliers_from_class(c)) for c in range(54)]
    assert ids == list(range(54))
    stretch = [class_summary(c)["stretch_stiffness"] for c in range(0, 54, 9)]
    assert stretch == sorted(stretch)
    bend = [class_summary(c)["bend_stiffness"] for c in range(9)]
    assert bend == sorted(bend)
    assert nearest_class(15.8, 3.5)[1:] == (20.0, 4.0)


@pytest.mark.parametrize("field", ["stretch_mult", "bend_mult"])
def test_non_positive_multipliers_rejected(field):
    with pytest.raises(MaterialError, match=field):
        ClothMaterial.from_wang(load_wang_material("camel-ponte-roma"), **{field: [1.0, 0.0]})
