"""Pearson and Spearman correlation with percentile-bootstrap 95 % intervals (thesis Table 7.3).

The bootstrap resamples videos with replacement (``rounds`` times, seeded); resamples whose
scores or targets are constant have no correlation and are skipped. Undefined values (fewer
than 3 videos, constant input) are ``None``, never NaN, so reports stay valid JSON.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import stats

__all__ = ["Correlation", "correlate"]

MIN_SAMPLES = 3


@dataclasses.dataclass(frozen=True)
class Correlation:
    """r with its bootstrap 95 % interval, for Pearson and Spearman, over ``count`` videos."""

    count: int
    pearson: float | None
    pearson_ci: tuple[float, float] | None
    spearman: float | None
    spearman_ci: tuple[float, float] | None

    def to_json(self) -> dict:
        """Plain dict (intervals as lists)."""
        out = dataclasses.asdict(self)
        for key in ("pearson_ci", "spearman_ci"):
            out[key] = None if out[key] is None else [float(v) for v in out[key]]
        return out


def _pearson(x: np.ndarray, y: np.ndarray) -> float | None:
    if x.size < MIN_SAMPLES or np.ptp(x) == 0 or np.ptp(y) == 0:
        return None
    return float(np.corrcoef(x, y)[0, 1])


def _spearman(x: np.ndarray, y: np.ndarray) -> float | None:
    return _pearson(stats.rankdata(x), stats.rankdata(y))


def _interval(values: list[float]) -> tuple[float, float] | None:
    if len(values) < 2:
        return None
    low, high = np.percentile(values, [2.5, 97.5])
    return float(low), float(high)


def correlate(scores, targets, *, rounds: int = 2000, seed: int = 0) -> Correlation:
    """Correlation of predicted ``scores`` with measured ``targets`` (both length N)."""
    x = np.asarray(scores, dtype=np.float64)
    y = np.asarray(targets, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"scores and targets must be equal-length 1-D, got {x.shape}, {y.shape}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise ValueError("scores and targets must be finite")
    if rounds < 0:
        raise ValueError(f"bootstrap rounds must be >= 0, got {rounds}")
    pearson, spearman = _pearson(x, y), _spearman(x, y)
    boot_p: list[float] = []
    boot_s: list[float] = []
    if pearson is not None:
        rng = np.random.default_rng(seed)
        for _ in range(rounds):
            pick = rng.integers(0, x.size, x.size)
            p, s = _pearson(x[pick], y[pick]), _spearman(x[pick], y[pick])
            if p is not None:
                boot_p.append(p)
            if s is not None:
                boot_s.append(s)
    return Correlation(
        count=int(x.size),
        pearson=pearson,
        pearson_ci=_interval(boot_p) if pearson is not None else None,
        spearman=spearman,
        spearman_ci=_interval(boot_s) if spearman is not None else None,
    )
