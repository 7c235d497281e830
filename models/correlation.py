"""Pearson and Spearman correlation with bootstrap 95 % intervals and p-values (Table 7.3).

Videos of one fabric (the same cloth at several wind levels) are not independent: with
``groups`` the percentile bootstrap resamples whole groups with replacement (``rounds``
times, seeded), so an interval reflects the number of fabrics, not of videos; without groups
each video is its own group. A resample that draws a group k times weighs its videos k
times, which is exactly the correlation of the expanded resample (ties get mid-ranks), so all
rounds are computed at once. Resamples whose scores or targets are constant have no
correlation and are skipped.

p-values are two-sided t-tests of r with ``groups - 2`` degrees of freedom: for ungrouped
data they are scipy's ``pearsonr`` / ``spearmanr`` p-values; with groups they count the
independent fabrics, not the videos. Undefined values (fewer than 3 videos for r, fewer than
3 groups for intervals and p-values, constant input) are ``None``, never NaN, so reports stay
valid JSON.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from scipy import stats

__all__ = ["Correlation", "correlate"]

MIN_SAMPLES = 3


@dataclasses.dataclass(frozen=True)
class Correlation:
    """r and rho with bootstrap 95 % intervals and p-values.

    ``count`` is the number of videos, ``group_count`` the number of independent groups
    (fabrics) the intervals and p-values rest on.
    """

    count: int
    group_count: int
    pearson: float | None
    pearson_ci: tuple[float, float] | None
    pearson_p: float | None
    spearman: float | None
    spearman_ci: tuple[float, float] | None
    spearman_p: float | None

    def to_json(self) -> dict:
        """Plain dict (intervals as lists)."""
        out = dataclasses.asdict(self)
        for key in ("pearson_ci", "spearman_ci"):
            out[key] = None if out[key] is None else [float(v) for v in out[key]]
        return out


def _pearson(x: np.ndarray, y: np.ndarray) -> float | None:
    if x.size < MIN_SAMPLES or np.ptp(x) == 0 or np.ptp(y) == 0:
        return None
    return float(np.clip(np.corrcoef(x, y)[0, 1], -1.0, 1.0))


def _spearman(x: np.ndarray, y: np.ndarray) -> float | None:
    return _pearson(stats.rankdata(x), stats.rankdata(y))


def _p_value(r: float | None, group_count: int) -> float | None:
    """Two-sided p of the t-test of r with ``group_count - 2`` degrees of freedom."""
    if r is None or group_count < MIN_SAMPLES:
        return None
    dof = group_count - 2
    if abs(r) >= 1.0:
        return 0.0
    t = r * np.sqrt(dof / (1.0 - r * r))
    return float(2.0 * stats.t.sf(abs(t), dof))


def _weighted_pearson(x: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Pearson r per row of weights ``w`` (R, N) (x, y (N,) or (R, N)); NaN where constant."""
    x, y = np.broadcast_to(x, w.shape), np.broadcast_to(y, w.shape)
    used = w > 0
    total = w.sum(axis=1, keepdims=True)
    dx = x - (w * x).sum(axis=1, keepdims=True) / total
    dy = y - (w * y).sum(axis=1, keepdims=True) / total
    cov = (w * dx * dy).sum(axis=1)
    var = (w * dx * dx).sum(axis=1) * (w * dy * dy).sum(axis=1)
    spread = [
        np.where(used, v, -np.inf).max(axis=1) > np.where(used, v, np.inf).min(axis=1)
        for v in (x, y)
    ]
    r = np.full(w.shape[0], np.nan)
    ok = spread[0] & spread[1] & (var > 0)
    r[ok] = np.clip(cov[ok] / np.sqrt(var[ok]), -1.0, 1.0)
    return r


def _weighted_ranks(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Mid-ranks (R, N) of ``v`` (N,) in each resample whose multiplicities are ``w`` (R, N)."""
    values, index = np.unique(v, return_inverse=True)
    per_value = w @ np.eye(values.size)[index]  # (R, U) weight of each distinct value
    before = np.cumsum(per_value, axis=1) - per_value
    return (before + (per_value + 1.0) / 2.0)[:, index]


def _interval(values: np.ndarray) -> tuple[float, float] | None:
    values = values[np.isfinite(values)]
    if values.size < 2:
        return None
    low, high = np.percentile(values, [2.5, 97.5])
    return float(low), float(high)


def correlate(
    scores,
    targets,
    *,
    groups: Sequence | None = None,
    rounds: int = 2000,
    seed: int = 0,
) -> Correlation:
    """Correlation of predicted ``scores`` with measured ``targets`` (both length N).

    Args:
        scores: Per-video model scores.
        targets: Per-video measured values.
        groups: Per-video group labels (e.g. fabric names); ``None``: every video its own.
        rounds: Bootstrap resamples (0: no intervals).
        seed: Bootstrap seed.
    """
    x = np.asarray(scores, dtype=np.float64)
    y = np.asarray(targets, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"scores and targets must be equal-length 1-D, got {x.shape}, {y.shape}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise ValueError("scores and targets must be finite")
    if rounds < 0:
        raise ValueError(f"bootstrap rounds must be >= 0, got {rounds}")
    if groups is None:
        member = np.arange(x.size)
    else:
        labels = np.asarray([str(g) for g in groups])
        if labels.shape != x.shape:
            raise ValueError(f"groups must have one label per video, got {labels.shape}")
        member = np.unique(labels, return_inverse=True)[1].reshape(-1)
    group_count = int(member.max()) + 1 if member.size else 0
    pearson, spearman = _pearson(x, y), _spearman(x, y)
    pearson_ci = spearman_ci = None
    if pearson is not None and group_count >= MIN_SAMPLES and rounds > 0:
        rng = np.random.default_rng(seed)
        picks = rng.integers(0, group_count, size=(rounds, group_count))
        drawn = np.zeros((rounds, group_count))
        np.add.at(drawn, (np.arange(rounds)[:, None], picks), 1.0)
        weights = drawn[:, member]  # (R, N): how often each video is in each resample
        pearson_ci = _interval(_weighted_pearson(x, y, weights))
        ranks_x, ranks_y = _weighted_ranks(x, weights), _weighted_ranks(y, weights)
        spearman_ci = _interval(_weighted_pearson(ranks_x, ranks_y, weights))
    return Correlation(
        count=int(x.size),
        group_count=group_count,
        pearson=pearson,
        pearson_ci=pearson_ci,
        pearson_p=_p_value(pearson, group_count),
        spearman=spearman,
        spearman_ci=spearman_ci,
        spearman_p=_p_value(spearman, group_count),
    )
