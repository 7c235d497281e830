"""Sew and drape garments on the mannequin to static equilibrium, a batch at a time.

A batch holds B garments of one type (one pattern topology): each instance has its own
sizing G (flat panels), material C and body pose θ. The model is the core's cloth model
(membrane + dihedral bending of a measured fabric, gravity, penalty contact with the body's
capsules and Coulomb friction) plus the seam energy; with one rest shape for the whole batch it
uses the core's energy types (so the compiled kernels apply), otherwise the per-instance rest
variants of :mod:`.energies` (torch path).

Drape (quasi-static): from the registered garment (seams still open), steps that each minimise
``E(x) + 1/(2 dt²) |x - x_n|²_M`` (a backward-Euler step from rest: the inertia term is a
proximal weight, so no kinetic energy builds up and the garment creeps into equilibrium
instead of swinging about it), until the **stopping test** holds: the largest vertex
displacement of a step is below ``speed_tol * dt`` for ``calm_steps`` consecutive steps (each
instance judged on its own; the batch runs until all rest or ``max_steps``). Friction acts
against every step's motion (sticking below its slip speed), as it holds a garment on a body.
The
garment's material C (:data:`MATERIAL_SPECS`) is a pair of multipliers of the basis fabric
(*thesis* §6.5.4: Gray Interlock as the softest, its bending times 100 as the stiffest).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence

import numpy as np
import torch

from common.errors import InputError
from simulator.cloth.material import ClothMaterial, load_wang_material
from simulator.cloth.model import GRAVITY
from simulator.energies import (
    EnergyBendingDihedral,
    EnergyContactCapsule,
    EnergyGravity,
    EnergyMembraneWang,
    EnergySelfCollision,
)
from simulator.forces import FrictionCapsule
from simulator.integrators import IntegratorBackwardEuler
from simulator.mesh import TriMesh
from simulator.model import SimControl, SimModel, SimState
from simulator.solvers import NewtonSettings
from simulator.solvers.block_sparse import BlockPattern
from simulator.solvers.coarse import grid_aggregates

from .body import Mannequin, capsule_distance
from .energies import (
    SEAM_STIFFNESS,
    EnergyBendingPattern,
    EnergyMembranePattern,
    EnergySeam,
    PatternRest,
    seam_pair_lengths,
)
from .patterns import ParamSpec, PatternTopology, atlas
from .skinning import linear_blend, remove_interpenetrations, rest_placement, skinning_weights

__all__ = [
    "BASIS_FABRIC",
    "MATERIAL_SPECS",
    "DrapeResult",
    "DrapeSettings",
    "GarmentBatch",
    "check_material",
    "drape",
    "garment_material",
]

BASIS_FABRIC = "gray-interlock"
"""The measured fabric whose multiples form the material space (*thesis* §6.5.4)."""

MATERIAL_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("bend", "x", 1.0, 100.0, 10.0, "bending stiffness multiplier of the basis fabric"),
    ParamSpec("stretch", "x", 0.5, 5.0, 1.0, "stretching stiffness multiplier of the basis fabric"),
)
"""Material parameters C (dimensionless multipliers of :data:`BASIS_FABRIC`)."""


def check_material(values: dict, field: str = "material") -> dict[str, float]:
    """C as floats within :data:`MATERIAL_SPECS`' ranges (missing ones take defaults)."""
    specs = {p.name: p for p in MATERIAL_SPECS}
    unknown = sorted(set(values) - set(specs))
    if unknown:
        raise InputError(f"{field}: unknown {unknown}; allowed: {list(specs)}")
    out = {}
    for name, spec in specs.items():
        value, number = spec.read(values)
        if (
            isinstance(value, bool)
            or not math.isfinite(number)
            or not (spec.low <= number <= spec.high)
        ):
            raise InputError(
                f"{field}.{name} ({spec.doc}) must lie in [{spec.low}, {spec.high}], got {value!r}"
            )
        out[name] = number
    return out


def garment_material(
    bend: Sequence[float], stretch: Sequence[float], *, dtype=torch.float64
) -> ClothMaterial:
    """Batch of basis-fabric multiples, one (bend, stretch) per instance."""
    return ClothMaterial.from_wang(
        load_wang_material(BASIS_FABRIC),
        stretch_mult=list(map(float, stretch)),
        bend_mult=list(map(float, bend)),
        dtype=dtype,
    )


