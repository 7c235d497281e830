"""Derivative, invariance, small-strain and inversion checks of every tet energy."""

import math

import pytest
import torch

from simulator.cloth.material import MaterialError
from simulator.energies import EnergyGravity, EnergyNodalForce
from simulator.energies.tet import (
    EnergyTetCorotated,
    EnergyTetLinear,
    EnergyTetMooneyRivlin,
    EnergyTetNeoHookean,
    EnergyTetStVK,
    lame_from_young_poisson,
    region_values,
)
from simulator.integrators import IntegratorBackwardEuler, solve_static
from simulator.model import SimControl, SimModel, SimState
from simulator.solvers.newton import NewtonSettings
from simulator.tetmesh import TetMesh
from tests.conftest import assert_close

DT = torch.float64
MODELS = ["linear", "corotated", "stvk", "neo_hookean", "mooney_rivlin"]
NONLINEAR = ["corotated", "stvk", "neo_hookean", "mooney_rivlin"]


def _energy(kind, batch, tets, young=3e4, nu=0.4):
    e = torch.full((batch, tets), young, dtype=DT) * torch.linspace(1, 2, batch, dtype=DT)[:, None]
    cls = {
        "linear": EnergyTetLinear,
        "corotated": EnergyTetCorotated,
        "stvk": EnergyTetStVK,
        "neo_hookean": EnergyTetNeoHookean,
    }
    if kind == "mooney_rivlin":
        return EnergyTetMooneyRivlin(e / 20, e / 30, e * 2)
    return cls[kind].from_young_poisson(e, nu)


def _model(mesh, energies=(), batch=2, pins=None):
    pins = torch.zeros(0, dtype=torch.long) if pins is None else pins
    mass = torch.ones(batch, mesh.vert_count, dtype=DT)
    return SimModel(mesh, tuple(energies), (), mass, pins)


def _mesh():
    return TetMesh.box((2, 1, 1), (0.02, 0.01, 0.01))


def _deformed(mesh, batch, scale=0.0015, seed=0):
    gen = torch.Generator().manual_seed(seed)
    pos = mesh.vert_pos[None].repeat(batch, 1, 1) @ torch.diag(
        torch.tensor([1.1, 0.95, 1.0], dtype=DT)
    )
    return pos + scale * torch.randn(pos.shape, generator=gen, dtype=DT)


@pytest.mark.parametrize("kind", MODELS)
def test_gradient_matches_finite_differences(kind):
    mesh = _mesh()
    energy = _energy(kind, 2, mesh.tet_count)
    model = _model(mesh)
    pos = _deformed(mesh, 2)
    gen = torch.Generator().manual_seed(1)
    direction = torch.randn(pos.shape, generator=gen, dtype=DT)
    h = 1e-7
    fd = (energy.energy(model, pos + h * direction) - energy.energy(model, pos - h * direction)) / (
        2 * h
    )
    analytic = (energy.gradient(model, pos) * direction).sum((1, 2))
    assert_close(analytic, fd, f"{kind}.gradient", rtol=1e-6, atol=1e-10)
    if kind != "corotated":  # autograd through an SVD is the thing we avoid there
        x = pos.clone().requires_grad_(True)
        (auto,) = torch.autograd.grad(energy.energy(model, x).sum(), x)
        assert_close(energy.gradient(model, pos), auto, f"{kind}.gradient vs autograd")


@pytest.mark.parametrize("kind", MODELS)
def test_hessian_matches_finite_differences(kind):
    mesh = _mesh()
    energy = _energy(kind, 2, mesh.tet_count)
    model = _model(mesh)
    pos = _deformed(mesh, 2)
    gen = torch.Generator().manual_seed(2)
    direction = torch.randn(pos.shape, generator=gen, dtype=DT)
    h = 1e-7
    fd = (
        energy.gradient(model, pos + h * direction) - energy.gradient(model, pos - h * direction)
    ) / (2 * h)
    hv = energy.hessian_product(model, pos, direction)
    scale = float(fd.abs().max())
    assert_close(hv, fd, f"{kind}.hessian_product", rtol=1e-5, atol=1e-6 * scale)


@pytest.mark.parametrize("kind", MODELS)
def test_blocks_are_symmetric_psd_and_exact_when_convex(kind):
    mesh = _mesh()
    energy = _energy(kind, 2, mesh.tet_count)
    model = _model(mesh)
    rest = mesh.vert_pos[None].repeat(2, 1, 1)
    blocks = energy.hessian_blocks(model, rest)
    dense = blocks.blocks.permute(0, 1, 3, 2, 4).reshape(-1, 12, 12)
    assert_close(dense, dense.transpose(1, 2), f"{kind}.blocks symmetry")
    assert float(torch.linalg.eigvalsh(dense).min()) > -1e-9 * float(dense.abs().max())
    # At rest every model is convex: the projected blocks equal the exact Hessian.
    gen = torch.Generator().manual_seed(3)
    v = torch.randn(rest.shape, generator=gen, dtype=DT)
    product = blocks.matvec(v.reshape(-1, 3)).view_as(v)
    assert_close(
        product, energy.hessian_product(model, rest, v), f"{kind}.blocks matvec", atol=1e-6
    )


