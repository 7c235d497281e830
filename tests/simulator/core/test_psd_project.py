"""PSD projection of 2x2 blocks stays finite for isotropic and zero matrices in float32."""

import pytest
import torch

from simulator.energies.base import psd_project_sym2


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_isotropic_and_zero_blocks_are_finite(dtype):
    mats = torch.stack(
        [
            torch.zeros(2, 2),
            3.0 * torch.eye(2),
            -2.0 * torch.eye(2),
            torch.tensor([[1.0, 0.5], [0.5, -1.0]]),
        ]
    ).to(dtype)
    out = psd_project_sym2(mats)
    assert torch.isfinite(out).all()
    torch.testing.assert_close(out[0], torch.zeros(2, 2, dtype=dtype))
    torch.testing.assert_close(out[1], 3.0 * torch.eye(2, dtype=dtype))
    torch.testing.assert_close(out[2], torch.zeros(2, 2, dtype=dtype))
    eig = torch.linalg.eigvalsh(out[3])
    assert eig.min() >= -1e-6 and eig.max() == pytest.approx(5**0.5 / 2, rel=1e-5)


def test_projection_matches_eigendecomposition():
    torch.manual_seed(0)
    a = torch.randn(200, 2, 2, dtype=torch.float64)
    sym = a + a.transpose(1, 2)
    vals, vecs = torch.linalg.eigh(sym)
    expected = vecs @ torch.diag_embed(vals.clamp_min(0)) @ vecs.transpose(1, 2)
    torch.testing.assert_close(psd_project_sym2(sym), expected)
