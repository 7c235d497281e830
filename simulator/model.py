"""Static model, dynamic state and per-step control of a batch of simulations.

All three are frozen dataclasses (MJX/newton style): the integrator's ``step``
never mutates them, and updates go through ``dataclasses.replace``. Topology
and rest data are shared by the batch; everything with a leading ``B`` is per
instance.
"""

from __future__ import annotations

import dataclasses

import torch

from .mesh import TriMesh
from .solvers.block_sparse import BlockPattern
from .solvers.coarse import grid_aggregates
from .tetmesh import TetMesh, voxel_aggregates

AGGREGATE_PATCH = 4
"""Vertices per side of a coarse aggregate (best measured in benchmarks/precond_bench.py)."""

TET_AGGREGATE_PATCH = 3
"""Vertices per side of a coarse aggregate on tet meshes (about 27 vertices each)."""

__all__ = ["SimControl", "SimModel", "SimState"]


def _to(obj, device=None, dtype=None):
    changes = {}
    for field in dataclasses.fields(obj):
        value = getattr(obj, field.name)
        if isinstance(value, torch.Tensor):
            changes[field.name] = value.to(
                device=device, dtype=dtype if value.is_floating_point() else None
            )
        elif isinstance(value, tuple) and value and hasattr(value[0], "to"):
            changes[field.name] = tuple(v.to(device=device, dtype=dtype) for v in value)
        elif hasattr(value, "to") and not isinstance(value, torch.Tensor):
            changes[field.name] = value.to(device=device, dtype=dtype)
    return dataclasses.replace(obj, **changes)


@dataclasses.dataclass(frozen=True)
class SimModel:
    """What does not change during a rollout."""

    mesh: TriMesh | TetMesh
    """Shared topology: a cloth :class:`TriMesh` or a tissue :class:`TetMesh`."""
    energies: tuple
    """Conservative terms (:class:`simulator.energies.base.Energy`)."""
    forces: tuple
    """Velocity-dependent and non-conservative forces (:mod:`simulator.forces`)."""
    vert_mass: torch.Tensor
    """Lumped vertex masses [kg], shape (B, V)."""
    pin_indices: torch.Tensor
    """Vertices held by Dirichlet conditions, int64, shape (P,)."""
    pattern: BlockPattern | None = None
    """Hessian sparsity of the shared-topology energies (see :meth:`with_pattern`)."""
    aggregates: torch.Tensor | None = None
    """Coarse-level aggregate id per vertex for the two-level preconditioner, int64 (V,)."""

    def with_pattern(self) -> SimModel:
        """Attach the block-sparse Hessian pattern of the mesh's elements and the aggregates.

        Cloth: triangles and bending hinges, aggregates from the 2D material coordinates.
        Tissue: tets, aggregates from 3D voxel cells of the rest positions.
        """
        mesh = self.mesh
        if isinstance(mesh, TetMesh):
            device = mesh.tet_indices.device
            pattern = BlockPattern.from_topologies(mesh.vert_count, [mesh.tet_indices.cpu()])
            aggregates = None
            if mesh.vert_count >= TET_AGGREGATE_PATCH**3 * 4:
                aggregates = voxel_aggregates(mesh.vert_pos.cpu(), TET_AGGREGATE_PATCH).to(device)
            return dataclasses.replace(self, pattern=pattern.to(device), aggregates=aggregates)
        pattern = BlockPattern.from_topologies(
            mesh.vert_count, [mesh.tri_indices.cpu(), mesh.edge_indices.cpu()]
        )
        aggregates = None
        if mesh.vert_count >= AGGREGATE_PATCH**2 * 4:
            aggregates = grid_aggregates(mesh.uv.cpu(), AGGREGATE_PATCH).to(mesh.tri_indices.device)
        return dataclasses.replace(
            self, pattern=pattern.to(mesh.tri_indices.device), aggregates=aggregates
        )

    @property
    def batch_size(self) -> int:
        """B."""
        return int(self.vert_mass.shape[0])

    def free_mask(self) -> torch.Tensor:
        """1 for free vertices, 0 for pinned, shape (V, 1) in the model's float dtype."""
        mask = torch.ones(
            self.mesh.vert_count, 1, dtype=self.vert_mass.dtype, device=self.vert_mass.device
        )
        mask[self.pin_indices] = 0.0
        return mask

    def to(self, device=None, dtype=None) -> SimModel:
        """Copy to ``device`` / float ``dtype``."""
        return _to(self, device, dtype)


@dataclasses.dataclass(frozen=True)
class SimState:
    """Dynamic state of B instances."""

    pos: torch.Tensor
    """Vertex positions [m], shape (B, V, 3)."""
    vel: torch.Tensor
    """Vertex velocities [m/s], shape (B, V, 3)."""
    time: torch.Tensor
    """Simulated time [s], shape (B,)."""
    acc: torch.Tensor | None = None
    """Vertex accelerations [m/s²], shape (B, V, 3), carried by second-order integrators
    (Newmark); ``None`` when unknown (Newmark then takes it from the equations of motion)."""

    def to(self, device=None, dtype=None) -> SimState:
        """Copy to ``device`` / float ``dtype``."""
        return _to(self, device, dtype)


@dataclasses.dataclass(frozen=True)
class SimControl:
    """Kinematic inputs for one step, evaluated at the end of the step (t + dt)."""

    pin_pos: torch.Tensor
    """Targets of the pinned vertices [m], shape (B, P, 3)."""
    wind_vel: torch.Tensor | None = None
    """Air velocity at each vertex [m/s], shape (B, V, 3); ``None`` for still air."""
    capsules: torch.Tensor | None = None
    """Capsule obstacles ``[p0 (3), p1 (3), radius]`` [m], shape (B, C, 7)."""
    capsule_vel: torch.Tensor | None = None
    """Velocities of the capsule end points ``[v0, v1]`` [m/s], shape (B, C, 6)."""

    def to(self, device=None, dtype=None) -> SimControl:
        """Copy to ``device`` / float ``dtype``."""
        return _to(self, device, dtype)
