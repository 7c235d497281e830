"""Grouped two-sample statistics: exact references, test level, power, grouped CV, compare()."""

import itertools
import json
import math

import numpy as np
import pytest

from sim2real import stats as st
from sim2real.stats import kernels, resampling

EXACT = 1e-12
ALPHA = 0.05


def grouped_sample(rng, group_count, clips, dim, *, offset=1.0, noise=1.0, shift=0.0):
    """Clips that share a random per-group offset (a simulation / a video); returns (x, groups)."""
    groups = np.repeat(np.arange(group_count), clips)
    x = offset * rng.normal(size=(group_count, dim))[groups]
    x = x + noise * rng.normal(size=(group_count * clips, dim))
    x[:, :3] += shift
    return x, groups


def mmd2_loop(x, y, kernel):
    n, m = len(x), len(y)
    xx = sum(kernel(x[i], x[j]) for i in range(n) for j in range(n) if i != j)
    yy = sum(kernel(y[i], y[j]) for i in range(m) for j in range(m) if i != j)
    xy = sum(kernel(x[i], y[j]) for i in range(n) for j in range(m))
    return xx / (n * (n - 1)) + yy / (m * (m - 1)) - 2 * xy / (n * m)


# ---------------------------------------------------------------------------- exact references


def test_mmd2_and_kid_match_double_loop():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(7, 3)), rng.normal(size=(5, 3)) + 0.4
    bw = 0.8

    def rbf(a, b):
        return math.exp(-np.sum((a - b) ** 2) / (2 * bw**2))

    def cubic(a, b):
        return (a @ b / 3 + 1) ** 3

    assert abs(st.mmd2_unbiased(x, y, bw) - mmd2_loop(x, y, rbf)) < EXACT
    assert abs(st.kid(x, y) - mmd2_loop(x, y, cubic)) < EXACT


def test_mmd2_is_unbiased_under_the_null():
    rng = np.random.default_rng(1)
    unbiased, biased = [], []
    for _ in range(300):
        x, y = rng.normal(size=(8, 2)), rng.normal(size=(8, 2))
        unbiased.append(st.mmd2_unbiased(x, y, 1.0))
        k = np.exp(-kernels._sq_dists(np.vstack([x, y]), np.vstack([x, y])) / 2)
        biased.append(k[:8, :8].mean() + k[8:, 8:].mean() - 2 * k[:8, 8:].mean())
    se = np.std(unbiased) / math.sqrt(300)
    assert abs(np.mean(unbiased)) < 3 * se
    # The V-statistic (diagonal kept) is biased upward; the test can tell the two apart.
    assert np.mean(biased) > 6 * se


def test_kernel_paths_of_compare_match_direct_formulas():
    rng = np.random.default_rng(2)
    x, gx = grouped_sample(rng, 5, 3, 4)
    y, gy = grouped_sample(rng, 4, 3, 4, shift=0.5)
    z, bw = np.vstack([x, y]), 1.3
    k = np.exp(-kernels._sq_dists(z, z) / (2 * bw**2))
    sides = resampling._permutation_sides(np.concatenate([gx, gy + 5]), 5, 9, 12, rng)
    fast = kernels._mmd2_sides(k, np.ones(len(z)), sides)
    slow = [st.mmd2_unbiased(z[s], z[~s], bw) for s in sides.T]
    np.testing.assert_allclose(fast, slow, rtol=0, atol=EXACT)


