"""Dynamic elastic bodies for UKF estimation: the measurement function g and test problems.

:class:`FrameMeasurement` is *thesis* Algorithm 2's "measurement computation": from three
observed frames it initialises the hidden state at frame n (positions ``y_n``; velocity
from eqs. 4.23-4.24 as ``u' + (dt - h)/2 u''``, the velocity that backward Euler with step
``h`` carries, which lags the true one by ``h/2 u''``), and simulates every sigma point to
frame n+1 as *one batch* of instances with the core's backward-Euler integrator; the
prediction is the observed (surface) vertex positions. Unobserved (interior) vertices are
hidden state: the first frame gets them from an affine fit of the observed displacement,
later frames from the mean sigma point's simulation of the previous update (coupled state
estimation, *thesis* §4.2.5).

Problems (each returns a :class:`DynamicProblem`):

* :func:`spring_strip_problem`: a hanging mass-spring strip under gravity (known-answer test);
* :func:`tet_beam_problem`: a tetrahedral linear-elastic beam (*thesis* §4.2.2: linear Lamé
  material, nu = 0.45) clamped at one end and driven by a known time-varying end traction,
  the stand-in for the thesis's synthetic heart with its computed contraction force;
* :func:`dropped_ball_problem`: a tetrahedral ball dropped on the ground, gravity the only
  load (*thesis* §4.3.2).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import torch

from ..energies.gravity import EnergyGravity
from ..energies.ground import EnergyGroundPlane
from ..energies.loads import EnergyNodalForce
from ..energies.springs import EnergyMassSpring
from ..energies.tet import EnergyTetCorotated, EnergyTetLinear
from ..integrators.backward_euler import IntegratorBackwardEuler
from ..mesh import TriMesh
from ..model import SimControl, SimModel, SimState
from ..solvers.newton import NewtonSettings
from ..tetmesh import TetMesh

__all__ = [
    "DynamicProblem",
    "FrameMeasurement",
    "dropped_ball_problem",
    "rollout",
    "spring_strip_problem",
    "tet_beam_problem",
]

GRAVITY = (0.0, 0.0, -9.81)
"""Gravitational acceleration [m/s²]."""


@dataclasses.dataclass(frozen=True)
class DynamicProblem:
    """A body whose single material parameter (log of a modulus) the UKF estimates."""

    name: str
    model: SimModel
    """Template model of one instance (mesh, pattern, pins, masses (1, V)); energies unused."""
    energies_for: Callable[[torch.Tensor, float], tuple]
    """``(modulus (S,), time [s]) -> energies`` of S instances at that time."""
    pin_pos: Callable[[float], torch.Tensor]
    """Pinned-vertex targets at a time [m], shape (P, 3)."""
    init_pos: torch.Tensor
    """Positions at t = 0 [m], shape (V, 3)."""
    init_vel: torch.Tensor
    """Velocities at t = 0 [m/s], shape (V, 3)."""
    observed: torch.Tensor
    """Tracked (surface) vertex ids, int64, shape (Vo,)."""
    dt: float
    """Frame interval [s]."""
    substeps: int
    """Integrator steps per frame in the estimator's model."""
    settings: NewtonSettings

    def batch_model(self, modulus: torch.Tensor, time: float) -> SimModel:
        """The template with S instances of the given moduli [Pa] at ``time``."""
        batch = modulus.shape[0]
        return dataclasses.replace(
            self.model,
            energies=self.energies_for(modulus, time),
            vert_mass=self.model.vert_mass.expand(batch, -1),
        )

    def control(self, time: float, batch: int) -> SimControl:
        """Pin targets for S instances."""
        return SimControl(pin_pos=self.pin_pos(time)[None].expand(batch, -1, -1))


def _advance(problem: DynamicProblem, modulus, state: SimState, t0: float, substeps: int):
    """Integrate a batch over one frame interval with ``substeps`` backward-Euler steps."""
    h = problem.dt / substeps
    integ = IntegratorBackwardEuler(problem.settings)
    batch = modulus.shape[0]
    for i in range(substeps):
        t1 = t0 + (i + 1) * h
        state, _ = integ.step(
            problem.batch_model(modulus, t1), state, problem.control(t1, batch), h
        )
    return state


def rollout(
    problem: DynamicProblem, modulus: torch.Tensor, frames: int, *, substeps: int | None = None
) -> torch.Tensor:
    """Positions of every frame for moduli (S,) [Pa], shape (K, S, V, 3), frame 0 at t = 0."""
    substeps = substeps or problem.substeps
    batch = modulus.shape[0]
    state = SimState(
        problem.init_pos[None].expand(batch, -1, -1).clone(),
        problem.init_vel[None].expand(batch, -1, -1).clone(),
        torch.zeros(batch, dtype=problem.init_pos.dtype),
    )
    out = [state.pos]
    for k in range(frames - 1):
        state = _advance(problem, modulus, state, k * problem.dt, substeps)
        out.append(state.pos)
    return torch.stack(out)


