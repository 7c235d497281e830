"""Contact-force boundary condition and multi-region recovery on a tiny organ mesh."""

import numpy as np
import pytest
import torch

from simulator.calibrate.multiregion import (
    MultiRegionObjective,
    point_triangle_distance_sq,
    recover_regions,
)
from simulator.tetmesh import TetMesh
from simulator.tissue.meshing import REGION_TISSUE, organ_scene
from simulator.tissue.scenes import (
    OrganForwardModel,
    OrganLoadCase,
    contact_forces,
    organ_load_case,
    solve_organ_scene,
)

TRUTH_KPA = (25.0, 40.0)


@pytest.fixture(scope="module")
def tiny_case():
    scene = organ_scene(0.0, tet_target=400)
    organ = scene.mesh.tet_region != REGION_TISSUE
    region = scene.mesh.tet_region[organ]
    mu = torch.tensor(TRUTH_KPA, dtype=torch.float64)[region][None] * 1e3
    pos, _ = solve_organ_scene(scene, mu, material="linear", compression=0.1)
    return scene, pos[0], organ_load_case(scene, pos[0]), mu


def test_contact_forces_vanish_inside_the_tissue(tiny_case):
    scene, pos, case, _ = tiny_case
    mesh = scene.mesh
    force = contact_forces(mesh, (pos - mesh.vert_pos)[None])[0]
    interior = torch.ones(mesh.vert_count, dtype=torch.bool)
    interior[case.scene_vert_ids] = False
    interior[scene.base_verts] = False
    interior[scene.top_verts] = False
    interior[torch.unique(mesh.surface_tri_indices)] = False
    assert float(force[interior].norm(dim=1).max()) < 1e-9 * float(force.norm(dim=1).max())
    assert float(case.force.norm(dim=-1).max()) > 0.01


@pytest.mark.parametrize("material", ["linear", "mooney_rivlin"])
def test_organ_alone_under_contact_forces_reproduces_the_scene(material):
    scene = organ_scene(0.0, tet_target=400)
    organ = scene.mesh.tet_region != REGION_TISSUE
    mu = torch.full((1, int(organ.sum())), 30e3, dtype=torch.float64)
    pos, _ = solve_organ_scene(scene, mu, material=material, compression=0.05)
    case = organ_load_case(scene, pos[0])
    forward = OrganForwardModel(case, material=material)
    out = forward.solve_tets(mu)
    assert float((out[0] - case.target_pos).norm(dim=1).max()) < 1e-7


def test_objective_is_zero_at_truth_and_grows_away(tiny_case):
    _, _, case, _ = tiny_case
    objective = MultiRegionObjective(OrganForwardModel(case), case.target_pos)
    values = objective(np.array([TRUTH_KPA, (30.0, 40.0), (25.0, 30.0)]) * 1e3)
    assert float(values[0]) < 1e-14
    assert float(values[1]) > 1e3 * float(values[0]) and float(values[2]) > 1e3 * float(values[0])
    # Shared (interface) vertices are left out of every region's query set.
    incidence = case.mesh.vert_regions()
    for verts in objective.query_verts:
        assert bool((incidence[verts].sum(-1) == 1).all())


def test_pso_recovers_known_region_moduli(tiny_case):
    _, _, case, _ = tiny_case
    objective = MultiRegionObjective(OrganForwardModel(case), case.target_pos)
    res = recover_regions(objective, [5e3, 5e3], [100e3, 100e3], swarm_size=20, max_iters=40)
    np.testing.assert_allclose(res["best_mu"] / 1e3, TRUTH_KPA, rtol=0.01)


def test_point_triangle_distance():
    tri = torch.tensor([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=torch.float64)
    pts = torch.tensor([[0.2, 0.2, 0.5], [2.0, 0.0, 0.0], [-1.0, -1.0, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(
        point_triangle_distance_sq(pts, tri), torch.tensor([0.25, 1.0, 2.0], dtype=torch.float64)
    )


def test_target_surface_without_vertices_is_an_error():
    box = TetMesh.box((3, 3, 3), (0.03, 0.03, 0.03))
    centre = box.vert_pos[box.tet_indices].mean(1)
    inner = ((centre > 0.01) & (centre < 0.02)).all(1).long()
    mesh = TetMesh.from_arrays(box.vert_pos.numpy(), box.tet_indices.numpy(), inner.numpy())
    case = OrganLoadCase(
        mesh,
        torch.arange(mesh.vert_count),
        torch.zeros(mesh.tet_count, dtype=torch.bool),
        torch.zeros(0, dtype=torch.long),
        torch.zeros(1, mesh.vert_count, 3, dtype=torch.float64),
        mesh.vert_pos,
    )
    with pytest.raises(ValueError, match="target_surface: region 1"):
        MultiRegionObjective(OrganForwardModel(case), mesh.vert_pos)
    with pytest.raises(ValueError, match="target_pos must have shape"):
        MultiRegionObjective(OrganForwardModel(case), mesh.vert_pos[:5])
