"""Two-level aggregation preconditioner: SPD-ness, pin handling and PCG convergence."""

import math

import pytest
import torch

from simulator.mesh import TriMesh
from simulator.solvers.block_sparse import BlockPattern, BlockSparse
from simulator.solvers.cg import conjugate_gradient
from simulator.solvers.coarse import TwoLevelPreconditioner, grid_aggregates

DT = torch.float64
VARIANTS = ("additive", "vcycle")


def _stiff_problem(n=8, batch=3, stiffness=(50.0, 500.0, 5000.0), mass=3.0, seed=0):
    """Membrane-like SPD systems on an n x n grid: anisotropic edge springs + small mass."""
    gen = torch.Generator().manual_seed(seed)
    grid = TriMesh.grid(n, size_u=0.3)
    tris = grid.tri_indices.long()
    pattern = BlockPattern.from_topologies(grid.vert_count, [tris])
    # Each triangle: sum over its edges of (e_i - e_j)(e_i - e_j)^T (x) S_e with S_e SPD.
    edge_pairs = torch.tensor([[0, 1], [1, 2], [2, 0]])
    sel = torch.zeros(3, 3, 3, dtype=DT)  # (edge, local vertex, local vertex)
    for e, (i, j) in enumerate(edge_pairs.tolist()):
        d = torch.zeros(3, dtype=DT)
        d[i], d[j] = 1.0, -1.0
        sel[e] = torch.outer(d, d)
    g = torch.randn(batch, tris.shape[0], 3, 3, 3, generator=gen, dtype=DT)
    spd = g @ g.transpose(-1, -2) / 3 + 0.05 * torch.eye(3, dtype=DT)  # (B, F, edge, 3, 3)
    k = torch.tensor(stiffness, dtype=DT)[:batch].view(batch, 1, 1, 1, 1)
    blocks = torch.einsum("eij,bfexy->bfijxy", sel, spd) * k[..., None]
    matrix = BlockSparse.zeros(pattern, batch, blocks)
    matrix.add_elements(tris, blocks)
    matrix.add_vertex_blocks(mass * torch.eye(3, dtype=DT).expand(batch, grid.vert_count, 3, 3))
    return matrix.finalize(), grid.uv


def _free(verts, pinned, batch=None):
    free = torch.ones(verts, 1, dtype=DT)
    free[pinned] = 0.0
    return free if batch is None else free[None].repeat(batch, 1, 1)


def _jacobi(matrix, free):
    diag_inv = torch.linalg.inv(matrix.diagonal())
    return lambda r: (diag_inv @ r[..., None])[..., 0] * free


def _dot(a, b):
    return (a * b).flatten(1).sum(-1)


def test_grid_aggregates_cover_grid_and_irregular_layouts():
    uv = TriMesh.grid(8, size_u=0.3).uv
    for patch in (1, 2, 3, 4, 8):
        ids = grid_aggregates(uv, patch)
        count = int(ids.max()) + 1
        assert ids.dtype == torch.int64 and ids.shape == (64,)
        assert int(ids.min()) == 0
        assert torch.bincount(ids).min() > 0  # every id in [0, A) is used
        assert count == math.ceil(8 / patch) ** 2
    gen = torch.Generator().manual_seed(1)
    angle = 2 * math.pi * torch.rand(500, generator=gen, dtype=DT)
    radius = torch.rand(500, generator=gen, dtype=DT).sqrt()
    disk = torch.stack([radius * angle.cos(), 2.0 + radius * angle.sin()], -1)  # not a grid
    ids = grid_aggregates(disk, 4)
    count = int(ids.max()) + 1
    assert torch.bincount(ids).min() > 0
    assert 500 / 16 / 1.5 <= count <= 500 / 16 * 1.5
    assert int(grid_aggregates(disk[:1], 4).max()) == 0


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("per_batch_pins", [False, True])
def test_symmetric_definite_and_zero_on_pins(variant, per_batch_pins):
    matrix, uv = _stiff_problem()
    batch, verts = matrix.values.shape[:2]
    pinned = torch.tensor([0, 7])
    free = _free(verts, pinned, batch if per_batch_pins else None)
    if per_batch_pins:
        free[1, 20] = 0.0  # instances may pin different vertices
    pc = TwoLevelPreconditioner.build(
        matrix, matrix.diagonal(), grid_aggregates(uv, 2), free, variant=variant
    )
    gen = torch.Generator().manual_seed(2)
    x = torch.randn(batch, verts, 3, generator=gen, dtype=DT)
    y = torch.randn(batch, verts, 3, generator=gen, dtype=DT)
    mx, my = pc(x), pc(y)
    torch.testing.assert_close(_dot(y, mx), _dot(x, my), rtol=1e-12, atol=0.0)
    assert float((mx * (1 - free)).abs().max()) == 0.0
    # Dense M on the free dofs of each instance: symmetric positive definite.
    eye = torch.eye(verts * 3, dtype=DT).view(verts * 3, verts, 3)
    for b in range(batch):
        dense = torch.stack([pc(e[None].expand(batch, -1, -1))[b].reshape(-1) for e in eye], 1)
        keep = (free[b] if per_batch_pins else free).repeat(1, 3).reshape(-1) > 0
        sub = dense[keep][:, keep]
        torch.testing.assert_close(sub, sub.T, rtol=0.0, atol=1e-12 * float(sub.abs().max()))
        assert float(torch.linalg.eigvalsh(0.5 * (sub + sub.T))[0]) > 0.0
        assert float(dense[~keep].abs().max()) == 0.0