def _affine_extend(rest: torch.Tensor, observed: torch.Tensor, values: torch.Tensor):
    """Least-squares affine map of rest positions fitted to observed values, at all vertices."""
    design = torch.cat([rest, torch.ones_like(rest[:, :1])], 1)
    coef = torch.linalg.lstsq(design[observed], values).solution
    return design @ coef


class FrameMeasurement:
    """``g(x_n, w)``: observed positions at frame n+1 simulated from frame n (see module doc)."""

    def __init__(self, problem: DynamicProblem, observations: torch.Tensor):
        """Observations: tracked positions of ``problem.observed`` per frame, (K, Vo, 3) [m]."""
        vo = problem.observed.numel()
        if observations.dim() != 3 or tuple(observations.shape[1:]) != (vo, 3):
            raise ValueError(
                f"observations must have shape (K, {vo}, 3), got {tuple(observations.shape)}"
            )
        if vo == 0:
            raise ValueError("observed: the target surface has no vertices")
        self.problem = problem
        self.observations = observations
        self.group_size: int | None = None
        """Sigma points per filter when several filters share a batch (None: one filter)."""
        self._carry: tuple[int, torch.Tensor, torch.Tensor] | None = None

    def state_at(self, n: int, groups: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
        """Hidden state (positions, velocities) (G, V, 3) at frame n from frames n-1, n, n+1."""
        p = self.problem
        y = self.observations
        vel_fd = (y[n] - y[n - 1]) / p.dt  # eq. 4.23
        acc_fd = (y[n + 1] - 2.0 * y[n] + y[n - 1]) / p.dt**2  # eq. 4.24
        # Backward Euler's velocity lags the true one by h/2 times the acceleration, so the
        # integrator-consistent estimate is u' + (dt - h)/2 u'' (= eq. 4.23 alone when h = dt).
        vel_obs = vel_fd + 0.5 * (p.dt - p.dt / p.substeps) * acc_fd
        if self._carry is not None and self._carry[0] == n and self._carry[1].shape[0] == groups:
            pos, vel = self._carry[1].clone(), self._carry[2].clone()
        else:
            rest = p.init_pos
            pos = _affine_extend(rest, p.observed, y[n])[None].repeat(groups, 1, 1)
            vel = _affine_extend(rest, p.observed, vel_obs)[None].repeat(groups, 1, 1)
        pos[:, p.observed] = y[n]
        vel[:, p.observed] = vel_obs
        if p.model.pin_indices.numel():
            pos[:, p.model.pin_indices] = p.pin_pos(n * p.dt)
        return pos, vel

    def __call__(self, sigma: torch.Tensor, n: int) -> torch.Tensor:
        """Predictions (G S, 3 Vo) for G groups of S sigma points (G S, 1) of log-modulus.

        The groups (independent filters, ``group_size`` rows each) run as one batch; each
        group's first row (its mean) carries that group's hidden interior state forward.
        """
        p = self.problem
        size = self.group_size or sigma.shape[0]
        groups = sigma.shape[0] // size
        modulus = torch.exp(sigma[:, 0]).to(p.init_pos.dtype)
        pos, vel = self.state_at(n, groups)
        state = SimState(
            pos.repeat_interleave(size, 0),
            vel.repeat_interleave(size, 0),
            torch.full((sigma.shape[0],), n * p.dt, dtype=pos.dtype),
        )
        state = _advance(p, modulus, state, n * p.dt, p.substeps)
        means = torch.arange(groups) * size
        self._carry = (n + 1, state.pos[means].clone(), state.vel[means].clone())
        return state.pos[:, p.observed].reshape(sigma.shape[0], -1)

    def reset(self) -> None:
        """Forget the carried hidden state (start of a new pass)."""
        self._carry = None


def spring_strip_problem(*, dt: float = 0.01, substeps: int = 2) -> DynamicProblem:
    """A 2 x 6 mass-spring strip hanging from its top edge, released unstretched.

    The unknown is the stretch stiffness (``k0 = k2``) [N/m] of the springs' membrane law.
    """
    mesh = TriMesh.grid(2, 6, size_u=0.05, size_v=0.15)
    top = torch.nonzero(mesh.uv[:, 1] >= mesh.uv[:, 1].max() - 1e-9).flatten()
    pos = mesh.vert_pos.clone()
    pos = torch.stack([pos[:, 0], torch.zeros_like(pos[:, 0]), pos[:, 1]], 1)  # hang in x-z
    mass = torch.full((1, mesh.vert_count), 0.01, dtype=pos.dtype)
    model = SimModel(mesh, (), (), mass, top).with_pattern()
    gravity = EnergyGravity(torch.tensor(GRAVITY, dtype=pos.dtype))
    bending = torch.zeros(1, 3, 5, dtype=pos.dtype)

    def energies_for(modulus, time):
        rows = torch.stack([modulus, 0.0 * modulus, modulus, 0.5 * modulus], -1)[:, None].expand(
            -1, 6, -1
        )
        springs = EnergyMassSpring.from_material(
            mesh, rows, bending.expand(modulus.shape[0], -1, -1)
        )
        return (springs, gravity)

    rest_top = pos[top].clone()
    return DynamicProblem(
        "spring_strip",
        dataclasses.replace(model, mesh=dataclasses.replace(mesh, vert_pos=pos)),
        energies_for,
        lambda t: rest_top,
        pos,
        torch.zeros_like(pos),
        torch.arange(mesh.vert_count),
        dt,
        substeps,
        NewtonSettings(max_iters=4, tol_dx=1e-9, cg_rtol=1e-8, cg_max_iters=200),
    )


def tet_beam_problem(
    *,
    load_modulus: float,
    cells: tuple[int, int, int] = (8, 3, 3),
    size: tuple[float, float, float] = (0.08, 0.03, 0.03),
    density: float = 1000.0,
    poisson_ratio: float = 0.45,
    dt: float = 0.01,
    substeps: int = 2,
) -> DynamicProblem:
    """Tet beam clamped at x = 0, driven by a known traction on its x = L end.

    The end force is ``F(t) = s(t) E_load A (0.02 sin(2 pi 2 t), 0, 0.003 (1 - cos(2 pi 3 t)))``
    with a smooth 0.1 s ramp s(t): like the thesis's contraction force it is computed from an
    assumed modulus (``load_modulus`` [Pa]) so that every ground truth deforms by a similar
    amount (tip motion ~2 mm axial, ~8 mm transverse).
    """
    mesh = TetMesh.box(cells, size)
    clamp = torch.nonzero(mesh.vert_pos[:, 0] <= 1e-9).flatten()
    tip = torch.nonzero(mesh.vert_pos[:, 0] >= size[0] - 1e-9).flatten()
    mass = (density * mesh.vert_volume)[None]
    model = SimModel(mesh, (), (), mass, clamp).with_pattern()
    area = size[1] * size[2]
    share = torch.zeros(1, mesh.vert_count, 1, dtype=mesh.vert_pos.dtype)
    share[0, tip] = 1.0 / tip.numel()

    def force_at(t):
        ramp = min(t / 0.1, 1.0)
        ramp = ramp * ramp * (3.0 - 2.0 * ramp)
        scale = ramp * load_modulus * area
        return (
            torch.tensor(
                [
                    0.02 * math.sin(2 * math.pi * 2.0 * t),
                    0.0,
                    0.003 * (1.0 - math.cos(2 * math.pi * 3.0 * t)),
                ],
                dtype=mesh.vert_pos.dtype,
            )
            * scale
        )

    def energies_for(modulus, time):
        elastic = EnergyTetLinear.from_young_poisson(modulus, poisson_ratio, mesh.tet_count)
        return (elastic, EnergyNodalForce(share * force_at(time)))

    rest_clamp = mesh.vert_pos[clamp].clone()
    return DynamicProblem(
        "tet_beam",
        model,
        energies_for,
        lambda t: rest_clamp,
        mesh.vert_pos.clone(),
        torch.zeros_like(mesh.vert_pos),
        mesh.surface_vertices(),
        dt,
        substeps,
        NewtonSettings(max_iters=3, tol_dx=1e-9, cg_rtol=1e-8, cg_max_iters=500),
    )


def dropped_ball_problem(
    *,
    radius: float = 0.03,
    mesh_size: float = 0.012,
    density: float = 400.0,
    poisson_ratio: float = 0.45,
    drop_speed: float = 1.0,
    gap: float = 0.002,
    dt: float = 5e-4,
    substeps: int = 2,
    ground_stiffness: float = 2.0e4,
) -> DynamicProblem:
    """A ball (gmsh tets) falling onto the ground at ``drop_speed`` [m/s]; gravity only.

    Co-rotated linear elasticity (the ball rotates and flattens; plain linear FEM would
    inflate under rotation). Penalty contact with ``z = 0``, frictionless; no pins.
    """
    from ..meshing import sphere_in_cube

    full = sphere_in_cube(
        cube_size=4.0 * radius,
        sphere_radius=radius,
        mesh_size=2.0 * mesh_size,
        sphere_mesh_size=mesh_size,
    )
    mesh, _ = full.submesh(full.tet_region == 0)
    pos = mesh.vert_pos + torch.tensor([0.0, 0.0, radius + gap], dtype=mesh.vert_pos.dtype)
    mesh = dataclasses.replace(mesh, vert_pos=pos)
    mass = (density * mesh.vert_volume)[None]
    model = SimModel(mesh, (), (), mass, torch.zeros(0, dtype=torch.int64)).with_pattern()
    gravity = EnergyGravity(torch.tensor(GRAVITY, dtype=pos.dtype))
    ground = EnergyGroundPlane(ground_stiffness)

    def energies_for(modulus, time):
        elastic = EnergyTetCorotated.from_young_poisson(modulus, poisson_ratio, mesh.tet_count)
        return (elastic, gravity, ground)

    vel = torch.zeros_like(pos)
    vel[:, 2] = -drop_speed
    empty = torch.zeros(0, 3, dtype=pos.dtype)
    return DynamicProblem(
        "dropped_ball",
        model,
        energies_for,
        lambda t: empty,
        pos,
        vel,
        mesh.surface_vertices(),
        dt,
        substeps,
        NewtonSettings(max_iters=4, tol_dx=1e-9, cg_rtol=1e-8, cg_max_iters=500),
    )
