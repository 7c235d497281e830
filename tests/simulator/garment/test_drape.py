"""Seam energy and per-instance-rest cloth energies (derivative, invariance and analytic checks),
sewing and draping on the mannequin and on a sphere."""

import dataclasses

import numpy as np
import pytest
import torch

from simulator.energies import EnergyBendingDihedral, EnergyGravity, EnergyMembraneWang
from simulator.garment.body import Mannequin, Pose, capsule_distance
from simulator.garment.drape import (
    DrapeSettings,
    GarmentBatch,
    drape,
    garment_material,
    register_batch,
)
from simulator.garment.energies import (
    SEAM_TOLERANCE,
    EnergyBendingPattern,
    EnergyMembranePattern,
    EnergySeam,
    PatternRest,
)
from simulator.garment.patterns import (
    GARMENT_TYPES,
    PatternTopology,
    build_pattern,
    from_search,
    search_box,
)
from simulator.integrators import solve_static
from simulator.mesh import TriMesh
from simulator.model import SimControl, SimModel, SimState
from simulator.solvers import NewtonSettings
from simulator.solvers.block_sparse import BlockPattern
from tests.conftest import assert_close


def _model(mesh, energies, batch):
    return SimModel(
        mesh=mesh,
        energies=tuple(energies),
        forces=(),
        vert_mass=torch.full((batch, mesh.vert_count), 0.01, dtype=torch.float64),
        pin_indices=torch.zeros(0, dtype=torch.int64),
    )


def _seam_setup(batch=2, seed=0):
    mesh = TriMesh.grid(3, size_u=0.2)
    gen = torch.Generator().manual_seed(seed)
    pos = mesh.vert_pos[None].repeat(batch, 1, 1) + 0.05 * torch.randn(
        batch, mesh.vert_count, 3, generator=gen, dtype=torch.float64
    )
    pairs = torch.tensor([[0, 8], [2, 6], [1, 7]])
    stiffness = torch.tensor([[100.0, 50.0, 20.0], [10.0, 5.0, 2.0]], dtype=torch.float64)
    seam = EnergySeam(pairs, stiffness[:batch])
    return mesh, pos, seam


def test_seam_derivatives_match_autograd():
    mesh, pos, seam = _seam_setup()
    model = _model(mesh, [seam], 2)
    x = pos.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(seam.energy(model, x).sum(), x)
    assert_close(seam.gradient(model, pos), grad, "seam gradient")
    dpos = torch.randn_like(pos)
    from simulator.energies.base import autograd_hessian_product

    hvp = autograd_hessian_product(seam.energy, model, pos, dpos)
    assert_close(seam.hessian_product(model, pos, dpos), hvp, "seam hessian_product")
    blocks = seam.hessian_blocks(model, pos)
    assert_close(blocks.matvec(dpos.reshape(-1, 3)).view_as(pos), hvp, "seam hessian_blocks")
    assert torch.autograd.gradcheck(
        lambda p: seam.energy(model, p), (pos.clone().requires_grad_(True),)
    )


