"""Thread settings of simulating processes (simulator/threads.py)."""

import os

import pytest
import torch

from common.checks import check_threads
from simulator.threads import THREAD_ENV_VARS, torch_threads, use_process_threads


@pytest.mark.parametrize("bad", [0, -1, 1.5, "2", True])
def test_bad_thread_counts_name_the_field(bad):
    with pytest.raises(ValueError, match="threads_per_job must be an integer >= 1 or null"):
        check_threads(bad, "threads_per_job")


def test_torch_threads_restores_the_previous_count():
    torch.set_num_threads(2)
    with torch_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == 2
    with pytest.raises(RuntimeError), torch_threads(1):
        raise RuntimeError("boom")
    assert torch.get_num_threads() == 2
    with torch_threads(None):
        assert torch.get_num_threads() == 2


def test_use_process_threads_sets_torch_opencv_and_the_children_env(monkeypatch):
    import cv2

    previous = cv2.getNumThreads()
    cv2.setNumThreads(2)
    for var in THREAD_ENV_VARS:
        monkeypatch.setenv(var, "7")  # recorded, so the test's writes are undone afterwards
        monkeypatch.delenv(var)
    torch.set_num_threads(2)
    use_process_threads(1)
    assert torch.get_num_threads() == 1
    assert all(os.environ[var] == "1" for var in THREAD_ENV_VARS)
    assert cv2.getNumThreads() == 1
    torch.set_num_threads(2)
    use_process_threads(None)  # null: torch's default stays
    assert torch.get_num_threads() == 2
    cv2.setNumThreads(previous)


@pytest.mark.parametrize(("preset", "expected"), [(None, "PASSIVE"), ("ACTIVE", "ACTIVE")])
def test_importing_the_simulator_makes_openmp_threads_sleep_unless_the_user_chose(preset, expected):
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if preset is not None:
        env["OMP_WAIT_POLICY"] = preset
    code = "import os, simulator; print(os.environ['OMP_WAIT_POLICY'])"
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == expected


def _openblas_thread_counts() -> list[int]:
    import ctypes

    from simulator.threads import _OPENBLAS_SETTERS, _loaded_openblas

    names = [n.replace("_set_", "_get_") for n in _OPENBLAS_SETTERS]
    counts = []
    for path in _loaded_openblas():
        library = ctypes.CDLL(path)
        getter = next((getattr(library, n) for n in names if hasattr(library, n)), None)
        if getter is not None:
            counts.append(getter())
    return counts


def test_openblas_already_loaded_by_numpy_and_scipy_gets_the_thread_count():
    import scipy.linalg  # noqa: F401  (loads SciPy's own OpenBLAS beside NumPy's)

    from simulator.threads import limit_openblas_threads

    before = _openblas_thread_counts()
    if not before:
        pytest.skip("no OpenBLAS loaded in this process (NumPy built against another BLAS)")
    try:
        assert limit_openblas_threads(1) == len(before)
        assert _openblas_thread_counts() == [1] * len(before)
    finally:
        limit_openblas_threads(max(before))
