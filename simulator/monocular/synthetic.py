"""Synthetic ground truth for the monocular benchmark (the paper §7.1-7.2), by our simulator.

A 100 x 100 mm sheet, 10 mm thick, E = 0.25 MPa, clamped on its left side; the right side is
gripped and moved rigidly: pulled to 130 % length, lifted and twisted about the pull axis,
while an unknown normal force pushes a central patch. Each frame is the static equilibrium
(quasi-static, as the paper assumes) of the *core's* membrane (deformation-gradient
St Venant-Kirchhoff, :class:`simulator.energies.membrane.EnergyMembraneWang` with the
isotropic plane-stress law) plus dihedral bending on a finer checkerboard grid than any
reconstruction mesh, so the reconstruction never sees its own discretisation (no inverse
crime). Features are points on the rest sheet, half uniform and half in texture-like
clusters, projected through the camera; noise, and an occluded region whose tracks freeze and
drift once it is hidden, are added in :func:`make_tracks`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from ..energies.bending import EnergyBendingDihedral
from ..energies.loads import EnergyNodalForce
from ..energies.membrane import EnergyMembraneWang
from ..mesh import TriMesh
from ..model import SimModel
from ..solvers.newton import NewtonSettings
from .camera import PinholeCamera, look_at
from .material import SheetMaterial
from .sheet import edge_vertices
from .solve import SparseDirectSystem, StaticPotential, solve_frame

__all__ = [
    "SheetScenario",
    "SheetSequence",
    "make_tracks",
    "simulate_sheet",
]


@dataclasses.dataclass(frozen=True)
class SheetScenario:
    """Parameters of the synthetic stretching sequence (defaults: the paper's sheet)."""

    material: SheetMaterial = dataclasses.field(
        default_factory=lambda: SheetMaterial(0.25e6, 0.45, 0.01)
    )
    size: float = 0.1
    """Sheet side [m]."""
    frames: int = 60
    max_stretch: float = 1.3
    """Final length / rest length of the pulled sheet."""
    lift: float = 0.015
    """Final lift of the gripped side along +z [m]."""
    twist_deg: float = 30.0
    """Final rotation of the gripped side about the pull (x) axis [deg]."""
    push_force: float = 8.0
    """Final total normal force on the central patch [N]."""
    push_radius: float = 0.015
    """Radius of the pushed patch [m]."""
    gt_vert_per_side: int = 41
    """Ground-truth grid resolution (checkerboard triangulation)."""
    camera_distance: float = 0.22
    camera_elevation_deg: float = 55.0
    """Angle of the viewing direction above the sheet plane [deg] (90 = head on)."""

    def camera(self) -> PinholeCamera:
        """The paper's virtual camera K = diag(500, 500, 1), looking obliquely at the sheet."""
        centre = torch.tensor([0.5 * self.max_stretch * self.size, 0.5 * self.size, 0.0])
        el = math.radians(self.camera_elevation_deg)
        eye = centre + self.camera_distance * torch.tensor([0.0, -math.cos(el), math.sin(el)])
        return look_at(eye, centre, torch.tensor([0.0, 1.0, 0.0]), focal=500.0)

    def gripper_pose(self, s: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Rotation (3, 3) and translation (3,) [m] of the gripped side at progress s in [0, 1]."""
        ang = math.radians(self.twist_deg) * s
        c, si = math.cos(ang), math.sin(ang)
        rot = torch.tensor([[1.0, 0.0, 0.0], [0.0, c, -si], [0.0, si, c]], dtype=torch.float64)
        pivot = torch.tensor([self.size, 0.5 * self.size, 0.0], dtype=torch.float64)
        shift = torch.tensor(
            [
                (self.max_stretch - 1.0) * self.size * s,
                0.0,
                self.lift * math.sin(0.5 * math.pi * s),
            ],
            dtype=torch.float64,
        )
        return rot, pivot + shift - rot @ pivot

    def boundary_positions(self, rest: torch.Tensor, right: torch.Tensor, s: float) -> torch.Tensor:
        """Positions [m] of boundary points with rest positions rest (P, 3) at progress s."""
        rot, trans = self.gripper_pose(s)
        moved = rest @ rot.T + trans
        return torch.where(right[:, None], moved, rest)


@dataclasses.dataclass(frozen=True)
class SheetSequence:
    """Ground-truth shapes of the synthetic sequence."""

    mesh: TriMesh
    """Ground-truth mesh (rest)."""
    pos: torch.Tensor
    """Positions per frame [m], shape (K, V, 3)."""
    progress: torch.Tensor
    """Load progress s of each frame in [0, 1], shape (K,)."""


def simulate_sheet(scenario: SheetScenario) -> SheetSequence:
    """Quasi-static ground truth: equilibrium of each frame, warm-started from the last."""
    mesh = TriMesh.grid(scenario.gt_vert_per_side, size_u=scenario.size)
    mat = scenario.material
    dtype = mesh.vert_pos.dtype
    membrane = EnergyMembraneWang(
        torch.tensor(mat.stiffness_rows(), dtype=dtype)[None], torch.zeros(1, 8, dtype=dtype)
    )
    bend = EnergyBendingDihedral.from_material(
        mesh,
        torch.full((1, 3, 5), mat.bending_rigidity, dtype=dtype),
        curvature_dependent=False,
        anisotropic=False,
    )
    left, right = edge_vertices(mesh, "left"), edge_vertices(mesh, "right")
    pins = torch.cat([left, right])
    is_right = torch.cat(
        [torch.zeros_like(left, dtype=torch.bool), torch.ones_like(right, dtype=torch.bool)]
    )
    centre = torch.tensor([0.5, 0.5], dtype=dtype) * scenario.size
    patch = torch.linalg.vector_norm(mesh.uv - centre, dim=1) <= scenario.push_radius
    area = mesh.vert_area * patch
    normal_load = torch.zeros(1, mesh.vert_count, 3, dtype=dtype)
    normal_load[0, :, 2] = area / area.sum()
    model = SimModel(
        mesh, (), (), torch.zeros(1, mesh.vert_count, dtype=dtype), pins
    ).with_pattern()
    free = model.free_mask()
    system = SparseDirectSystem(model.pattern, free[:, 0] > 0)
    settings = NewtonSettings(max_iters=40, tol_dx=1e-8)
    progress = torch.linspace(0.0, 1.0, scenario.frames, dtype=dtype)
    x = mesh.vert_pos.clone()[None]
    frames = []
    for s in progress.tolist():
        push = EnergyNodalForce(normal_load * scenario.push_force * s * s)
        x = x.clone()
        x[0, pins] = scenario.boundary_positions(mesh.vert_pos[pins], is_right, s)
        objective = StaticPotential(model, (membrane, bend, push), regularization=1e-9)
        x, _ = solve_frame(objective, x, free, settings, system=system)
        frames.append(x[0])
    return SheetSequence(mesh, torch.stack(frames), progress)


def make_tracks(
    points: torch.Tensor,
    camera: PinholeCamera,
    *,
    noise_px: float,
    seed: int,
    occluded: torch.Tensor | None = None,
    occlusion_start: int | None = None,
    drift_px: float = 0.0,
) -> torch.Tensor:
    """Tracked pixels (K, N, 2) of 3D feature trajectories ``points`` (K, N, 3) [m].

    Gaussian pixel noise of std ``noise_px``; features flagged in ``occluded`` (N,) lose
    their target from frame ``occlusion_start`` on: as an optical-flow tracker does, they
    stay at their last seen pixel and drift by a random walk of ``drift_px`` px per frame.
    """
    if noise_px < 0:
        raise ValueError(f"noise_px must be >= 0 px, got {noise_px}")
    gen = torch.Generator().manual_seed(int(seed))
    pix = camera.project(points)
    pix = pix + noise_px * torch.randn(pix.shape, generator=gen, dtype=pix.dtype)
    if occluded is not None and occlusion_start is not None and bool(occluded.any()):
        k0 = int(occlusion_start)
        steps = drift_px * torch.randn(pix.shape, generator=gen, dtype=pix.dtype)
        walk = torch.cumsum(steps[k0:], dim=0)
        frozen = pix[k0 - 1 : k0].expand_as(walk) + walk
        pix[k0:, occluded] = frozen[:, occluded]
    return pix


def sample_feature_uv(
    size: float, count: int, *, seed: int, clusters: int = 6
) -> tuple[np.ndarray, np.ndarray]:
    """Rest positions (N, 2) [m] and detection scores (N,) of candidate features.

    Half are uniform, half in Gaussian "texture" clusters (SURF-like detectors bunch up on
    texture); scores are uniform in [0, 1), cluster features get a bonus of 0.5 (strong
    texture gives strong responses). Points are kept 1 % of the side inside the sheet.
    """
    rng = np.random.default_rng(seed)
    n_uniform = count // 2
    uniform = rng.uniform(0.0, size, size=(n_uniform, 2))
    centres = rng.uniform(0.15 * size, 0.85 * size, size=(clusters, 2))
    which = rng.integers(0, clusters, size=count - n_uniform)
    clustered = centres[which] + rng.normal(0.0, 0.06 * size, size=(count - n_uniform, 2))
    uv = np.clip(np.concatenate([uniform, clustered]), 0.01 * size, 0.99 * size)
    scores = rng.uniform(0.0, 1.0, size=count)
    scores[n_uniform:] += 0.5
    return uv, scores