def test_seam_invariants():
    mesh, pos, seam = _seam_setup()
    model = _model(mesh, [seam], 2)
    e = seam.energy(model, pos)
    assert (e > 0).all()
    q, _ = torch.linalg.qr(
        torch.randn(3, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    )
    moved = pos @ q.T + torch.tensor([0.3, -1.0, 2.0], dtype=torch.float64)
    assert_close(seam.energy(model, moved), e, "seam energy under a rigid motion")
    closed = pos.clone()
    closed[:, seam.pairs[:, 1]] = closed[:, seam.pairs[:, 0]]
    assert_close(seam.energy(model, closed), torch.zeros(2, dtype=torch.float64), "closed seam")
    assert_close(seam.gradient(model, closed), torch.zeros_like(pos), "closed seam gradient")
    assert_close(seam.gaps(closed), torch.zeros(2, 3, dtype=torch.float64), "closed gaps")


def test_seam_gap_under_a_hanging_weight_is_force_over_stiffness():
    """A panel hangs by two seam pairs from a pinned one: each gap is (weight / 2) / k."""
    top = TriMesh.grid(2, size_u=0.1)
    pos = torch.cat([top.vert_pos, top.vert_pos - torch.tensor([0.0, 0.12, 0.0])]).double()
    tri = torch.cat([top.tri_indices, top.tri_indices + 4])
    uv = pos[:, :2].clone()
    mesh = TriMesh.from_arrays(pos.numpy(), tri.numpy(), uv.numpy())
    k = 400.0
    # Lower panel's top edge (verts 6, 7) hangs from the upper panel's bottom edge (0, 1).
    seam = EnergySeam(torch.tensor([[0, 6], [1, 7]]), torch.full((2,), k, dtype=torch.float64))
    mat = garment_material([5.0], [1.0])
    gravity = torch.tensor([0.0, -9.81, 0.0], dtype=torch.float64)
    # Hang along -y so that the panel plane holds the load.
    model = SimModel(
        mesh=mesh,
        energies=(
            EnergyMembraneWang.from_material(mat.stretching),
            EnergyBendingDihedral.from_material(mesh, mat.bending),
            EnergyGravity(gravity),
            seam,
        ),
        forces=(),
        vert_mass=torch.full((1, 8), 0.002, dtype=torch.float64),
        pin_indices=torch.arange(4),
        pattern=BlockPattern.from_topologies(8, [mesh.tri_indices, mesh.edge_indices, seam.pairs]),
    )
    start = pos.clone()
    start[4:] += torch.tensor([0.0, 0.12, 0.0])  # lower panel starts sewn shut
    state = SimState(
        start[None], torch.zeros(1, 8, 3, dtype=torch.float64), torch.zeros(1, dtype=torch.float64)
    )
    control = SimControl(pin_pos=start[None, :4])
    state, stats = solve_static(
        model,
        state,
        control,
        settings=NewtonSettings(max_iters=60, tol_dx=1e-12, linear_solver="direct"),
        regularization=1e-10,
    )
    assert bool(stats.converged.all())
    weight = 4 * 0.002 * 9.81
    gap = state.pos[0, seam.pairs[:, 1]] - state.pos[0, seam.pairs[:, 0]]
    # The seams carry the whole weight (the panel's Poisson contraction tilts them sideways,
    # nearly symmetrically): sum of k * gap is the weight; each pair takes about half of it (the
    # diagonal of the triangulation breaks the symmetry slightly).
    assert_close(
        k * gap.sum(0),
        torch.tensor([0.0, -weight, 0.0], dtype=torch.float64),
        "seam forces",
        atol=1e-10,
    )
    assert_close(
        gap[:, 1], torch.full((2,), -weight / 2 / k, dtype=torch.float64), "seam gap y", rtol=1e-2
    )


def _two_patterns(garment, batch=3, seed=0):
    topology = PatternTopology.build(garment, 0.08)
    rng = np.random.default_rng(seed)
    _, lo, hi = search_box(garment)
    patterns = [
        build_pattern(garment, from_search(garment, rng.uniform(lo, hi)), topology=topology)
        for _ in range(batch)
    ]
    return topology, np.stack([p.coords for p in patterns])


@pytest.mark.parametrize("garment", ["skirt", "tshirt"])
def test_per_instance_rest_energies_equal_the_core_terms(garment):
    """Fast path (one batch, B rest shapes) against the reference (one core model each)."""
    topology, coords = _two_patterns(garment)
    batch = coords.shape[0]
    mat = garment_material([2.0, 30.0, 80.0], [0.7, 1.0, 3.0])
    flat0 = np.concatenate([coords[0], np.zeros((coords.shape[1], 1))], 1)
    mesh0 = TriMesh.from_arrays(flat0, topology.tri_indices, coords[0])
    rest = PatternRest.from_coords(torch.as_tensor(coords), mesh0.tri_indices, mesh0.edge_indices)
    membrane = EnergyMembranePattern.from_rest(mat.stretching, rest)
    bending = EnergyBendingPattern.from_rest(mesh0, mat.bending, rest)
    gen = torch.Generator().manual_seed(2)
    pos = torch.as_tensor(flat0)[None].repeat(batch, 1, 1)
    pos = pos + 0.02 * torch.randn(pos.shape, generator=gen, dtype=torch.float64)
    model = _model(mesh0, [membrane, bending], batch)
    dpos = torch.randn(pos.shape, generator=gen, dtype=torch.float64)
    for b in range(batch):
        flat = np.concatenate([coords[b], np.zeros((coords.shape[1], 1))], 1)
        mesh = TriMesh.from_arrays(flat, topology.tri_indices, coords[b])
        core_m = dataclasses.replace(EnergyMembraneWang.from_material(mat.stretching[b : b + 1]))
        core_b = EnergyBendingDihedral.from_material(mesh0, mat.bending[b : b + 1])
        ref = _model(mesh, [core_m, core_b], 1)
        for ours, core in ((membrane, core_m), (bending, core_b)):
            name = type(core).__name__
            assert_close(ours.energy(model, pos)[b], core.energy(ref, pos[b : b + 1])[0], name)
            assert_close(
                ours.gradient(model, pos)[b],
                core.gradient(ref, pos[b : b + 1])[0],
                f"{name} gradient",
            )
            ob = ours.hessian_blocks(model, pos)
            cb = core.hessian_blocks(ref, pos[b : b + 1])
            mv = ob.matvec(dpos.reshape(-1, 3)).view_as(pos)[b]
            assert_close(mv, cb.matvec(dpos[b].reshape(-1, 3)).view(-1, 3), f"{name} blocks")


def test_per_instance_rest_gradients_match_autograd():
    topology, coords = _two_patterns("pants", batch=2, seed=4)
    mat = garment_material([3.0, 50.0], [1.0, 2.0])
    flat0 = np.concatenate([coords[0], np.zeros((coords.shape[1], 1))], 1)
    mesh0 = TriMesh.from_arrays(flat0, topology.tri_indices, coords[0])
    rest = PatternRest.from_coords(torch.as_tensor(coords), mesh0.tri_indices, mesh0.edge_indices)
    gen = torch.Generator().manual_seed(5)
    pos = torch.as_tensor(flat0)[None].repeat(2, 1, 1) + 0.03 * torch.randn(
        2, mesh0.vert_count, 3, generator=gen, dtype=torch.float64
    )
    for energy in (
        EnergyMembranePattern.from_rest(mat.stretching, rest),
        EnergyBendingPattern.from_rest(mesh0, mat.bending, rest),
    ):
        model = _model(mesh0, [energy], 2)
        x = pos.clone().requires_grad_(True)
        (grad,) = torch.autograd.grad(energy.energy(model, x).sum(), x)
        assert_close(energy.gradient(model, pos), grad, type(energy).__name__)


def _edges(topology):
    tri = topology.tri_indices
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


@pytest.mark.parametrize("garment", GARMENT_TYPES)
def test_sewing_closes_every_seam_on_the_mannequin(garment):
    body = Mannequin.build()
    topology = PatternTopology.build(garment, 0.08)
    pattern = build_pattern(garment, topology=topology)
    pose = Pose.from_dict({"shoulder_r": [0, -60, 0], "shoulder_l": [0, 60, 0]})
    angles = pose.angles[None]
    x0 = register_batch(topology, pattern.coords[None], [pattern.params], body, angles)
    initial = (
        EnergySeam(
            torch.as_tensor(np.concatenate(list(topology.seam_pairs.values()))), torch.ones(1)
        )
        .gaps(torch.as_tensor(x0))
        .max()
    )
    batch = GarmentBatch.build(
        topology,
        pattern.coords[None],
        garment_material([10.0], [1.0]),
        body.capsules(angles),
        pos_hint=x0,
    )
    result = drape(batch, x0, DrapeSettings(max_steps=60))
    assert float(initial) > 3 * SEAM_TOLERANCE  # there was sewing to do
    assert result.seam_gap.max() < SEAM_TOLERANCE, result.seam_gap
    assert result.min_body_distance.min() > -2e-3


def test_drape_on_a_sphere_converges_with_no_vertex_inside():
    """A skirt's waist ring comes to rest on a sphere: the stopping test passes, nothing inside."""
    topology = PatternTopology.build("skirt", 0.08)
    pattern = build_pattern("skirt", topology=topology)
    body = Mannequin.build()
    x0 = register_batch(
        topology, pattern.coords[None], [pattern.params], body, np.zeros((1, 15, 3))
    )
    centre = np.array([0.0, 0.0, body.levels["waist"] - 0.1])
    sphere = np.concatenate([centre, centre, [0.16]])[None, None]
    batch = GarmentBatch.build(
        topology, pattern.coords[None], garment_material([20.0], [2.0]), sphere
    )
    settings = DrapeSettings(max_steps=150)
    result = drape(batch, x0, settings)
    assert bool(result.converged.all()), result.max_speed
    assert result.max_speed.max() < settings.speed_tol
    dist, _ = capsule_distance(result.pos[0].numpy(), sphere[0])
    assert dist.min() > 0.0
    # The ring rests on the sphere: the top edge is above the sphere's equator.
    waist = topology.segment_vertices[("yoke_front", "waist")]
    assert result.pos[0, waist, 2].mean() > centre[2]
    # Same input, same bytes.
    again = drape(batch, x0, settings)
    assert torch.equal(again.pos, result.pos)
