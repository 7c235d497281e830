"""Wind velocity fields: constant, or gusty (varying in space and time).

The gusty field multiplies the mean wind by ``1 + a sum_m c_m sin(k_m . x - w_m t + p_m)``
and adds a cross-flow of the same size, with random wave vectors (wavelengths
0.3-1.5 m), frequencies (0.5-3 Hz) and phases drawn from the instance's seed,
so every instance gets its own reproducible turbulence.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

__all__ = ["WindField"]


@dataclasses.dataclass(frozen=True)
class WindField:
    """Per-instance wind: mean velocity plus optional travelling-wave gusts."""

    mean: torch.Tensor
    """Mean air velocity [m/s], shape (B, 3)."""
    wave_vectors: torch.Tensor | None = None
    """Gust wave vectors [rad/m], shape (B, M, 3)."""
    frequencies: torch.Tensor | None = None
    """Gust angular frequencies [rad/s], shape (B, M)."""
    phases: torch.Tensor | None = None
    """Gust phases [rad], shape (B, M, 2) (along-wind, cross-wind)."""
    amplitude: float = 0.0
    """Gust amplitude relative to the mean speed."""

    @staticmethod
    def gusty(mean: torch.Tensor, seeds: list[int], *, amplitude: float, modes: int) -> WindField:
        """Draw gust modes per instance from ``seeds`` (one int per instance)."""
        waves, freqs, phases = [], [], []
        for seed in seeds:
            rng = np.random.default_rng(seed)
            direction = rng.normal(size=(modes, 3))
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            wavelength = rng.uniform(0.3, 1.5, size=(modes, 1))
            waves.append(direction * 2 * math.pi / wavelength)
            freqs.append(2 * math.pi * rng.uniform(0.5, 3.0, size=modes))
            phases.append(rng.uniform(0, 2 * math.pi, size=(modes, 2)))
        as_t = lambda a: torch.as_tensor(np.stack(a), dtype=mean.dtype, device=mean.device)  # noqa: E731
        return WindField(mean, as_t(waves), as_t(freqs), as_t(phases), float(amplitude))

    def velocity(self, pos: torch.Tensor, time: float, ramp: float = 1.0) -> torch.Tensor:
        """Air velocity at each vertex [m/s], shape (B, V, 3), scaled by ``ramp`` in [0, 1]."""
        mean = self.mean[:, None, :] * ramp
        if self.wave_vectors is None or self.amplitude == 0.0:
            return mean.expand_as(pos)
        arg = (
            torch.einsum("bvx,bmx->bvm", pos, self.wave_vectors) - self.frequencies[:, None] * time
        )
        along = torch.sin(arg + self.phases[:, None, :, 0]).mean(-1, keepdim=True)
        across = torch.sin(arg + self.phases[:, None, :, 1]).mean(-1, keepdim=True)
        speed = torch.linalg.vector_norm(self.mean, dim=-1, keepdim=True)[:, None]
        up = torch.zeros_like(self.mean)
        up[:, 2] = 1.0
        side = torch.linalg.cross(self.mean, up, dim=-1)
        side = side / torch.linalg.vector_norm(side, dim=-1, keepdim=True).clamp_min(1e-12)
        scale = self.amplitude * math.sqrt(2.0)
        return mean * (1 + scale * along) + scale * ramp * speed * across * side[:, None, :]

    def to(self, device=None, dtype=None) -> WindField:
        """Copy to ``device`` / ``dtype``."""
        move = lambda t: None if t is None else t.to(device=device, dtype=dtype)  # noqa: E731
        return WindField(
            move(self.mean),
            move(self.wave_vectors),
            move(self.frequencies),
            move(self.phases),
            self.amplitude,
        )
