"""Derivative, invariance and analytic checks of every cloth energy term."""

import math

import pytest
import torch

from simulator.cloth.material import ClothMaterial
from simulator.energies import (
    EnergyBendingDihedral,
    EnergyContactCapsule,
    EnergyGravity,
    EnergyMassSpring,
    EnergyMembraneWang,
    EnergySelfCollision,
)
from simulator.mesh import TriMesh
from simulator.model import SimControl, SimModel
from tests.conftest import assert_close

DT = torch.float64


def _model(mesh, energies=(), batch=2):
    return SimModel(
        mesh,
        tuple(energies),
        (),
        torch.ones(batch, mesh.vert_count, dtype=DT),
        torch.zeros(0, dtype=torch.long),
    )


def _mesh(n=4, size=0.3):
    grid = TriMesh.grid(n, size_u=size)
    # Tilt the rest placement so rest data is not axis-aligned in 3D.
    return grid


def _random_rotation(gen):
    q, _ = torch.linalg.qr(torch.randn(3, 3, generator=gen, dtype=DT))
    return q * torch.sign(torch.det(q))


def _deformed(mesh, batch, scale, gen):
    pos = mesh.vert_pos[None].repeat(batch, 1, 1).clone()
    pos = pos @ torch.diag(torch.tensor([1.08, 0.95, 1.0], dtype=DT))  # stretch into stiffening
    return pos + scale * torch.randn(pos.shape, generator=gen, dtype=DT)


def _materials(batch):
    return ClothMaterial.from_classes([3, 50][:batch] if batch <= 2 else list(range(batch)))


def _capsules(batch):
    cap = torch.tensor([[0.05, -0.1, -0.02, 0.25, 0.4, -0.02, 0.05]], dtype=DT)
    return cap[None].repeat(batch, 1, 1)


def _energy_cases():
    mat = _materials(2)
    mesh = _mesh()
    cases = {
        "membrane_wang": EnergyMembraneWang.from_material(mat.stretching),
        "membrane_isotropic_constant": EnergyMembraneWang.from_material(
            mat.stretching, strain_dependent=False, anisotropic=False
        ),
        "bending": EnergyBendingDihedral.from_material(mesh, mat.bending),
        "bending_constant_isotropic": EnergyBendingDihedral.from_material(
            mesh, mat.bending, curvature_dependent=False, anisotropic=False
        ),
        "mass_spring": EnergyMassSpring.from_material(mesh, mat.stretching, mat.bending),
        "gravity": EnergyGravity(torch.tensor([0.0, 0.0, -9.81], dtype=DT)),
    }
    return mesh, cases


def _bound(name, energy, model, pos):
    control = SimControl(pin_pos=pos[:, :0], capsules=_capsules(pos.shape[0]))
    return energy.bind(model, control, pos)


ELASTIC = [
    "membrane_wang",
    "membrane_isotropic_constant",
    "bending",
    "bending_constant_isotropic",
    "mass_spring",
]
ALL = [*ELASTIC, "gravity", "contact", "self_collision"]


def _setup(name, seed=0):
    gen = torch.Generator().manual_seed(seed)
    mesh, cases = _energy_cases()
    if name == "contact":
        energy = EnergyContactCapsule(stiffness=1e5, thickness=0.01)
        pos = _deformed(mesh, 2, 0.01, gen)
    elif name == "self_collision":
        energy = EnergySelfCollision(radius=0.15, stiffness=1e3)
        pos = _deformed(mesh, 2, 0.01, gen)
        pos[:, -1, 2] -= 0.0  # keep generic
    else:
        energy = cases[name]
        pos = _deformed(mesh, 2, 0.015, gen)
    model = _model(mesh, [energy])
    return mesh, model, _bound(name, energy, model, pos), pos


