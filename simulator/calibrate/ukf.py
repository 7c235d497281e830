"""Unscented Kalman filter for material parameters from deformation sequences (thesis §4.2).

:class:`UnscentedKalmanFilter` is the parameter-estimation UKF of *thesis* §4.2.4 (eqs.
4.8-4.22, Wan and van der Merwe 2000): the parameters ``w`` (L of them, e.g. log Young's
modulus) are the filter state with an identity transition, sigma points are drawn from the
prior, the measurement function maps *all* sigma points at once (one batch of simulation
instances) to predicted observations, and the Kalman update moves the mean and shrinks the
covariance. Observations can be large (every tracked surface vertex), so the gain is formed
through the push-through identity with (2L+1)-sized matrices only; ``R`` is isotropic.

:func:`estimate_sequence` is *thesis* Algorithm 2: passes over the keyframes; for each
triple ``(y_{n-1}, y_n, y_{n+1})`` the hidden state at frame n is initialised by finite
differences (eqs. 4.23-4.24) and the measurement ``d = g(x_n, w)`` is the simulated frame
n+1 (see :class:`simulator.calibrate.ukf_body.FrameMeasurement`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import torch

__all__ = [
    "UKFSettings",
    "UKFStep",
    "UnscentedKalmanFilter",
    "estimate_sequence",
    "finite_difference_state",
]


@dataclasses.dataclass(frozen=True)
class UKFSettings:
    """Filter constants (thesis §4.2.4: beta = 2, alpha between 0.1 and 2)."""

    alpha: float = 1.0
    """Sigma-point spread."""
    beta: float = 2.0
    """Prior-distribution term (2 is optimal for Gaussians)."""
    kappa: float = 0.0
    """Secondary scaling; ``lambda = alpha² (L + kappa) - L``."""
    measurement_std: float = 1e-5
    """Standard deviation of each observed coordinate, sqrt of R's diagonal (> 0)."""
    process_std: float = 0.0
    """Parameter random-walk std per update (Q = process_std² I); 0 is eq. 4.11."""

    def __post_init__(self):
        if not (math.isfinite(self.alpha) and self.alpha > 0):
            raise ValueError(f"alpha must be > 0, got {self.alpha}")
        if not math.isfinite(self.beta):
            raise ValueError(f"beta must be finite, got {self.beta}")
        if not (math.isfinite(self.measurement_std) and self.measurement_std > 0):
            raise ValueError(f"measurement_std must be > 0, got {self.measurement_std}")
        if not (math.isfinite(self.process_std) and self.process_std >= 0):
            raise ValueError(f"process_std must be >= 0, got {self.process_std}")


@dataclasses.dataclass(frozen=True)
class UKFStep:
    """Diagnostics of one filter update."""

    mean: torch.Tensor
    """Posterior mean, shape (L,)."""
    cov: torch.Tensor
    """Posterior covariance, shape (L, L)."""
    innovation_rms: float
    """RMS of ``y - d^-`` (same unit as the observation)."""
    predicted: torch.Tensor
    """Measurement of each sigma point, shape (2L+1, M)."""


