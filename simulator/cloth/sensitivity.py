"""Material sensitivity tests of thesis Fig. 7.3 and the Table 7.1 multiplier estimates.

* Stretch test: a 0.5 m square hangs from its pinned top edge under gravity;
  ``D = max_u |u - u_0|`` (eq. 7.2) at static equilibrium.
* Bend test: a 0.1 m x 0.02 m strip (2.5 mm mesh, fine enough to resolve the
  root curvature ~ (weight / D)^(1/3)) clamped horizontally along one short edge
  (two vertex columns held) droops under gravity; ``C = max_e |e| acos(n1 . n2) /
  (A1 + A2)`` (eq. 7.3) at rest, after a damped dynamic settle and a static polish.

Every test runs all its materials as one batch. The Table 7.1 estimate of a
fabric's ratio inverts the basis material's curve: the multiplier of
``camel-ponte-roma`` whose test value equals the fabric's (log-log interpolation).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from simulator.cloth.material import ClothMaterial, WangMaterial
from simulator.cloth.model import build_cloth_model
from simulator.forces import AirDamping
from simulator.integrators import IntegratorBackwardEuler, solve_static
from simulator.mesh import TriMesh
from simulator.model import SimControl, SimState
from simulator.solvers import NewtonSettings

__all__ = [
    "bend_test",
    "invert_curve",
    "max_curvature",
    "max_displacement",
    "stretch_test",
]


_STATIC = NewtonSettings(max_iters=40, tol_dx=1e-6, cg_rtol=1e-4, cg_max_iters=500)
"""Equilibrium accuracy of the tests: 1 µm is far below the measured quantities."""


def max_displacement(pos: torch.Tensor, rest: torch.Tensor) -> torch.Tensor:
    """Eq. 7.2: largest vertex displacement from rest [m], shape (B,)."""
    return torch.linalg.vector_norm(pos - rest, dim=-1).amax(dim=-1)


def max_curvature(pos: torch.Tensor, mesh: TriMesh) -> torch.Tensor:
    """Eq. 7.3: largest ``|e| acos(n1 . n2) / (A1 + A2)`` over interior edges [1/m], shape (B,)."""
    x = pos[:, mesh.edge_indices]
    o0, o1, v1, v2 = x.unbind(2)
    n1 = torch.linalg.cross(v1 - o0, v2 - o0, dim=-1)
    n2 = torch.linalg.cross(v2 - o1, v1 - o1, dim=-1)
    a1 = 0.5 * torch.linalg.vector_norm(n1, dim=-1)
    a2 = 0.5 * torch.linalg.vector_norm(n2, dim=-1)
    cos = (n1 * n2).sum(-1) / (4 * a1 * a2)
    angle = torch.arccos(cos.clamp(-1.0, 1.0))
    edge = torch.linalg.vector_norm(v2 - v1, dim=-1)
    return (edge * angle / (a1 + a2)).amax(dim=-1)


def _placed(nu: int, nv: int, size_u: float, size_v: float, origin, axis_u, axis_v) -> TriMesh:
    grid = TriMesh.grid(nu, nv, size_u=size_u, size_v=size_v)
    u, v = grid.uv[:, :1], grid.uv[:, 1:]
    pos = torch.tensor(origin) + u * torch.tensor(axis_u) + v * torch.tensor(axis_v)
    return TriMesh.from_arrays(pos.numpy(), grid.tri_indices.numpy(), grid.uv.numpy())


def stretch_test(material: ClothMaterial, *, vert_per_side: int = 17) -> torch.Tensor:
    """Hang test of every instance; returns D [m], shape (B,)."""
    n = vert_per_side
    mesh = _placed(n, n, 0.5, 0.5, (-0.25, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0))
    pins = torch.arange(n)
    model = build_cloth_model(mesh, material, pins, wind_drag=False)
    batch = material.batch_size
    rest = mesh.vert_pos[None].repeat(batch, 1, 1)
    state = SimState(rest.clone(), torch.zeros_like(rest), torch.zeros(batch, dtype=rest.dtype))
    control = SimControl(pin_pos=rest[:, pins])
    state, _ = solve_static(model, state, control, settings=_STATIC)
    return max_displacement(state.pos, rest)


def bend_test(
    material: ClothMaterial, *, settle_time: float = 0.5, dt: float = 0.005
) -> torch.Tensor:
    """Cantilever fold test of every instance; returns C [1/m], shape (B,)."""
    nu, nv = 41, 9
    mesh = _placed(nu, nv, 0.1, 0.02, (0.0, -0.01, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    clamp = torch.cat([torch.arange(nv) * nu, torch.arange(nv) * nu + 1])
    model = build_cloth_model(mesh, material, clamp, wind_drag=False)
    model = dataclasses.replace(model, forces=(*model.forces, AirDamping(coefficient=0.5)))
    batch = material.batch_size
    rest = mesh.vert_pos[None].repeat(batch, 1, 1)
    state = SimState(rest.clone(), torch.zeros_like(rest), torch.zeros(batch, dtype=rest.dtype))
    control = SimControl(pin_pos=rest[:, clamp])
    integrator = IntegratorBackwardEuler(
        NewtonSettings(max_iters=1, cg_rtol=1e-3, cg_max_iters=400)
    )
    for _ in range(round(settle_time / dt)):
        state, _ = integrator.step(model, state, control, dt)
    state, _ = solve_static(model, state, control, settings=_STATIC)
    return max_curvature(state.pos, mesh)


def invert_curve(multipliers: np.ndarray, values: np.ndarray, target: float) -> float:
    """Multiplier at which a monotone test curve reaches ``target`` (log-log interpolation).

    Extrapolates linearly in log-log space beyond the sampled range.
    """
    x = np.log(np.asarray(multipliers, dtype=np.float64))
    y = np.log(np.asarray(values, dtype=np.float64))
    order = np.argsort(y)
    x, y = x[order], y[order]
    t = np.log(target)
    if t <= y[0]:
        i = 0
    elif t >= y[-1]:
        i = len(y) - 2
    else:
        i = int(np.searchsorted(y, t)) - 1
    slope = (x[i + 1] - x[i]) / (y[i + 1] - y[i])
    return float(np.exp(x[i] + slope * (t - y[i])))


def basis_curves(basis: WangMaterial, multipliers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stretch-test D(p) and bend-test C(k) of the basis material, one batch each."""
    stretch = stretch_test(ClothMaterial.from_wang(basis, stretch_mult=list(multipliers)))
    bend = bend_test(ClothMaterial.from_wang(basis, bend_mult=list(multipliers)))
    return stretch.numpy(), bend.numpy()


