"""One rung's comparison of S and R: a :class:`Gap` with its tests, intervals and floors."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from .checks import _as_features, _check_pair, _check_rng, _group_codes, _scaler
from .classifier import _oof_scores, auc_score, c2st_pvalue, domain_auc
from .kernels import (
    _mmd2_blocks,
    _mmd2_group_bootstrap,
    _mmd2_sides,
    _sq_dists,
    kid,
    median_bandwidth,
)
from .resampling import _bootstrap_draws, _permutation_sides, _pvalue, _split_sides

__all__ = ["CI_LEVEL", "MIN_FLOOR_GROUPS", "Gap", "auc_above_floor", "compare", "gap_closed"]


CI_LEVEL = 0.95
"""Coverage of the percentile bootstrap intervals in :class:`Gap`."""


MIN_FLOOR_GROUPS = 4
"""A domain needs this many groups for a half/half split with grouped CV on each half."""


def _json_float(v: float) -> float | None:
    return None if not math.isfinite(v) else float(v)


@dataclasses.dataclass(frozen=True)
class Gap:
    """Gap between two domains on one rung (x = simulated S or S_e, y = real R).

    Kernel statistics are on features standardized with the reference's (default x's) mean
    and std; ``bandwidth`` is in those standardized units. Intervals are 95 % percentile
    group-bootstrap intervals. NaN marks what could not be computed (a floor needs a domain
    with >= :data:`MIN_FLOOR_GROUPS` groups).
    """

    mmd2: float
    """Unbiased RBF MMD² between x and y."""
    mmd2_ci: tuple[float, float]
    """Group-bootstrap interval (lo, hi) of mmd2."""
    kid: float
    """KID (cubic-kernel unbiased MMD²) between x and y."""
    auc: float
    """Out-of-fold AUC of the grouped-CV logistic domain classifier (x = 0, y = 1)."""
    auc_ci: tuple[float, float]
    """Group-bootstrap interval (lo, hi) of auc, classifiers held fixed."""
    p_value: float
    """Group-permutation p-value of mmd2."""
    floor_mmd2: float
    """MMD² expected between x and y if they differed only by group sampling."""
    floor_auc: float
    """Mean half-vs-half AUC, averaged over the domains that have a floor."""
    bandwidth: float
    """RBF bandwidth (standardized units)."""
    n_x: int
    """Clips in x."""
    n_y: int
    """Clips in y."""
    groups_x: int
    """Groups (simulations / videos) in x."""
    groups_y: int
    """Groups in y."""
    p_c2st: float = math.nan
    """Classifier two-sample test p-value (:func:`c2st_pvalue`)."""
    floor_mmd2_halves: tuple[float, float] = (math.nan, math.nan)
    """Mean MMD² between random group halves of x and of y (raw, before size matching)."""
    floor_auc_halves: tuple[float, float] = (math.nan, math.nan)
    """Mean AUC between random group halves of x and of y."""

    @property
    def p_gap(self) -> float:
        """p-value of "a gap", from either test: min(1, 2 min(p_value, p_c2st)).

        The kernel test sees any difference but spreads its power over every dimension; the
        classifier test finds the few directions a shift takes (on a sealed set with motion
        blur its AUC was 0.88 where the MMD² had p 0.06). Bonferroni over the two keeps the
        level.
        """
        if math.isnan(self.p_c2st):
            return self.p_value
        return min(1.0, 2.0 * min(self.p_value, self.p_c2st))

    @property
    def corrected_mmd2(self) -> float:
        """mmd2 - floor_mmd2: the part of the MMD² not explained by group sampling."""
        return self.mmd2 - self.floor_mmd2

    @property
    def corrected_auc(self) -> float:
        """max(0, auc - floor_auc) / (1 - floor_auc): 0 = within noise, 1 = fully separable.

        Clipped at 0 because a cross-validated AUC below its floor is noise, not a direction;
        NaN when there is no floor.
        """
        if math.isnan(self.floor_auc):
            return math.nan
        return auc_above_floor(self.auc, self.floor_auc)

    def to_json(self) -> dict:
        """Plain-JSON dict (intervals as lists, NaN as None), with the corrected values."""
        out = dataclasses.asdict(self)
        out["corrected_mmd2"] = self.corrected_mmd2
        out["p_gap"] = self.p_gap
        out["corrected_auc"] = self.corrected_auc
        for key, value in out.items():
            if isinstance(value, tuple):
                out[key] = [_json_float(v) for v in value]
            elif isinstance(value, float):
                out[key] = _json_float(value)
        json.dumps(out, allow_nan=False)  # fail here, not in the report writer
        return out


def _pair_fraction(codes: np.ndarray) -> float:
    """Share of ordered clip pairs (i != j) that lie within one group."""
    n = codes.shape[0]
    sizes = np.bincount(codes).astype(np.float64)
    return float((sizes * (sizes - 1.0)).sum() / (n * (n - 1.0)))


def _group_excess(half_mmd2: float, half_share: float) -> float:
    """Δ = MMD² per unit of within-group pair share (NaN if no floor, 0 without groups)."""
    if math.isnan(half_mmd2):
        return math.nan
    return half_mmd2 / half_share if half_share > 0.0 else 0.0


def _percentile_ci(values: np.ndarray) -> tuple[float, float]:
    # A replicate can be undefined (e.g. one singleton group drawn every time): skip it.
    if not np.any(np.isfinite(values)):
        return math.nan, math.nan
    lo, hi = np.nanquantile(values, [(1.0 - CI_LEVEL) / 2.0, (1.0 + CI_LEVEL) / 2.0])
    return float(lo), float(hi)


def _half_floors(
    feats: np.ndarray,
    k: np.ndarray,
    codes: np.ndarray,
    group_count: int,
    *,
    n_floor: int,
    folds: int,
    l2: float,
    rng: np.random.Generator,
) -> tuple[float, float, float]:
    """Mean half-vs-half MMD², mean within-group pair share of the halves, mean AUC."""
    if n_floor < 1 or group_count < MIN_FLOOR_GROUPS:
        return math.nan, math.nan, math.nan
    sides = _split_sides(codes, group_count, n_floor, rng)
    mmd = _mmd2_sides(k, np.diag(k), sides)
    share = [_pair_fraction(codes[s]) + _pair_fraction(codes[~s]) for s in sides.T]
    aucs = [
        domain_auc(feats[s], feats[~s], codes[s], codes[~s], folds=folds, l2=l2, rng=rng)
        for s in sides.T
    ]
    return float(mmd.mean()), float(np.mean(share)), float(np.mean(aucs))


def compare(
    x: np.ndarray,
    y: np.ndarray,
    gx: np.ndarray,
    gy: np.ndarray,
    *,
    bandwidth: float | None = None,
    n_perm: int = 200,
    n_boot: int = 200,
    n_floor: int = 10,
    folds: int = 5,
    l2: float = 1.0,
    reference: np.ndarray | None = None,
    rng: np.random.Generator,
) -> Gap:
    """All gap statistics between x (simulated) and y (real) on one rung.

    Features are standardized with the reference's statistics (default x). The RBF
    bandwidth is the median heuristic on the standardized x unless given: the diagnosis
    fixes it from S so that S-vs-R and S_e-vs-R on one rung use one kernel (pass
    ``reference=S`` as well, so both also use one scaling). One pooled kernel matrix serves
    the estimate, ``n_perm`` group permutations, ``n_boot`` group-bootstrap replicates and
    ``n_floor`` half splits per domain.

    Choices the caller should know:

    * ``floor_mmd2``: the raw half-vs-half MMD² of a domain is about twice the group-sampling
      MMD² expected at full size (halves have half the groups), so it is size-matched: with
      s(A) the share of ordered clip pairs of A that lie in one group, the half splits give
      Δ = mean MMD²(A, B) / mean (s(A) + s(B)) per domain, and
      ``floor_mmd2 = Δ_x s(x) + Δ_y s(y)`` (one domain's Δ for both if the other has too few
      groups). This is the expected MMD² of x vs y if y were a fresh draw of x's domain; it
      is 0 for independent clips and is not clipped at 0. The raw means are in
      ``floor_mmd2_halves``.
    * ``floor_auc`` is the mean half-vs-half AUC averaged over the two domains (the larger
      of the two would sit above 0.5 by chance); see :attr:`Gap.corrected_auc`.
    * ``mmd2_ci`` drops pairs of clips from two copies of one drawn-twice group (see
      :func:`_within_mean_resampled`); a plain bootstrap of the unbiased MMD² sits above the
      estimate when groups differ.
    * ``auc_ci`` group-bootstraps the out-of-fold scores with the classifiers held fixed
      (cheap, all ``n_boot`` replicates); it omits the retraining variance.

    Args:
        x: Simulated rows, shape (n, d), n >= 2.
        y: Real rows, shape (m, d), m >= 2.
        gx: Group (simulation) id per row of x, shape (n,), >= 2 groups.
        gy: Group (video) id per row of y, shape (m,), >= 2 groups.
        bandwidth: RBF bandwidth in standardized units; median heuristic on x if None.
        n_perm: Group permutations for ``p_value``.
        n_boot: Group-bootstrap replicates for both intervals.
        n_floor: Random half splits per domain for the floors (0 = no floors, NaN).
        folds: Grouped CV folds of the domain classifier.
        l2: Classifier penalty (see :func:`fit_logistic`).
        reference: Rows whose mean / std standardize everything, shape (r, d); x if None.
        rng: Source of all randomness (split into independent streams).

    Returns:
        The :class:`Gap`.
    """
    _check_rng(rng)
    x, y = _check_pair(x, y)
    cx, gx_count = _group_codes(gx, x.shape[0], "gx")
    cy, gy_count = _group_codes(gy, y.shape[0], "gy")
    if gx_count < 2 or gy_count < 2:
        raise ValueError(
            f"compare needs >= 2 groups per domain: gx has {gx_count}, gy has {gy_count}"
        )
    if n_perm < 1 or n_boot < 1:
        raise ValueError(f"n_perm and n_boot must be >= 1, got {n_perm} and {n_boot}")
    ref = x if reference is None else _as_features(reference, "reference")
    if ref.shape[1] != x.shape[1]:
        raise ValueError(f"reference must have d={x.shape[1]} columns, got d={ref.shape[1]}")
    mean, scale = _scaler(ref)
    xs, ys = (x - mean) / scale, (y - mean) / scale
    bw = median_bandwidth(xs) if bandwidth is None else float(bandwidth)
    if not (math.isfinite(bw) and bw > 0.0):
        raise ValueError(f"bandwidth must be finite and > 0, got {bandwidth}")
    rng_perm, rng_boot, rng_cv, rng_floor_x, rng_floor_y = rng.spawn(5)

    n = x.shape[0]
    z = np.vstack([xs, ys])
    k = np.exp(-_sq_dists(z, z) / (2.0 * bw**2))
    np.fill_diagonal(k, 1.0)
    kxx, kyy, kxy = k[:n, :n], k[n:, n:], k[:n, n:]
    mmd2 = _mmd2_blocks(kxx, kyy, kxy)

    pooled = np.concatenate([cx, cy + gx_count])
    sides = _permutation_sides(pooled, gx_count, gx_count + gy_count, n_perm, rng_perm)
    p_value = _pvalue(mmd2, _mmd2_sides(k, np.ones(z.shape[0]), sides))

    draws_x = _bootstrap_draws(gx_count, n_boot, rng_boot)
    draws_y = _bootstrap_draws(gy_count, n_boot, rng_boot)
    boot_mmd2 = _mmd2_group_bootstrap(kxx, kyy, kxy, cx, cy, draws_x, draws_y)

    labels = np.concatenate([np.zeros(n), np.ones(y.shape[0])])
    scores = _oof_scores(xs, ys, cx, cy, folds=folds, l2=l2, rng=rng_cv)
    auc = auc_score(scores, labels)
    p_c2st = c2st_pvalue(scores, cx, cy)
    rows = np.concatenate([draws_x[cx], draws_y[cy]])
    boot_auc = np.array(
        [
            auc_score(np.repeat(scores, rows[:, b]), np.repeat(labels, rows[:, b]))
            for b in range(n_boot)
        ]
    )

    half = {"n_floor": n_floor, "folds": folds, "l2": l2}
    fx_mmd, fx_share, fx_auc = _half_floors(xs, kxx, cx, gx_count, rng=rng_floor_x, **half)
    fy_mmd, fy_share, fy_auc = _half_floors(ys, kyy, cy, gy_count, rng=rng_floor_y, **half)
    delta_x, delta_y = _group_excess(fx_mmd, fx_share), _group_excess(fy_mmd, fy_share)
    if math.isnan(delta_x):
        delta_x = delta_y
    if math.isnan(delta_y):
        delta_y = delta_x
    floor_mmd2 = delta_x * _pair_fraction(cx) + delta_y * _pair_fraction(cy)
    finite_auc = [v for v in (fx_auc, fy_auc) if math.isfinite(v)]
    floor_auc = float(np.mean(finite_auc)) if finite_auc else math.nan

    return Gap(
        mmd2=mmd2,
        mmd2_ci=_percentile_ci(boot_mmd2),
        kid=kid(xs, ys),
        auc=auc,
        auc_ci=_percentile_ci(boot_auc),
        p_value=p_value,
        p_c2st=p_c2st,
        floor_mmd2=float(floor_mmd2),
        floor_auc=float(floor_auc),
        bandwidth=bw,
        n_x=n,
        n_y=y.shape[0],
        groups_x=gx_count,
        groups_y=gy_count,
        floor_mmd2_halves=(fx_mmd, fy_mmd),
        floor_auc_halves=(fx_auc, fy_auc),
    )


def auc_above_floor(auc: float, floor: float) -> float:
    """max(0, auc - floor) / (1 - floor): a domain AUC's share of what lies above its floor."""
    return max(0.0, auc - floor) / max(1e-9, 1.0 - floor)


def gap_closed(gap_before: float, gap_after: float, floor: float) -> float:
    """Fraction of the above-floor gap that a change closed, in [-1, 1].

    (before - after) / (before - floor): 1 = down to the noise floor, 0 = unchanged,
    negative = the change made the gap larger. Clipped to [-1, 1]; 0.0 when the gap was
    already at or below the floor (nothing to close).

    Args:
        gap_before: Gap (e.g. ``Gap.mmd2``) before the change, e.g. S vs R.
        gap_after: Gap after it, e.g. S_e vs R.
        floor: Noise floor of the gap (e.g. ``Gap.floor_mmd2`` of the "before" comparison).

    Returns:
        The fraction closed (float, never NaN).
    """
    for name, value in (("gap_before", gap_before), ("gap_after", gap_after), ("floor", floor)):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value}")
    if gap_before <= floor:
        return 0.0
    return float(np.clip((gap_before - gap_after) / (gap_before - floor), -1.0, 1.0))