def test_group_bootstrap_kernel_form_drops_pairs_of_group_copies():
    rng = np.random.default_rng(3)
    x, gx = grouped_sample(rng, 4, 2, 3)
    y, gy = grouped_sample(rng, 3, 3, 3)
    bw = 1.1
    z = np.vstack([x, y])
    k = np.exp(-kernels._sq_dists(z, z) / (2 * bw**2))
    n = len(x)
    draws_x = resampling._bootstrap_draws(4, 6, rng)
    draws_y = resampling._bootstrap_draws(3, 6, rng)
    fast = kernels._mmd2_group_bootstrap(k[:n, :n], k[n:, n:], k[:n, n:], gx, gy, draws_x, draws_y)

    def resample(rows, groups, draws):
        # (row, original group, copy number) of every clip of the resampled sample
        return [
            (i, g, copy)
            for g in range(draws.shape[0])
            for copy in range(draws[g])
            for i in np.flatnonzero(groups == g)
        ]

    def within(clips, kk):
        pairs = [
            kk[a[0], b[0]]
            for a, b in itertools.permutations(clips, 2)
            if not (a[1] == b[1] and a[2] != b[2])
        ]
        return np.mean(pairs)

    for b in range(6):
        cx = resample(x, gx, draws_x[:, b])
        cy = resample(y, gy, draws_y[:, b])
        cross = np.mean([k[i, n + j] for i, _, _ in cx for j, _, _ in cy])
        ref = within(cx, k[:n, :n]) + within(cy, k[n:, n:]) - 2 * cross
        assert abs(fast[b] - ref) < EXACT


def test_auc_matches_pairwise_count_with_ties():
    rng = np.random.default_rng(4)
    scores = rng.integers(0, 5, size=40).astype(float)  # many ties
    labels = rng.integers(0, 2, size=40)
    pos, neg = scores[labels == 1], scores[labels == 0]
    wins = sum((p > q) + 0.5 * (p == q) for p in pos for q in neg)
    assert abs(st.auc_score(scores, labels) - wins / (len(pos) * len(neg))) < EXACT
    assert st.auc_score([0.1, 0.9], [0, 1]) == 1.0
    assert st.auc_score([3.0, 3.0], [0, 1]) == 0.5


