"""Tissue scenes on the shared solver core (*thesis* ch. 3).

Ground truth, the contact-force boundary condition, and the batched organ-only forward
model used by the multi-region recovery.

* :func:`solve_organ_scene`: static equilibrium of organ + surrounding tissue (the synthetic
  "target image"): the tissue box's base rests on bone (fixed), its top is pushed down; the
  organ (Mooney-Rivlin, *thesis* eq. 3.8, per-tet moduli) and the tissue (linear, known
  default stiffness) are one conforming mesh.
* :func:`contact_forces`: *thesis* §3.2.2.3, eq. 3.9: ``f = K u_s`` on the tissue-only FEM
  domain with the tissue's known linear stiffness; minus ``f`` at the organ's interface
  nodes is the contact force that the tissue exerts on the organ.
* :class:`OrganForwardModel`: the organ alone, loaded by those contact forces and held at
  its base, for a batch of per-region moduli (a PSO swarm), solved statically with
  warm starts.
"""

from __future__ import annotations

import dataclasses

import torch

from simulator.energies.loads import EnergyNodalForce
from simulator.energies.tet import EnergyTetLinear, EnergyTetMooneyRivlin, region_values
from simulator.errors import MaterialError
from simulator.integrators.backward_euler import solve_static
from simulator.model import SimControl, SimModel, SimState
from simulator.solvers.block_sparse import BlockSparse
from simulator.solvers.newton import NewtonSettings, StepStats, lu_solve, sparse_lu_factors
from simulator.tetmesh import TetMesh
from simulator.tissue.meshing import REGION_TISSUE, OrganScene

__all__ = [
    "DEFAULT_V1",
    "STATIC_SETTINGS",
    "TISSUE_POISSON",
    "TISSUE_YOUNG",
    "OrganForwardModel",
    "OrganLoadCase",
    "contact_forces",
    "organ_energy",
    "organ_load_case",
    "solve_organ_scene",
]

TISSUE_YOUNG = 300e3
"""Default (known) Young's modulus of the surrounding tissue [Pa]."""
TISSUE_POISSON = 0.45
"""Default Poisson ratio of the surrounding tissue."""
DEFAULT_V1 = 2.5e6
"""Fixed Mooney-Rivlin volumetric parameter v1 [Pa] (bulk modulus 2 v1 = 5 MPa), large for
near-incompressibility as in *thesis* §3.2.2.2 (Poisson ~0.48 at mu1 = mu2 = 30 kPa)."""
STATIC_SETTINGS = NewtonSettings(max_iters=15, tol_dx=1e-8, linear_solver="direct")
"""Newton/PCG settings of the static tissue solves (tolerance in metres)."""


MATERIALS = ("mooney_rivlin", "linear")
"""Organ material models: *thesis* eq. 3.8, or its small-strain linearisation."""


def organ_energy(
    mu: torch.Tensor,
    *,
    v1: float = DEFAULT_V1,
    tet_subset: torch.Tensor | None = None,
    material: str = "mooney_rivlin",
) -> EnergyTetMooneyRivlin | EnergyTetLinear:
    """Organ energy with ``mu1 = mu2 = mu`` (*thesis* §3.3.1), mu (B, T) [Pa].

    ``material="linear"`` gives linear elasticity with the same small-strain moduli
    (shear ``7 mu``, bulk ``2 v1``), so that both models share the parameter ``mu``.
    """
    if not bool((mu > 0).all()):
        raise MaterialError(f"mu must be > 0 Pa, got min {float(mu.min()):.4g} Pa")
    if material not in MATERIALS:
        raise MaterialError(f"material must be one of {MATERIALS}, got {material!r}")
    mr = EnergyTetMooneyRivlin(mu, mu, torch.full_like(mu, v1), tet_subset)
    if material == "linear":
        lin_mu, lin_lam = mr.small_strain_lame()
        return EnergyTetLinear(lin_mu, lin_lam, tet_subset)
    return mr


def _tissue_energy(mesh: TetMesh, batch: int, young: float, poisson: float, like):
    subset = torch.nonzero(mesh.tet_region == REGION_TISSUE).reshape(-1)
    e = torch.full((batch, subset.numel()), float(young), dtype=like.dtype, device=like.device)
    return EnergyTetLinear.from_young_poisson(e, poisson, tet_subset=subset)


def _static_model(mesh: TetMesh, energies: tuple, pins: torch.Tensor, batch: int) -> SimModel:
    mass = mesh.vert_volume.new_ones(batch, mesh.vert_count)  # statics: masses unused
    return SimModel(mesh, energies, (), mass, pins).with_pattern()