THESIS_TABLE_7_1: dict[str, tuple[float, float, float, float]] = {
    "ivory-rib-knit": (1.3817, 1, 2.3, 2),
    "pink-ribbon-brown": (2.9343, 3, 12, 10),
    "camel-ponte-roma": (1, 1, 0.52, 0.5),
    "white-dots-on-blk": (15.8108, 20, 3.5, 4),
    "navy-sparkle-sweat": (0.5613, 0.5, 1.7, 2),
    "gray-interlock": (1.0164, 1, 1.6, 2),
    "11oz-black-denim": (3.6079, 3, 3, 3),
    "white-swim-solid": (1.9126, 2, 2.9, 3),
    "tango-red-jet-set": (1.9784, 2, 1.9, 2),
    "royal-target": (22.2857, 20, 19, 20),
}
"""Thesis Table 7.1: (stretch ratio, its class p, bend ratio, its class k) per fabric."""

SWEEP_MULTIPLIERS = np.geomspace(0.05, 50.0, 13)
"""Multipliers of the basis material sampled for the Fig. 7.3 curves."""


@dataclasses.dataclass(frozen=True)
class FabricStudy:
    """Basis curves and the ten fabrics' test values and estimated ratios."""

    multipliers: np.ndarray
    basis_stretch: np.ndarray
    """D(p) of the basis [m]."""
    basis_bend: np.ndarray
    """C(k) of the basis [1/m]."""
    fabrics: list[str]
    fabric_stretch: np.ndarray
    fabric_bend: np.ndarray
    stretch_ratio: np.ndarray
    bend_ratio: np.ndarray


def fabric_study(multipliers: np.ndarray = SWEEP_MULTIPLIERS) -> FabricStudy:
    """Run both tests on the basis sweep and on the ten measured fabrics."""
    from simulator.cloth.material import BASIS_MATERIAL, load_wang_material, wang_material_names

    basis = load_wang_material(BASIS_MATERIAL)
    stretch_curve, bend_curve = basis_curves(basis, multipliers)
    names = list(wang_material_names())
    fabrics = ClothMaterial.from_wang([load_wang_material(n) for n in names])
    d = stretch_test(fabrics).numpy()
    c = bend_test(fabrics).numpy()
    p = np.array([invert_curve(multipliers, stretch_curve, v) for v in d])
    k = np.array([invert_curve(multipliers, bend_curve, v) for v in c])
    return FabricStudy(multipliers, stretch_curve, bend_curve, names, d, c, p, k)
