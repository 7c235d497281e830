"""Fixed-pattern block-sparse (ELL) matrices for fast batched Hessian products.

The Hessian of elements on a shared mesh always has the same sparsity: vertex
``i`` couples to the vertices it shares an element with. :class:`BlockPattern`
stores, once per mesh, each vertex's neighbour list padded to a common width
``K`` (ELLPACK layout) and where every entry of every element block lands in it.
Assembling is then one ``index_add`` per element type, and a product is one
gather plus one batched contraction, with no scatter; this is several times
faster than multiplying element by element, on CPU and GPU alike.
"""

from __future__ import annotations

import dataclasses

import torch

__all__ = ["BlockPattern", "BlockSparse"]


@dataclasses.dataclass(frozen=True)
class BlockPattern:
    """Neighbour lists of a mesh's vertices (ELLPACK layout)."""

    cols: torch.Tensor
    """Neighbour vertex of each slot (padded with the row itself), int64, shape (V, K)."""
    _slot_cache: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)

    @property
    def vert_count(self) -> int:
        """V."""
        return int(self.cols.shape[0])

    @staticmethod
    def from_topologies(vert_count: int, topologies: list[torch.Tensor]) -> BlockPattern:
        """Build the pattern that covers every element of every topology (each (N, k))."""
        rows, nbrs = [torch.arange(vert_count)], [torch.arange(vert_count)]
        for topo in topologies:
            k = topo.shape[1]
            rows.append(topo[:, :, None].expand(-1, k, k).reshape(-1))
            nbrs.append(topo[:, None, :].expand(-1, k, k).reshape(-1))
        pairs = torch.unique(torch.stack([torch.cat(rows), torch.cat(nbrs)], 1), dim=0)
        counts = torch.bincount(pairs[:, 0], minlength=vert_count)
        width = int(counts.max())
        cols = torch.arange(vert_count)[:, None].repeat(1, width)
        start = torch.cumsum(counts, 0) - counts
        slot = torch.arange(pairs.shape[0]) - start[pairs[:, 0]]
        cols[pairs[:, 0], slot] = pairs[:, 1]
        return BlockPattern(cols)

    def slot_map(self, topology: torch.Tensor) -> torch.Tensor:
        """Flat slot ``row * K + slot`` of each entry (a, b) of each element, shape (N, k, k)."""
        key = (topology.data_ptr(), tuple(topology.shape), topology.device)
        cached = self._slot_cache.get(key)
        if cached is not None and cached[0] is topology:
            return cached[1]
        k = topology.shape[1]
        rows = topology[:, :, None].expand(-1, k, k)
        target = topology[:, None, :].expand(-1, k, k)
        hit = self.cols[rows] == target[..., None]  # (N, k, k, K)
        if not bool(hit.any(-1).all()):
            raise ValueError("BlockPattern does not cover this element topology")
        slots = rows * self.cols.shape[1] + hit.int().argmax(-1)
        self._slot_cache[key] = (topology, slots)
        return slots

    def diagonal_slots(self) -> torch.Tensor:
        """Flat slot ``row * K + k`` of each row's diagonal block (V,), computed once."""
        cached = self._slot_cache.get("diagonal")
        if cached is None:
            rows = torch.arange(self.cols.shape[0], device=self.cols.device)
            first = (self.cols == rows[:, None]).int().argmax(dim=1)
            cached = self._slot_cache["diagonal"] = rows * self.cols.shape[1] + first
        return cached

    def to(self, device=None, dtype=None) -> BlockPattern:
        """Copy to ``device``."""
        return BlockPattern(self.cols.to(device))


@dataclasses.dataclass(frozen=True)
class BlockSparse:
    """A batch of block-sparse matrices sharing one :class:`BlockPattern`.

    Assemble with :meth:`add_elements` / :meth:`add_vertex_blocks`; the first product lays
    rows out as (3, 3K) matrices (or call :meth:`finalize`), so that a product is a single
    batched matmul. Solvers that read ``values`` directly (the compiled kernels) never pay
    for that layout.
    """

    pattern: BlockPattern
    values: torch.Tensor
    """3x3 blocks, shape (B, V, K, 3, 3)."""
    rows: torch.Tensor | None = None
    """Finalised row matrices, shape (B * V, 3, 3K)."""
    _lazy_rows: dict = dataclasses.field(
        default_factory=dict, init=False, compare=False, repr=False
    )
    """Row layout built by the first :meth:`matvec` of an unfinalised matrix."""

    @staticmethod
    def zeros(pattern: BlockPattern, batch: int, like: torch.Tensor) -> BlockSparse:
        """All-zero matrices."""
        v, k = pattern.cols.shape
        return BlockSparse(pattern, like.new_zeros(batch, v, k, 3, 3))

    def add_elements(self, topology: torch.Tensor, blocks: torch.Tensor) -> None:
        """Accumulate element blocks (B, N, k, k, 3, 3) of ``topology`` (N, k) in place."""
        batch = blocks.shape[0]
        slots = self.pattern.slot_map(topology).reshape(1, -1)
        per_batch = self.values.shape[1] * self.values.shape[2]
        offset = torch.arange(batch, device=slots.device)[:, None] * per_batch
        # One flat index_add over dim 0 is several times faster on CPU than along dim 1.
        self.values.view(-1, 3, 3).index_add_(
            0, (slots + offset).reshape(-1), blocks.reshape(-1, 3, 3)
        )

    def add_vertex_blocks(self, blocks: torch.Tensor) -> None:
        """Accumulate per-vertex diagonal blocks (B, V, 3, 3) in place."""
        self.values.view(blocks.shape[0], -1, 3, 3).index_add_(1, self._diag_slots(), blocks)

    def _diag_slots(self) -> torch.Tensor:
        """Flat slot of each row's diagonal block (V,) (:meth:`BlockPattern.diagonal_slots`)."""
        return self.pattern.diagonal_slots()

    def diagonal(self) -> torch.Tensor:
        """Diagonal 3x3 blocks, shape (B, V, 3, 3)."""
        batch = self.values.shape[0]
        return self.values.view(batch, -1, 3, 3)[:, self._diag_slots()]

    def finalize(self) -> BlockSparse:
        """Return the matrix with its product layout built."""
        return dataclasses.replace(self, rows=self._row_layout())

    def _row_layout(self) -> torch.Tensor:
        batch, verts, width = self.values.shape[:3]
        rows = self.values.permute(0, 1, 3, 2, 4).reshape(batch * verts, 3, 3 * width)
        return rows.contiguous()

    def matvec(self, vec: torch.Tensor) -> torch.Tensor:
        """Product with a field (B, V, 3); returns (B, V, 3).

        Unfinalised matrices build their row layout on the first product, so assemble
        everything before multiplying.
        """
        rows = self.rows
        if rows is None:
            rows = self._lazy_rows.get("rows")
            if rows is None:
                rows = self._lazy_rows["rows"] = self._row_layout()
        batch, verts = vec.shape[:2]
        gathered = vec[:, self.pattern.cols].reshape(batch * verts, -1, 1)
        return torch.bmm(rows, gathered).view(batch, verts, 3)
