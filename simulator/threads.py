"""One torch thread per simulating process: the thread count that survives a busy CPU.

The solver runs thousands of small tensor operations per step. With torch's default (one
OpenMP thread per core), every one of them is a parallel region whose threads spin-wait for
each other; when another process holds a core, the waiting thread is descheduled and each
region stalls for a scheduler slice. Measured on a 2-core machine (issue 26): a 32 x 32 wind
cloth took 99 s instead of 9.6 s beside a second process with two threads, and 10.8 s with
one thread (``python -m benchmarks.thread_load_bench`` repeats the measurement). A second
thread gains only 3-14 % on a quiet machine, so simulating processes use one by default and
parallelism comes from processes (joblib workers, Hydra launchers), one thread each.

Entry points call :func:`use_process_threads` once; library code that needs a fixed count for
a block (e.g. to fix the bytes a worker writes) uses :func:`torch_threads`.

NumPy and SciPy each load their own OpenBLAS, which reads ``OPENBLAS_NUM_THREADS`` only when
it loads: setting the variable cannot reach a library already in memory, so
:func:`use_process_threads` also sets the count of every OpenBLAS loaded in the process
(:func:`limit_openblas_threads`). The same spinning hits it: beside a busy 2-thread matrix
product, 20 logistic fits on (300, 512) features (the diagnosis's domain classifier) took
4.9 s with OpenBLAS's default 2 threads and 0.12 s with one; a sealed set's diagnosis took
11 min instead of about 1 beside two other validation processes (2026-11-26).

Where a process does take several threads (``--threads 2`` for a batched run, whose compiled
kernels spread the instances over numba's OpenMP threads), importing any of the project's
packages (through :mod:`common`) sets ``OMP_WAIT_POLICY=PASSIVE`` unless the environment
already chose: idle OpenMP threads sleep instead of spinning. OpenMP reads it when it loads, so
it reaches every process started from one that imported the project (generation workers,
benchmark children), and a main process that imports the project before torch. Measured with
``thread_load_bench --backend kernels --batch 8`` (2 cores, 2 threads in each of two
processes): the loaded run slowed 9.9x with spinning threads, 1.4x with sleeping ones (fair:
2x); quiet batched throughput was unchanged (54 instances, 32.9 vs 32.5 s). On the torch path
sleeping threads cost a quiet 2-thread run 43 % (2.29 -> 3.28 s; every small op is a parallel
region), which the default of one thread does not pay.

OpenCV keeps a thread pool of its own (one thread per core), which no variable above reaches:
:func:`use_process_threads` sets it too. Its optical flow (Farneback, pyramidal Lucas-Kanade)
is most of the sim-to-real features; beside other busy processes on 2 cores, one candidate
set's features took 21-24 s with OpenCV's 2 threads and 8.7-9.5 s with one, the same bytes.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
from collections.abc import Iterator

import torch

from common.checks import check_threads

__all__ = [
    "SIM_THREADS",
    "THREAD_ENV_VARS",
    "limit_openblas_threads",
    "torch_threads",
    "use_process_threads",
]

SIM_THREADS = 1
"""Default torch intra-op threads of a simulating process."""

THREAD_ENV_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
"""Thread-pool sizes that child processes (joblib workers) read when they start."""


_OPENBLAS_SETTERS = (
    "openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
    "scipy_openblas_set_num_threads64_",
)
"""The setter's name in a plain OpenBLAS, an ILP64 one, and NumPy's and SciPy's wheels."""


def _loaded_openblas() -> list[str]:
    """Paths of the OpenBLAS libraries mapped into this process (Linux; else none)."""
    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if "openblas" in line.lower()}
    except OSError:
        return []
    return sorted(p for p in paths if p.startswith("/"))


def limit_openblas_threads(threads: int) -> int:
    """Set the thread count of every OpenBLAS loaded in this process; returns how many."""
    count = 0
    for path in _loaded_openblas():
        try:
            library = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(library, n) for n in _OPENBLAS_SETTERS if hasattr(library, n)), None)
        if setter is not None:
            setter(ctypes.c_int(threads))
            count += 1
    return count


def use_process_threads(threads: int | None = SIM_THREADS, *, name: str = "threads") -> None:
    """Set this process's torch, OpenBLAS and OpenCV threads and its children's pool variables.

    Args:
        threads: Threads per process; ``None`` leaves torch's default (one per core).
        name: Config field named in the error for a bad value.
    """
    threads = check_threads(threads, name)
    if threads is None:
        return
    torch.set_num_threads(threads)
    for var in THREAD_ENV_VARS:
        os.environ[var] = str(threads)
    limit_openblas_threads(threads)
    import cv2

    cv2.setNumThreads(threads)


@contextlib.contextmanager
def torch_threads(threads: int | None, *, name: str = "threads") -> Iterator[None]:
    """Run the block with ``threads`` torch intra-op threads, then restore the previous count.

    ``None`` leaves the count unchanged.
    """
    threads = check_threads(threads, name)
    previous = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