@pytest.mark.parametrize("variant", VARIANTS)
def test_pcg_converges_faster_than_block_jacobi(variant):
    matrix, uv = _stiff_problem()
    batch, verts = matrix.values.shape[:2]
    free = _free(verts, torch.tensor([0, 7]))

    def matvec(v):
        return matrix.matvec(v * free) * free

    gen = torch.Generator().manual_seed(3)
    rhs = torch.randn(batch, verts, 3, generator=gen, dtype=DT) * free
    pc = TwoLevelPreconditioner.build(
        matrix, matrix.diagonal(), grid_aggregates(uv, 2), free, variant=variant
    )
    x, iters, res = conjugate_gradient(matvec, rhs, pc, rtol=1e-8, max_iters=500, check_every=1)
    _, iters_jac, res_jac = conjugate_gradient(
        matvec, rhs, _jacobi(matrix, free), rtol=1e-8, max_iters=500, check_every=1
    )
    assert bool((res <= 1e-8).all()) and bool((res_jac <= 1e-8).all())
    true_res = torch.linalg.vector_norm((rhs - matvec(x)).flatten(1), dim=1)
    assert bool((true_res <= 1e-7 * torch.linalg.vector_norm(rhs.flatten(1), dim=1)).all())
    assert int(iters.max()) < int(iters_jac.max())
    assert bool((iters <= iters_jac).all())


def test_fully_pinned_aggregate_and_float32():
    matrix, uv = _stiff_problem(batch=2)
    verts = matrix.values.shape[1]
    agg = grid_aggregates(uv, 2)
    free = _free(verts, torch.nonzero(agg == agg[0]).flatten())  # the whole first aggregate
    m32 = BlockSparse(matrix.pattern, matrix.values.float())  # not finalised on purpose
    for variant in VARIANTS:
        pc = TwoLevelPreconditioner.build(m32, m32.diagonal(), agg, free.float(), variant=variant)
        assert pc.coarse_inv.dtype == torch.float32
        r = torch.randn(2, verts, 3) * free.float()
        z = pc(r)
        assert bool(torch.isfinite(z).all())
        assert float(_dot(r, z).min()) > 0.0
        assert float((z * (1 - free.float())).abs().max()) == 0.0


def test_build_validates_inputs():
    matrix, uv = _stiff_problem(batch=1)
    free = _free(matrix.values.shape[1], torch.tensor([0]))
    with pytest.raises(ValueError, match="variant"):
        TwoLevelPreconditioner.build(
            matrix, matrix.diagonal(), grid_aggregates(uv, 2), free, variant="w"
        )
    with pytest.raises(ValueError, match="aggregates"):
        TwoLevelPreconditioner.build(matrix, matrix.diagonal(), torch.zeros(3).long(), free)
    with pytest.raises(ValueError, match="patch"):
        grid_aggregates(uv, 0)