class UnscentedKalmanFilter:
    """Parameter-estimation UKF (identity transition, eqs. 4.8-4.22)."""

    def __init__(self, mean: torch.Tensor, cov: torch.Tensor, settings: UKFSettings | None = None):
        """Start from the initial guess ``mean`` (L,) and its covariance ``cov`` (L, L)."""
        mean = torch.as_tensor(mean, dtype=torch.float64).reshape(-1)
        cov = torch.as_tensor(cov, dtype=torch.float64)
        size = mean.numel()
        if size == 0 or not bool(torch.isfinite(mean).all()):
            raise ValueError("mean must be a non-empty finite parameter vector")
        if tuple(cov.shape) != (size, size) or not bool(torch.isfinite(cov).all()):
            raise ValueError(
                f"cov must be a finite ({size}, {size}) matrix, got {tuple(cov.shape)}"
            )
        if not torch.allclose(cov, cov.T) or float(torch.linalg.eigvalsh(cov).min()) <= 0:
            raise ValueError("cov must be symmetric positive definite")
        self.settings = settings or UKFSettings()
        self.mean, self.cov = mean, cov
        s = self.settings
        self.lam = s.alpha**2 * (size + s.kappa) - size
        if size + self.lam <= 0:
            raise ValueError(f"alpha/kappa give L + lambda = {size + self.lam} <= 0")
        wm = torch.full((2 * size + 1,), 0.5 / (size + self.lam), dtype=torch.float64)
        wc = wm.clone()
        wm[0] = self.lam / (size + self.lam)
        wc[0] = wm[0] + 1.0 - s.alpha**2 + s.beta
        self.weights_mean, self.weights_cov = wm, wc

    @property
    def size(self) -> int:
        """L, the number of parameters."""
        return int(self.mean.numel())

    def sigma_points(self, mean: torch.Tensor, cov: torch.Tensor) -> torch.Tensor:
        """Eq. 4.13: ``[w, w + gamma sqrt(P)_i, w - gamma sqrt(P)_i]``, shape (2L+1, L)."""
        jitter = 1e-12 * float(cov.diagonal().abs().max())
        root = torch.linalg.cholesky(
            (self.size + self.lam) * (cov + jitter * torch.eye(self.size, dtype=cov.dtype))
        )
        cols = root.T  # rows are the columns of the matrix square root
        return torch.cat([mean[None], mean[None] + cols, mean[None] - cols])

    def prior_sigma_points(self) -> torch.Tensor:
        """Sigma points of the prior (eqs. 4.10-4.13), shape (2L+1, L)."""
        prior_cov = self.cov + self.settings.process_std**2 * torch.eye(
            self.size, dtype=torch.float64
        )
        return self.sigma_points(self.mean, prior_cov)

    def update(
        self, measure: Callable[[torch.Tensor], torch.Tensor], observation: torch.Tensor
    ) -> UKFStep:
        """One iteration (eqs. 4.10-4.22) with measurement function ``measure`` (S, L) -> (S, M)."""
        sigma = self.prior_sigma_points()
        return self.correct(sigma, measure(sigma), observation)

    def correct(
        self, sigma: torch.Tensor, predicted: torch.Tensor, observation: torch.Tensor
    ) -> UKFStep:
        """Kalman correction (eqs. 4.17-4.22) from the sigma points' measurements (S, M)."""
        s = self.settings
        prior_cov = self.cov + s.process_std**2 * torch.eye(self.size, dtype=torch.float64)
        pred = torch.as_tensor(predicted, dtype=torch.float64)
        obs = torch.as_tensor(observation, dtype=torch.float64).reshape(-1)
        if pred.dim() != 2 or pred.shape[0] != sigma.shape[0] or pred.shape[1] != obs.numel():
            raise ValueError(
                f"measure must return shape ({sigma.shape[0]}, {obs.numel()}), "
                f"got {tuple(pred.shape)}"
            )
        if not bool(torch.isfinite(pred).all()):
            raise FloatingPointError("measure returned non-finite predictions")
        count = sigma.shape[0]
        eye = torch.eye(count, dtype=torch.float64)
        d_mean = self.weights_mean @ pred  # eq. 4.17
        yc = pred - d_mean  # (S, M)
        xc = sigma - self.mean  # (S, L)
        c = torch.diag(self.weights_cov)
        inv_r = 1.0 / s.measurement_std**2
        gram = inv_r * yc @ yc.T  # Yc R^-1 Yc^T, (S, S)
        core = torch.linalg.solve(eye + gram @ c, eye)
        innovation = obs - d_mean
        # K = Xc^T C (I + G C)^-1 Yc R^-1 (push-through form of eqs. 4.18-4.20).
        gain_left = xc.T @ c @ core  # (L, S)
        self.mean = self.mean + gain_left @ (inv_r * (yc @ innovation))  # eq. 4.21
        shrink = gain_left @ gram @ c @ xc  # K P_wd^T = K P_d K^T, eq. 4.22
        cov = prior_cov - shrink
        self.cov = 0.5 * (cov + cov.T)
        return UKFStep(
            self.mean.clone(), self.cov.clone(), float(innovation.square().mean().sqrt()), pred
        )


def finite_difference_state(
    prev: torch.Tensor, cur: torch.Tensor, nxt: torch.Tensor, dt: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Eqs. 4.23-4.24: ``u' = (y_n - y_{n-1}) / dt``, ``u'' = (y_{n+1} - 2 y_n + y_{n-1}) / dt²``.

    Returns velocity and acceleration with the shape of the frames.
    """
    if not dt > 0:
        raise ValueError(f"dt must be > 0 s, got {dt}")
    return (cur - prev) / dt, (nxt - 2.0 * cur + prev) / (dt * dt)


def estimate_sequence(
    ukf: UnscentedKalmanFilter | list[UnscentedKalmanFilter],
    measure_frame: Callable[[torch.Tensor, int], torch.Tensor],
    observations: torch.Tensor,
    *,
    passes: int = 3,
    keyframes: list[int] | None = None,
    tol: float = 1e-4,
) -> list[list[UKFStep]]:
    """Algorithm 2: UKF iterations over the keyframes until the means stop moving.

    Several independent filters on the same observations (e.g. different initial guesses)
    run in lockstep: their sigma points are stacked filter-major into one batch, so every
    measurement is a single batched simulation of ``G (2L+1)`` instances.

    Args:
        ukf: one filter or a list of G filters (their mean/cov are the initial guesses).
        measure_frame: ``(sigma (G (2L+1), L), n) -> (G (2L+1), M)``, the simulated
            observation of frame n + 1 from the state at frame n (built from frames n-1, n,
            n+1); it may call ``reset`` hooks itself, see ``on_pass``.
        observations: observed frames, shape (K, ...) with ``prod(...) = M``.
        passes: maximum passes over the keyframes ("while not converged").
        keyframes: frames n used (each needs n-1 and n+1); default 1 .. K-2.
        tol: stop after a pass that changed every parameter of every filter by less than this.

    Returns:
        Per filter, the diagnostics of each update.
    """
    filters = ukf if isinstance(ukf, list) else [ukf]
    frames = observations.shape[0]
    if frames < 3:
        raise ValueError(f"observations need at least 3 frames (K >= 3), got {frames}")
    keys = list(range(1, frames - 1)) if keyframes is None else list(keyframes)
    if not keys or any(n < 1 or n > frames - 2 for n in keys):
        raise ValueError(f"keyframes must lie in [1, {frames - 2}], got {keys}")
    history: list[list[UKFStep]] = [[] for _ in filters]
    for _ in range(passes):
        reset = getattr(measure_frame, "reset", None)
        if reset is not None:
            reset()
        start = torch.stack([f.mean for f in filters])
        for n in keys:
            sigma = [f.prior_sigma_points() for f in filters]
            pred = measure_frame(torch.cat(sigma), n)
            parts = torch.split(pred, [s.shape[0] for s in sigma])
            for i, f in enumerate(filters):
                history[i].append(f.correct(sigma[i], parts[i], observations[n + 1]))
        moved = torch.stack([f.mean for f in filters]) - start
        if float(moved.abs().max()) < tol:
            break
    return history
