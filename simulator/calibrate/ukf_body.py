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
* :func:`heart_problem`: the gmsh biventricular heart (:func:`simulator.tissue.meshing.heart`), base
  fixed, linear Lamé walls (nu = 0.45), driven by a known contraction force computed from an
  assumed modulus and integrated with Newmark, as in *thesis* §4.2.2 and §4.3.1;
* :func:`dropped_ball_problem`: a tetrahedral ball dropped on the ground, gravity the only
  load (*thesis* §4.3.2).

Each problem names its integrator: backward Euler (default) or Newmark (average
acceleration). With Newmark the hidden state at frame n is the thesis's ``[u, u', u'']``
(eq. 4.3): the velocity is the central difference ``u' + dt/2 u''`` (Newmark carries the
true velocity) and the acceleration is eq. 4.24.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import torch

from simulator.energies.gravity import EnergyGravity
from simulator.energies.ground import EnergyGroundPlane
from simulator.energies.loads import EnergyNodalForce, surface_traction_forces
from simulator.energies.springs import EnergyMassSpring
from simulator.energies.tet import EnergyTetCorotated, EnergyTetLinear
from simulator.integrators.backward_euler import IntegratorBackwardEuler
from simulator.integrators.newmark import IntegratorNewmark
from simulator.mesh import TriMesh
from simulator.model import SimControl, SimModel, SimState
from simulator.solvers.newton import NewtonSettings
from simulator.tetmesh import TetMesh

__all__ = [
    "BEAM_CELLS",
    "HEART_MESH_SIZE",
    "INTEGRATORS",
    "DynamicProblem",
    "FrameMeasurement",
    "dropped_ball_problem",
    "heart_problem",
    "rollout",
    "spring_strip_problem",
    "tet_beam_problem",
]

GRAVITY = (0.0, 0.0, -9.81)
"""Gravitational acceleration [m/s²]."""
BEAM_CELLS = (8, 3, 3)
"""Cells of the tet beam along x, y, z."""
HEART_MESH_SIZE = 0.007
"""gmsh element size of the heart [m]."""
INTEGRATORS = {"backward_euler": IntegratorBackwardEuler, "newmark": IntegratorNewmark}
"""Time integrators a problem can name."""


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
    integrator: str = "backward_euler"
    """Key of :data:`INTEGRATORS` used by the estimator and the ground truth."""

    def __post_init__(self):
        if self.integrator not in INTEGRATORS:
            raise ValueError(
                f"integrator must be one of {sorted(INTEGRATORS)}, got {self.integrator!r}"
            )

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
    """Integrate a batch over one frame interval with ``substeps`` integrator steps."""
    h = problem.dt / substeps
    integ = INTEGRATORS[problem.integrator](problem.settings)
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


def _rows(state: SimState, rows: torch.Tensor) -> SimState:
    """A copy of the given batch rows of every field."""
    fields = (state.pos, state.vel, state.time, state.acc)
    return SimState(*(None if v is None else v[rows].clone() for v in fields))


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
        self._carry: tuple[int, SimState] | None = None

    def state_at(self, n: int, groups: int = 1) -> SimState:
        """Hidden state (G instances) at frame n from frames n-1, n, n+1 (``acc``: Newmark)."""
        p = self.problem
        y = self.observations
        vel_fd = (y[n] - y[n - 1]) / p.dt  # eq. 4.23
        acc_fd = (y[n + 1] - 2.0 * y[n] + y[n - 1]) / p.dt**2  # eq. 4.24
        newmark = p.integrator == "newmark"
        # Backward Euler's velocity lags the true one by h/2 times the acceleration, so the
        # integrator-consistent estimate is u' + (dt - h)/2 u'' (= eq. 4.23 alone when h = dt);
        # Newmark carries the true velocity, u' + dt/2 u''.
        lag = 0.0 if newmark else p.dt / p.substeps
        vel_obs = vel_fd + 0.5 * (p.dt - lag) * acc_fd
        if (
            self._carry is not None
            and self._carry[0] == n
            and self._carry[1].pos.shape[0] == groups
        ):
            carried = self._carry[1]
            pos, vel = carried.pos.clone(), carried.vel.clone()
            acc = carried.acc.clone() if newmark else None
        else:
            rest = p.init_pos
            pos = _affine_extend(rest, p.observed, y[n])[None].repeat(groups, 1, 1)
            vel = _affine_extend(rest, p.observed, vel_obs)[None].repeat(groups, 1, 1)
            acc = None
            if newmark:
                acc = _affine_extend(rest, p.observed, acc_fd)[None].repeat(groups, 1, 1)
        pos[:, p.observed] = y[n]
        vel[:, p.observed] = vel_obs
        if acc is not None:
            acc[:, p.observed] = acc_fd
        if p.model.pin_indices.numel():
            pos[:, p.model.pin_indices] = p.pin_pos(n * p.dt)
            if acc is not None:
                acc[:, p.model.pin_indices] = 0.0
        return SimState(pos, vel, torch.full((groups,), n * p.dt, dtype=pos.dtype), acc)

    def __call__(self, sigma: torch.Tensor, n: int) -> torch.Tensor:
        """Predictions (G S, 3 Vo) for G groups of S sigma points (G S, 1) of log-modulus.

        The groups (independent filters, ``group_size`` rows each) run as one batch; each
        group's first row (its mean) carries that group's hidden interior state forward.
        """
        p = self.problem
        size = self.group_size or sigma.shape[0]
        groups = sigma.shape[0] // size
        modulus = torch.exp(sigma[:, 0]).to(p.init_pos.dtype)
        start = self.state_at(n, groups)
        state = _rows(start, torch.arange(groups).repeat_interleave(size))
        state = _advance(p, modulus, state, n * p.dt, p.substeps)
        self._carry = (n + 1, _rows(state, torch.arange(groups) * size))
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
    cells: tuple[int, int, int] = BEAM_CELLS,
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