@dataclasses.dataclass(frozen=True)
class DrapeSettings:
    """Time step, stopping test and solver tolerances of a drape."""

    dt: float = 0.05
    """Quasi-static step [s]: sets the proximal weight ``m / dt²``."""
    max_steps: int = 150
    speed_tol: float = 0.01
    """Stopping test: largest vertex displacement per step over ``dt`` [m/s] below which an
    instance counts as resting."""
    calm_steps: int = 2
    """Consecutive resting steps required."""
    friction: float = 0.5
    """Coulomb coefficient between cloth and body."""
    contact_thickness: float = 0.005
    """Distance kept between garment vertices and the body surface [m]: vertex contact lets
    an edge of length L sag L² / (8 R) into a limb of radius R (4 mm for 4 cm on an arm)."""
    seam_stiffness: float = SEAM_STIFFNESS
    """Seam stiffness per unit length [N/m²]."""
    self_collision: bool = False
    """Vertex-vertex self-collision (off by default: single-layer garments on a convex-ish
    body rarely fold onto themselves in a static drape, and its O(V²) pair search dominates)."""
    self_collision_radius: float = 0.012
    """Contact distance of self-collision [m] (about the edge length)."""
    newton_iters: int = 2
    """Newton iterations per step (the next step continues where a step stopped)."""
    linear_solver: str = "direct"
    """``direct`` (sparse LU per instance) or ``pcg``; the drape's contact-stiffened systems are
    ill-conditioned for PCG (measured: ~100 CG iterations per Newton iteration)."""
    cg_rtol: float = 1e-3
    cg_max_iters: int = 300
    capsule_margin: float = 0.25
    """Body primitives farther than this from the garment's start [m] are left out of the
    contact (they cannot be reached in a drape; the search is O(V C))."""

    def __post_init__(self):
        for name in (
            "dt",
            "speed_tol",
            "friction",
            "seam_stiffness",
            "cg_rtol",
            "contact_thickness",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise InputError(f"drape.{name} must be a finite number >= 0, got {value!r}")
        if self.dt <= 0:
            raise InputError(f"drape.dt must be > 0 s, got {self.dt}")
        if self.linear_solver not in ("direct", "pcg"):
            raise InputError(
                f"drape.linear_solver must be direct or pcg, got {self.linear_solver!r}"
            )
        for name in ("max_steps", "calm_steps", "newton_iters", "cg_max_iters"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"drape.{name} must be an integer >= 1, got {value!r}")

    def newton(self) -> NewtonSettings:
        """The Newton / PCG settings of one step."""
        return NewtonSettings(
            max_iters=self.newton_iters,
            tol_dx=1e-6,
            cg_rtol=self.cg_rtol,
            cg_max_iters=self.cg_max_iters,
            linear_solver=self.linear_solver,
        )


@dataclasses.dataclass(frozen=True)
class DrapeResult:
    """Outcome of :func:`drape` for a batch."""

    pos: torch.Tensor
    """Draped vertex positions [m], shape (B, V, 3)."""
    steps: np.ndarray
    """Steps until each instance passed the stopping test (max_steps if never), (B,)."""
    converged: np.ndarray
    """Whether each instance passed the stopping test, bool (B,)."""
    max_speed: np.ndarray
    """Largest vertex speed of each instance at the end [m/s], (B,)."""
    seam_gap: np.ndarray
    """Largest seam gap of each instance at the end [m], (B,)."""
    min_body_distance: np.ndarray
    """Smallest signed distance of a vertex to the body surface [m] (negative: inside), (B,)."""
    failed: np.ndarray
    """Instances whose simulation produced non-finite positions (frozen at their last finite
    state), bool (B,)."""
    seconds: float
    """Wall time of the drape [s]."""


@dataclasses.dataclass(frozen=True)
class GarmentBatch:
    """B garments of one topology ready to simulate: model, seams and the bodies' capsules."""

    topology: PatternTopology
    coords: np.ndarray
    """Panel coordinates per instance [m], shape (B, V, 2)."""
    model: SimModel
    seam: EnergySeam
    capsules: torch.Tensor
    """Posed body primitives [m], shape (B, C, 7)."""

    @staticmethod
    def build(
        topology: PatternTopology,
        coords: np.ndarray,
        material: ClothMaterial,
        capsules: np.ndarray,
        settings: DrapeSettings | None = None,
        *,
        pos_hint: np.ndarray | None = None,
        dtype: torch.dtype = torch.float64,
    ) -> GarmentBatch:
        """Model of B garments: coords (B, V, 2) [m], material (B), capsules (B, C, 7) [m].

        ``pos_hint`` (B, V, 3) [m]: where the garments start; primitives farther than
        ``settings.capsule_margin`` from every instance are left out of the contact.
        """
        settings = settings or DrapeSettings()
        capsules = np.asarray(capsules, dtype=np.float64)
        if pos_hint is not None:
            near = np.zeros(capsules.shape[1], dtype=bool)
            for p, c in zip(np.asarray(pos_hint), capsules, strict=True):
                near |= capsule_distance(p, c)[0].min(axis=0) < settings.capsule_margin
            capsules = capsules[:, near]
        coords = np.asarray(coords, dtype=np.float64)
        batch = coords.shape[0]
        if material.batch_size != batch or len(capsules) != batch:
            raise ValueError(
                f"coords ({batch}), material ({material.batch_size}) and capsules "
                f"({len(capsules)}) need the same batch size"
            )
        shared = bool(np.all(coords == coords[:1]))
        flat = np.concatenate([coords[0], np.zeros((coords.shape[1], 1))], axis=1)
        mesh = TriMesh.from_arrays(
            flat, topology.tri_indices, atlas(topology, coords[0]), dtype=dtype
        )
        material = material.to(dtype=dtype)
        if shared:
            elastic = (
                EnergyMembraneWang.from_material(material.stretching),
                EnergyBendingDihedral.from_material(mesh, material.bending),
            )
            vert_area = mesh.vert_area[None].expand(batch, -1)
        else:
            rest = PatternRest.from_coords(
                torch.as_tensor(coords, dtype=dtype), mesh.tri_indices, mesh.edge_indices
            )
            elastic = (
                EnergyMembranePattern.from_rest(material.stretching, rest),
                EnergyBendingPattern.from_rest(mesh, material.bending, rest),
            )
            vert_area = rest.vert_area
        pairs = np.concatenate(list(topology.seam_pairs.values()))
        lengths = np.concatenate(
            [seam_pair_lengths(coords[0], p) for p in topology.seam_pairs.values()]
        )
        seam = EnergySeam(
            torch.as_tensor(pairs, dtype=torch.int64),
            torch.as_tensor(settings.seam_stiffness * lengths, dtype=dtype),
        )
        energies = [
            *elastic,
            EnergyGravity(torch.tensor(GRAVITY, dtype=dtype)),
            seam,
            EnergyContactCapsule(thickness=settings.contact_thickness),
        ]
        if settings.self_collision:
            energies.append(EnergySelfCollision(radius=settings.self_collision_radius))
        model = SimModel(
            mesh=mesh,
            energies=tuple(energies),
            forces=(FrictionCapsule(mu=settings.friction),),
            vert_mass=material.density[:, None] * vert_area,
            pin_indices=torch.zeros(0, dtype=torch.int64),
        )
        pattern = BlockPattern.from_topologies(
            mesh.vert_count, [mesh.tri_indices, mesh.edge_indices, seam.pairs]
        )
        model = dataclasses.replace(model, pattern=pattern, aggregates=grid_aggregates(mesh.uv, 4))
        return GarmentBatch(
            topology, coords, model, seam, torch.as_tensor(np.asarray(capsules), dtype=dtype)
        )

    def control(self) -> SimControl:
        """Controls of a static body: the capsules, at rest."""
        batch = self.capsules.shape[0]
        return SimControl(
            pin_pos=self.capsules.new_zeros(batch, 0, 3),
            capsules=self.capsules,
            capsule_vel=self.capsules.new_zeros(batch, self.capsules.shape[1], 6),
        )


def register_batch(
    topology: PatternTopology,
    coords: np.ndarray,
    params: Sequence[dict],
    body: Mannequin,
    angles: np.ndarray,
) -> np.ndarray:
    """Registered garments (rest placement, skinning, push-out), shape (B, V, 3) [m]."""
    from .patterns import Pattern

    out = []
    edges = _edges(topology)
    bones = body.bone_transforms(angles)
    caps = body.capsules(angles)
    for b in range(len(coords)):
        pattern = Pattern(topology, dict(params[b]), coords[b])
        rest = rest_placement(pattern, body)
        weights = skinning_weights(rest, body)
        posed = linear_blend(rest, weights, bones[b : b + 1])[0]
        rest_len = np.linalg.norm(rest[edges[:, 1]] - rest[edges[:, 0]], axis=1)
        out.append(remove_interpenetrations(posed, caps[b], edges, rest_len))
    return np.stack(out)


def _edges(topology: PatternTopology) -> np.ndarray:
    tri = topology.tri_indices
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def drape(
    batch: GarmentBatch,
    pos0: np.ndarray | torch.Tensor,
    settings: DrapeSettings | None = None,
    *,
    should_stop=None,
) -> DrapeResult:
    """Sew and drape ``pos0`` (B, V, 3) [m] to rest (see the module docstring).

    ``should_stop()`` is polled between steps (a Ctrl-C handler); when it returns true the
    drape ends early with ``converged`` false for the instances still moving.
    """
    settings = settings or DrapeSettings()
    start = time.perf_counter()
    model = batch.model
    dtype = model.vert_mass.dtype
    pos = torch.as_tensor(np.asarray(pos0), dtype=dtype).clone()
    bsz = pos.shape[0]
    integrator = IntegratorBackwardEuler(settings.newton())
    control = batch.control()
    calm = np.zeros(bsz, dtype=np.int64)
    done_at = np.full(bsz, settings.max_steps, dtype=np.int64)
    speed = np.full(bsz, np.inf)
    failed = np.zeros(bsz, dtype=bool)
    # Instances that rest leave the batch (their rows stop costing), once a quarter has.
    active = np.arange(bsz)
    sub_model, sub_control = model, control
    step = 0
    for step in range(settings.max_steps):
        cur = pos[active]
        state = SimState(cur, torch.zeros_like(cur), torch.zeros(len(active), dtype=dtype))
        state, _ = integrator.step(sub_model, state, sub_control, settings.dt)
        bad = ~torch.isfinite(state.pos).flatten(1).all(1)
        new = torch.where(bad.view(-1, 1, 1), cur, state.pos)
        vel = torch.where(bad.view(-1, 1, 1), torch.zeros_like(state.vel), state.vel)
        pos[active] = new
        failed[active] |= bad.numpy()
        sp = torch.linalg.vector_norm(vel, dim=-1).amax(-1).numpy()
        speed[active] = np.where(failed[active], 0.0, sp)
        resting = speed[active] < settings.speed_tol
        calm[active] = np.where(resting, calm[active] + 1, 0)
        newly = active[
            (calm[active] >= settings.calm_steps) & (done_at[active] == settings.max_steps)
        ]
        done_at[newly] = step + 1
        still = active[done_at[active] == settings.max_steps]
        if len(still) == 0:
            break
        if should_stop is not None and should_stop():
            break
        if len(still) <= 0.75 * len(active):
            keep = np.searchsorted(active, still)
            sub_model = _take_model(sub_model, keep)
            sub_control = _take_control(sub_control, keep)
            active = still
    converged = (done_at < settings.max_steps) & ~failed
    gaps = batch.seam.gaps(pos).amax(-1).numpy()
    caps = batch.capsules.numpy()
    pos_np = pos.numpy()
    min_dist = np.array(
        [capsule_distance(p, c)[0].min() for p, c in zip(pos_np, caps, strict=True)]
    )
    return DrapeResult(
        pos,
        np.minimum(done_at, step + 1),
        converged,
        speed,
        gaps,
        min_dist,
        failed,
        time.perf_counter() - start,
    )


_PER_INSTANCE = {
    EnergyMembraneWang: ("row0", "fibres"),
    EnergyMembranePattern: ("row0", "fibres", "rest_inv", "rest_area"),
    EnergyBendingDihedral: ("edge_stiffness",),
    EnergyBendingPattern: ("edge_stiffness", "rest_length", "rest_area"),
}
"""Fields of the garment energies that carry the batch (dimension 0)."""


def _take_model(model: SimModel, keep: np.ndarray) -> SimModel:
    """The model of the instances ``keep`` (indices into the batch)."""
    idx = torch.as_tensor(keep, dtype=torch.int64)
    energies = []
    for e in model.energies:
        fields = _PER_INSTANCE.get(type(e), ())
        if isinstance(e, EnergySeam) and e.stiffness.dim() == 2:
            fields = ("stiffness",)
        energies.append(dataclasses.replace(e, **{f: getattr(e, f)[idx] for f in fields}))
    return dataclasses.replace(model, energies=tuple(energies), vert_mass=model.vert_mass[idx])


def _take_control(control: SimControl, keep: np.ndarray) -> SimControl:
    idx = torch.as_tensor(keep, dtype=torch.int64)
    return SimControl(
        pin_pos=control.pin_pos[idx],
        capsules=control.capsules[idx],
        capsule_vel=control.capsule_vel[idx],
    )
