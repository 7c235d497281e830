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

The modules: :mod:`.checks` (inputs), :mod:`.kernels` (MMD², KID), :mod:`.classifier` (the
grouped-CV domain classifier), :mod:`.resampling` (group permutations, bootstrap, splits) and
:mod:`.compare` (one rung's :class:`Gap`).
"""

from __future__ import annotations

from .checks import STD_FLOOR, Statistic, standardize
from .classifier import (
    LogisticFit,
    auc_score,
    c2st_pvalue,
    classifier_divergence,
    domain_auc,
    domain_scores,
    fit_logistic,
    grouped_folds,
    logistic_loss,
    weighted_auc,
)
from .compare import CI_LEVEL, MIN_FLOOR_GROUPS, Gap, auc_above_floor, compare, gap_closed
from .kernels import MAX_BANDWIDTH_ROWS, kid, median_bandwidth, mmd2_replicates, mmd2_unbiased
from .resampling import (
    TIE_RTOL,
    bootstrap_draws,
    group_bootstrap,
    noise_floor,
    permutation_pvalue,
    split_groups,
)

__all__ = [
    "CI_LEVEL",
    "MAX_BANDWIDTH_ROWS",
    "MIN_FLOOR_GROUPS",
    "STD_FLOOR",
    "TIE_RTOL",
    "Gap",
    "LogisticFit",
    "Statistic",
    "auc_above_floor",
    "auc_score",
    "bootstrap_draws",
    "c2st_pvalue",
    "classifier_divergence",
    "compare",
    "domain_auc",
    "domain_scores",
    "fit_logistic",
    "gap_closed",
    "group_bootstrap",
    "grouped_folds",
    "kid",
    "logistic_loss",
    "median_bandwidth",
    "mmd2_replicates",
    "mmd2_unbiased",
    "noise_floor",
    "permutation_pvalue",
    "split_groups",
    "standardize",
    "weighted_auc",
]
