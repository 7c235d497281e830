"""Does the class signal transfer: a ridge probe trained on S, tested on R, per rung."""

from __future__ import annotations

import numpy as np
from scipy import stats as sstats

from ..ladder import LadderFeatures
from .scoring import _scaled

__all__ = ["probe_transfer"]


def _ridge(x: np.ndarray, y: np.ndarray, l2: float = 1.0) -> np.ndarray:
    gram = x.T @ x + l2 * len(x) * np.eye(x.shape[1])
    return np.linalg.solve(gram, x.T @ (y - y.mean()))


def probe_transfer(sim: LadderFeatures, real: LadderFeatures, *, l2: float = 1.0) -> dict:
    """Per rung: a ridge probe of the class position trained on S, tested on R.

    The class id is a stiffness ordering (``models.scores``); on R the per-video mean
    prediction is correlated (Spearman) with the measured stiffness and density. A rung
    with a large gap whose probe still transfers carries a harmless gap; a probe that
    transfers on ``motion`` but not on the network's layers points at appearance.
    """
    out = {}
    videos = np.unique(real.groups)
    index = {v: i for i, v in enumerate(videos)}
    rows = np.array([index[g] for g in real.groups])
    counts = np.bincount(rows, minlength=len(videos)).astype(float)
    stiff = np.bincount(rows, real.stiffness, len(videos)) / counts
    dens = np.bincount(rows, real.density, len(videos)) / counts
    target = sim.class_id.astype(float)
    for name in sim.rungs:
        xs, xr = _scaled(sim.rungs[name], sim.rungs[name], real.rungs[name])
        weight = _ridge(xs, target, l2)
        pred = xr @ weight
        per_video = np.bincount(rows, pred, len(videos)) / counts
        fit = np.corrcoef(xs @ weight, target)[0, 1] if np.std(xs @ weight) > 0 else 0.0
        entry = {"sim_fit_r": float(fit)}
        for label, measured in (("stiffness", stiff), ("density", dens)):
            if len(videos) >= 3 and np.std(per_video) > 0 and np.std(measured) > 0:
                entry[f"{label}_spearman"] = float(sstats.spearmanr(per_video, measured)[0])
            else:
                entry[f"{label}_spearman"] = None
        out[name] = entry
    return out
