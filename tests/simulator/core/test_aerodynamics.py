"""Wind drag: the normal and the orientation-blind (isotropic) share, against formulas,
rotations and the analytic terminal velocity of a falling sheet."""

import math
from types import SimpleNamespace

import pytest
import torch

from simulator.cloth.effects import PhysicsEffects
from simulator.cloth.material import ClothMaterial
from simulator.cloth.model import build_cloth_model
from simulator.forces import AerodynamicDrag
from simulator.geometry import vertex_area_normals
from simulator.integrators import IntegratorBackwardEuler
from simulator.mesh import TriMesh
from simulator.model import SimControl, SimState
from simulator.solvers import NewtonSettings
from tests.conftest import assert_close

DT = torch.float64
RHO = 1.2
GRAVITY = 9.81


def _sheet(normal_axis: str, n: int = 4):
    """A flat 0.2 m sheet with unit normal along ``normal_axis`` (y: vertical, z: horizontal)."""
    grid = TriMesh.grid(n, size_u=0.2)
    u, v = grid.uv[:, 0], grid.uv[:, 1]
    zero = torch.zeros_like(u)
    pos = torch.stack([u, zero, 1 - v], -1) if normal_axis == "y" else torch.stack([u, v, zero], -1)
    return TriMesh.from_arrays(pos.numpy(), grid.tri_indices.numpy(), grid.uv.numpy())


def _model(mesh, isotropy: float, classes=(20,)):
    effects = PhysicsEffects(isotropic_drag=isotropy > 0, drag_isotropy=max(isotropy, 0.25))
    empty = torch.zeros(0, dtype=torch.long)
    return build_cloth_model(
        mesh, ClothMaterial.from_classes(list(classes)), empty, effects=effects
    )


def _drag_force(mesh, isotropy, pos, vel, wind):
    """The force of the linearised drag at the current velocity, ``-D (v - w)``."""
    drag = AerodynamicDrag(isotropy=isotropy)
    state = SimState(pos, vel, torch.zeros(pos.shape[0], dtype=DT))
    control = SimControl(pin_pos=pos[:, :0], wind_vel=wind)
    step = drag.linearize(SimpleNamespace(mesh=mesh), state, control, ())
    return -(step.damping_vertex @ (vel - wind)[..., None])[..., 0]


def _random_state(seed=0):
    mesh = _sheet("y")
    gen = torch.Generator().manual_seed(seed)
    pos = mesh.vert_pos[None] + 0.02 * torch.randn((1, *mesh.vert_pos.shape), generator=gen)
    vel = torch.randn(pos.shape, generator=gen, dtype=DT)
    wind = 2.0 * torch.randn(pos.shape, generator=gen, dtype=DT)
    return mesh, pos, vel, wind


@pytest.mark.parametrize("isotropy", [0.0, 0.4, 1.0])
def test_drag_matches_its_formula(isotropy):
    mesh, pos, vel, wind = _random_state()
    a = vertex_area_normals(pos, mesh.tri_indices)
    area = a.norm(dim=-1, keepdim=True)
    normal = a / area
    u = vel - wind
    u_n = (u * normal).sum(-1, keepdim=True)
    normal_drag = -0.5 * RHO * area * u_n.abs() * u_n * normal
    blind_drag = -0.5 * RHO * area * u.norm(dim=-1, keepdim=True) * u
    expected = (1 - isotropy) * normal_drag + isotropy * blind_drag
    assert_close(
        _drag_force(mesh, isotropy, pos, vel, wind), expected, "drag", rtol=1e-12, atol=1e-15
    )


def test_edge_on_flow_meets_only_the_orientation_blind_drag():
    mesh = _sheet("y")
    pos = mesh.vert_pos[None]
    wind = torch.zeros_like(pos)
    wind[..., 0] = 3.0  # along the sheet's plane
    vel = torch.zeros_like(pos)
    normal_only = _drag_force(mesh, 0.0, pos, vel, wind)
    blind = _drag_force(mesh, 1.0, pos, vel, wind)
    assert normal_only.abs().max() < 1e-12
    assert (blind[..., 0] > 0).all() and blind[..., 1:].abs().max() < 1e-12
    total = blind[..., 0].sum()
    assert_close(total, torch.tensor(0.5 * RHO * 0.2 * 0.2 * 9.0, dtype=DT), "force", rtol=1e-12)


@pytest.mark.parametrize("isotropy", [0.0, 0.5, 1.0])
def test_drag_rotates_with_the_scene(isotropy):
    mesh, pos, vel, wind = _random_state(seed=1)
    q, _ = torch.linalg.qr(torch.randn(3, 3, generator=torch.Generator().manual_seed(2), dtype=DT))
    rotated = _drag_force(mesh, isotropy, pos @ q.T, vel @ q.T, wind @ q.T)
    assert_close(rotated, _drag_force(mesh, isotropy, pos, vel, wind) @ q.T, "rotated", atol=1e-12)


def _terminal_speed(normal_axis: str, isotropy: float) -> float:
    mesh = _sheet(normal_axis)
    model = _model(mesh, isotropy)
    rest = mesh.vert_pos[None].clone()
    state = SimState(rest, torch.zeros_like(rest), torch.zeros(1, dtype=DT))
    control = SimControl(pin_pos=rest[:, :0])
    integrator = IntegratorBackwardEuler(NewtonSettings(max_iters=4, tol_dx=1e-12, cg_rtol=1e-10))
    for _ in range(150):
        state, _ = integrator.step(model, state, control, 0.01)
    return float(-state.vel[..., 2].mean())


@pytest.mark.parametrize(
    ("normal_axis", "isotropy", "share"),
    [("z", 0.0, 1.0), ("y", 1.0, 1.0), ("y", 0.5, 0.5), ("z", 0.5, 1.0)],
    ids=["face-on normal", "edge-on blind", "edge-on half blind", "face-on half blind"],
)
def test_falling_sheet_reaches_the_analytic_terminal_speed(normal_axis, isotropy, share):
    """Weight = drag: ``rho_A g = 1/2 rho C_d s v^2`` with ``s`` the drag share the fall meets."""
    density = float(ClothMaterial.from_classes([20]).density[0])
    expected = math.sqrt(2 * density * GRAVITY / (RHO * share))
    assert abs(_terminal_speed(normal_axis, isotropy) - expected) < 2e-3 * expected


def test_drag_isotropy_out_of_range_names_the_field():
    with pytest.raises(ValueError, match="drag_isotropy"):
        PhysicsEffects(isotropic_drag=True, drag_isotropy=1.5)
    with pytest.raises(ValueError, match="isotropy"):
        AerodynamicDrag(isotropy=-0.1)
