"""Newmark (average acceleration) on a linear-elastic tet cantilever: energy, order, input."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from simulator.energies import EnergyGravity
from simulator.energies.tet import EnergyTetLinear, EnergyTetNeoHookean
from simulator.forces.damping import StrainRateDamping
from simulator.integrators import IntegratorBackwardEuler, IntegratorNewmark
from simulator.model import SimControl, SimModel, SimState
from simulator.solvers.newton import NewtonSettings
from simulator.tetmesh import TetMesh
from tests.conftest import assert_close

DT = torch.float64
EXACT = NewtonSettings(max_iters=3, tol_dx=1e-13, linear_solver="direct")
LENGTH, DENSITY = 0.04, 1000.0


def _beam(young=(1e5,)):
    """4 x 1 x 1-cell tet cantilever clamped at x = 0, one instance per modulus."""
    mesh = TetMesh.box((4, 1, 1), (LENGTH, 0.01, 0.01))
    moduli = torch.tensor(young, dtype=DT)[:, None].expand(-1, mesh.tet_count)
    energy = EnergyTetLinear.from_young_poisson(moduli, 0.3)
    pins = torch.nonzero(mesh.vert_pos[:, 0] < 1e-12).reshape(-1)
    mass = (DENSITY * mesh.vert_volume)[None].expand(len(young), -1)
    model = SimModel(mesh, (energy,), (), mass, pins).with_pattern()
    rest = mesh.vert_pos[None].repeat(len(young), 1, 1)
    return model, rest, SimControl(rest[:, pins])


def _first_mode(model, rest):
    """Lowest angular frequency [rad/s] and its mode shape (max |entry| 1), shape (1, V, 3)."""
    energy = model.energies[0]
    stiffness = torch.autograd.functional.hessian(
        lambda x: energy.energy(model, x.view(1, -1, 3)).sum(), rest[:1].reshape(-1)
    )
    free = model.free_mask()[:, 0].bool().repeat_interleave(3)
    inv_sqrt_mass = model.vert_mass[0].repeat_interleave(3)[free].rsqrt()
    scaled = inv_sqrt_mass[:, None] * stiffness[free][:, free] * inv_sqrt_mass[None]
    omega_sq, vectors = torch.linalg.eigh(scaled)
    shape = torch.zeros(free.numel(), dtype=DT)
    shape[free] = inv_sqrt_mass * vectors[:, 0]
    shape = shape.view(1, -1, 3)
    return float(omega_sq[0].sqrt()), shape / shape.abs().max()


def _total_energy(model, state):
    kinetic = 0.5 * (model.vert_mass[..., None] * state.vel**2).sum(dim=(1, 2))
    return kinetic + sum(e.energy(model, state.pos) for e in model.energies)


def test_average_acceleration_conserves_energy_backward_euler_damps_it():
    model, rest, control = _beam()
    vel = 0.05 * torch.randn(rest.shape, generator=torch.Generator().manual_seed(0), dtype=DT)
    vel[:, model.pin_indices] = 0.0
    start = SimState(rest.clone(), vel, torch.zeros(1, dtype=DT))
    initial = _total_energy(model, start)
    # dt is ~7 / omega_max: far beyond any explicit scheme's stability limit.
    for integ, check in (
        (IntegratorNewmark(EXACT), lambda e: torch.allclose(e, initial, rtol=1e-10)),
        (IntegratorBackwardEuler(EXACT), lambda e: bool((e < 0.1 * initial).all())),
    ):
        state = start
        for _ in range(150):
            state, _ = integ.step(model, state, control, 2e-3)
            energy = _total_energy(model, state)
            assert torch.isfinite(energy).all()
        assert check(energy), (type(integ).__name__, float(energy / initial))


@pytest.mark.parametrize("zeta", [0.0, 0.1])
def test_newmark_second_order_backward_euler_first_against_modal_solution(zeta):
    """First bending mode released with velocity v0 (Rayleigh damping ratio zeta)."""
    model, rest, control = _beam()
    omega, shape = _first_mode(model, rest)
    if zeta:
        damping = StrainRateDamping(2.0 * zeta / omega, (EnergyTetLinear,))
        model = dataclasses.replace(model, forces=(damping,))
    v0, period = 0.05, 2.0 * math.pi / omega
    omega_d = omega * math.sqrt(1.0 - zeta**2)
    decay = math.exp(-zeta * omega * period)
    exact_pos = rest + shape * v0 / omega_d * decay * math.sin(omega_d * period)
    phase = math.cos(omega_d * period) - zeta * omega / omega_d * math.sin(omega_d * period)
    exact_vel = shape * v0 * decay * phase
    amplitude = (shape * v0 / omega).norm()

    def error(integ, steps):
        state = SimState(rest.clone(), v0 * shape, torch.zeros(1, dtype=DT))
        for _ in range(steps):
            state, _ = integ.step(model, state, control, period / steps)
        return float(
            (state.pos - exact_pos).norm() / amplitude
            + (state.vel - exact_vel).norm() / (amplitude * omega)
        )

    steps = np.array([32, 64, 128])
    errors = {}
    for integ, order in ((IntegratorNewmark(EXACT), 2.0), (IntegratorBackwardEuler(EXACT), 1.0)):
        errors[order] = np.array([error(integ, n) for n in steps])
        slope = -np.polyfit(np.log(steps), np.log(errors[order]), 1)[0]
        assert abs(slope - order) < 0.2, (type(integ).__name__, slope, errors[order])
    assert errors[1.0][-1] > 10 * errors[2.0][-1]


def test_constant_acceleration_is_integrated_exactly():
    mesh = TetMesh.box((2, 2, 2), (0.02, 0.02, 0.02))
    energy = EnergyTetNeoHookean.from_young_poisson(
        torch.full((1, mesh.tet_count), 3e4, dtype=DT), 0.4
    )
    gravity = EnergyGravity(torch.tensor([0.0, 0.0, -9.81], dtype=DT))
    mass = (DENSITY * mesh.vert_volume)[None]
    no_pins = torch.zeros(0, dtype=torch.long)
    model = SimModel(mesh, (energy, gravity), (), mass, no_pins).with_pattern()
    pos = mesh.vert_pos[None].clone()
    state = SimState(pos, torch.zeros_like(pos), torch.zeros(1, dtype=DT))
    dt, steps = 0.01, 10
    for _ in range(steps):
        state, _ = IntegratorNewmark(EXACT).step(model, state, SimControl(pos[:, :0]), dt)
    t = dt * steps

    def field(z):
        return torch.tensor([0.0, 0.0, z], dtype=DT).expand_as(pos)

    assert_close(state.pos - pos, field(-4.905 * t * t), "pos")
    assert_close(state.vel, field(-9.81 * t), "vel")
    assert_close(state.acc, field(-9.81), "acc")


def test_batch_equals_single_runs_and_step_is_pure():
    young = (1e5, 3e5)
    model, rest, control = _beam(young)
    vel = torch.zeros_like(rest)
    vel[..., 2] = 0.1 * rest[..., 0] / LENGTH
    state = SimState(rest.clone(), vel.clone(), torch.zeros(2, dtype=DT))
    integ = IntegratorNewmark(EXACT)
    for _ in range(5):
        state, _ = integ.step(model, state, control, 1e-3)
    for b, e in enumerate(young):
        one, rest1, control1 = _beam((e,))
        single = SimState(rest1.clone(), vel[b : b + 1].clone(), torch.zeros(1, dtype=DT))
        for _ in range(5):
            before = single.pos.clone()
            single, _ = integ.step(one, single, control1, 1e-3)
        assert not torch.equal(single.pos, before)
        assert_close(state.pos[b], single.pos[0], f"pos of instance {b}", atol=1e-12)
        assert_close(state.acc[b], single.acc[0], f"acc of instance {b}", atol=1e-6)


@pytest.mark.parametrize(
    ("beta", "gamma", "field"),
    [
        (0.0, 0.5, "beta"),
        (0.6, 0.5, "beta"),
        (0.25, 0.6, "beta"),  # 2 beta < gamma: only conditionally stable
        (0.25, 0.4, "gamma"),
        (0.5, 1.2, "gamma"),
        (float("nan"), 0.5, "beta"),
    ],
)
def test_bad_parameters_are_named(beta, gamma, field):
    with pytest.raises(ValueError, match=f"IntegratorNewmark.{field} must lie in"):
        IntegratorNewmark(beta=beta, gamma=gamma)


def test_bad_dt_is_named():
    model, rest, control = _beam()
    state = SimState(rest, torch.zeros_like(rest), torch.zeros(1, dtype=DT))
    with pytest.raises(ValueError, match="dt must be > 0"):
        IntegratorNewmark().step(model, state, control, 0.0)
