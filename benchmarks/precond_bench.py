"""Block-Jacobi vs two-level (aggregation) PCG preconditioners on a realistic cloth Hessian.

Builds the backward-Euler Hessian of the reference scene (0.5 m x 0.5 m cloth, 32 x 32 vertices,
hanging in the x-z plane from its two top corners, wind along +y, dt = 5 ms) for all 54 material
classes, whose membranes reach a few thousand N/m against mass terms of ~3 N/m per vertex, so
block-Jacobi PCG needs 100+ iterations. The matrix is rebuilt as a :class:`BlockSparse` exactly
as :meth:`IncrementalPotential.hessian` does (and checked against the objective's own product),
and the right-hand side is random on the free vertices. For each dtype, batch size (54
instances, or the stiffest one alone), preconditioner and tolerance it prints the CG iterations
(max and median over the batch) and the median wall time of building the preconditioner and of
the whole solve, then, as the last line, JSON with the figures of the fastest configuration
(build + solve at the largest B, first dtype, loosest tolerance) next to block-Jacobi.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import time
from collections.abc import Callable

import torch

from simulator.cloth.material import ClothMaterial
from simulator.energies import EnergyBendingDihedral, EnergyGravity, EnergyMembraneWang
from simulator.forces import AerodynamicDrag
from simulator.integrators.base import IncrementalPotential
from simulator.mesh import TriMesh
from simulator.model import SimControl, SimModel, SimState
from simulator.solvers.block_sparse import BlockSparse
from simulator.solvers.cg import conjugate_gradient
from simulator.solvers.coarse import TwoLevelPreconditioner, grid_aggregates
from simulator.threads import use_process_threads


@dataclasses.dataclass
class Problem:
    """One batch of linear systems."""

    matrix: BlockSparse
    """The Hessian as assembled by the integrator (finalised)."""
    matvec: Callable[[torch.Tensor], torch.Tensor]
    """The product masked to free dofs."""
    diag: torch.Tensor
    """Diagonal blocks (B, V, 3, 3) [N/m]."""
    free: torch.Tensor
    """Free mask (V, 1)."""
    rhs: torch.Tensor
    """Right-hand sides (B, V, 3) [N], zero at pinned vertices."""
    uv: torch.Tensor
    """Material coordinates (V, 2) [m]."""


def _bending(mesh, bending):
    if hasattr(EnergyBendingDihedral, "from_material"):
        return EnergyBendingDihedral.from_material(mesh, bending)
    return EnergyBendingDihedral(bending)


def build_problem(n: int = 32, batch: int = 54, seed: int = 0) -> Problem:
    """Hessian of one backward-Euler step of the reference scene, in float64 on the CPU."""
    gen = torch.Generator().manual_seed(seed)
    grid = TriMesh.grid(n, size_u=0.5)
    zeros = torch.zeros(grid.vert_count, dtype=torch.float64)
    pos0 = torch.stack([grid.uv[:, 0] - 0.25, zeros, 1.0 - grid.uv[:, 1]], -1)
    mesh = TriMesh.from_arrays(pos0.numpy(), grid.tri_indices.numpy(), grid.uv.numpy())
    mat = ClothMaterial.from_classes(list(range(batch)))
    pins = torch.tensor([0, n - 1])
    energies = (
        EnergyMembraneWang(mat.stretching),
        _bending(mesh, mat.bending),
        EnergyGravity(torch.tensor([0.0, 0.0, -9.81], dtype=torch.float64)),
    )
    mass = mat.density[:, None] * mesh.vert_area[None]
    model = SimModel(mesh, energies, (AerodynamicDrag(),), mass, pins).with_pattern()
    noise = 1e-3 * torch.randn(batch, mesh.vert_count, 3, generator=gen, dtype=torch.float64)
    pos = pos0[None].repeat(batch, 1, 1) + noise  # slightly deformed
    state = SimState(pos, torch.zeros_like(pos), torch.zeros(batch, dtype=torch.float64))
    wind = torch.zeros(batch, mesh.vert_count, 3, dtype=torch.float64)
    wind[..., 1] = 3.0
    control = SimControl(pin_pos=pos0[pins][None].repeat(batch, 1, 1), wind_vel=wind)
    bound = tuple(e.bind(model, control, state.pos) for e in model.energies)
    forces = tuple(f.linearize(model, state, control, bound) for f in model.forces)
    dt = 0.005
    obj = IncrementalPotential(model, bound, forces, state.pos, state.pos, dt)
    hess_matvec, diag, _ = obj.hessian(state.pos)

    # The same BlockSparse as IncrementalPotential.hessian assembles (element blocks with a
    # topology plus per-vertex mass and drag terms); anything else stays in the product only.
    eye = torch.eye(3, dtype=pos.dtype)
    vertex = (model.vert_mass[..., None] / (dt * dt))[..., None] * eye
    sparse = BlockSparse.zeros(model.pattern, batch, pos)
    for energy in bound:
        blocks = energy.hessian_blocks(model, pos)
        if blocks is not None and blocks.topology is not None:
            count = blocks.topology.shape[0]
            shaped = blocks.blocks.view(batch, count, *blocks.blocks.shape[1:])
            sparse.add_elements(blocks.topology, shaped)
    for force in forces:
        if force.damping_vertex is not None:
            vertex = vertex + force.damping_vertex / dt
    sparse.add_vertex_blocks(vertex)
    sparse = sparse.finalize()

    free = model.free_mask()
    probe = torch.randn(pos.shape, generator=gen, dtype=pos.dtype)
    mismatch = float((sparse.matvec(probe) - hess_matvec(probe)).abs().max())
    scale = float(hess_matvec(probe).abs().max())
    if mismatch > 1e-9 * scale:
        print(f"note: BlockSparse misses part of the Hessian (max |diff| {mismatch:.2e})")
    rhs = torch.randn(pos.shape, generator=gen, dtype=pos.dtype) * free

    def matvec(v):
        return hess_matvec(v * free) * free

    return Problem(sparse, matvec, diag, free, rhs, mesh.uv)


def subset(problem: Problem, index: slice, dtype: torch.dtype, device: str) -> Problem:
    """Instances ``index`` of ``problem`` as ``dtype`` on ``device`` (product via BlockSparse)."""

    def cast(t):
        return t.to(device=device, dtype=dtype)

    pattern = dataclasses.replace(
        problem.matrix.pattern, cols=problem.matrix.pattern.cols.to(device)
    )
    matrix = BlockSparse(pattern, cast(problem.matrix.values[index])).finalize()
    free = cast(problem.free)

    def matvec(v):
        return matrix.matvec(v * free) * free

    return Problem(
        matrix, matvec, cast(problem.diag[index]), free, cast(problem.rhs[index]), problem.uv
    )


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def _timed(fn, device: str):
    _sync(device)
    start = time.perf_counter()
    out = fn()
    _sync(device)
    return time.perf_counter() - start, out


def jacobi(problem: Problem):
    """Block-Jacobi, as in :func:`newton_minimize`."""
    diag_inv = torch.linalg.inv(problem.diag)
    free = problem.free

    def precond(r):
        return (diag_inv @ r[..., None])[..., 0] * free

    return precond


def run_config(problem: Problem, make, rtols, repeats: int, device: str) -> dict:
    """Median build / solve times and iteration counts of one preconditioner."""
    make()  # warm-up
    builds = []
    for _ in range(repeats):
        seconds, precond = _timed(make, device)
        builds.append(seconds)
    out = {"build_ms": 1e3 * statistics.median(builds)}
    for rtol in rtols:
        times = []
        for _ in range(repeats):

            def solve(rtol=rtol, precond=precond):
                return conjugate_gradient(
                    problem.matvec, problem.rhs, precond, rtol=rtol, max_iters=2000
                )

            seconds, (_, iters, res) = _timed(solve, device)
            times.append(seconds)
        out[f"{rtol:g}"] = {
            "iters_max": int(iters.max()),
            "iters_median": int(iters.median()),
            "solve_ms": 1e3 * statistics.median(times),
            "total_ms": out["build_ms"] + 1e3 * statistics.median(times),
            "max_rel_residual": float(res.max()),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dtypes", default="float64,float32")
    parser.add_argument("--batches", default="54,1", help="54 = all classes, 1 = the stiffest")
    parser.add_argument("--patches", default="2,4,8")
    parser.add_argument("--variants", default="additive,vcycle")
    parser.add_argument("--rtols", default="1e-2,1e-4")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (0: one per core)")
    args = parser.parse_args()
    use_process_threads(args.threads or None)
    rtols = [float(r) for r in args.rtols.split(",")]
    base = build_problem()
    total = base.rhs.shape[0]
    rows = []
    header = f"{'dtype':8s} {'B':>3s} {'precond':12s} {'A':>4s} {'build ms':>9s}" + "".join(
        f" | rtol {r:<6g} it max/med   solve ms   total ms" for r in rtols
    )
    print(f"torch {torch.__version__}, device {args.device}, threads {torch.get_num_threads()}")
    print(header)
    print("-" * len(header))
    for dtype_name in args.dtypes.split(","):
        dtype = getattr(torch, dtype_name)
        for batch in (int(b) for b in args.batches.split(",")):
            problem = subset(base, slice(total - batch, total), dtype, args.device)
            configs = [("jacobi", 0, lambda problem=problem: jacobi(problem))]
            for patch in (int(p) for p in args.patches.split(",")):
                agg = grid_aggregates(problem.uv, patch).to(args.device)
                for variant in args.variants.split(","):

                    def make(problem=problem, agg=agg, variant=variant):
                        return TwoLevelPreconditioner.build(
                            problem.matrix, problem.diag, agg, problem.free, variant=variant
                        )

                    configs.append((f"{variant}-p{patch}", int(agg.max()) + 1, make))
            for name, n_agg, make in configs:
                result = run_config(problem, make, rtols, args.repeats, args.device)
                row = {"dtype": dtype_name, "batch": batch, "precond": name, "aggregates": n_agg}
                row.update(result)
                rows.append(row)
                line = f"{dtype_name:8s} {batch:3d} {name:12s} {n_agg:4d} {result['build_ms']:9.1f}"
                for r in rtols:
                    f = result[f"{r:g}"]
                    line += (
                        f" | {'':11s} {f['iters_max']:4d}/{f['iters_median']:<4d}"
                        f" {f['solve_ms']:10.1f} {f['total_ms']:10.1f}"
                    )
                print(line, flush=True)
    key = f"{rtols[0]:g}"
    big = [r for r in rows if r["batch"] == max(x["batch"] for x in rows)]
    first = [r for r in big if r["dtype"] == big[0]["dtype"]]
    best = min(first, key=lambda r: r[key]["total_ms"])
    baseline = next(r for r in first if r["precond"] == "jacobi")
    summary = {
        "best": best,
        "jacobi": baseline,
        "speedup_total": baseline[key]["total_ms"] / best[key]["total_ms"],
        "iteration_ratio": baseline[key]["iters_max"] / best[key]["iters_max"],
        "device": args.device,
        "threads": torch.get_num_threads(),
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
