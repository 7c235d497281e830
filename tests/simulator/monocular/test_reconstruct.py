"""The monocular solver recovers a known synthetic deformation (the paper §7.1 protocol)."""

import dataclasses

import pytest
import torch

from benchmarks.thesis.monocular_benchmark import CONDITIONS, mono_case, run_mono_benchmark
from simulator.monocular.features import locate_features
from simulator.monocular.reconstruct import DEFAULT_SETTINGS, MonocularReconstructor
from simulator.monocular.sheet import crossed_grid, edge_vertices
from simulator.monocular.synthetic import SheetScenario, simulate_sheet
from tests.conftest import assert_close

SMALL = SheetScenario(frames=10, gt_vert_per_side=25)
THREE = dataclasses.replace(DEFAULT_SETTINGS, max_iters=3)


def test_ground_truth_reaches_130_percent_and_holds_boundary():
    seq = simulate_sheet(SMALL)
    right = edge_vertices(seq.mesh, "right")
    length = seq.pos[-1, right, 0].mean() - seq.pos[-1, edge_vertices(seq.mesh, "left"), 0].mean()
    assert abs(float(length) - 0.13) < 1e-9
    assert float(seq.pos[-1, :, 2].abs().max()) > 0.01  # lifted, twisted and pushed out of plane
    assert torch.isfinite(seq.pos).all()


def test_reconstruction_is_submillimetre_without_noise():
    row = mono_case(256, "stvk", CONDITIONS["clean"], scenario=SMALL, settings=THREE)
    assert row["mean_err_mm"] < 1.0, row
    assert row["rms_err_mm"] < 1.0, row


def test_direct_and_pcg_solvers_agree():
    scenario = SMALL
    seq = simulate_sheet(scenario)
    mesh = crossed_grid(4)
    uv = torch.rand(40, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 0.1
    feats_truth = locate_features(seq.mesh, uv)
    cam = scenario.camera()
    tracks = cam.project(feats_truth.points(seq.mesh, seq.pos))
    bnd = torch.cat([edge_vertices(mesh, "left"), edge_vertices(mesh, "right")])
    is_right = mesh.uv[bnd, 0] > 0.05
    bpos = torch.stack(
        [scenario.boundary_positions(mesh.vert_pos[bnd], is_right, float(s)) for s in seq.progress]
    )
    out = {}
    for solver in ("direct", "pcg"):
        rec = MonocularReconstructor(
            mesh,
            scenario.material,
            cam,
            locate_features(mesh, uv),
            bnd,
            solver=solver,
            settings=THREE,
        )
        out[solver] = rec.reconstruct(tracks, bpos).pos
    assert_close(out["direct"], out["pcg"], "direct vs pcg positions", rtol=0, atol=1e-6)


def test_reconstructor_bad_input():
    scenario = SMALL
    mesh = crossed_grid(2)
    feats = locate_features(mesh, torch.tensor([[0.05, 0.05]], dtype=torch.float64))
    with pytest.raises(ValueError, match="boundary"):
        MonocularReconstructor(
            mesh, scenario.material, scenario.camera(), feats, torch.zeros(0, dtype=torch.int64)
        )
    with pytest.raises(ValueError, match="model"):
        MonocularReconstructor(
            mesh, scenario.material, scenario.camera(), feats, torch.tensor([0]), model="fem2"
        )
    rec = MonocularReconstructor(
        mesh, scenario.material, scenario.camera(), feats, torch.tensor([0])
    )
    with pytest.raises(ValueError, match="tracks"):
        rec.reconstruct(torch.zeros(3, 2, 2), torch.zeros(3, 1, 3))
    with pytest.raises(ValueError, match="boundary_pos"):
        rec.reconstruct(torch.zeros(3, 1, 2, dtype=torch.float64), torch.zeros(2, 1, 3))


def test_deterministic():
    a = mono_case(256, "stvk", CONDITIONS["noisy"], scenario=SMALL, seed=3)
    b = mono_case(256, "stvk", CONDITIONS["noisy"], scenario=SMALL, seed=3)
    assert a["mean_err_mm"] == b["mean_err_mm"]


@pytest.mark.slow
def test_run_mono_benchmark_headline():
    out = run_mono_benchmark()
    assert out["mono_mean_err_mm"] < 1.0
    assert out["mono_fps_1600"] > 0
