"""Kernel two-sample statistics: unbiased RBF MMD², KID, and their group-bootstrap replicates."""

from __future__ import annotations

import math

import numpy as np

from .checks import _as_features, _check_pair, _group_codes

__all__ = ["MAX_BANDWIDTH_ROWS", "kid", "median_bandwidth", "mmd2_replicates", "mmd2_unbiased"]


MAX_BANDWIDTH_ROWS = 1000
"""Rows (strided subsample) used by :func:`median_bandwidth`."""


def _sq_dists(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise squared Euclidean distances, shape (len(a), len(b)), clipped at 0."""
    d2 = (a * a).sum(axis=1)[:, None] + (b * b).sum(axis=1)[None, :] - 2.0 * (a @ b.T)
    return np.maximum(d2, 0.0)


def _rbf(a: np.ndarray, b: np.ndarray, bandwidth: float) -> np.ndarray:
    return np.exp(-_sq_dists(a, b) / (2.0 * bandwidth**2))


def _poly3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a @ b.T / a.shape[1] + 1.0) ** 3


def median_bandwidth(x: np.ndarray) -> float:
    """RBF bandwidth by the median heuristic: sqrt(median pairwise squared distance / 2).

    Gives a kernel scale matched to the data without tuning. At most
    :data:`MAX_BANDWIDTH_ROWS` evenly strided rows are used, so the result is deterministic.

    Args:
        x: Rows, shape (n, d).

    Returns:
        Bandwidth > 0; the median of the non-zero distances if most rows coincide, 1.0 if all
        rows are equal (or n < 2).
    """
    x = _as_features(x, "x")
    if x.shape[0] > MAX_BANDWIDTH_ROWS:
        x = x[np.linspace(0, x.shape[0] - 1, MAX_BANDWIDTH_ROWS).round().astype(np.int64)]
    if x.shape[0] < 2:
        return 1.0
    d2 = _sq_dists(x, x)[np.triu_indices(x.shape[0], k=1)]
    # Round-off of the expanded form leaves ~eps·|x|² instead of 0 for equal rows.
    d2[d2 <= 1e-12 * max(1.0, float((x * x).sum(axis=1).max()))] = 0.0
    med = float(np.median(d2))
    if med <= 0.0:
        positive = d2[d2 > 0.0]
        if positive.size == 0:
            return 1.0
        med = float(np.median(positive))
    return math.sqrt(med / 2.0)


def _mmd2_blocks(kxx: np.ndarray, kyy: np.ndarray, kxy: np.ndarray) -> float:
    """Unbiased MMD² from kernel blocks (diagonals of kxx, kyy excluded)."""
    n, m = kxx.shape[0], kyy.shape[0]
    within_x = (kxx.sum() - np.trace(kxx)) / (n * (n - 1))
    within_y = (kyy.sum() - np.trace(kyy)) / (m * (m - 1))
    return float(within_x + within_y - 2.0 * kxy.mean())


def mmd2_unbiased(x: np.ndarray, y: np.ndarray, bandwidth: float) -> float:
    """Unbiased MMD² (Gretton et al. 2012, eq. 3) with k(a, b) = exp(-|a-b|² / (2 bw²)).

    Zero in expectation when x and y come from one distribution, so small gaps are not
    masked by a positive bias; it can be slightly negative.

    Args:
        x: First sample, shape (n, d), n >= 2.
        y: Second sample, shape (m, d), m >= 2.
        bandwidth: RBF bandwidth bw > 0 (same units as the features).

    Returns:
        The estimate (float).
    """
    x, y = _check_pair(x, y)
    if not (math.isfinite(bandwidth) and bandwidth > 0.0):
        raise ValueError(f"bandwidth must be finite and > 0, got {bandwidth}")
    return _mmd2_blocks(_rbf(x, x, bandwidth), _rbf(y, y, bandwidth), _rbf(x, y, bandwidth))


def kid(x: np.ndarray, y: np.ndarray) -> float:
    """Kernel Inception Distance (Bińkowski et al. 2018): unbiased MMD², cubic kernel.

    The kernel k(a, b) = (a·b / d + 1)³ needs no bandwidth, so KID is a bandwidth-free
    cross-check of the RBF MMD².

    Args:
        x: First sample, shape (n, d), n >= 2.
        y: Second sample, shape (m, d), m >= 2.

    Returns:
        The estimate (float).
    """
    x, y = _check_pair(x, y)
    return _mmd2_blocks(_poly3(x, x), _poly3(y, y), _poly3(x, y))


def _mmd2_sides(k: np.ndarray, diag: np.ndarray, side: np.ndarray) -> np.ndarray:
    """Unbiased MMD² between the rows with side 1 and side 0, for many splits at once.

    Args:
        k: Kernel matrix of all rows, shape (N, N).
        diag: Its diagonal, shape (N,).
        side: 0/1 membership of the first sample, shape (N, P), one column per split.

    Returns:
        MMD² per split, shape (P,).
    """
    u = side.astype(np.float64)
    ku = k @ u
    uku = np.einsum("ip,ip->p", u, ku)
    one_ku = ku.sum(axis=0)
    vkv = k.sum() - 2.0 * one_ku + uku
    ukv = one_ku - uku
    n_a = u.sum(axis=0)
    n_b = k.shape[0] - n_a
    diag_a = diag @ u
    diag_b = diag.sum() - diag_a
    return (
        (uku - diag_a) / (n_a * (n_a - 1.0))
        + (vkv - diag_b) / (n_b * (n_b - 1.0))
        - 2.0 * ukv / (n_a * n_b)
    )


def _group_block_sums(
    k: np.ndarray, codes: np.ndarray, group_count: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-group kernel block sums (diagonal included), diagonal sums and sizes, each (G,)."""
    onehot = np.zeros((codes.shape[0], group_count))
    onehot[np.arange(codes.shape[0]), codes] = 1.0
    block = np.einsum("ig,ig->g", onehot, k @ onehot)
    return block, np.bincount(codes, weights=np.diag(k), minlength=group_count), onehot.sum(0)


def _within_mean_resampled(k: np.ndarray, codes: np.ndarray, group_draws: np.ndarray) -> np.ndarray:
    """Mean kernel over the admissible pairs of a group-resampled sample, per replicate.

    A pair is admissible unless both clips come from copies of one original group that are
    different draws (or it is a clip with itself). Pairs of two copies of one group would
    count that group's high within-group similarity as between-group similarity and inflate
    the bootstrap MMD² by about (between-group variance) / G; dropping them keeps the
    replicates centred on the estimate.

    Args:
        k: Kernel matrix of one domain, shape (n, n).
        codes: Group code per row, shape (n,), values 0..G-1.
        group_draws: Times each group was drawn, shape (G, B).

    Returns:
        Mean kernel over admissible ordered pairs, shape (B,).
    """
    block, diag, sizes = _group_block_sums(k, codes, group_draws.shape[0])
    c = group_draws.astype(np.float64)
    rows = c[codes]
    total = np.einsum("ib,ib->b", rows, k @ rows) - (c * c).T @ block + c.T @ (block - diag)
    pairs = (c.T @ sizes) ** 2 - (c * c).T @ (sizes * sizes) + c.T @ (sizes * sizes - sizes)
    with np.errstate(invalid="ignore", divide="ignore"):  # no pairs: NaN replicate
        return total / pairs


def _mmd2_group_bootstrap(
    kxx: np.ndarray,
    kyy: np.ndarray,
    kxy: np.ndarray,
    cx: np.ndarray,
    cy: np.ndarray,
    draws_x: np.ndarray,
    draws_y: np.ndarray,
) -> np.ndarray:
    """Group-bootstrap replicates of the unbiased MMD², from the kernel blocks.

    Args:
        kxx: Kernel block of x, shape (n, n).
        kyy: Kernel block of y, shape (m, m).
        kxy: Cross block, shape (n, m).
        cx: Group code per row of x, shape (n,).
        cy: Group code per row of y, shape (m,).
        draws_x: Times each x group was drawn, shape (Gx, B).
        draws_y: Times each y group was drawn, shape (Gy, B).

    Returns:
        MMD² per replicate, shape (B,); see :func:`_within_mean_resampled` for the pairs used.
    """
    rows_x = draws_x[cx].astype(np.float64)
    rows_y = draws_y[cy].astype(np.float64)
    cross = np.einsum("ib,ib->b", rows_x, kxy @ rows_y) / (rows_x.sum(0) * rows_y.sum(0))
    return (
        _within_mean_resampled(kxx, cx, draws_x)
        + _within_mean_resampled(kyy, cy, draws_y)
        - 2.0 * cross
    )


def mmd2_replicates(
    x: np.ndarray,
    y: np.ndarray,
    gx: np.ndarray,
    gy: np.ndarray,
    bandwidth: float,
    draws_x: np.ndarray | None,
    draws_y: np.ndarray,
) -> np.ndarray:
    """Group-bootstrap replicates of the unbiased RBF MMD² for given group draws.

    The caller draws (:func:`bootstrap_draws`) and can share one draw between several
    comparisons, e.g. between the sets of one candidate at several strengths, which hold the
    same simulations: their replicates then differ only by the strength.

    Args:
        x: First sample, shape (n, d).
        y: Second sample, shape (m, d).
        gx: Group id per row of x, shape (n,); codes follow ``np.unique`` order.
        gy: Group id per row of y, shape (m,).
        bandwidth: RBF bandwidth > 0.
        draws_x: Times each x group is drawn, shape (Gx, B); ``None`` keeps x as it is.
        draws_y: Times each y group is drawn, shape (Gy, B).

    Returns:
        MMD² per replicate, shape (B,).
    """
    x, y = _check_pair(x, y)
    cx, gx_count = _group_codes(gx, x.shape[0], "gx")
    cy, gy_count = _group_codes(gy, y.shape[0], "gy")
    if draws_x is None:
        draws_x = np.ones((gx_count, draws_y.shape[1]), dtype=np.int64)
    if draws_x.shape[0] != gx_count or draws_y.shape[0] != gy_count:
        raise ValueError(
            f"draws must have one row per group: x {draws_x.shape[0]} vs {gx_count}, "
            f"y {draws_y.shape[0]} vs {gy_count}"
        )
    kxx, kyy, kxy = _rbf(x, x, bandwidth), _rbf(y, y, bandwidth), _rbf(x, y, bandwidth)
    return _mmd2_group_bootstrap(kxx, kyy, kxy, cx, cy, draws_x, draws_y)