@pytest.mark.parametrize("name", ALL)
def test_gradient_matches_autograd_and_finite_differences(name):
    _, model, energy, pos = _setup(name)
    grad = energy.gradient(model, pos)
    x = pos.clone().requires_grad_(True)
    (auto,) = torch.autograd.grad(energy.energy(model, x).sum(), x)
    assert_close(grad, auto, f"{name} gradient vs autograd", rtol=1e-7, atol=1e-10)
    gen = torch.Generator().manual_seed(1)
    for _ in range(3):
        d = torch.randn(pos.shape, generator=gen, dtype=DT)
        eps = 1e-6
        fd = (energy.energy(model, pos + eps * d) - energy.energy(model, pos - eps * d)) / (2 * eps)
        assert_close(
            (grad * d).sum(dim=(1, 2)), fd, f"{name} directional derivative", rtol=1e-5, atol=1e-8
        )


@pytest.mark.parametrize("name", ALL)
def test_hessian_product_matches_finite_differences(name):
    _, model, energy, pos = _setup(name)
    gen = torch.Generator().manual_seed(2)
    d = torch.randn(pos.shape, generator=gen, dtype=DT)
    eps = 1e-6
    fd = (energy.gradient(model, pos + eps * d) - energy.gradient(model, pos - eps * d)) / (2 * eps)
    hvp = energy.hessian_product(model, pos, d)
    assert_close(hvp, fd, f"{name} Hessian-vector product", rtol=1e-4, atol=1e-6 * fd.abs().max())


def _dense(blocks, batch, verts):
    eye = torch.eye(batch * verts * 3, dtype=DT)
    cols = [blocks.matvec(eye[:, j].reshape(-1, 3)).reshape(-1) for j in range(eye.shape[1])]
    return torch.stack(cols, dim=1)


@pytest.mark.parametrize(
    "name", ["membrane_wang", "bending", "mass_spring", "contact", "self_collision"]
)
def test_solver_blocks_are_symmetric_psd(name):
    mesh, model, energy, pos = _setup(name)
    blocks = energy.hessian_blocks(model, pos)
    if blocks is None:
        pytest.skip("no active elements")
    dense = _dense(blocks, pos.shape[0], mesh.vert_count)
    assert_close(dense, dense.T, f"{name} blocks symmetry")
    eig = torch.linalg.eigvalsh(dense)
    assert eig.min() >= -1e-9 * eig.abs().max(), f"{name}: blocks not PSD ({eig.min()})"


@pytest.mark.parametrize("name", ["membrane_wang", "bending", "mass_spring"])
def test_solver_blocks_equal_exact_hessian_near_rest(name):
    """At small, stretching deformations the PSD approximation is the exact Hessian."""
    gen = torch.Generator().manual_seed(3)
    mesh, cases = _energy_cases()
    energy = cases[name]
    model = _model(mesh, [energy])
    pos = mesh.vert_pos[None].repeat(2, 1, 1) * 1.001
    if name == "bending":
        pos = pos + 1e-9 * torch.randn(pos.shape, generator=gen, dtype=DT)
    dense = _dense(energy.hessian_blocks(model, pos), 2, mesh.vert_count)
    d = torch.randn(pos.shape, generator=gen, dtype=DT)
    exact = energy.hessian_product(model, pos, d).reshape(-1)
    rel = (dense @ d.reshape(-1) - exact).norm() / exact.norm()
    # Strain-stiffening terms vanish at 0.1 % strain only to first order.
    assert rel < 2e-2, f"{name}: PSD blocks differ from exact Hessian by {rel:.2e}"


@pytest.mark.parametrize("name", ELASTIC)
def test_zero_energy_and_force_at_rest(name):
    mesh, cases = _energy_cases()
    energy = cases[name]
    model = _model(mesh, [energy])
    pos = mesh.vert_pos[None].repeat(2, 1, 1)
    assert_close(
        energy.energy(model, pos), torch.zeros(2, dtype=DT), f"{name} rest energy", atol=1e-14
    )
    assert_close(
        energy.gradient(model, pos), torch.zeros_like(pos), f"{name} rest force", atol=1e-10
    )


