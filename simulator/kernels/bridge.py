"""Torch side of the compiled kernels: what the Newton loop calls on ``backend='kernels'``.

:class:`ShellKernel` stands in for a cloth model's membrane and bending energies inside the
incremental potential (value, gradient and Hessian from one fused pass); :func:`solve_two_level`
replaces the batched torch PCG by the per-instance compiled one. Everything else (gravity,
contact, air, friction, damping) stays on the torch path, which is cheap next to these two.
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np
import torch

from ..energies.bending import (
    BEND_SAMPLE_CURVATURES,
    BEND_SCALE,
    EnergyBendingDihedral,
    secant_knot_integrals,
)
from ..energies.membrane import STRETCH_SAMPLE_STRAIN, EnergyMembraneWang, _fibre_vectors
from .pcg import coarse_envelope, coarse_factor, coarse_matrix, pcg_two_level
from .shell import shell_assemble, shell_energy
from .step import newton_whole

__all__ = ["ShellKernel", "minimize_whole", "solve_two_level", "split_shell"]


def _match_threads() -> None:
    """Give numba's parallel loops as many threads as torch has, and keep torch's count.

    That is one per simulating process by default (:mod:`simulator.threads`), so the kernels
    never oversubscribe the CPU. numba's OpenMP layer shares libgomp with torch, and starting
    its thread pool resets the shared count to one per core (measured: torch went from 1 to 2
    threads on the 2-core machine), so torch's count is put back afterwards.
    """
    threads = torch.get_num_threads()
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)


def _np(t: torch.Tensor) -> np.ndarray:
    """A contiguous float64 (or int64) numpy view or copy of a CPU tensor."""
    t = t.detach()
    t = t.double() if t.is_floating_point() else t.long()
    return np.ascontiguousarray(t.cpu().numpy())


@dataclasses.dataclass(frozen=True)
class ShellKernel:
    """Membrane + bending energy of one cloth model, evaluated by the compiled kernels."""

    geometry: tuple
    """Mesh arrays in kernel order: tri, rest_inv, tri_area, then hinge arrays."""
    slots: tuple
    """ELL slots of the triangle (F, 3, 3) and hinge (E, 4, 4) blocks."""
    params: tuple
    """row0 (B, 4), fibres (B, 8), edge samples (B, E, 5) and their knot integrals (B, E, 5),
    all float64."""
    dtype: torch.dtype
    _last: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)

    @staticmethod
    def build(model, membrane: EnergyMembraneWang, bending: EnergyBendingDihedral) -> ShellKernel:
        """Kernel arrays of ``model``'s mesh and pattern and the two energies' parameters."""
        mesh = model.mesh
        geometry = (
            _np(mesh.tri_indices),
            _np(mesh.tri_rest_inv),
            _np(mesh.tri_rest_area),
            _np(_fibre_vectors(torch.float64, "cpu")),
            _np(mesh.edge_indices),
            _np(mesh.edge_rest_angle),
            _np(mesh.edge_rest_length / mesh.edge_rest_area),
            _np(mesh.edge_rest_area),
            np.asarray(BEND_SAMPLE_CURVATURES, dtype=np.float64),
        )
        slots = (
            _np(model.pattern.slot_map(mesh.tri_indices)),
            _np(model.pattern.slot_map(mesh.edge_indices)),
        )
        samples = bending.edge_stiffness
        params = (
            _np(membrane.row0),
            _np(membrane.fibres),
            _np(samples),
            _np(secant_knot_integrals(samples.double())),
        )
        return ShellKernel(geometry, slots, params, model.vert_mass.dtype)

    def _args(self) -> tuple[tuple, tuple]:
        """``(geometry, params)`` as :func:`.shell.shell_assemble` takes them."""
        tri, rest_inv, tri_area, fvec, hinges, rest_angle, scale, area, knots = self.geometry
        tri_slots, hinge_slots = self.slots
        geometry = (
            tri,
            rest_inv,
            tri_area,
            tri_slots,
            fvec,
            STRETCH_SAMPLE_STRAIN,
            hinges,
            rest_angle,
            scale,
            area,
            knots,
            BEND_SCALE,
            hinge_slots,
        )
        return geometry, self.params

    def value(self, x: torch.Tensor) -> torch.Tensor:
        """Energy [J] per instance, shape (B,) (from the last fused pass when it was at ``x``)."""
        last = self._last.get("x")
        if last is not None and last[0] is x and last[1] == x._version:
            return torch.from_numpy(self._last["out"][0].copy()).to(self.dtype)
        _match_threads()
        out = shell_energy(_np(x), *self._args())
        return torch.from_numpy(out).to(self.dtype)

    def assemble(self, x: torch.Tensor, verts: int, width: int, *, values_needed: bool = True):
        """``(energy (B,), gradient (B, V, 3), ELL values (B, V, K, 3, 3))`` at ``x``, float64.

        The last result is kept, so the Newton loop's gradient and Hessian calls at one point
        cost one pass. Values handed out by :meth:`hessian_values` are not kept (the caller
        adds into them), so the result then holds ``None`` for them.
        """
        last = self._last.get("x")
        if last is not None and last[0] is x and last[1] == x._version:
            if values_needed is False or self._last["out"][2] is not None:
                return self._last["out"]
        batch = x.shape[0]
        energy = np.zeros(batch)
        grad = np.zeros((batch, verts, 3))
        values = np.zeros((batch, verts * width, 3, 3))
        _match_threads()
        shell_assemble(_np(x), *self._args(), energy, grad, values)
        out = (energy, grad, values.reshape(batch, verts, width, 3, 3))
        self._last["x"] = (x, x._version)
        self._last["out"] = out
        return out

    def gradient(self, x: torch.Tensor, width: int) -> torch.Tensor:
        """dE/dx [N], shape (B, V, 3)."""
        _, grad, _ = self.assemble(x, x.shape[1], width, values_needed=False)
        return torch.from_numpy(grad).to(self.dtype)

    def hessian_values(self, x: torch.Tensor, width: int) -> torch.Tensor:
        """PSD Hessian blocks in the ELL layout, shape (B, V, K, 3, 3), owned by the caller."""
        energy, grad, values = self.assemble(x, x.shape[1], width)
        self._last["out"] = (energy, grad, None)
        return torch.from_numpy(values).to(self.dtype)


def split_shell(model, energies: tuple) -> tuple[ShellKernel | None, tuple]:
    """``(kernel, other energies)``: the membrane and bending terms taken over by a kernel.

    Returns ``(None, energies)`` when the model is not a discrete-shell cloth with a
    block-sparse pattern (mass-spring cloth, tissue), which then stays on the torch path.
    """
    membrane = [e for e in energies if type(e) is EnergyMembraneWang]
    bending = [e for e in energies if type(e) is EnergyBendingDihedral]
    if model.pattern is None or len(membrane) != 1 or len(bending) != 1:
        return None, energies
    if not hasattr(model.mesh, "tri_rest_inv"):
        return None, energies
    rest = tuple(e for e in energies if e is not membrane[0] and e is not bending[0])
    key = (id(model.mesh), id(model.pattern), id(membrane[0]), id(bending[0]), model.batch_size)
    hit = _BUILT.get(key)
    if hit is None or hit[0] is not model.mesh or hit[1] is not membrane[0]:
        if len(_BUILT) >= _BUILT_SIZE:
            _BUILT.pop(next(iter(_BUILT)))
        kernel = ShellKernel.build(model, membrane[0], bending[0])
        # The objects are kept alive with the entry so their ids cannot be reused.
        hit = _BUILT[key] = (model.mesh, membrane[0], bending[0], model.pattern, kernel)
    return hit[4], rest


_BUILT: dict = {}
"""Kernel arrays of recent (mesh, pattern, membrane, bending): built once per rollout."""
_BUILT_SIZE = 8


def solve_two_level(
    sparse,
    diag: torch.Tensor,
    aggregates: torch.Tensor,
    free: torch.Tensor,
    rhs: torch.Tensor,
    active: torch.Tensor,
    rtol: float,
    max_iters: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-instance additive two-level PCG of the block-sparse system (see :mod:`.pcg`).

    Args:
        sparse: the whole Hessian as a :class:`BlockSparse` (values (B, V, K, 3, 3)).
        diag: its diagonal blocks (B, V, 3, 3), made invertible at empty rows.
        aggregates: coarse aggregate per vertex (V,).
        free: 1 for free, 0 for pinned vertices, (V, 1) or (B, V, 1).
        rhs: right-hand sides (B, V, 3), zero at pinned vertices.
        active: instances still iterating, bool (B,).
        rtol: relative residual tolerance.
        max_iters: iteration cap.

    Returns:
        ``(solution (B, V, 3) in rhs's dtype, iterations (B,) int64)``.
    """
    batch, verts = rhs.shape[:2]
    free_b = free.expand(batch, verts, 1) if free.dim() == 2 else free
    free_np = _np(free_b[..., 0])
    agg = _np(aggregates)
    n_agg = int(agg.max()) + 1
    values = _np(sparse.values)
    cols = _np(sparse.pattern.cols)
    _match_threads()
    first = coarse_envelope(cols, agg, n_agg)
    factor = coarse_factor(coarse_matrix(values, cols, agg, free_np, n_agg), first, agg, free_np)
    x, iters, _ = pcg_two_level(
        values,
        cols,
        _np(diag),
        agg,
        factor,
        first,
        free_np,
        _np(rhs),
        active.cpu().numpy(),
        float(rtol),
        int(max_iters),
    )
    return torch.from_numpy(x).to(rhs), torch.from_numpy(iters)


