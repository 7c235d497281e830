"""Derivative checks and invariants of the monocular sheet energies."""

import math

import pytest
import torch

from simulator.energies.bending import EnergyBendingDihedral
from simulator.energies.membrane import EnergyMembraneWang
from simulator.model import SimModel
from simulator.monocular.bending import EnergyBendingQuadratic
from simulator.monocular.camera import look_at
from simulator.monocular.features import locate_features
from simulator.monocular.image_fit import EnergyImageFit
from simulator.monocular.linear import EnergySheetLinear, sheet_mass_spring
from simulator.monocular.material import SheetMaterial
from simulator.monocular.sheet import crossed_grid
from simulator.monocular.stvk import EnergySheetStVK
from tests.conftest import assert_close

MATERIAL = SheetMaterial(0.25e6, 0.45, 0.01)


def _setup(batch=2, seed=0):
    mesh = crossed_grid(3, size=0.1)
    model = SimModel(
        mesh,
        (),
        (),
        torch.ones(batch, mesh.vert_count, dtype=torch.float64),
        torch.zeros(0, dtype=torch.int64),
    )
    gen = torch.Generator().manual_seed(seed)
    pos = mesh.vert_pos[None] * torch.tensor([1.2, 0.9, 1.0], dtype=torch.float64)
    pos = pos + 0.004 * torch.randn(batch, mesh.vert_count, 3, generator=gen, dtype=torch.float64)
    return mesh, model, pos


def _image_energy(mesh, batch=2):
    camera = look_at([0.05, -0.1, 0.2], [0.05, 0.05, 0.0], [0.0, 1.0, 0.0])
    gen = torch.Generator().manual_seed(3)
    uv = 0.01 + 0.08 * torch.rand(20, 2, generator=gen, dtype=torch.float64)
    feats = locate_features(mesh, uv)
    targets = camera.project(feats.points(mesh, mesh.vert_pos[None])).expand(batch, -1, -1)
    targets = targets + 3.0 * torch.randn(targets.shape, generator=gen, dtype=torch.float64)
    return EnergyImageFit.build(mesh, feats, camera, targets, stiffness=500.0)


def _energies(mesh, batch=2):
    return {
        "stvk": EnergySheetStVK.from_mesh(mesh, MATERIAL),
        "linear": EnergySheetLinear.from_mesh(mesh, MATERIAL),
        "bending": EnergyBendingQuadratic.from_mesh(mesh, MATERIAL.bending_rigidity),
        "image": _image_energy(mesh, batch),
        "mass_spring": sheet_mass_spring(mesh, MATERIAL),
    }


@pytest.mark.parametrize("name", ["stvk", "linear", "bending", "image"])
def test_gradient_matches_finite_differences(name):
    mesh, model, pos = _setup()
    energy = _energies(mesh)[name]
    grad = energy.gradient(model, pos)
    gen = torch.Generator().manual_seed(1)
    direction = torch.randn(pos.shape, generator=gen, dtype=torch.float64)
    h = 1e-7
    fd = (energy.energy(model, pos + h * direction) - energy.energy(model, pos - h * direction)) / (
        2 * h
    )
    assert_close((grad * direction).sum(dim=(1, 2)), fd, f"{name}.gradient", rtol=1e-5, atol=1e-6)
    x = pos.clone().requires_grad_(True)
    (auto,) = torch.autograd.grad(energy.energy(model, x).sum(), x)
    assert_close(grad, auto, f"{name}.gradient vs autograd", rtol=1e-8, atol=1e-8)


@pytest.mark.parametrize("name", ["stvk", "linear", "bending", "image"])
def test_hessian_product_matches_finite_differences(name):
    mesh, model, pos = _setup()
    energy = _energies(mesh)[name]
    gen = torch.Generator().manual_seed(2)
    direction = torch.randn(pos.shape, generator=gen, dtype=torch.float64)
    h = 1e-6
    fd = (
        energy.gradient(model, pos + h * direction) - energy.gradient(model, pos - h * direction)
    ) / (2 * h)
    hvp = energy.hessian_product(model, pos, direction)
    assert_close(hvp, fd, f"{name}.hessian_product", rtol=1e-4, atol=1e-4 * float(fd.abs().max()))


def test_stvk_blocks_are_exact_in_tension_and_psd():
    """Uniform stretch: every element is in tension, so the projected blocks are exact."""
    mesh, model, _ = _setup(batch=1)
    pos = mesh.vert_pos[None] * torch.tensor([1.25, 1.1, 1.0], dtype=torch.float64)
    pos = pos + torch.tensor([0.0, 0.0, 1e-3], dtype=torch.float64) * torch.rand(
        1, mesh.vert_count, 1, dtype=torch.float64
    )
    energy = EnergySheetStVK.from_mesh(mesh, MATERIAL)
    blocks = energy.hessian_blocks(model, pos)
    direction = torch.randn(pos.shape, dtype=torch.float64)
    via_blocks = blocks.matvec(direction.reshape(-1, 3)).view_as(pos)
    assert_close(
        via_blocks,
        energy.hessian_product(model, pos, direction),
        "stvk.hessian_blocks",
        rtol=1e-8,
        atol=1e-6,
    )
    for name, e in _energies(mesh, 1).items():
        b = e.hessian_blocks(model, pos)
        dense = b.blocks.permute(0, 1, 3, 2, 4).reshape(
            b.blocks.shape[0], 3 * b.blocks.shape[1], -1
        )
        eig = torch.linalg.eigvalsh(0.5 * (dense + dense.transpose(1, 2)))
        assert float(eig.min()) >= -1e-8 * float(eig.abs().max()), f"{name} blocks not PSD"