@pytest.mark.parametrize("name", ELASTIC)
def test_rigid_motion_invariance_and_nonnegativity(name):
    gen = torch.Generator().manual_seed(4)
    mesh, model, energy, pos = _setup(name)
    rot = _random_rotation(gen)
    shift = torch.randn(3, generator=gen, dtype=DT)
    moved = pos @ rot.T + shift
    assert_close(
        energy.energy(model, moved),
        energy.energy(model, pos),
        f"{name} energy invariance",
        rtol=1e-9,
        atol=1e-14,
    )
    assert_close(
        energy.gradient(model, moved),
        energy.gradient(model, pos) @ rot.T,
        f"{name} force covariance",
        rtol=1e-7,
        atol=1e-11,
    )
    assert (energy.energy(model, pos) >= 0).all(), f"{name}: negative energy"
    # Rigid motion of the rest shape is force free.
    rest = mesh.vert_pos[None].repeat(2, 1, 1) @ rot.T + shift
    assert_close(
        energy.gradient(model, rest), torch.zeros_like(rest), f"{name} rigid rest force", atol=1e-10
    )


def test_gradcheck_two_triangle_cloth_and_all_finite():
    mesh = TriMesh.from_arrays(
        [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0.02]],
        [[0, 1, 3], [0, 3, 2]],
        [[0, 0], [0.1, 0], [0, 0.1], [0.1, 0.1]],
    )
    mat = ClothMaterial.from_classes([10])
    for energy in (
        EnergyMembraneWang.from_material(mat.stretching),
        EnergyBendingDihedral.from_material(mesh, mat.bending),
    ):
        model = _model(mesh, [energy], batch=1)
        x = (mesh.vert_pos[None] * 1.05 + 0.003).clone().requires_grad_(True)
        assert torch.autograd.gradcheck(lambda p, e=energy, m=model: e.energy(m, p), (x,))
        assert torch.isfinite(energy.gradient(model, x.detach())).all()


def test_rolled_sheet_stores_continuum_bending_energy():
    """E = 1/2 D kappa^2 A for a cylinder, converging as the mesh is refined."""
    ratios = []
    for n in (16, 32, 64):
        mesh = TriMesh.grid(n, size_u=0.5)
        d = 1e-4
        energy = EnergyBendingDihedral.from_material(mesh, torch.full((1, 3, 5), d, dtype=DT))
        model = _model(mesh, [energy], batch=1)
        radius = 0.3
        u, w = mesh.uv[:, 0], mesh.uv[:, 1]
        pos = torch.stack(
            [radius * torch.sin(u / radius), w, radius * (1 - torch.cos(u / radius))], -1
        )
        ratios.append(energy.energy(model, pos[None]).item() / (0.5 * d / radius**2 * 0.25))
    assert abs(ratios[-1] - 1) < 0.02, ratios
    assert abs(ratios[0] - 1) > abs(ratios[1] - 1) > abs(ratios[2] - 1), ratios


def test_membrane_uniaxial_stretch_matches_closed_form():
    """Pure warp stretch at constant stiffness: W = 1/2 k0 G00^2 with G00 = (s^2 - 1) / 2."""
    mesh = TriMesh.grid(3, size_u=0.2)
    rows = torch.tensor([[[100.0, 0.0, 60.0, 30.0]] * 6], dtype=DT)
    energy = EnergyMembraneWang.from_material(rows, strain_dependent=False)
    model = _model(mesh, [energy], batch=1)
    s = 1.1
    pos = mesh.vert_pos.clone()
    pos[:, 0] *= s
    expected = 0.5 * 100.0 * (0.5 * (s * s - 1)) ** 2 * 0.04
    assert_close(
        energy.energy(model, pos[None]),
        torch.tensor([expected], dtype=DT),
        "uniaxial stretch energy",
        rtol=1e-12,
    )