def solve_organ_scene(
    scene: OrganScene,
    organ_mu: torch.Tensor,
    *,
    compression: float = 0.15,
    tissue_young: float = TISSUE_YOUNG,
    tissue_poisson: float = TISSUE_POISSON,
    v1: float = DEFAULT_V1,
    material: str = "mooney_rivlin",
    settings: NewtonSettings = STATIC_SETTINGS,
) -> tuple[torch.Tensor, StepStats]:
    """Static equilibrium of the whole scene (the synthetic target).

    Args:
        scene: organ + tissue mesh.
        organ_mu: ``mu1 = mu2`` per organ tet [Pa], shape (B, T_organ) in the order of the
            scene's organ tets (``tet_region != REGION_TISSUE``).
        compression: top-face displacement as a fraction of the box height.
        tissue_young: tissue Young's modulus [Pa].
        tissue_poisson: tissue Poisson ratio.
        v1: organ volumetric parameter [Pa].
        material: organ model, one of MATERIALS.
        settings: static Newton settings.

    Returns:
        Deformed positions (B, V, 3) [m] and solver statistics.
    """
    if not 0.0 <= compression < 0.5:
        raise ValueError(f"compression must lie in [0, 0.5), got {compression}")
    mesh = scene.mesh
    organ = torch.nonzero(mesh.tet_region != REGION_TISSUE).reshape(-1)
    batch = organ_mu.shape[0]
    energies = (
        organ_energy(organ_mu.to(mesh.vert_pos), v1=v1, tet_subset=organ, material=material),
        _tissue_energy(mesh, batch, tissue_young, tissue_poisson, mesh.vert_pos),
    )
    pins = torch.cat([scene.base_verts, scene.top_verts]).unique()
    model = _static_model(mesh, energies, pins, batch)
    rest = mesh.vert_pos[None].repeat(batch, 1, 1)
    target = rest[:, pins].clone()
    is_top = torch.isin(pins, scene.top_verts)
    target[:, is_top, 2] -= compression * scene.box_height
    # Load in steps so that each static solve starts close to its equilibrium.
    pos = rest
    stats = None
    steps = 3
    for k in range(1, steps + 1):
        pin_pos = rest[:, pins] + (target - rest[:, pins]) * (k / steps)
        state = SimState(pos, torch.zeros_like(pos), rest.new_zeros(batch))
        state, stats = solve_static(model, state, SimControl(pin_pos), settings=settings)
        pos = state.pos
    return pos, stats


def contact_forces(
    mesh: TetMesh,
    displacement: torch.Tensor,
    *,
    tissue_young: float = TISSUE_YOUNG,
    tissue_poisson: float = TISSUE_POISSON,
) -> torch.Tensor:
    """Forces the surrounding tissue exerts on every vertex, ``-K_s u_s`` (*thesis* eq. 3.9).

    ``K_s`` is the linear stiffness of the tissue-only FEM domain (tets with
    ``REGION_TISSUE``) with its known default moduli; ``u_s`` is the tissue displacement
    (from the two image sets). At the organ's interface vertices the result is the contact
    force on the organ; it is zero (to solver tolerance) at interior tissue vertices.

    Args:
        mesh: the whole scene mesh.
        displacement: tissue vertex displacements [m], shape (B, V, 3) (organ-only vertices
            are ignored).
        tissue_young: known tissue Young's modulus [Pa].
        tissue_poisson: known tissue Poisson ratio.

    Returns:
        Nodal forces [N], shape (B, V, 3).
    """
    energy = _tissue_energy(mesh, displacement.shape[0], tissue_young, tissue_poisson, displacement)
    model = SimModel(mesh, (energy,), (), displacement.new_ones(1, 1), torch.zeros(0).long())
    # The linear energy's gradient at X + u is exactly K u.
    return -energy.gradient(model, mesh.vert_pos[None].to(displacement) + displacement)


@dataclasses.dataclass(frozen=True)
class OrganLoadCase:
    """The organ-only problem: mesh, Dirichlet base, contact forces, observed target."""

    mesh: TetMesh
    """Organ mesh; ``tet_region`` 0 (tumour side) and 1 (normal)."""
    scene_vert_ids: torch.Tensor
    """Scene vertex of each organ vertex, int64, (Vo,)."""
    tet_tumour: torch.Tensor
    """Tumour tets of the organ mesh, bool, (To,)."""
    pin_indices: torch.Tensor
    """Organ vertices on the bone (fixed), int64, (P,)."""
    force: torch.Tensor
    """Contact forces from the tissue [N], shape (1, Vo, 3)."""
    target_pos: torch.Tensor
    """Observed deformed organ vertex positions [m], shape (Vo, 3)."""


def organ_load_case(
    scene: OrganScene,
    scene_pos: torch.Tensor,
    *,
    tissue_young: float = TISSUE_YOUNG,
    tissue_poisson: float = TISSUE_POISSON,
) -> OrganLoadCase:
    """Cut the organ out of a solved scene and turn the tissue into contact forces.

    Args:
        scene: the scene mesh and masks.
        scene_pos: deformed scene positions (V, 3) [m] (the target "image").
        tissue_young: known tissue Young's modulus [Pa].
        tissue_poisson: known tissue Poisson ratio.
    """
    mesh = scene.mesh
    organ_mask = mesh.tet_region != REGION_TISSUE
    organ, vert_ids = mesh.submesh(organ_mask)
    disp = (scene_pos - mesh.vert_pos)[None]
    force = contact_forces(mesh, disp, tissue_young=tissue_young, tissue_poisson=tissue_poisson)
    pins = torch.nonzero(torch.isin(vert_ids, scene.base_verts)).reshape(-1)
    return OrganLoadCase(
        organ,
        vert_ids,
        scene.tet_tumour[organ_mask],
        pins,
        force[:, vert_ids],
        scene_pos[vert_ids],
    )


