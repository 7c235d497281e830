"""The domain classifier: grouped-CV logistic regression, its AUC, divergence and C2ST p-value."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import optimize, special, stats

from .checks import _as_features, _check_pair, _check_rng, _group_codes, _row_count, _scaler

__all__ = [
    "LogisticFit",
    "auc_score",
    "c2st_pvalue",
    "classifier_divergence",
    "domain_auc",
    "domain_scores",
    "fit_logistic",
    "grouped_folds",
    "logistic_loss",
    "weighted_auc",
]


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