def test_membrane_density_is_convex_in_strain():
    """The fitted fibre model keeps W convex in G (ArcSim's blend is not)."""
    from simulator.energies.membrane import membrane_density

    mat = ClothMaterial.from_classes([9])
    energy = EnergyMembraneWang.from_material(mat.stretching)
    gen = torch.Generator().manual_seed(5)
    g = (torch.rand(1, 4000, 3, generator=gen, dtype=DT) - 0.5) * torch.tensor([0.4, 0.4, 0.3])
    g.requires_grad_(True)
    w = membrane_density(g, energy.row0, energy.fibres)
    (grad,) = torch.autograd.grad(w.sum(), g, create_graph=True)
    rows = [torch.autograd.grad(grad[..., i].sum(), g, retain_graph=True)[0] for i in range(3)]
    hess = torch.stack(rows, dim=-2)[0]
    assert torch.linalg.eigvalsh(0.5 * (hess + hess.mT)).min() > -1e-9


def test_fibre_fit_is_the_nonnegative_least_squares_optimum():
    """The fit meets the optimality (KKT) conditions on random systems, on a known answer and
    on every measured fabric, whatever scipy is installed (its nnls can stop short)."""
    import numpy as np

    from simulator.cloth.material import (
        load_wang_material,
        stabilize_stretching,
        wang_material_names,
    )
    from simulator.energies.membrane import _nnls_exact, fit_fibres

    def assert_kkt(design, target, x):
        grad = design.T @ (design @ x - target)
        scale = np.abs(design).max() * (np.abs(target).max() + 1.0)
        assert (x >= 0).all()
        assert np.abs(grad[x > 0]).max(initial=0.0) < 1e-9 * scale
        assert grad[x == 0].min(initial=0.0) > -1e-9 * scale

    # unconstrained solution (-1, 3): the optimum drops x0 and refits x1 alone
    design = np.array([[1.0, 1.0], [0.0, 1.0], [1.0, 2.0]])
    target = design @ np.array([-1.0, 3.0])
    x = _nnls_exact(design, target)
    np.testing.assert_allclose(x, [0.0, (design[:, 1] @ target) / (design[:, 1] @ design[:, 1])])
    rng = np.random.default_rng(3)
    for _ in range(200):
        design, target = rng.normal(size=(5, 5)), rng.normal(size=5)
        assert_kkt(design, target, _nnls_exact(design, target))
    for name in wang_material_names():
        assert (fit_fibres(stabilize_stretching(load_wang_material(name).stretching)) >= 0).all()


@pytest.mark.parametrize("fabric", ["camel-ponte-roma", "11oz-black-denim", "royal-target"])
def test_fibres_reproduce_measured_directional_stiffening(fabric):
    """Tangent stiffness along each measured direction at the measured strain matches the row
    wherever the row is stiffer than row 0 (NNLS fit)."""
    from simulator.cloth.material import (
        STRETCH_SAMPLE_STRAIN,
        load_wang_material,
        stabilize_stretching,
    )
    from simulator.energies.membrane import membrane_density

    rows = torch.as_tensor(stabilize_stretching(load_wang_material(fabric).stretching))[None]
    energy = EnergyMembraneWang.from_material(rows)
    for j, angle in enumerate((0.0, 22.5, 45.0, 67.5, 90.0)):
        c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
        direction = torch.tensor([c * c, s * s, c * s], dtype=DT)
        e = torch.tensor(STRETCH_SAMPLE_STRAIN, dtype=DT, requires_grad=True)
        w = membrane_density((e * direction)[None, None], energy.row0, energy.fibres)
        (d1,) = torch.autograd.grad(w.sum(), e, create_graph=True)
        (d2,) = torch.autograd.grad(d1, e)
        k0, k1, k2, k3 = rows[0, j + 1]
        measured = k0 * c**4 + k2 * s**4 + (2 * k1 + k3) * c * c * s * s
        r0 = rows[0, 0]
        base = r0[0] * c**4 + r0[2] * s**4 + (2 * r0[1] + r0[3]) * c * c * s * s
        assert d2 >= base - 1e-6, (fabric, angle)
        assert d2 <= max(measured, base) * 1.35 + 1e-6, (fabric, angle, d2, measured)
