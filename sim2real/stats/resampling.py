"""Resampling that moves whole groups: permutations, bootstrap draws, half splits, noise floors."""

from __future__ import annotations

import numpy as np

from .checks import Statistic, _as_features, _check_pair, _check_rng, _group_codes, _row_count

__all__ = [
    "TIE_RTOL",
    "bootstrap_draws",
    "group_bootstrap",
    "noise_floor",
    "permutation_pvalue",
    "split_groups",
]


TIE_RTOL = 1e-10
"""Resampled statistics within this relative distance of the observed one count as ties."""


def bootstrap_draws(group_count: int, n_boot: int, rng: np.random.Generator) -> np.ndarray:
    """Times each of ``group_count`` groups is drawn in each of ``n_boot`` replicates, (G, B)."""
    _check_rng(rng)
    return _bootstrap_draws(group_count, n_boot, rng)


def _permutation_sides(
    codes: np.ndarray, side_groups: int, group_count: int, n_perm: int, rng: np.random.Generator
) -> np.ndarray:
    """Random side-0 membership per row, shape (N, n_perm): side_groups whole groups each."""
    chosen = np.zeros((n_perm, group_count), dtype=bool)
    for p in range(n_perm):
        chosen[p, rng.permutation(group_count)[:side_groups]] = True
    return chosen[:, codes].T


def _bootstrap_draws(group_count: int, n_boot: int, rng: np.random.Generator) -> np.ndarray:
    """Times each group is drawn, shape (G, n_boot): G draws with replacement per replicate."""
    draws = rng.integers(group_count, size=(n_boot, group_count))
    flat = (draws + group_count * np.arange(n_boot)[:, None]).ravel()
    return np.bincount(flat, minlength=n_boot * group_count).reshape(n_boot, group_count).T


def _split_sides(
    codes: np.ndarray, group_count: int, n_splits: int, rng: np.random.Generator
) -> np.ndarray:
    """Half/half group splits, shape (n, n_splits); True marks the first half's rows."""
    return _permutation_sides(codes, group_count // 2, group_count, n_splits, rng)


def _pvalue(observed: float, resampled: np.ndarray) -> float:
    tol = TIE_RTOL * max(1.0, abs(observed))  # round-off ties count as ties (conservative)
    return float((1 + np.count_nonzero(resampled >= observed - tol)) / (1 + resampled.size))


def permutation_pvalue(
    x: np.ndarray,
    y: np.ndarray,
    gx: np.ndarray,
    gy: np.ndarray,
    statistic: Statistic,
    *,
    n_perm: int = 200,
    rng: np.random.Generator,
) -> float:
    """Group-level permutation test of "x and y come from one distribution".

    Whole groups are re-assigned to the two sides (each side keeps its number of groups), so
    the test holds its level when clips within a group are correlated; a clip-level
    permutation would not.

    Args:
        x: First sample, shape (n, d).
        y: Second sample, shape (m, d).
        gx: Group id per row of x, shape (n,).
        gy: Group id per row of y, shape (m,).
        statistic: ``f(x', y') -> float``, larger = more different.
        n_perm: Number of permutations.
        rng: Source of the permutations.

    Returns:
        p = (1 + #{permuted >= observed}) / (1 + n_perm).
    """
    _check_rng(rng)
    x, y = _check_pair(x, y)
    cx, gx_count = _group_codes(gx, x.shape[0], "gx")
    cy, gy_count = _group_codes(gy, y.shape[0], "gy")
    if n_perm < 1:
        raise ValueError(f"n_perm must be >= 1, got {n_perm}")
    z = np.vstack([x, y])
    sides = _permutation_sides(
        np.concatenate([cx, cy + gx_count]), gx_count, gx_count + gy_count, n_perm, rng
    )
    resampled = np.array([statistic(z[s], z[~s]) for s in sides.T], dtype=np.float64)
    return _pvalue(float(statistic(x, y)), resampled)


def group_bootstrap(
    x: np.ndarray,
    y: np.ndarray,
    gx: np.ndarray,
    gy: np.ndarray,
    statistic: Statistic,
    *,
    n_boot: int = 200,
    rng: np.random.Generator,
) -> np.ndarray:
    """Group bootstrap: resample groups with replacement within each domain.

    A drawn group brings all its clips, so the spread reflects how many simulations and
    videos there are, not how many clips. The statistic sees a group drawn twice as two
    copies of its clips; for a pairwise statistic such as :func:`mmd2_unbiased` those copies
    pair up and bias the replicates upward (by about the between-group variance / G), which
    is why :func:`compare` uses a kernel form that drops such pairs.

    Args:
        x: First sample, shape (n, d).
        y: Second sample, shape (m, d).
        gx: Group id per row of x, shape (n,).
        gy: Group id per row of y, shape (m,).
        statistic: ``f(x*, y*) -> float`` (must not depend on row order).
        n_boot: Number of replicates.
        rng: Source of the draws.

    Returns:
        The statistic per replicate, shape (n_boot,).
    """
    _check_rng(rng)
    x, y = _check_pair(x, y, min_rows=1)
    cx, gx_count = _group_codes(gx, x.shape[0], "gx")
    cy, gy_count = _group_codes(gy, y.shape[0], "gy")
    count_x = _bootstrap_draws(gx_count, n_boot, rng)[cx]
    count_y = _bootstrap_draws(gy_count, n_boot, rng)[cy]
    return np.array(
        [
            statistic(np.repeat(x, count_x[:, b], axis=0), np.repeat(y, count_y[:, b], axis=0))
            for b in range(n_boot)
        ],
        dtype=np.float64,
    )


def split_groups(groups: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Random half/half split of the groups (never of clips) of one domain.

    The two halves are independent draws of the same domain, so a statistic between them is
    the within-domain noise floor (S vs S' split by simulation).

    Args:
        groups: Group id per row, shape (n,), at least 2 distinct ids.
        rng: Source of the split.

    Returns:
        ``(mask_a, mask_b)``, complementary boolean row masks, shape (n,); mask_a holds
        floor(G / 2) of the G groups.
    """
    _check_rng(rng)
    codes, group_count = _group_codes(groups, _row_count(groups), "groups")
    if group_count < 2:
        raise ValueError(f"groups must hold >= 2 distinct ids to split, got {group_count}")
    side = _split_sides(codes, group_count, 1, rng)[:, 0]
    return side, ~side


def noise_floor(
    x: np.ndarray,
    gx: np.ndarray,
    statistic: Statistic,
    *,
    n_splits: int = 10,
    rng: np.random.Generator,
) -> np.ndarray:
    """A two-sample statistic between random group halves of one domain.

    Args:
        x: Rows of one domain, shape (n, d).
        gx: Group id per row, shape (n,), at least 2 distinct ids.
        statistic: ``f(half_a, half_b) -> float``.
        n_splits: Number of random splits.
        rng: Source of the splits.

    Returns:
        The statistic per split, shape (n_splits,).
    """
    _check_rng(rng)
    x = _as_features(x, "x")
    codes, group_count = _group_codes(gx, x.shape[0], "gx")
    if group_count < 2:
        raise ValueError(f"gx must hold >= 2 distinct ids to split, got {group_count}")
    sides = _split_sides(codes, group_count, n_splits, rng)
    return np.array([statistic(x[s], x[~s]) for s in sides.T], dtype=np.float64)