@dataclasses.dataclass
class OrganForwardModel:
    """Batched static solves of the organ for per-region (or per-tet) moduli, warm-started.

    Mutable on purpose: it keeps the last solution per batch row as the next start.
    """

    case: OrganLoadCase
    v1: float = DEFAULT_V1
    settings: NewtonSettings = STATIC_SETTINGS
    warm_start: bool = True
    material: str = "linear"
    """Organ model (MATERIALS); ``linear`` is one factorisation per candidate."""
    method: str = "chord"
    """``chord`` (small-strain stiffness factored once, fallback to Newton) or ``newton``."""
    chord_max_iters: int = 60
    last_pos: torch.Tensor | None = None
    last_stats: StepStats | None = None
    solve_count: int = 0

    def solve_tets(self, mu: torch.Tensor) -> torch.Tensor:
        """Equilibrium positions (B, Vo, 3) [m] for per-tet ``mu1 = mu2 = mu`` (B, To) [Pa]."""
        mesh = self.case.mesh
        batch = mu.shape[0]
        mu = mu.to(mesh.vert_pos)
        rest = mesh.vert_pos[None].repeat(batch, 1, 1)
        start = rest
        if self.warm_start and self.last_pos is not None and self.last_pos.shape == rest.shape:
            start = self.last_pos
        if self.method == "chord":
            pos, converged = self._chord(mu, start)
            if not bool(converged.all()):
                bad = torch.nonzero(~converged).reshape(-1)
                pos = pos.clone()
                pos[bad] = self._newton(mu[bad], rest[bad])
        else:
            pos = self._newton(mu, start)
        self.last_pos = pos
        self.solve_count += batch
        return pos

    def _model(self, energies, batch) -> SimModel:
        return _static_model(self.case.mesh, energies, self.case.pin_indices, batch)

    def _newton(self, mu: torch.Tensor, start: torch.Tensor) -> torch.Tensor:
        mesh = self.case.mesh
        energies = (
            organ_energy(mu, v1=self.v1, material=self.material),
            EnergyNodalForce(self.case.force.to(mu)),
        )
        model = self._model(energies, mu.shape[0])
        state = SimState(start, torch.zeros_like(start), start.new_zeros(mu.shape[0]))
        control = SimControl(mesh.vert_pos[self.case.pin_indices][None].expand(mu.shape[0], -1, -1))
        state, self.last_stats = solve_static(model, state, control, settings=self.settings)
        return state.pos

    def _chord(self, mu: torch.Tensor, start: torch.Tensor):
        """Chord iterations ``x <- x - K0^-1 g(x)`` with ``K0`` the small-strain stiffness.

        ``K0`` (linear elasticity with the Mooney-Rivlin small-strain moduli) is factored once
        per instance; each iteration then costs one batched gradient and a triangular solve,
        and no tangent. Converges linearly (fast at the moderate strains of these scenes).
        """
        mesh = self.case.mesh
        batch = mu.shape[0]
        energies = (
            organ_energy(mu, v1=self.v1, material=self.material),
            EnergyNodalForce(self.case.force.to(mu)),
        )
        model = self._model(energies, batch)
        linear = organ_energy(mu, v1=self.v1, material="linear")
        x = start.clone()
        x[:, self.case.pin_indices] = mesh.vert_pos[self.case.pin_indices]
        blocks = linear.hessian_blocks(model, x)
        stiffness = BlockSparse.zeros(model.pattern, batch, x)
        stiffness.add_elements(blocks.topology, blocks.blocks.view(batch, -1, 4, 4, 3, 3))
        free = model.free_mask()
        factors = sparse_lu_factors(stiffness, free)
        active = torch.ones(batch, dtype=torch.bool)
        update = torch.full((batch,), float("inf"), dtype=x.dtype)
        for _ in range(self.chord_max_iters):
            grad = sum(e.gradient(model, x) for e in energies) * free
            dx = -lu_solve(factors, grad) * active.view(-1, 1, 1)
            x = x + dx
            step = torch.linalg.vector_norm(dx, dim=-1).amax(-1)
            update = torch.where(active, step, update)
            active = active & (update > self.settings.tol_dx) & torch.isfinite(update)
            if not bool(active.any()):
                break
        converged = torch.isfinite(update) & (update <= self.settings.tol_dx)
        return x, converged

    def solve_regions(self, region_mu: torch.Tensor) -> torch.Tensor:
        """Equilibrium positions (B, Vo, 3) for one ``mu`` per region, (B, R) [Pa]."""
        return self.solve_tets(region_values(region_mu, self.case.mesh.tet_region))
