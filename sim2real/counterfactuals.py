"""Counterfactual stage swaps: how much of the gap is left once one stage of S is made R's.

Two swaps complement the candidate search (:mod:`sim2real.diagnosis`), each answering "if
this stage were the real one, would the gap go away?" without a search over effects:

* **camera** (:func:`camera_signatures`, :func:`match_camera`): every camera effect of the
  library is given a *signature statistic*, the clip statistic (median or spread over clips
  of one pixel or motion feature) that it moves most and the other camera effects move
  least, found from the effect's own sets, with no table of which statistic belongs to which
  effect (a new camera switch gets one automatically). R's value of each signature is
  measured; where it differs from S's beyond the group-bootstrap noise, in the direction the
  effect moves it, the effect's strength is read off its sets by interpolation. S with every
  matched effect at its strength is R's camera emulated on S; the gap it leaves per rung is
  what the camera does not explain.
* **batch norm** (:func:`batchnorm_swap`): the network with its batch-norm statistics
  re-estimated on R (AdaBN, :func:`sim2real.network.adapt_batchnorm`). The share of a layer's
  gap it closes is the part a per-channel shift and scale explain; the model's scores on R
  before and after, correlated with the measured stiffness and density, say whether that
  cheap test-time fix also repairs what the model predicts.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from common.grid import ClassGrid

from .ladder import LadderFeatures
from .rungs import hand_rung, hand_rung_names
from .stats import Gap, bootstrap_draws, domain_auc, gap_closed, mmd2_unbiased, standardize

__all__ = [
    "MIN_SIGNATURE_Z",
    "SCALE_FLOOR",
    "batchnorm_swap",
    "camera_signatures",
    "clip_statistics",
    "group_scores",
    "match_camera",
    "swap_closure",
]

MIN_SIGNATURE_Z = 3.0
"""R's signature statistic must differ from S's by this many standard errors (group bootstrap
of both) for the effect to count as present, and an effect's strongest set must move its own
signature at least this far from S to have a usable signature at all."""

STATISTIC_BOOT = 200
"""Group-bootstrap replicates for the statistics' standard errors."""


def statistic_names() -> list[str]:
    """Names of the clip statistics, in the order of :func:`clip_statistics`' columns."""
    return [
        f"{kind}({rung}.{name})"
        for kind in ("median", "spread")
        for rung in hand_rung_names()
        for name in hand_rung(rung).feature_names
    ]


def _weighted_quantiles(values: np.ndarray, weights: np.ndarray, qs) -> np.ndarray:
    """Weighted quantiles of each column of ``values`` (n, d), shape (len(qs), B, d).

    Rows are weighted by each of the B columns of ``weights`` (n, B); the quantile is the
    inverted empirical CDF's (numpy's ``method="inverted_cdf"``), defined for any weights.
    """
    order = np.argsort(values, axis=0)
    out = np.empty((len(qs), weights.shape[1], values.shape[1]))
    for j in range(values.shape[1]):
        sorted_values = values[order[:, j], j]
        cumulative = np.cumsum(weights[order[:, j]], axis=0)  # (n, B)
        total = cumulative[-1]
        for q, level in enumerate(qs):
            index = (cumulative < level * total[None, :]).sum(axis=0)
            out[q, :, j] = sorted_values[np.minimum(index, len(sorted_values) - 1)]
    return out


def clip_statistics(features: LadderFeatures, weights: np.ndarray | None = None) -> np.ndarray:
    """Median and spread (interquartile range) over clips of every hand-made rung's feature.

    Args:
        features: A clip set on the ladder.
        weights: Per-clip weights (n, B) of B group-bootstrap replicates; ``None``: one plain
            evaluation.

    Returns:
        Shape (B, S) (B = 1 without weights); columns named by :func:`statistic_names`.
    """
    values = np.concatenate([features.rungs[r] for r in hand_rung_names()], axis=1)
    if weights is None:
        weights = np.ones((len(values), 1))
    q25, q50, q75 = _weighted_quantiles(values, weights, (0.25, 0.5, 0.75))
    return np.concatenate([q50, q75 - q25], axis=1)