def heart_problem(
    *,
    load_modulus: float,
    mesh_size: float = HEART_MESH_SIZE,
    density: float = 1060.0,
    poisson_ratio: float = 0.45,
    contraction: float = 0.05,
    beat: float = 0.4,
    dt: float = 0.01,
    substeps: int = 2,
    integrator: str = "newmark",
) -> DynamicProblem:
    """Biventricular heart (gmsh), base fixed, squeezed by a known contraction force.

    The contraction force is a dead traction on the epicardium, inward along the normal plus
    an apex-to-base (longitudinal shortening) part that grows towards the apex,
    ``t = s(t) c E_load (-n + 0.5 (-z / 65 mm) e_z)`` with ``s(t) = sin²(pi t / beat)``
    (systole, then diastole). Like the thesis's it is computed from an assumed modulus
    (``load_modulus`` [Pa]), so every ground truth deforms alike: with c = 0.05 the
    epicardium moves ~2 mm on average (5 mm at most) at end-systole.
    """
    from simulator.tissue.meshing import HEART_ELLIPSOIDS, heart

    if not contraction > 0:
        raise ValueError(f"contraction must be > 0 (traction / modulus), got {contraction}")
    if not beat > 0:
        raise ValueError(f"beat must be > 0 s, got {beat}")
    body = heart(mesh_size)
    mesh = body.mesh
    x = mesh.vert_pos
    tris = body.epicardium_tris
    normal = torch.linalg.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]])
    normal = normal / torch.linalg.vector_norm(normal, dim=-1, keepdim=True)
    apex_depth = HEART_ELLIPSOIDS["lv_outer"][1][2]
    depth = (-x[tris].mean(1)[:, 2] / apex_depth).clamp(0.0, 1.0)
    pattern = -normal + 0.5 * depth[:, None] * normal.new_tensor([0.0, 0.0, 1.0])
    unit_force = surface_traction_forces(x, tris, contraction * pattern)  # per Pa of E_load
    mass = (density * mesh.vert_volume)[None]
    model = SimModel(mesh, (), (), mass, body.base_verts).with_pattern()

    def energies_for(modulus, time):
        elastic = EnergyTetLinear.from_young_poisson(modulus, poisson_ratio, mesh.tet_count)
        phase = math.sin(math.pi * min(time / beat, 1.0)) ** 2
        return (elastic, EnergyNodalForce(phase * load_modulus * unit_force))

    rest_base = x[body.base_verts].clone()
    # Linear walls under dead loads: one Newton step with an exact linear solve is exact.
    # Sparse LU wins on the default mesh (592 vertices: 1.5x faster than PCG), PCG on fine
    # ones (2,522 vertices: 4x faster), measured single-threaded.
    settings = NewtonSettings(max_iters=1, tol_dx=1e-9, linear_solver="direct")
    if mesh.vert_count > 1500:
        settings = NewtonSettings(max_iters=1, tol_dx=1e-9, cg_rtol=1e-10, cg_max_iters=2000)
    return DynamicProblem(
        "heart",
        model,
        energies_for,
        lambda t: rest_base,
        x.clone(),
        torch.zeros_like(x),
        mesh.surface_vertices(),
        dt,
        substeps,
        settings,
        integrator,
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
    from simulator.tissue.meshing import sphere_in_cube

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
