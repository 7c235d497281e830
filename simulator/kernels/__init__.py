"""Compiled CPU kernels (numba) of the cloth step: the fast path of ``sim.backend=kernels``.

The torch path stays the reference, the CUDA path and the autograd oracle; these kernels
compute the same incremental potential on CPU with fused element passes and per-instance
PCG (``shell`` and ``pcg`` hold the kernels, ``bridge`` the torch-facing side). Numba is
imported only when the kernels are used, so the rest of the package works without it.
"""

from __future__ import annotations

import importlib.util

import torch

__all__ = ["BACKENDS", "available", "resolve_backend"]

BACKENDS = ("auto", "torch", "kernels")
"""``sim.backend`` values: ``auto`` = kernels on CPU (when numba is installed), torch on CUDA."""


def available() -> bool:
    """Whether numba is installed."""
    return importlib.util.find_spec("numba") is not None


def resolve_backend(backend: str, device: torch.device | str) -> str:
    """``torch`` or ``kernels`` for ``backend`` on ``device``; a ValueError names bad values."""
    if backend not in BACKENDS:
        raise ValueError(f"sim.backend must be one of {list(BACKENDS)}, got {backend!r}")
    on_cpu = torch.device(device).type == "cpu"
    if backend == "auto":
        return "kernels" if on_cpu and available() else "torch"
    if backend == "kernels" and not on_cpu:
        raise ValueError("sim.backend=kernels runs on CPU only; use 'torch' or 'auto' on CUDA")
    if backend == "kernels" and not available():
        raise ValueError("sim.backend=kernels needs numba (pip install numba); or use 'torch'")
    return backend