def _bootstrap_se(features: LadderFeatures, rng: np.random.Generator) -> np.ndarray:
    """Group-bootstrap standard error of every clip statistic, shape (S,)."""
    groups, codes = np.unique(features.groups, return_inverse=True)
    draws = bootstrap_draws(len(groups), STATISTIC_BOOT, rng)
    return clip_statistics(features, draws[codes].astype(np.float64)).std(axis=0)


SCALE_FLOOR = 0.02
"""A statistic's noise scale is at least this share of its spread over all sets tried: a
statistic S never varies (the clipped-white share of a clean render) must not make any
change look infinitely significant."""


def camera_signatures(
    sim: LadderFeatures,
    effect_sets: dict[str, tuple[tuple, list[LadderFeatures], float | None]],
    rivals: dict[str, list[LadderFeatures]] | None = None,
    *,
    rng: np.random.Generator,
) -> dict[str, dict]:
    """Each camera effect's signature statistic, found from its sets.

    For an effect e and a statistic j, z_ej = the largest |T_j(S_e(s)) - T_j(S)| over the
    tried strengths s, in units of the statistic's noise scale: S's group-bootstrap standard
    error, at least :data:`SCALE_FLOOR` of the statistic's spread over all sets. The
    signature is the statistic with the largest specificity z_ej / (1 + max z_e'j over every
    other effect e', the ``rivals`` included) among those with z_ej >=
    :data:`MIN_SIGNATURE_Z`, leaving out features that never vary over S's clips (a clean
    render's clipped-black share: any real background would move it); an effect that moves
    no statistic that far has none. Rivals from
    other stages (physics, scene, appearance) keep a statistic that the cloth's motion also
    moves from standing for a camera effect.

    Args:
        sim: The nominal set S.
        effect_sets: Camera effect name -> (strengths, its sets in the same order, the
            neutral strength or ``None``: see :func:`_invert`).
        rivals: Other candidates' sets by name (any stage), for specificity only.
        rng: Bootstrap randomness.

    Returns:
        Effect name -> ``{"statistic", "index", "z", "specificity", "strengths", "values",
        "nominal", "nominal_se", "neutral"}`` (``statistic`` None when there is none).
    """
    names = statistic_names()
    nominal = clip_statistics(sim)[0]
    curves = {
        e: np.stack([clip_statistics(f)[0] for f in sets])
        for e, (_, sets, _) in effect_sets.items()
    }
    curves.update(
        {
            f"rival:{r}": np.stack([clip_statistics(f)[0] for f in sets])
            for r, sets in (rivals or {}).items()
            if r not in effect_sets
        }
    )
    spread = np.concatenate([nominal[None], *curves.values()]).std(axis=0)
    raw_se = _bootstrap_se(sim, rng)
    se = np.maximum(raw_se, SCALE_FLOOR * spread + 1e-12)
    z = {e: np.abs(c - nominal).max(axis=0) / se for e, c in curves.items()}
    features = np.concatenate([sim.rungs[r] for r in hand_rung_names()], axis=1)
    # a feature S never varies, or a statistic no resampling of S moves (the median of a
    # clipped-black share that most clean clips have at 0), is no signature
    usable = np.tile(features.std(axis=0) > 0, 2) & (raw_se > 0)
    out = {}
    for effect, (strengths, _, neutral) in effect_sets.items():
        others = [z[o] for o in z if o != effect]
        rival = np.max(others, axis=0) if others else np.zeros_like(z[effect])
        specificity = np.where(
            usable & (z[effect] >= MIN_SIGNATURE_Z), z[effect] / (1.0 + rival), -np.inf
        )
        j = int(np.argmax(specificity))
        found = math.isfinite(specificity[j])
        out[effect] = {
            "statistic": names[j] if found else None,
            "index": j if found else None,
            "z": float(z[effect][j]),
            "specificity": float(specificity[j]) if found else None,
            "strengths": list(strengths),
            "values": curves[effect][:, j].tolist(),
            "nominal": float(nominal[j]),
            "nominal_se": float(se[j]),
            "neutral": neutral,
        }
    return out


