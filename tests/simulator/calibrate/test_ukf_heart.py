"""The gmsh biventricular heart and the Table 4.1 experiment on it (Newmark, thesis §4.3.1)."""

import dataclasses

import pytest
import torch

from benchmarks.thesis.ukf_experiments import ukf_table41
from simulator.calibrate.ukf_body import heart_problem
from simulator.mesh import MeshError
from simulator.tissue.meshing import heart


def test_heart_is_a_closed_hollow_body_with_fixed_base_and_outward_epicardium():
    body = heart()
    mesh = body.mesh
    tris = mesh.surface_tri_indices
    edges = torch.cat([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]).sort(dim=1).values
    _, counts = torch.unique(edges, dim=0, return_counts=True)
    assert bool((counts == 2).all()), "the surface must be closed (each edge in two triangles)"
    volume_ml = float(mesh.tet_rest_volume.sum()) * 1e6
    assert 50.0 < volume_ml < 90.0, volume_ml  # walls only: the cavities are cut out
    x = mesh.vert_pos
    assert float(x[:, 2].max()) <= 1e-12 and float(x[:, 2].min()) < -0.06
    assert body.base_verts.numel() > 20 and bool((x[body.base_verts, 2].abs() < 1e-9).all())
    epi = body.epicardium_tris
    assert 0.3 * tris.shape[0] < epi.shape[0] < 0.7 * tris.shape[0]
    normal = torch.linalg.cross(x[epi[:, 1]] - x[epi[:, 0]], x[epi[:, 2]] - x[epi[:, 0]])
    centre = x.new_tensor([0.01, 0.0, -0.02])
    assert bool(((normal * (x[epi].mean(1) - centre)).sum(-1) > 0).all()), "epicardium outward"
    with pytest.raises(MeshError, match="mesh_size"):
        heart(0.05)


def test_heart_table41_row_recovers_the_modulus():
    rows = ukf_table41(body="heart", moduli_kpa=(40,), trials=1, frames=8, passes=1)
    assert rows[0]["integrator"] == "newmark"
    assert rows[0]["avg_rel_err_pct"] < 1.0, rows


def test_bad_body_and_integrator_are_named():
    with pytest.raises(ValueError, match="body"):
        ukf_table41(body="liver")
    with pytest.raises(ValueError, match="integrator"):
        ukf_table41(integrator="leapfrog")
    with pytest.raises(ValueError, match="truth_mesh_refine"):
        ukf_table41(body="heart", truth_mesh_refine=0)
    with pytest.raises(ValueError, match="integrator"):
        dataclasses.replace(heart_problem(load_modulus=4e4), integrator="rk4")
