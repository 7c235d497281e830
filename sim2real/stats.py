"""Two-sample statistics for the sim-to-real gap, with resampling that respects clip groups.

Clips are not independent: several come from one simulation (domain S) or one video (domain
R), so every resampling here moves whole groups (a group = a simulation or video id). Feature
arrays are ``x (n, d)`` and ``y (m, d)`` with group ids ``gx (n,)`` and ``gy (m,)`` (ints or
strings; the ids of x and y are separate namespaces even when equal). All randomness goes
through an explicit ``np.random.Generator``, so every result is a function of its generator.

Statistics: unbiased MMD² with an RBF kernel (Gretton et al. 2012, eq. 3), KID (Bińkowski et
al. 2018), and the out-of-fold AUC of a grouped-cross-validated logistic domain classifier.
:func:`compare` bundles them per rung into a :class:`Gap` with group-permutation p-value,
group-bootstrap intervals and a within-domain noise floor; it builds one pooled kernel matrix
and evaluates every permutation, bootstrap replicate and split from it by matrix products.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from typing import NamedTuple, overload

import numpy as np
from scipy import optimize, special, stats

Statistic = Callable[[np.ndarray, np.ndarray], float]
"""Two-sample statistic ``f(x (n, d), y (m, d)) -> float``, larger = more different."""

MAX_BANDWIDTH_ROWS = 1000
"""Rows (strided subsample) used by :func:`median_bandwidth`."""
STD_FLOOR = 1e-12
"""Columns whose std is below this fraction of the largest std are only centred."""
CI_LEVEL = 0.95
"""Coverage of the percentile bootstrap intervals in :class:`Gap`."""
TIE_RTOL = 1e-10
"""Resampled statistics within this relative distance of the observed one count as ties."""
MIN_FLOOR_GROUPS = 4
"""A domain needs this many groups for a half/half split with grouped CV on each half."""


# ---------------------------------------------------------------------------- input checks


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


# ---------------------------------------------------------------------------- scaling, kernels


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


# ---------------------------------------------------------------------------- MMD², KID


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


def bootstrap_draws(group_count: int, n_boot: int, rng: np.random.Generator) -> np.ndarray:
    """Times each of ``group_count`` groups is drawn in each of ``n_boot`` replicates, (G, B)."""
    _check_rng(rng)
    return _bootstrap_draws(group_count, n_boot, rng)


# ---------------------------------------------------------------------------- AUC, classifier


def auc_score(scores: np.ndarray, labels: np.ndarray) -> float:
    """ROC AUC via the Mann-Whitney U statistic, ties counted as 1/2 (average ranks).

    Args:
        scores: Classifier scores, larger = more likely label 1, shape (N,).
        labels: 0/1 labels, shape (N,); both classes must be present.

    Returns:
        P(score of a random 1 > score of a random 0) + 0.5 P(tie), in [0, 1].
    """
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    labels = np.asarray(labels).reshape(-1)
    if scores.shape != labels.shape:
        raise ValueError(f"scores {scores.shape} and labels {labels.shape} differ in length")
    if not np.all(np.isin(labels, (0, 1))):
        raise ValueError("labels must be 0 or 1")
    pos = labels == 1
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    if n_pos == 0 or n_neg == 0:
        raise ValueError(f"labels need both classes, got {n_pos} ones and {n_neg} zeros")
    ranks = stats.rankdata(scores)
    u = ranks[pos].sum() - n_pos * (n_pos + 1) / 2.0
    return float(u / (n_pos * n_neg))


class LogisticFit(NamedTuple):
    """Linear logistic model on raw features: logit = x @ weight + bias."""

    weight: np.ndarray
    """Weights for raw (unscaled) features, shape (d,)."""
    bias: float
    """Intercept (logit units)."""

    def decision(self, x: np.ndarray) -> np.ndarray:
        """Logits (log-odds of label 1) for rows x, shape (n, d) -> (n,)."""
        return np.asarray(x, dtype=np.float64) @ self.weight + self.bias


def _balanced_weights(labels: np.ndarray) -> np.ndarray:
    n_pos = labels.sum()
    n_neg = labels.size - n_pos
    return np.where(labels == 1, labels.size / (2.0 * n_pos), labels.size / (2.0 * n_neg))


def logistic_loss(
    params: np.ndarray,
    x: np.ndarray,
    labels: np.ndarray,
    *,
    l2: float,
    sample_weight: np.ndarray | None = None,
) -> tuple[float, np.ndarray]:
    """Penalised logistic loss and its gradient (the objective of :func:`fit_logistic`).

    loss = Σ_i w_i log(1 + exp(-s_i (x_i·β + b))) + l2/2 |β|², s_i = 2 label_i - 1; the
    intercept is not penalised (scikit-learn's C = 1 / l2).

    Args:
        params: ``[β, b]``, shape (d + 1,).
        x: Rows, shape (n, d).
        labels: 0/1 labels, shape (n,).
        l2: Penalty strength >= 0.
        sample_weight: Per-row weights w_i, shape (n,); ones if None.

    Returns:
        ``(loss, gradient)``; the gradient has shape (d + 1,).
    """
    beta, bias = params[:-1], params[-1]
    sign = 2.0 * np.asarray(labels, dtype=np.float64) - 1.0
    weight = np.ones(x.shape[0]) if sample_weight is None else sample_weight
    margin = sign * (x @ beta + bias)
    value = float(weight @ np.logaddexp(0.0, -margin) + 0.5 * l2 * (beta @ beta))
    dlogit = -weight * sign * special.expit(-margin)
    grad = np.empty_like(params)
    grad[:-1] = x.T @ dlogit + l2 * beta
    grad[-1] = dlogit.sum()
    return value, grad


def fit_logistic(x: np.ndarray, labels: np.ndarray, l2: float = 1.0) -> LogisticFit:
    """L2-regularised, class-balanced logistic regression (L-BFGS-B on standardized x).

    Standardizing first makes one ``l2`` mean the same on every rung; class-balanced weights
    keep the classifier from favouring the larger domain.

    Args:
        x: Rows, shape (n, d).
        labels: 0/1 labels, shape (n,); both classes present.
        l2: Penalty on the standardized-scale weights (see :func:`logistic_loss`).

    Returns:
        :class:`LogisticFit` whose weights apply to the raw x; unpacks as ``(weight, bias)``.
    """
    x = _as_features(x, "x")
    labels = np.asarray(labels).reshape(-1)
    if labels.shape[0] != x.shape[0]:
        raise ValueError(f"labels must have {x.shape[0]} entries like x, got {labels.shape[0]}")
    if not np.all(np.isin(labels, (0, 1))) or np.unique(labels).size != 2:
        raise ValueError("labels must be 0/1 with both classes present")
    labels = labels.astype(np.float64)
    mean, scale = _scaler(x)
    xs = (x - mean) / scale
    weight = _balanced_weights(labels)
    res = optimize.minimize(
        lambda p: logistic_loss(p, xs, labels, l2=l2, sample_weight=weight),
        np.zeros(x.shape[1] + 1),
        method="L-BFGS-B",
        jac=True,
        options={"maxiter": 500},
    )
    beta = res.x[:-1] / scale
    return LogisticFit(weight=beta, bias=float(res.x[-1] - mean @ beta))


# ---------------------------------------------------------------------------- group resampling


def _fold_of_rows(codes: np.ndarray, group_count: int, k: int, rng: np.random.Generator):
    """Fold index per row, shape (n,): whole groups, greedy largest-first into the lightest fold."""
    sizes = np.bincount(codes, minlength=group_count)
    order = rng.permutation(group_count)  # random tie-breaks between equal-sized groups
    order = order[np.argsort(-sizes[order], kind="stable")]
    load = np.zeros(k, dtype=np.int64)
    fold_of_group = np.empty(group_count, dtype=np.int64)
    for g in order:
        f = int(np.argmin(load))
        fold_of_group[g] = f
        load[f] += sizes[g]
    return fold_of_group[codes]


def grouped_folds(groups: np.ndarray, k: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Split rows into k folds of whole groups, as even in rows as a greedy fill allows.

    Cross-validation over these folds never tests on a group it trained on, so a classifier
    cannot score by recognising a simulation or a video.

    Args:
        groups: Group id per row, shape (n,).
        k: Number of folds, 2 <= k <= number of groups.
        rng: Source of the random order of the groups.

    Returns:
        k boolean test masks, each shape (n,); every row is in exactly one.
    """
    _check_rng(rng)
    codes, group_count = _group_codes(groups, _row_count(groups), "groups")
    if not 2 <= k <= group_count:
        raise ValueError(f"k must be in [2, {group_count}] (the group count), got k={k}")
    fold = _fold_of_rows(codes, group_count, k, rng)
    return [fold == f for f in range(k)]


def _oof_scores(
    x: np.ndarray,
    y: np.ndarray,
    cx: np.ndarray,
    cy: np.ndarray,
    *,
    folds: int,
    l2: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Out-of-fold logits (x = 0, y = 1) for rows [x; y], shape (n + m,)."""
    gx_count, gy_count = int(cx.max()) + 1, int(cy.max()) + 1
    k = min(folds, gx_count, gy_count)
    if k < 2:
        raise ValueError(
            "grouped cross-validation needs >= 2 groups in each domain: "
            f"gx has {gx_count}, gy has {gy_count}"
        )
    # Folds are stratified by domain: each fold takes groups of both, so every training set
    # holds both classes. Group ids of x and y never meet, so equal ids are distinct groups.
    fold = np.concatenate(
        [_fold_of_rows(cx, gx_count, k, rng), _fold_of_rows(cy, gy_count, k, rng)]
    )
    z = np.vstack([x, y])
    labels = np.concatenate([np.zeros(x.shape[0]), np.ones(y.shape[0])])
    scores = np.empty(z.shape[0])
    for f in range(k):
        test = fold == f
        scores[test] = fit_logistic(z[~test], labels[~test], l2=l2).decision(z[test])
    return scores


def domain_scores(
    x: np.ndarray,
    y: np.ndarray,
    gx: np.ndarray,
    gy: np.ndarray,
    *,
    folds: int = 5,
    l2: float = 1.0,
    rng: np.random.Generator,
) -> np.ndarray:
    """Out-of-fold logits of the grouped-CV domain classifier for rows [x; y], shape (n + m,).

    The scores :func:`domain_auc` ranks; exposed so that a caller can resample them by group
    (classifiers held fixed) or test them (:func:`c2st_pvalue`).
    """
    _check_rng(rng)
    x, y = _check_pair(x, y)
    cx, _ = _group_codes(gx, x.shape[0], "gx")
    cy, _ = _group_codes(gy, y.shape[0], "gy")
    return _oof_scores(x, y, cx, cy, folds=folds, l2=l2, rng=rng)


def weighted_auc(scores: np.ndarray, labels: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """AUC of ``scores`` under row weights, for many weightings at once (ties count 1/2).

    Args:
        scores: Scores, shape (n,).
        labels: 0/1 labels, shape (n,).
        weights: Non-negative row weights, shape (n, B) (e.g. group-bootstrap counts).

    Returns:
        Weighted P(score of a 1 > score of a 0) per column, shape (B,).
    """
    order = np.argsort(scores, kind="stable")
    s, pos, w = scores[order], labels[order] == 1, weights[order].astype(np.float64)
    neg_w = np.where(pos[:, None], 0.0, w)
    # negatives with a lower score count 1, with an equal score 1/2 (runs of equal scores)
    _, start, count = np.unique(s, return_index=True, return_counts=True)
    tie_total = np.add.reduceat(neg_w, start, axis=0)
    tie_before = np.repeat(np.cumsum(tie_total, axis=0) - tie_total, count, axis=0)
    equal = np.repeat(tie_total, count, axis=0)
    below = tie_before + 0.5 * equal
    pos_w = np.where(pos[:, None], w, 0.0)
    total = pos_w.sum(axis=0) * neg_w.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (pos_w * below).sum(axis=0) / total


def classifier_divergence(
    scores: np.ndarray, labels: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray | float:
    """Mean out-of-fold logit of class 1 minus that of class 0 [nats].

    A classifier two-sample statistic that keeps growing where the AUC stops at 1. A logistic
    classifier's logit estimates the log density ratio of the two sets (up to a constant that
    cancels here), so this estimates their Jeffreys divergence ``KL(1||0) + KL(0||1)``: about 0
    (at most 0 up to noise, held out) for sets the classifier cannot tell apart, ``d²`` for
    two Gaussians ``d`` standard deviations apart, and additive over independent differences,
    so taking one of two differences away leaves the other's share. Regularisation shrinks
    it, the same for every set compared.

    Args:
        scores: Out-of-fold logits, shape (n,) (class 1 = positive logit).
        labels: 0/1 labels, shape (n,).
        weights: Optional non-negative row weights, shape (n, B) (group-bootstrap counts).

    Returns:
        The divergence (float), or one per weighting (B,) with ``weights``.
    """
    pos = labels == 1
    if weights is None:
        return float(scores[pos].mean() - scores[~pos].mean())
    w = weights.astype(np.float64)
    mean_pos = (scores[pos, None] * w[pos]).sum(axis=0) / np.maximum(w[pos].sum(axis=0), 1e-300)
    mean_neg = (scores[~pos, None] * w[~pos]).sum(axis=0) / np.maximum(w[~pos].sum(axis=0), 1e-300)
    return mean_pos - mean_neg


def c2st_pvalue(scores: np.ndarray, cx: np.ndarray, cy: np.ndarray) -> float:
    """Classifier two-sample test (Lopez-Paz and Oquab 2017) with whole groups as units.

    Out-of-fold scores (x rows first, then y rows) are averaged per group, and a one-sided
    Mann-Whitney U test asks whether y's groups score higher than x's. Groups, not clips, are
    the independent units, and each group's score comes from classifiers that never saw it.

    Args:
        scores: Out-of-fold scores of the rows [x; y].
        cx: Group codes 0..Gx-1 of x's rows.
        cy: Group codes 0..Gy-1 of y's rows.

    Returns:
        The p-value.
    """
    n = cx.shape[0]
    mean_x = np.bincount(cx, scores[:n]) / np.bincount(cx)
    mean_y = np.bincount(cy, scores[n:]) / np.bincount(cy)
    return float(stats.mannwhitneyu(mean_y, mean_x, alternative="greater").pvalue)


def domain_auc(
    x: np.ndarray,
    y: np.ndarray,
    gx: np.ndarray,
    gy: np.ndarray,
    *,
    folds: int = 5,
    l2: float = 1.0,
    rng: np.random.Generator,
) -> float:
    """Out-of-fold AUC of a logistic domain classifier (x = 0, y = 1) under grouped CV.

    A group never sits in both a training and a test fold (folds are built per domain and
    paired, so each holds groups of both domains), so the AUC measures a difference between
    the domains, not memorised simulations or videos. Uses min(folds, groups in x, groups in
    y) folds.

    Args:
        x: Domain 0 rows, shape (n, d).
        y: Domain 1 rows, shape (m, d).
        gx: Group id per row of x, shape (n,).
        gy: Group id per row of y, shape (m,).
        folds: Requested fold count.
        l2: Classifier penalty (see :func:`fit_logistic`).
        rng: Source of the fold assignment.

    Returns:
        AUC of the pooled out-of-fold logits; ~0.5 when the domains are alike.

    Raises:
        ValueError: If either domain has fewer than 2 groups.
    """
    scores = domain_scores(x, y, gx, gy, folds=folds, l2=l2, rng=rng)
    n = _row_count(x)
    return auc_score(scores, np.concatenate([np.zeros(n), np.ones(scores.shape[0] - n)]))


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


# ---------------------------------------------------------------------------- per-rung gap


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
