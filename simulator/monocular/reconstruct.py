"""Monocular template-based reconstruction of an elastic sheet (the paper §5), frame by frame.

Inputs: the rest template mesh, its material, the calibrated camera, features anchored on the
template and their 2D tracks, and the known boundary vertex positions per frame. For each frame
the shape minimising elastic + bending + image-fitting energy under the boundary conditions is
found by Newton, warm-started from the previous frame. ``model`` picks the elastic law:
``stvk`` (the paper's), or the baselines ``linear`` (small-strain FEM) and ``mass_spring``.
"""

from __future__ import annotations

import dataclasses
import enum
import time

import torch

from ..mesh import TriMesh
from ..model import SimModel
from ..solvers.newton import NewtonSettings
from .bending import EnergyBendingQuadratic
from .camera import PinholeCamera
from .features import FeatureSet
from .image_fit import EnergyImageFit
from .linear import EnergySheetLinear, sheet_mass_spring
from .material import SheetMaterial
from .solve import LinearSolverKind, SparseDirectSystem, StaticPotential, solve_frame
from .stvk import EnergySheetStVK

__all__ = ["ElasticModelKind", "MonocularReconstructor", "ReconstructionResult"]

DEFAULT_SETTINGS = NewtonSettings(max_iters=1, tol_dx=1e-6, cg_rtol=1e-6, cg_max_iters=2000)
"""One Newton iteration per frame (warm start; 2 iterations: ~30 % lower error at half the
rate, see the benchmark table), PCG to 1e-6 when PCG is used."""


class ElasticModelKind(enum.StrEnum):
    """Elastic law of the reconstruction."""

    STVK = "stvk"
    LINEAR = "linear"
    MASS_SPRING = "mass_spring"


@dataclasses.dataclass(frozen=True)
class ReconstructionResult:
    """Reconstructed shapes of a sequence and solver timings."""

    pos: torch.Tensor
    """Vertex positions per frame [m], shape (K, V, 3)."""
    frame_seconds: torch.Tensor
    """Wall time of each frame's solve [s], shape (K,)."""
    newton_iters: torch.Tensor
    """Newton iterations per frame, int64, shape (K,)."""

    @property
    def fps(self) -> float:
        """Frames per second over the sequence (total frames / total solve time)."""
        return float(self.frame_seconds.numel() / self.frame_seconds.sum())


class MonocularReconstructor:
    """Eq. 20 solved per frame: ``min sum W + E_s`` subject to ``v_i = Q_i, i in B``."""

    def __init__(
        self,
        mesh: TriMesh,
        material: SheetMaterial,
        camera: PinholeCamera,
        features: FeatureSet,
        boundary: torch.Tensor,
        *,
        feature_stiffness: float = 1.0e3,
        model: ElasticModelKind | str = ElasticModelKind.STVK,
        solver: LinearSolverKind | str = LinearSolverKind.DIRECT,
        settings: NewtonSettings = DEFAULT_SETTINGS,
    ):
        """Build energies, boundary mask and the linear-solver structure once.

        Args:
            mesh: rest template (flat sheet, float64).
            material: sheet material.
            camera: calibrated camera.
            features: features anchored on ``mesh`` (non-empty).
            boundary: boundary vertex ids, int64 (P,), P >= 1.
            feature_stiffness: k of eq. 18 [N/m].
            model: ``stvk``, ``linear`` or ``mass_spring``.
            solver: ``direct`` (sparse LU) or ``pcg`` (core Newton/PCG).
            settings: Newton tolerances per frame.
        """
        try:
            self.kind = ElasticModelKind(model)
        except ValueError as err:
            allowed = [k.value for k in ElasticModelKind]
            raise ValueError(f"model must be one of {allowed}, got {model!r}") from err
        self.solver = LinearSolverKind(solver)
        boundary = torch.as_tensor(boundary, dtype=torch.int64)
        if boundary.dim() != 1 or boundary.numel() == 0:
            raise ValueError("boundary: at least one fixed vertex is needed (eq. 19)")
        if int(boundary.min()) < 0 or int(boundary.max()) >= mesh.vert_count:
            raise ValueError(f"boundary: vertex ids must lie in [0, {mesh.vert_count - 1}]")
        self.mesh, self.camera, self.features, self.boundary = mesh, camera, features, boundary
        self.settings = settings
        self.image = EnergyImageFit.build(
            mesh,
            features,
            camera,
            torch.zeros(1, features.count, 2, dtype=mesh.vert_pos.dtype),
            stiffness=feature_stiffness,
        )
        bend = EnergyBendingQuadratic.from_mesh(mesh, material.bending_rigidity)
        if self.kind is ElasticModelKind.STVK:
            self.elastic: tuple = (EnergySheetStVK.from_mesh(mesh, material), bend)
        elif self.kind is ElasticModelKind.LINEAR:
            self.elastic = (EnergySheetLinear.from_mesh(mesh, material), bend)
        else:
            self.elastic = (sheet_mass_spring(mesh, material),)
        self.model = SimModel(
            mesh,
            energies=(),
            forces=(),
            vert_mass=torch.zeros(1, mesh.vert_count, dtype=mesh.vert_pos.dtype),
            pin_indices=boundary,
        ).with_pattern()
        self.free = self.model.free_mask()
        self.system = (
            SparseDirectSystem(self.model.pattern, self.free[:, 0] > 0)
            if self.solver is LinearSolverKind.DIRECT
            else None
        )

    def solve(
        self,
        tracks: torch.Tensor,
        boundary_pos: torch.Tensor,
        x_start: torch.Tensor,
        *,
        visible: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, int]:
        """One frame: tracks (N, 2) [px], boundary positions (P, 3) [m], start (V, 3) [m]."""
        image = self.image.with_targets(
            tracks[None], None if visible is None else visible[None].to(tracks)
        )
        objective = StaticPotential(self.model, (*self.elastic, image))
        x0 = x_start.clone()
        x0[self.boundary] = boundary_pos
        x, stats = solve_frame(
            objective, x0[None], self.free, self.settings, solver=self.solver, system=self.system
        )
        return x[0], int(stats.newton_iters[0])

    def reconstruct(
        self,
        tracks: torch.Tensor,
        boundary_pos: torch.Tensor,
        *,
        visible: torch.Tensor | None = None,
    ) -> ReconstructionResult:
        """A whole sequence: tracks (K, N, 2) [px], boundary (K, P, 3) [m], visible (K, N).

        Frame 0 starts from the rest template; every later frame from the previous solution.
        """
        frames = tracks.shape[0]
        if tuple(tracks.shape[1:]) != (self.features.count, 2):
            raise ValueError(
                f"tracks must have shape (K, N, 2) with N = {self.features.count}, "
                f"got {tuple(tracks.shape)}"
            )
        if tuple(boundary_pos.shape) != (frames, self.boundary.numel(), 3):
            raise ValueError(
                f"boundary_pos must have shape (K, P, 3) = ({frames}, {self.boundary.numel()}, 3), "
                f"got {tuple(boundary_pos.shape)}"
            )
        x = self.mesh.vert_pos.clone()
        if self.system is not None:
            self.system.reset()
        out, times, iters = [], [], []
        for k in range(frames):
            tic = time.perf_counter()
            x, n = self.solve(
                tracks[k], boundary_pos[k], x, visible=None if visible is None else visible[k]
            )
            times.append(time.perf_counter() - tic)
            out.append(x)
            iters.append(n)
        return ReconstructionResult(
            torch.stack(out),
            torch.tensor(times, dtype=torch.float64),
            torch.tensor(iters, dtype=torch.int64),
        )