@pytest.mark.parametrize("kind", MODELS)
def test_rest_state_is_stress_free(kind):
    mesh = _mesh()
    energy = _energy(kind, 2, mesh.tet_count)
    model = _model(mesh)
    rest = mesh.vert_pos[None].repeat(2, 1, 1)
    assert_close(
        energy.energy(model, rest), torch.zeros(2, dtype=DT), f"{kind}.energy at rest", atol=1e-12
    )
    assert_close(
        energy.gradient(model, rest), torch.zeros_like(rest), f"{kind}.gradient at rest", atol=1e-9
    )


def _rotation(seed):
    q, _ = torch.linalg.qr(
        torch.randn(3, 3, generator=torch.Generator().manual_seed(seed), dtype=DT)
    )
    return q * torch.sign(torch.det(q))


@pytest.mark.parametrize("kind", NONLINEAR)
def test_rotation_invariance(kind):
    mesh = _mesh()
    energy = _energy(kind, 2, mesh.tet_count)
    model = _model(mesh)
    pos = _deformed(mesh, 2)
    rotated = pos @ _rotation(4).T + torch.tensor([0.3, -0.1, 2.0], dtype=DT)
    assert_close(
        energy.energy(model, rotated),
        energy.energy(model, pos),
        f"{kind}.energy rotated",
        rtol=1e-9,
    )
    assert bool((energy.energy(model, pos) >= 0).all())


@pytest.mark.parametrize("kind", ["corotated", "stvk", "neo_hookean", "mooney_rivlin"])
def test_small_strain_tangent_matches_linear_elasticity(kind):
    mesh = TetMesh.box((1, 1, 1), (0.01, 0.01, 0.01))
    energy = _energy(kind, 1, mesh.tet_count)
    if kind == "mooney_rivlin":
        mu, lam = energy.small_strain_lame()
    else:
        mu, lam = energy.mu, energy.lam
    linear = EnergyTetLinear(mu, lam)
    eye = torch.eye(3, dtype=DT).expand(1, mesh.tet_count, 3, 3)
    assert_close(
        energy.tangent(eye), linear.tangent(eye), f"{kind}.tangent at rest", rtol=1e-9, atol=1e-6
    )


@pytest.mark.parametrize("kind", MODELS)
def test_inverted_element_is_finite(kind):
    mesh = TetMesh.box((1, 1, 1), (0.01, 0.01, 0.01))
    energy = _energy(kind, 1, mesh.tet_count)
    model = _model(mesh, batch=1)
    pos = mesh.vert_pos.clone()[None]
    pos[0, :, 2] *= -1.0  # mirror: every tet inverted
    for value in (energy.energy(model, pos), energy.gradient(model, pos)):
        assert bool(torch.isfinite(value).all()), kind
    blocks = energy.hessian_blocks(model, pos)
    assert bool(torch.isfinite(blocks.blocks).all())