def _invert(strengths: list, values: list, nominal: float, target: float, neutral=None):
    """Strength at which the effect's statistic reaches ``target`` (piecewise linear).

    The curve runs through the sets' (strength, value) points and, at the ``neutral``
    strength, the nominal value (without one, the effect's off state sits just below the
    weakest strength: a target between the nominal and the weakest set's value gives the
    weakest strength). Where the curve reaches the target more than once, the crossing
    nearest the neutral end wins (the weakest effect that explains R); where it never does,
    the point closest to the target. The result is clipped to the strengths tried.
    """
    points = sorted(zip(strengths, values, strict=True))
    if neutral is not None:
        points = sorted([*points, (neutral, nominal)])
        anchor = neutral
    else:
        points = [(points[0][0], nominal), *points]  # off, then the weakest strength
        anchor = points[0][0]
    crossings = []
    for (s0, v0), (s1, v1) in itertools.pairwise(points):
        if v0 != v1 and min(v0, v1) <= target <= max(v0, v1):
            crossings.append(s0 + (target - v0) / (v1 - v0) * (s1 - s0))
    if crossings:
        value = min(crossings, key=lambda c: abs(c - anchor))
    else:
        value = min(points, key=lambda p: abs(p[1] - target))[0]
    return float(np.clip(value, min(strengths), max(strengths)))


def _weakest_value(sig: dict) -> float:
    """The signature's value at the effect's weakest strength tried (nearest its neutral)."""
    strengths = np.asarray(sig["strengths"], dtype=float)
    neutral = sig["neutral"]
    i = int(np.argmin(strengths if neutral is None else np.abs(np.log(strengths / neutral))))
    return float(sig["values"][i])


def match_camera(
    signatures: dict[str, dict],
    real: LadderFeatures,
    sim: LadderFeatures,
    *,
    rng: np.random.Generator,
) -> dict[str, dict]:
    """R's value of every signature and the strength that reproduces it on S (or none).

    An effect counts as present when R's signature value differs from S's by at least
    :data:`MIN_SIGNATURE_Z` combined standard errors (group bootstrap of R's videos and S's
    simulations) in a direction the effect moves it, and by at least half as much as the
    effect's weakest plausible strength moves it (closer to S, the effect even at its
    weakest would overshoot R: a sensor's shot noise alone is several levels); its strength
    is then read off the effect's curve (:func:`_invert`).

    Returns:
        Effect name -> ``{"statistic", "real", "nominal", "z", "present", "strength"}``.
    """
    real_stats = clip_statistics(real)[0]
    real_se = _bootstrap_se(real, rng)
    out = {}
    for effect, sig in signatures.items():
        if sig["index"] is None:
            out[effect] = {"statistic": None, "present": False, "strength": None}
            continue
        j = sig["index"]
        value, nominal = float(real_stats[j]), sig["nominal"]
        z = (value - nominal) / math.hypot(sig["nominal_se"], float(real_se[j]))
        directions = set(np.sign(np.subtract(sig["values"], nominal)).tolist())
        weakest = _weakest_value(sig)
        present = (
            abs(z) >= MIN_SIGNATURE_Z
            and np.sign(value - nominal) in directions
            and abs(value - nominal) >= 0.5 * abs(weakest - nominal)
        )
        strength = (
            _invert(sig["strengths"], sig["values"], nominal, value, sig["neutral"])
            if present
            else None
        )
        out[effect] = {
            "statistic": sig["statistic"],
            "real": value,
            "nominal": nominal,
            "z": float(z),
            "present": bool(present),
            "strength": strength,
        }
    return out


def _mmd2(
    sim: LadderFeatures,
    real: LadderFeatures,
    x: np.ndarray,
    y: np.ndarray,
    rung: str,
    bandwidth: float,
) -> float:
    pooled = np.concatenate([sim.rungs[rung], real.rungs[rung]])
    return mmd2_unbiased(standardize(pooled, x)[1], standardize(pooled, y)[1], bandwidth)


