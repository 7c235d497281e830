"""Shared test helpers: float64 tolerances and a field-naming assert_close."""

import os

import pytest
import torch

from common.configs import register_config_resolvers
from simulator.threads import torch_threads

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
register_config_resolvers()  # the configs' ${path_component:...}, as every command registers it

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def subprocess_env() -> dict:
    """Environment of a command-line test's child: one thread, the repository importable
    ahead of (not instead of) the caller's PYTHONPATH."""
    path = os.pathsep.join(filter(None, [REPO_ROOT, os.environ.get("PYTHONPATH")]))
    return {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": path}


RTOL = 1e-6
ATOL = 1e-9


def assert_close(actual, expected, name, *, rtol=RTOL, atol=ATOL):
    """torch.testing.assert_close with a message naming the compared field."""
    torch.testing.assert_close(
        torch.as_tensor(actual),
        torch.as_tensor(expected),
        rtol=rtol,
        atol=atol,
        msg=lambda m: f"{name}: {m}",
    )


@pytest.fixture(autouse=True)
def _single_thread():
    """Tests are small: one intra-op thread avoids oversubscription on 2-core CI."""
    with torch_threads(1):
        yield