def test_image_blocks_are_gauss_newton_exact_at_zero_residual():
    mesh, model, _ = _setup(batch=1)
    energy = _image_energy(mesh, 1)
    pos = mesh.vert_pos[None].clone()
    energy = energy.with_targets(energy.camera.project(energy._points(pos)))
    direction = torch.randn(pos.shape, dtype=torch.float64)
    via_blocks = energy.hessian_blocks(model, pos).matvec(direction.reshape(-1, 3)).view_as(pos)
    assert_close(
        via_blocks,
        energy.hessian_product(model, pos, direction),
        "image.hessian_blocks",
        rtol=1e-8,
        atol=1e-8,
    )


def test_edge_based_stvk_equals_deformation_gradient_stvk():
    """Kikuuwe's edge form equals the core's F-based membrane with the same plane-stress law."""
    mesh, model, pos = _setup()
    edge = EnergySheetStVK.from_mesh(mesh, MATERIAL)
    rows = torch.tensor(MATERIAL.stiffness_rows(), dtype=torch.float64)[None].expand(2, 4)
    core = EnergyMembraneWang(rows, torch.zeros(2, 8, dtype=torch.float64))
    assert_close(edge.energy(model, pos), core.energy(model, pos), "stvk energy vs core membrane")
    assert_close(
        edge.gradient(model, pos),
        core.gradient(model, pos),
        "stvk gradient vs core membrane",
        atol=1e-8,
    )
    assert_close(
        edge.hessian_blocks(model, pos).blocks,
        core.hessian_blocks(model, pos).blocks,
        "stvk blocks vs core membrane",
        rtol=1e-8,
        atol=1e-6,
    )


def test_quadratic_bending_equals_core_dihedral_with_constant_stiffness():
    mesh, model, pos = _setup()
    d = MATERIAL.bending_rigidity
    ours = EnergyBendingQuadratic.from_mesh(mesh, d)
    core = EnergyBendingDihedral.from_material(
        mesh,
        torch.full((2, 3, 5), d, dtype=torch.float64),
        curvature_dependent=False,
        anisotropic=False,
    )
    assert_close(ours.energy(model, pos), core.energy(model, pos), "bending energy vs core")


@pytest.mark.parametrize("name", ["stvk", "bending", "mass_spring"])
def test_rotation_translation_invariance(name):
    mesh, model, pos = _setup()
    energy = _energies(mesh)[name]
    ang = 0.7
    axis = torch.tensor([1.0, 2.0, -0.5], dtype=torch.float64)
    axis = axis / axis.norm()
    kx = torch.tensor(
        [[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]],
        dtype=torch.float64,
    )
    rot = torch.eye(3, dtype=torch.float64) + math.sin(ang) * kx + (1 - math.cos(ang)) * kx @ kx
    moved = pos @ rot.T + torch.tensor([0.3, -1.0, 2.0], dtype=torch.float64)
    assert_close(
        energy.energy(model, moved), energy.energy(model, pos), f"{name} invariance", rtol=1e-9
    )


def test_linear_fem_is_not_rotation_invariant_but_zero_at_rest():
    mesh, model, _ = _setup()
    energy = _energies(mesh)["linear"]
    rest = mesh.vert_pos[None]
    assert float(energy.energy(model, rest).abs()) == 0.0
    c, s = math.cos(0.5), math.sin(0.5)
    rot = torch.tensor([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=torch.float64)
    assert float(energy.energy(model, rest @ rot.T)) > 1e-3


def test_zero_energy_and_gradient_at_rest():
    mesh, model, _ = _setup(batch=1)
    rest = mesh.vert_pos[None].clone()
    for name, e in _energies(mesh, 1).items():
        if name == "image":
            continue
        assert float(e.energy(model, rest).abs()) < 1e-12, name
        assert float(e.gradient(model, rest).abs().max()) < 1e-9, name


def test_uniaxial_plane_stress_reference():
    """Free uniaxial stretch lambda: S_xx = E h (lambda² - 1) / 2 at zero lateral stress."""
    mesh, model, _ = _setup(batch=1)
    lam = 1.3
    energy = EnergySheetStVK.from_mesh(mesh, MATERIAL)
    lateral = math.sqrt(1.0 - MATERIAL.poisson_ratio * (lam * lam - 1.0))  # e_yy = -nu e_xx
    pos = mesh.vert_pos[None] * torch.tensor([lam, lateral, 1.0], dtype=torch.float64)
    exx = 0.5 * (lam * lam - 1.0)
    expected = 0.5 * MATERIAL.youngs_modulus * MATERIAL.thickness * exx * exx * 0.1 * 0.1
    assert_close(
        energy.energy(model, pos),
        torch.tensor([expected], dtype=torch.float64),
        "uniaxial energy",
        rtol=1e-10,
    )
