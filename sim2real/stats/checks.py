"""Inputs of the statistics: feature matrices, group codes, generators, standardisation."""

from __future__ import annotations

from collections.abc import Callable
from typing import overload

import numpy as np

__all__ = ["STD_FLOOR", "Statistic", "standardize"]


Statistic = Callable[[np.ndarray, np.ndarray], float]
"""Two-sample statistic ``f(x (n, d), y (m, d)) -> float``, larger = more different."""


STD_FLOOR = 1e-12
"""Columns whose std is below this fraction of the largest std are only centred."""


def _row_count(a: np.ndarray) -> int:
    return int(np.shape(a)[0]) if np.ndim(a) else 0


def _as_features(a: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be 2-D (rows, features), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


def _check_pair(
    x: np.ndarray, y: np.ndarray, *, min_rows: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    x = _as_features(x, "x")
    y = _as_features(y, "y")
    if x.shape[1] != y.shape[1]:
        raise ValueError(
            f"x and y must have the same feature count d: x has d={x.shape[1]}, "
            f"y has d={y.shape[1]}"
        )
    if x.shape[0] < min_rows or y.shape[0] < min_rows:
        raise ValueError(
            f"need at least {min_rows} rows in each sample: x has n={x.shape[0]}, "
            f"y has m={y.shape[0]}"
        )
    return x, y


def _group_codes(groups: np.ndarray, row_count: int, name: str) -> tuple[np.ndarray, int]:
    """Dense codes 0..G-1 for the group ids (one per row) and the group count G."""
    g = np.asarray(groups)
    if g.ndim != 1 or g.shape[0] != row_count:
        raise ValueError(
            f"{name} must hold one group id per row: expected shape ({row_count},), got {g.shape}"
        )
    uniq, codes = np.unique(g, return_inverse=True)
    return codes.reshape(-1).astype(np.int64), len(uniq)


def _check_rng(rng: np.random.Generator) -> None:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")


def _scaler(ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = ref.mean(axis=0)
    std = ref.std(axis=0)
    # Constant (or numerically constant) columns are only centred, so they stay ~0, not NaN.
    scale = np.where(std > STD_FLOOR * std.max(initial=0.0), std, 1.0)
    return mean, scale


@overload
def standardize(x: np.ndarray, y: None = None) -> np.ndarray: ...


@overload
def standardize(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


def standardize(
    x: np.ndarray, y: np.ndarray | None = None
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Scale columns to zero mean and unit std using x's statistics.

    Features on different scales (pixel means vs. layer activations) then weigh alike in the
    kernel and the classifier. Columns that are constant in x are only centred (no NaN).

    Args:
        x: Reference rows, shape (n, d).
        y: Optional second sample, shape (m, d), scaled with x's mean and std.

    Returns:
        The scaled x, shape (n, d); or ``(x_scaled, y_scaled)`` when y is given.
    """
    x = _as_features(x, "x")
    mean, scale = _scaler(x)
    xs = (x - mean) / scale
    if y is None:
        return xs
    y = _as_features(y, "y")
    if y.shape[1] != x.shape[1]:
        raise ValueError(f"y must have d={x.shape[1]} columns like x, got d={y.shape[1]}")
    return xs, (y - mean) / scale
