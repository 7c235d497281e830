"""Solvers and integrator: CG, Newton monotonicity, equilibrium, convergence order."""

import numpy as np
import pytest
import torch

from simulator.cloth.material import ClothMaterial
from simulator.cloth.model import build_cloth_model
from simulator.integrators import IntegratorBackwardEuler, solve_static
from simulator.integrators.base import IncrementalPotential
from simulator.mesh import TriMesh
from simulator.model import SimControl, SimState
from simulator.solvers import NewtonSettings, conjugate_gradient
from tests.conftest import assert_close

DT = torch.float64
TIGHT = NewtonSettings(max_iters=30, tol_dx=1e-11, cg_rtol=1e-10, cg_max_iters=3000)


def test_cg_reaches_tolerance_on_spd_batch():
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(3, 30, 30, generator=gen, dtype=DT)
    a = q @ q.transpose(1, 2) + 0.1 * torch.eye(30, dtype=DT)
    b = torch.randn(3, 10, 3, generator=gen, dtype=DT)

    def matvec(v):
        return (a @ v.reshape(3, 30, 1)).reshape(3, 10, 3)

    diag = torch.diagonal(a, dim1=1, dim2=2).reshape(3, 10, 3)
    x, iters, res = conjugate_gradient(matvec, b, lambda r: r / diag, rtol=1e-10, max_iters=500)
    assert (res <= 1e-10).all()
    assert_close(matvec(x), b, "CG solution", rtol=1e-8, atol=1e-8)
    assert (iters > 0).all() and (iters <= 500).all()


def _hanging(n=6, classes=(0, 30)):
    grid = TriMesh.grid(n, size_u=0.2)
    pos = torch.stack(
        [grid.uv[:, 0], torch.zeros(grid.vert_count, dtype=DT), 1 - grid.uv[:, 1]], -1
    )
    mesh = TriMesh.from_arrays(pos.numpy(), grid.tri_indices.numpy(), grid.uv.numpy())
    pins = torch.arange(n)
    model = build_cloth_model(
        mesh, ClothMaterial.from_classes(list(classes)), pins, wind_drag=False
    )
    batch = len(classes)
    rest = mesh.vert_pos[None].repeat(batch, 1, 1)
    state = SimState(rest.clone(), torch.zeros_like(rest), torch.zeros(batch, dtype=DT))
    return model, state, SimControl(pin_pos=rest[:, pins]), pins


def test_static_newton_decreases_energy_monotonically_and_balances_weight():
    model, state, control, pins = _hanging()
    potential = IncrementalPotential(model, model.energies, (), state.pos, state.pos, None)
    values = [potential.value(state.pos)]
    for _ in range(25):
        state, stats = solve_static(
            model,
            state,
            control,
            settings=NewtonSettings(max_iters=1, tol_dx=1e-12, cg_rtol=1e-10, cg_max_iters=3000),
        )
        values.append(potential.value(state.pos))
    values = torch.stack(values)
    assert (values[1:] <= values[:-1] + 1e-12).all(), values
    state, stats = solve_static(model, state, control, settings=TIGHT)
    assert stats.converged.all()
    grad = potential.gradient(state.pos)
    free = model.free_mask()
    assert (grad * free).abs().max() < 1e-7
    # Pin reactions carry the whole weight.
    # The pins supply R = dE/dx at the pinned vertices (equilibrium of those vertices).
    reaction = grad[:, pins].sum(dim=1)
    weight = model.vert_mass.sum(dim=1) * 9.81
    assert_close(reaction[:, 2], weight, "pin reaction z", rtol=1e-6)
    assert_close(reaction[:, :2], torch.zeros_like(reaction[:, :2]), "pin reaction xy", atol=1e-8)


def _pendulum_error(dt, reference):
    model, state, control, _ = _hanging(n=4, classes=(9,))
    model = build_cloth_model(
        model.mesh, ClothMaterial.from_classes([9]), torch.tensor([0]), wind_drag=False
    )
    control = SimControl(pin_pos=state.pos[:, :1])
    integ = IntegratorBackwardEuler(TIGHT)
    steps = round(0.12 / dt)
    for _ in range(steps):
        state, _ = integ.step(model, state, control, dt)
    if reference is None:
        return state.pos
    return (state.pos - reference).norm().item()


def test_backward_euler_is_first_order():
    reference = _pendulum_error(0.12 / 960, None)
    dts = np.array([0.12 / 60, 0.12 / 120, 0.12 / 240])
    errors = np.array([_pendulum_error(dt, reference) for dt in dts])
    slope = np.polyfit(np.log(dts), np.log(errors), 1)[0]
    assert abs(slope - 1.0) < 0.2, (slope, errors)


def test_step_is_pure_and_rejects_bad_dt():
    model, state, control, _ = _hanging(n=4)
    before = state.pos.clone()
    integ = IntegratorBackwardEuler()
    integ.step(model, state, control, 0.005)
    assert torch.equal(state.pos, before)
    for bad in (0.0, -0.01):
        with pytest.raises(ValueError, match="dt"):
            integ.step(model, state, control, bad)
    with pytest.raises(ValueError, match="cg_rtol"):
        NewtonSettings(cg_rtol=0)


@pytest.mark.parametrize("symmetric", [True, False])
def test_sparse_lu_solves_the_free_block_as_a_dense_solve(symmetric):
    """The direct solver's LU (symmetric mode, a hint only) equals a dense solve of the free
    dofs, on a symmetric and on a nonsymmetric matrix; constrained dofs get zero."""
    from simulator.solvers.block_sparse import BlockPattern, BlockSparse
    from simulator.solvers.newton import _coo_pattern, lu_solve, sparse_lu_factors

    gen = torch.Generator().manual_seed(3)
    tri = torch.tensor([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    verts, batch = 6, 2
    mat = BlockSparse.zeros(
        BlockPattern.from_topologies(verts, [tri]), batch, torch.zeros(1, dtype=DT)
    )
    dense_el = torch.randn(batch, len(tri), 9, 9, generator=gen, dtype=DT)
    if symmetric:
        dense_el = dense_el @ dense_el.transpose(-1, -2)
    # (B, N, 9, 9) -> (B, N, k, k, 3, 3): row (a, i), column (b, j).
    mat.add_elements(tri, dense_el.reshape(batch, len(tri), 3, 3, 3, 3).permute(0, 1, 2, 4, 3, 5))
    mat.add_vertex_blocks(torch.eye(3, dtype=DT).expand(batch, verts, 3, 3) * 20.0)
    free = torch.ones(batch, verts, 1, dtype=DT)
    free[0, 2] = 0.0  # one vertex pinned in the first instance
    rhs = torch.randn(batch, verts, 3, generator=gen, dtype=DT) * free
    got = lu_solve(sparse_lu_factors(mat, free), rhs)
    rows, cols = _coo_pattern(mat)
    for b in range(batch):
        full = np.zeros((3 * verts, 3 * verts))
        np.add.at(full, (rows, cols), mat.values[b].reshape(-1).numpy())
        assert np.abs(full - full.T).max() < 1e-9 if symmetric else np.abs(full - full.T).max() > 1
        dofs = np.nonzero(np.repeat(free[b, :, 0].numpy() > 0, 3))[0]
        want = np.zeros(3 * verts)
        want[dofs] = np.linalg.solve(full[np.ix_(dofs, dofs)], rhs[b].reshape(-1).numpy()[dofs])
        assert np.abs(got[b].reshape(-1).numpy() - want).max() < 1e-10 * np.abs(want).max()
