"""Thesis Table 4.1-style UKF experiment and the dropped ball (*thesis* §4.3).

* :func:`ukf_table41`: for each ground-truth Young's modulus, a tetrahedral linear-elastic
  beam driven by a known end traction (computed from the true modulus, as the thesis's heart
  contraction force) is simulated with a 4x finer time step than the estimator uses; the
  tracked surface vertices (0.01 mm Gaussian noise) are the observations. Several noisy
  initial guesses (the thesis's "initialized" row: half the true value, uniform within its
  spread) are filtered in lockstep as one batch. Reported: recovered modulus mean and std,
  average relative error, and the average surface distance between the sequence re-simulated
  with the recovered modulus and the observations. ``body="heart"`` runs the same protocol on
  the thesis's body instead: the gmsh biventricular heart squeezed by a contraction force
  computed from the true modulus, integrated with Newmark (*thesis* §4.2.2, §4.3.1).
* :func:`ukf_dropped_ball`: a co-rotated ball dropped on the ground, gravity the only load.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import time

import numpy as np
import torch

from simulator.calibrate.ukf import UKFSettings, UnscentedKalmanFilter, estimate_sequence
from simulator.calibrate.ukf_body import (
    BEAM_CELLS,
    HEART_MESH_SIZE,
    INTEGRATORS,
    DynamicProblem,
    FrameMeasurement,
    dropped_ball_problem,
    heart_problem,
    rollout,
    tet_beam_problem,
)
from simulator.threads import torch_threads

__all__ = [
    "TABLE41_BODIES",
    "THESIS_TABLE_4_1",
    "run_ukf_benchmark",
    "ukf_dropped_ball",
    "ukf_table41",
]

THESIS_TABLE_4_1 = {
    40: {"init": (20, 10), "recovered": (37, 2), "rel_err": 7.5, "surface_mm": (0.2, 0.1)},
    80: {"init": (40, 10), "recovered": (76, 3), "rel_err": 5.0, "surface_mm": (0.3, 0.1)},
    100: {"init": (50, 10), "recovered": (93, 4), "rel_err": 7.0, "surface_mm": (0.3, 0.1)},
    140: {"init": (70, 20), "recovered": (134, 7), "rel_err": 4.3, "surface_mm": (0.5, 0.2)},
    180: {"init": (90, 20), "recovered": (167, 10), "rel_err": 7.2, "surface_mm": (0.7, 0.2)},
}
"""Thesis Table 4.1 (synthetic heart) in kPa / %: initial mean +- spread, recovered mean +- std."""

GT_REFINE = 4
"""Ground truth uses this many times more integrator steps per frame than the estimator."""
TABLE41_BODIES = {"beam": tet_beam_problem, "heart": heart_problem}
"""Bodies of the Table 4.1 experiment: builders taking ``load_modulus`` [Pa]."""
PRIOR_LOG_STD = 0.7
"""Initial std of log E (a factor of 2 either way)."""


def _observe(
    problem: DynamicProblem,
    modulus: float,
    frames: int,
    noise: float,
    seed: int,
    *,
    truth_problem: DynamicProblem | None = None,
):
    """Noisy tracked positions of ``problem.observed``, simulated on ``truth_problem``.

    ``truth_problem`` (default: the same body) may use another mesh of the same body; its
    motion is interpolated (barycentric, at the rest positions) at the observed vertices.
    """
    source = truth_problem or problem
    truth = rollout(
        source,
        torch.tensor([modulus], dtype=torch.float64),
        frames,
        substeps=problem.substeps * GT_REFINE,
    )[:, 0]
    if truth_problem is None:
        truth = truth[:, problem.observed]
    else:
        mesh = source.model.mesh
        tet, weights = mesh.locate(problem.model.mesh.vert_pos[problem.observed])
        truth = (truth[:, mesh.tet_indices[tet]] * weights[None, :, :, None]).sum(2)
    gen = torch.Generator().manual_seed(seed)
    return truth + noise * torch.randn(truth.shape, generator=gen, dtype=truth.dtype)


def _estimate(problem, observations, guesses, *, measurement_std, passes):
    """Filters for each initial guess [Pa], in lockstep; recovered moduli [Pa]."""
    settings = UKFSettings(alpha=1.0, beta=2.0, measurement_std=measurement_std)
    filters = [
        UnscentedKalmanFilter(
            torch.tensor([math.log(g)]), torch.tensor([[PRIOR_LOG_STD**2]]), settings
        )
        for g in guesses
    ]
    measure = FrameMeasurement(problem, observations)
    measure.group_size = 2 * filters[0].size + 1
    history = estimate_sequence(filters, measure, observations, passes=passes)
    return [math.exp(float(f.mean[0])) for f in filters], history


def _surface_error_mm(problem, observations, modulus: float) -> float:
    sim = rollout(problem, torch.tensor([modulus], dtype=torch.float64), observations.shape[0])
    return (
        float(torch.linalg.vector_norm(sim[:, 0, problem.observed] - observations, dim=-1).mean())
        * 1e3
    )


def ukf_table41(
    *,
    seed: int = 0,
    moduli_kpa: tuple[int, ...] = (40, 80, 100, 140, 180),
    trials: int = 5,
    frames: int = 40,
    passes: int = 2,
    noise: float = 1e-5,
    truth_mesh_refine: int = 1,
    body: str = "beam",
    integrator: str | None = None,
) -> list[dict]:
    """One row per ground-truth modulus (see module docstring).

    ``truth_mesh_refine > 1`` simulates the ground truth on a finer mesh of the body (beam:
    that many times more cells per side; heart: that many times smaller gmsh elements), so
    the estimator's coarse mesh also differs in space from the truth. ``body`` is a key of
    :data:`TABLE41_BODIES`; ``integrator`` (a key of ``INTEGRATORS``) overrides the body's own.
    """
    if body not in TABLE41_BODIES:
        raise ValueError(f"body must be one of {sorted(TABLE41_BODIES)}, got {body!r}")
    if integrator is not None and integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {sorted(INTEGRATORS)}, got {integrator!r}")
    if truth_mesh_refine < 1:
        raise ValueError(f"truth_mesh_refine must be >= 1, got {truth_mesh_refine}")
    rng = np.random.default_rng(seed)
    rows = []
    for e_kpa in moduli_kpa:
        init_mean, spread = THESIS_TABLE_4_1.get(e_kpa, {"init": (e_kpa / 2, e_kpa / 4)})["init"]
        guesses = [
            1e3 * float(g) for g in rng.uniform(init_mean - spread, init_mean + spread, trials)
        ]
        problem = TABLE41_BODIES[body](load_modulus=1e3 * e_kpa)
        if integrator is not None:
            problem = dataclasses.replace(problem, integrator=integrator)
        truth = None
        if truth_mesh_refine > 1:
            finer = {
                "beam": {"cells": tuple(truth_mesh_refine * c for c in BEAM_CELLS)},
                "heart": {"mesh_size": HEART_MESH_SIZE / truth_mesh_refine},
            }[body]
            truth = TABLE41_BODIES[body](load_modulus=1e3 * e_kpa, **finer)
            truth = dataclasses.replace(truth, integrator=problem.integrator)
        obs = _observe(problem, 1e3 * e_kpa, frames, noise, seed + e_kpa, truth_problem=truth)
        tic = time.perf_counter()
        recovered, _ = _estimate(problem, obs, guesses, measurement_std=3.0 * noise, passes=passes)
        seconds = time.perf_counter() - tic
        rel = [abs(r / (1e3 * e_kpa) - 1.0) for r in recovered]
        surf = [_surface_error_mm(problem, obs, r) for r in recovered]
        rows.append(
            {
                "true_kpa": e_kpa,
                "init_mean_kpa": statistics.mean(guesses) / 1e3,
                "init_std_kpa": statistics.pstdev(guesses) / 1e3,
                "recovered_mean_kpa": statistics.mean(recovered) / 1e3,
                "recovered_std_kpa": statistics.pstdev(recovered) / 1e3,
                "avg_rel_err_pct": 100.0 * statistics.mean(rel),
                "max_rel_err_pct": 100.0 * max(rel),
                "surface_err_mm": statistics.mean(surf),
                "surface_err_std_mm": statistics.pstdev(surf),
                "trials": trials,
                "body": body,
                "integrator": problem.integrator,
                "seconds": seconds,
            }
        )
    return rows


def ukf_dropped_ball(
    *,
    seed: int = 0,
    true_kpa: float = 20.0,
    trials: int = 3,
    frames: int = 40,
    passes: int = 2,
    noise: float = 1e-6,
) -> dict:
    """Foam-like ball (20 kPa, 400 kg/m³, r = 30 mm) hitting the ground at 1 m/s, 2000 fps."""
    rng = np.random.default_rng(seed)
    guesses = [1e3 * float(g) for g in rng.uniform(0.25 * true_kpa, 0.75 * true_kpa, trials)]
    problem = dropped_ball_problem()
    obs = _observe(problem, 1e3 * true_kpa, frames, noise, seed)
    tic = time.perf_counter()
    recovered, _ = _estimate(problem, obs, guesses, measurement_std=10.0 * noise, passes=passes)
    seconds = time.perf_counter() - tic
    rel = [abs(r / (1e3 * true_kpa) - 1.0) for r in recovered]
    return {
        "true_kpa": true_kpa,
        "init_kpa": [g / 1e3 for g in guesses],
        "recovered_kpa": [r / 1e3 for r in recovered],
        "avg_rel_err_pct": 100.0 * statistics.mean(rel),
        "max_rel_err_pct": 100.0 * max(rel),
        "seconds": seconds,
    }


def run_ukf_benchmark(seed: int = 0) -> dict:
    """Headline UKF figures (single-threaded): Table 4.1 sweep (3 trials each) and the ball.

    Returns:
        ``ukf_rel_err``: the largest per-modulus average relative error of the recovered
        Young's modulus (fraction; the thesis's "within 7.5 %" is 0.075), plus
        ``ukf_rel_err_mean``, ``ukf_ball_rel_err`` (fractions) and ``ukf_minutes``.
    """
    tic = time.perf_counter()
    with torch_threads(1):
        rows = ukf_table41(seed=seed, trials=3)
        ball = ukf_dropped_ball(seed=seed)
    return {
        "ukf_rel_err": max(r["avg_rel_err_pct"] for r in rows) / 100.0,
        "ukf_rel_err_mean": statistics.mean(r["avg_rel_err_pct"] for r in rows) / 100.0,
        "ukf_ball_rel_err": ball["avg_rel_err_pct"] / 100.0,
        "ukf_minutes": (time.perf_counter() - tic) / 60.0,
    }