def _solve_arrays(pattern, aggregates: torch.Tensor) -> tuple:
    """``(cols, diag_slots, agg, envelope, A)`` of a pattern and aggregation, cached on it."""
    key = ("kernel_solve", aggregates.data_ptr(), tuple(aggregates.shape))
    hit = pattern._slot_cache.get(key)
    if hit is not None and hit[0] is aggregates:
        return hit[1]
    cols = _np(pattern.cols)
    agg = _np(aggregates)
    n_agg = int(agg.max()) + 1
    out = (cols, _np(pattern.diagonal_slots()), agg, coarse_envelope(cols, agg, n_agg), n_agg)
    pattern._slot_cache[key] = (aggregates, out)
    return out


def minimize_whole(
    shell: ShellKernel,
    quadratic: tuple,
    x0: torch.Tensor,
    free: torch.Tensor,
    settings,
    aggregates: torch.Tensor,
    pattern,
):
    """Whole Newton solve of ``shell(x) + 1/2 y^T Q y - g^T y + const`` in one kernel call.

    Args:
        shell: the membrane + bending kernel.
        quadratic: ``(Q (B, V, 3, 3), z (B, V, 3), g (B, V, 3), const (B,))`` of the other
            terms (:meth:`simulator.integrators.base.IncrementalPotential.vertex_quadratic`).
        x0: start (B, V, 3), pinned vertices at their values.
        free: 1 for free, 0 for pinned, (V, 1) or (B, V, 1).
        settings: :class:`simulator.solvers.NewtonSettings`.
        aggregates: coarse aggregate per vertex (V,).
        pattern: the model's :class:`simulator.solvers.block_sparse.BlockPattern`.

    Returns:
        ``(x (B, V, 3), (Newton iterations, CG iterations, last max update))`` as tensors.
    """
    batch, verts = x0.shape[:2]
    free_b = free.expand(batch, verts, 1) if free.dim() == 2 else free
    quad, centre, force, const = quadratic
    geometry, params = shell._args()
    _match_threads()
    newton = (
        int(settings.max_iters),
        float(settings.tol_dx),
        float(settings.cg_rtol),
        int(settings.cg_max_iters),
        bool(settings.line_search),
        int(settings.max_halvings),
    )
    x, newton_iters, cg_iters, update = newton_whole(
        _np(x0),
        _np(quad),
        _np(centre),
        _np(force),
        _np(const),
        _np(free_b[..., 0]),
        geometry,
        params,
        _solve_arrays(pattern, aggregates),
        newton,
    )
    as_torch = torch.from_numpy
    return as_torch(x).to(x0), (as_torch(newton_iters), as_torch(cg_iters), as_torch(update).to(x0))