def test_classifier_divergence_keeps_growing_where_the_auc_stops():
    rng = np.random.default_rng(0)
    n = 20000
    labels = np.r_[np.zeros(n), np.ones(n // 2)]

    def exact_logits(shifts):
        """Log density ratio of N(shifts, I) to N(0, I) at samples of both classes."""
        shifts = np.asarray(shifts, dtype=np.float64)
        x = rng.normal(size=(len(labels), len(shifts))) + labels[:, None] * shifts
        return x @ shifts - 0.5 * shifts @ shifts

    # the Jeffreys divergence of two unit Gaussians d apart is d^2, additive over dimensions
    for shifts in ([1.0], [2.0, 1.0], [6.0], [8.0]):
        expected = float(np.sum(np.square(shifts)))
        got = st.classifier_divergence(exact_logits(shifts), labels)
        assert got == pytest.approx(expected, rel=0.05, abs=0.05)
    # at 6 and 8 standard deviations both AUCs are 1, the divergences 36 and 64
    assert st.auc_score(exact_logits([6.0]), labels) > 0.999
    # logits that carry no information: zero
    assert st.classifier_divergence(rng.normal(size=len(labels)), labels) == pytest.approx(
        0.0, abs=0.05
    )
    # weights of 1 change nothing; doubling every class-1 weight leaves the class means alone
    scores = exact_logits([1.0])
    weights = np.ones((len(labels), 3))
    plain = st.classifier_divergence(scores, labels)
    assert np.allclose(st.classifier_divergence(scores, labels, weights), plain, rtol=1e-12)
    weights[labels == 1] = 2.0
    assert np.allclose(st.classifier_divergence(scores, labels, weights), plain, rtol=1e-12)


def test_median_bandwidth():
    assert st.median_bandwidth(np.array([[0.0], [1.0], [2.0]])) == pytest.approx(math.sqrt(0.5))
    assert st.median_bandwidth(np.ones((5, 3))) == 1.0
    big = np.random.default_rng(5).normal(size=(2500, 2))
    strided = big[np.linspace(0, 2499, st.MAX_BANDWIDTH_ROWS).round().astype(int)]
    assert st.median_bandwidth(big) == st.median_bandwidth(strided) > 0


def test_standardize_uses_x_statistics_and_survives_constant_columns():
    rng = np.random.default_rng(6)
    x = np.column_stack([rng.normal(3, 2, 50), np.full(50, 0.1)])
    y = x[:10] * 2
    xs, ys = st.standardize(x, y)
    np.testing.assert_allclose(xs.mean(0), 0, atol=1e-12)
    np.testing.assert_allclose(xs[:, 0].std(), 1)
    assert np.all(np.isfinite(xs)) and np.all(np.abs(xs[:, 1]) < 1e-12)
    np.testing.assert_allclose(ys[:, 0], (y[:, 0] - x[:, 0].mean()) / x[:, 0].std())
    np.testing.assert_allclose(st.standardize(x), xs)


# ---------------------------------------------------------------------------- classifier


def test_logistic_loss_gradient_matches_finite_differences():
    rng = np.random.default_rng(7)
    x, labels = rng.normal(size=(30, 4)), rng.integers(0, 2, size=30)
    weight, params = rng.uniform(0.5, 2, size=30), rng.normal(size=5)
    _, grad = st.logistic_loss(params, x, labels, l2=0.7, sample_weight=weight)
    h = 1e-6
    numeric = [
        (
            st.logistic_loss(params + h * e, x, labels, l2=0.7, sample_weight=weight)[0]
            - st.logistic_loss(params - h * e, x, labels, l2=0.7, sample_weight=weight)[0]
        )
        / (2 * h)
        for e in np.eye(5)
    ]
    np.testing.assert_allclose(grad, numeric, rtol=1e-6, atol=1e-6)


def test_fit_logistic_separates_and_weights_apply_to_raw_features():
    rng = np.random.default_rng(8)
    x = rng.normal(size=(60, 5))
    labels = (x @ np.array([1.0, -2.0, 0.5, 0.0, 0.0]) > 0).astype(int)
    fit = st.fit_logistic(x, labels)
    assert st.auc_score(fit.decision(x), labels) == 1.0
    weight, bias = fit  # unpacks as (w, b)
    np.testing.assert_allclose(fit.decision(x), x @ weight + bias)
    # Standardizing inside: an affine rescale of the raw input gives the same logits.
    scaled = st.fit_logistic(1000 * x + 5, labels)
    np.testing.assert_allclose(scaled.decision(1000 * x + 5), fit.decision(x), atol=1e-5)


# ---------------------------------------------------------------------------- level and power


def test_grouped_permutation_holds_alpha_and_clip_level_does_not():
    rng = np.random.default_rng(9)
    draws = 60
    grouped, naive = [], []
    for _ in range(draws):
        x, gx = grouped_sample(rng, 10, 4, 8)
        y, gy = grouped_sample(rng, 10, 4, 8)
        bw = st.median_bandwidth(x)

        def stat(a, b, bw=bw):
            return st.mmd2_unbiased(a, b, bw)

        grouped.append(st.permutation_pvalue(x, y, gx, gy, stat, n_perm=99, rng=rng))
        clips = np.arange(len(x))
        naive.append(st.permutation_pvalue(x, y, clips, clips, stat, n_perm=99, rng=rng))
    limit = ALPHA + 3 * math.sqrt(ALPHA * (1 - ALPHA) / draws)
    assert np.mean(np.array(grouped) <= ALPHA) <= limit
    # Why groups matter: permuting clips ignores the shared offsets and rejects far too often.
    assert np.mean(np.array(naive) <= ALPHA) > 2 * limit


def test_planted_shift_is_detected_and_null_auc_is_chance():
    rng = np.random.default_rng(10)
    x, gx = grouped_sample(rng, 20, 4, 8, offset=0.3)
    y, gy = grouped_sample(rng, 20, 4, 8, offset=0.3, shift=0.5)
    bw = st.median_bandwidth(x)

    def stat(a, b):
        return st.mmd2_unbiased(a, b, bw)

    assert st.permutation_pvalue(x, y, gx, gy, stat, n_perm=99, rng=rng) < ALPHA
    assert st.domain_auc(x, y, gx, gy, rng=rng) > 0.7
    y0, gy0 = grouped_sample(rng, 20, 4, 8, offset=0.3)
    assert abs(st.domain_auc(x, y0, gx, gy0, rng=rng) - 0.5) < 0.15


def test_grouped_folds_keep_groups_whole_and_balanced():
    rng = np.random.default_rng(11)
    sizes = rng.integers(1, 6, size=23)
    groups = np.repeat([f"video{i}" for i in range(23)], sizes)
    folds = st.grouped_folds(groups, 5, rng)
    assert len(folds) == 5
    np.testing.assert_array_equal(np.sum(folds, axis=0), 1)  # every row in exactly one fold
    for g in np.unique(groups):
        assert sum(np.any(f[groups == g]) for f in folds) == 1
    counts = [f.sum() for f in folds]
    assert max(counts) - min(counts) <= sizes.max()
    with pytest.raises(ValueError, match="k must be"):
        st.grouped_folds(groups, 24, rng)


def test_domain_auc_does_not_memorise_groups():
    rng = np.random.default_rng(12)
    grouped, clip_level = [], []
    for _ in range(12):
        # Strong private offset per group (24 offsets in 40 dims: a linear model can learn
        # them all), identical domains; x and y reuse the ids 0..11 for different groups.
        x, gx = grouped_sample(rng, 12, 5, 40, offset=3.0, noise=0.3)
        y, gy = grouped_sample(rng, 12, 5, 40, offset=3.0, noise=0.3)
        grouped.append(st.domain_auc(x, y, gx, gy, rng=rng))
        clips = np.arange(60)
        clip_level.append(st.domain_auc(x, y, clips, clips, rng=rng))
    # One draw has only 12 groups a side (AUC sd ~0.15), hence the average over draws.
    assert abs(np.mean(grouped) - 0.5) < 0.15
    # Clip-level folds let the classifier recognise the groups it trained on.
    assert np.mean(clip_level) > 0.9


# ---------------------------------------------------------------------------- resampling helpers


def test_splits_permutations_and_bootstrap_move_whole_groups():
    rng = np.random.default_rng(13)
    x, gx = grouped_sample(rng, 7, 3, 2)
    y, gy = grouped_sample(rng, 5, 3, 2)
    a, b = st.split_groups(gx, rng)
    assert np.all(a ^ b) and len(np.unique(gx[a])) == 3
    assert not set(gx[a]) & set(gx[b])

    seen = []

    def sizes(p, q):
        seen.append((len(p), len(q)))
        return 0.0

    st.permutation_pvalue(x, y, gx, gy, sizes, n_perm=20, rng=rng)
    assert set(seen) == {(21, 15)}  # 7 and 5 groups of 3 clips, every time
    boot = st.group_bootstrap(
        x, y, gx, gy, lambda p, q: len(p) % 3 + len(q) % 3, n_boot=15, rng=rng
    )
    assert boot.shape == (15,) and np.all(boot == 0)
    floor = st.noise_floor(x, gx, lambda p, q: len(p), n_splits=4, rng=rng)
    np.testing.assert_array_equal(floor, 9)


# ---------------------------------------------------------------------------- compare, gap_closed


def test_compare_is_deterministic_and_intervals_hold_the_estimates():
    rng = np.random.default_rng(14)
    x, gx = grouped_sample(rng, 16, 4, 8, offset=0.5)
    y, gy = grouped_sample(rng, 16, 4, 8, offset=0.5, shift=1.0)
    kwargs = {"n_perm": 99, "n_boot": 100, "n_floor": 4}
    gap = st.compare(x, y, gx, gy, rng=np.random.default_rng(3), **kwargs)
    again = st.compare(x, y, gx, gy, rng=np.random.default_rng(3), **kwargs)
    assert gap == again
    assert gap.mmd2_ci[0] <= gap.mmd2 <= gap.mmd2_ci[1]
    assert gap.auc_ci[0] <= gap.auc <= gap.auc_ci[1]
    assert gap.p_value < ALPHA and gap.corrected_mmd2 > 0 and gap.corrected_auc > 0
    assert gap.mmd2 == pytest.approx(st.mmd2_unbiased(*st.standardize(x, y), gap.bandwidth))
    assert (gap.n_x, gap.groups_y) == (64, 16)
    assert json.loads(json.dumps(gap.to_json()))["corrected_mmd2"] == gap.corrected_mmd2
    fixed = st.compare(x, y, gx, gy, bandwidth=2.0, rng=np.random.default_rng(3), **kwargs)
    assert fixed.bandwidth == 2.0 and fixed.mmd2 != gap.mmd2


def test_compare_floor_matches_the_null_mmd2():
    rng = np.random.default_rng(15)
    null, floor, halves = [], [], []
    for _ in range(24):
        x, gx = grouped_sample(rng, 12, 4, 6)
        y, gy = grouped_sample(rng, 12, 4, 6)
        gap = st.compare(x, y, gx, gy, n_perm=1, n_boot=1, n_floor=6, folds=2, rng=rng)
        null.append(gap.mmd2)
        floor.append(gap.floor_mmd2)
        halves.append(max(gap.floor_mmd2_halves))
    # Size-matched floor tracks the group-sampling MMD² of x vs y; the raw half splits
    # (half the groups per side) sit about twice as high.
    assert 0.6 < np.mean(floor) / np.mean(null) < 1.5
    assert np.mean(halves) / np.mean(null) > 1.6


def test_compare_floor_is_near_zero_without_group_effects():
    rng = np.random.default_rng(16)
    x, gx = grouped_sample(rng, 16, 4, 6, offset=0.0)
    y, gy = grouped_sample(rng, 16, 4, 6, offset=0.0)
    gap = st.compare(x, y, gx, gy, n_perm=50, n_boot=50, n_floor=6, rng=rng)
    assert abs(gap.floor_mmd2) < 0.01
    assert abs(gap.floor_auc - 0.5) < 0.15
    assert gap.p_value > ALPHA


def test_gap_closed_edge_cases():
    assert st.gap_closed(1.0, 0.1, 0.1) == 1.0
    assert st.gap_closed(1.0, 0.55, 0.1) == pytest.approx(0.5)
    assert st.gap_closed(1.0, 1.0, 0.1) == 0.0
    assert st.gap_closed(1.0, 1.45, 0.1) == pytest.approx(-0.5)
    assert st.gap_closed(1.0, 5.0, 0.1) == -1.0  # clipped, sign kept
    assert st.gap_closed(1.0, 0.0, 0.1) == 1.0  # below the floor counts as fully closed
    assert st.gap_closed(0.1, 0.0, 0.1) == 0.0  # nothing above the floor to close
    assert st.gap_closed(0.05, 0.5, 0.1) == 0.0
    with pytest.raises(ValueError, match="gap_after"):
        st.gap_closed(1.0, math.nan, 0.1)


# ---------------------------------------------------------------------------- bad input


def test_bad_input_names_the_argument():
    rng = np.random.default_rng(17)
    x, y = rng.normal(size=(6, 3)), rng.normal(size=(5, 3))
    g6, g5 = np.arange(6) // 2, np.arange(5) // 2
    with pytest.raises(ValueError, match="n=1"):
        st.mmd2_unbiased(x[:1], y, 1.0)
    with pytest.raises(ValueError, match="m=1"):
        st.kid(x, y[:1])
    with pytest.raises(ValueError, match="d=2"):
        st.mmd2_unbiased(x, y[:, :2], 1.0)
    with pytest.raises(ValueError, match="gx"):
        st.permutation_pvalue(x, y, g5, g5, st.kid, rng=rng)
    with pytest.raises(ValueError, match="gy"):
        st.compare(x, y, g6, g6, rng=rng)
    with pytest.raises(ValueError, match="groups"):
        st.compare(x, y, np.zeros(6), g5, rng=rng)
    with pytest.raises(ValueError, match="gx has 1"):
        st.domain_auc(x, y, np.zeros(6), g5, rng=rng)
    with pytest.raises(ValueError, match="bandwidth"):
        st.mmd2_unbiased(x, y, 0.0)
    with pytest.raises(ValueError, match="x contains NaN"):
        st.kid(np.full((3, 3), np.nan), y)