def swap_closure(
    sim: LadderFeatures,
    real: LadderFeatures,
    gaps: dict[str, Gap],
    *,
    sim_after: LadderFeatures | None = None,
    real_after: LadderFeatures | None = None,
    rungs: list[str] | None = None,
    rng: np.random.Generator,
) -> dict[str, dict]:
    """Per rung, the gap after a swap (S -> ``sim_after`` and/or R -> ``real_after``).

    MMD² uses each rung's fixed scaling and kernel (S and R pooled, as in
    :func:`sim2real.diagnosis.rung_gaps`); the closure is the fraction of the floor-corrected
    gap removed; the domain AUC after the swap is floor-corrected with the rung's floor.
    """
    sim_after = sim_after or sim
    real_after = real_after or real
    out = {}
    for rung in rungs or list(gaps):
        gap = gaps[rung]
        floor = gap.floor_mmd2 if math.isfinite(gap.floor_mmd2) else 0.0
        x, y = sim_after.rungs[rung], real_after.rungs[rung]
        after = _mmd2(sim, real, x, y, rung, gap.bandwidth)
        pooled = np.concatenate([sim.rungs[rung], real.rungs[rung]])
        auc = domain_auc(
            standardize(pooled, x)[1],
            standardize(pooled, y)[1],
            sim_after.groups,
            real_after.groups,
            rng=rng,
        )
        corrected = (
            max(0.0, auc - gap.floor_auc) / max(1e-9, 1.0 - gap.floor_auc)
            if math.isfinite(gap.floor_auc)
            else math.nan
        )
        out[rung] = {
            "mmd2_before": gap.mmd2,
            "mmd2_after": after,
            "floor_mmd2": floor,
            "closure": gap_closed(gap.mmd2, after, floor),
            "corrected_auc_before": gap.corrected_auc,
            "corrected_auc_after": corrected,
        }
    return out


def group_scores(
    groups, logits: np.ndarray, stiffness, density, grid: ClassGrid
) -> dict[str, np.ndarray]:
    """Per-group (video or simulation) material scores from clip logits over ``grid``'s classes.

    Probabilities are averaged per group first, as :mod:`models.evaluate` does; the group's
    stiffness and density come along (means over its clips).
    """
    import torch

    from models.scores import correlated_scores, material_scores

    videos, rows = np.unique(np.asarray(groups), return_inverse=True)
    counts = np.bincount(rows)
    probs = torch.softmax(torch.as_tensor(logits), dim=1).numpy()
    mean = np.zeros((len(videos), probs.shape[1]))
    np.add.at(mean, rows, probs)
    scores = material_scores(torch.as_tensor(mean / counts[:, None]), grid)
    out = {name: scores[name].numpy() for name in correlated_scores(grid)}
    out["stiffness"] = np.bincount(rows, np.asarray(stiffness, dtype=float)) / counts
    out["density"] = np.bincount(rows, np.asarray(density, dtype=float)) / counts
    return out


def score_correlations(
    real: LadderFeatures, logits: np.ndarray, grid: ClassGrid, *, seed: int = 0
) -> dict:
    """Spearman and Pearson (group bootstrap CIs) of each model score with each measured value."""
    from models.correlation import correlate
    from models.scores import correlated_scores

    per_video = group_scores(real.groups, logits, real.stiffness, real.density, grid)
    return {
        f"{score}~{target}": correlate(
            per_video[score], per_video[target], rounds=1000, seed=seed
        ).to_json()
        for score in correlated_scores(grid)
        for target in ("stiffness", "density")
    }


def batchnorm_swap(
    sim: LadderFeatures,
    real: LadderFeatures,
    real_adapted: LadderFeatures | None,
    gaps: dict[str, Gap],
    grid: ClassGrid,
    *,
    rng: np.random.Generator,
) -> dict:
    """Counterfactual (c): the layers' gaps and the model's correlations after AdaBN on R.

    Args:
        sim: S through the trained network.
        real: R through the trained network.
        real_adapted: R through the network with batch-norm statistics re-estimated on R
            (``None``: the network has no batch-norm layer).
        gaps: S vs R per rung.
        grid: The network's class grid (its scores' meaning).
        rng: Randomness of the domain classifier's folds.
    """
    if real_adapted is None:
        return {"available": False, "reason": "the network has no batch-norm layer"}
    layers = [n for n in gaps if n not in hand_rung_names() and n in real_adapted.rungs]
    out = {
        "available": True,
        "layers": swap_closure(sim, real, gaps, real_after=real_adapted, rungs=layers, rng=rng),
    }
    if "logits" in real.rungs and "logits" in real_adapted.rungs:
        out["correlations"] = {
            "before": score_correlations(real, real.rungs["logits"], grid),
            "after": score_correlations(real_adapted, real_adapted.rungs["logits"], grid),
        }
    return out