@pytest.mark.parametrize("kind", ["corotated", "neo_hookean", "mooney_rivlin"])
def test_inverted_element_recovers(kind):
    mesh = TetMesh.from_arrays(
        [[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], [[0, 1, 2, 3]]
    )
    energy = _energy(kind, 1, 1)
    pins = torch.tensor([0, 1, 2])
    model = _model(mesh, (energy,), batch=1, pins=pins).with_pattern()
    start = mesh.vert_pos.clone()[None]
    start[0, 3, 2] = -0.004  # pushed through the base: inverted
    state = SimState(start, torch.zeros_like(start), torch.zeros(1, dtype=DT))
    settings = NewtonSettings(max_iters=60, tol_dx=1e-10, cg_rtol=1e-10, preconditioner="jacobi")
    out, _ = solve_static(model, state, SimControl(start[:, pins]), settings=settings)
    assert_close(out.pos[0, 3], mesh.vert_pos[3], f"{kind}: recovered apex", atol=1e-7)


def test_lame_parameters_and_bad_material_input():
    mu, lam = lame_from_young_poisson(torch.tensor(2.6, dtype=DT), torch.tensor(0.3, dtype=DT))
    assert math.isclose(float(mu), 1.0) and math.isclose(float(lam), 1.5)
    with pytest.raises(MaterialError, match="youngs_modulus"):
        lame_from_young_poisson(torch.tensor([1e4, 0.0]), 0.3)
    with pytest.raises(MaterialError, match="youngs_modulus"):
        EnergyTetNeoHookean.from_young_poisson(torch.tensor([[-1.0]]), 0.3)
    for nu in (0.5, -1.0, 0.7):
        with pytest.raises(MaterialError, match=r"poisson_ratio must lie in \(-1, 0.5\)"):
            EnergyTetLinear.from_young_poisson(torch.tensor([[1e4]]), nu)
    with pytest.raises(MaterialError, match="v1"):
        EnergyTetMooneyRivlin(torch.ones(1, 1), torch.ones(1, 1), torch.zeros(1, 1))
    with pytest.raises(MaterialError, match="region"):
        region_values(torch.ones(2, 3), torch.tensor([0, 1, 1]))


def test_patch_test_linear_field_is_reproduced_exactly():
    mesh = TetMesh.box((3, 3, 3), (0.03, 0.03, 0.03))
    energy = _energy("linear", 1, mesh.tet_count)
    x = mesh.vert_pos
    on_boundary = ((x < 1e-12) | (x > 0.03 - 1e-12)).any(1)
    pins = torch.nonzero(on_boundary).reshape(-1)
    grad_u = torch.tensor(
        [[0.01, 0.003, -0.002], [0.004, -0.005, 0.001], [0.0, 0.002, 0.007]], dtype=DT
    )
    exact = x + x @ grad_u.T + torch.tensor([1e-3, 0.0, -2e-3], dtype=DT)
    model = _model(mesh, (energy,), batch=1, pins=pins).with_pattern()
    rest = x[None].clone()
    state = SimState(rest, torch.zeros_like(rest), torch.zeros(1, dtype=DT))
    settings = NewtonSettings(max_iters=5, tol_dx=1e-12, linear_solver="direct")
    out, _ = solve_static(model, state, SimControl(exact[None, pins]), settings=settings)
    assert_close(out.pos[0], exact, "patch test positions", atol=1e-12)


def _cantilever_tip(cells):
    length, side, young, load = 0.1, 0.01, 1e6, 0.05
    mesh = TetMesh.box(cells, (length, side, side))
    energy = EnergyTetLinear.from_young_poisson(
        torch.full((1, mesh.tet_count), young, dtype=DT), 0.0
    )
    x = mesh.vert_pos
    pins = torch.nonzero(x[:, 0] < 1e-12).reshape(-1)
    tip = torch.nonzero(x[:, 0] > length - 1e-12).reshape(-1)
    force = torch.zeros(1, mesh.vert_count, 3, dtype=DT)
    force[0, tip, 2] = -load / len(tip)
    model = _model(mesh, (energy, EnergyNodalForce(force)), batch=1, pins=pins).with_pattern()
    rest = x[None].clone()
    state = SimState(rest, torch.zeros_like(rest), torch.zeros(1, dtype=DT))
    settings = NewtonSettings(max_iters=3, tol_dx=1e-12, linear_solver="direct")
    out, _ = solve_static(model, state, SimControl(rest[:, pins]), settings=settings)
    deflection = -float((out.pos[0, tip, 2] - x[tip, 2]).mean())
    inertia = side**4 / 12
    shear = 0.5 * young  # nu = 0
    analytic = load * length**3 / (3 * young * inertia) + load * length / (5 / 6 * shear * side**2)
    return deflection, analytic


def test_cantilever_converges_to_beam_theory():
    errors = []
    for n in (1, 2, 4):
        got, analytic = _cantilever_tip((10 * n, n, n))
        errors.append(abs(got - analytic) / analytic)
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.2  # linear tets lock in bending; the error halves per refinement


def test_free_fall_with_lumped_mass():
    mesh = TetMesh.box((2, 2, 2), (0.02, 0.02, 0.02))
    density = 1000.0
    mass = (density * mesh.vert_volume)[None]
    energy = _energy("neo_hookean", 1, mesh.tet_count)
    gravity = EnergyGravity(torch.tensor([0.0, 0.0, -9.81], dtype=DT))
    model = SimModel(
        mesh, (energy, gravity), (), mass, torch.zeros(0, dtype=torch.long)
    ).with_pattern()
    assert math.isclose(float(mass.sum()), density * 8e-6, rel_tol=1e-12)
    pos = mesh.vert_pos[None].clone()
    state = SimState(pos, torch.zeros_like(pos), torch.zeros(1, dtype=DT))
    integ = IntegratorBackwardEuler(
        NewtonSettings(max_iters=4, tol_dx=1e-12, linear_solver="direct")
    )
    dt, steps = 0.01, 10
    for _ in range(steps):
        state, _ = integ.step(model, state, SimControl(pos[:, :0]), dt)
    drop = float((pos[0, :, 2] - state.pos[0, :, 2]).mean())
    # Backward Euler: z_n = -g dt² n (n + 1) / 2.
    assert math.isclose(drop, 9.81 * dt * dt * steps * (steps + 1) / 2, rel_tol=1e-9)
