"""UKF parameter estimation (thesis §4.2): exactness on linear problems, known-answer recovery."""

import math

import pytest
import torch

from benchmarks.thesis.ukf_experiments import ukf_dropped_ball, ukf_table41
from simulator.calibrate.ukf import (
    UKFSettings,
    UnscentedKalmanFilter,
    estimate_sequence,
    finite_difference_state,
)
from simulator.calibrate.ukf_body import FrameMeasurement, rollout, spring_strip_problem
from simulator.energies.ground import EnergyGroundPlane
from simulator.model import SimModel
from simulator.monocular.sheet import crossed_grid
from tests.conftest import assert_close


def test_linear_gaussian_update_equals_kalman_filter():
    """For y = H w + noise the unscented transform is exact: UKF = Kalman filter."""
    gen = torch.Generator().manual_seed(0)
    h = torch.randn(7, 2, generator=gen, dtype=torch.float64)
    mean = torch.tensor([0.3, -1.0], dtype=torch.float64)
    cov = torch.tensor([[0.5, 0.1], [0.1, 0.3]], dtype=torch.float64)
    r = 0.2
    y = torch.randn(7, generator=gen, dtype=torch.float64)
    for alpha, kappa in ((1.0, 0.0), (0.5, 1.0)):
        ukf = UnscentedKalmanFilter(
            mean, cov, UKFSettings(alpha=alpha, kappa=kappa, measurement_std=r)
        )
        step = ukf.update(lambda w: w @ h.T, y)
        s = h @ cov @ h.T + r * r * torch.eye(7, dtype=torch.float64)
        gain = cov @ h.T @ torch.linalg.inv(s)
        assert_close(step.mean, mean + gain @ (y - h @ mean), f"mean (alpha={alpha})")
        assert_close(step.cov, cov - gain @ s @ gain.T, f"cov (alpha={alpha})")


def test_scalar_parameter_converges_on_static_nonlinear_map():
    """Repeated updates on y = exp(w) * x recover w (a known answer, no simulator)."""
    x = torch.linspace(0.1, 1.0, 20, dtype=torch.float64)
    w_true = math.log(3.0)
    ukf = UnscentedKalmanFilter(
        torch.tensor([0.0]), torch.tensor([[1.0]]), UKFSettings(measurement_std=1e-3)
    )
    for _ in range(10):
        ukf.update(lambda w: torch.exp(w) * x, math.exp(w_true) * x)
    assert abs(float(ukf.mean[0]) - w_true) < 1e-4


def test_finite_difference_state_is_exact_on_quadratics():
    t = torch.tensor([0.0, 0.1, 0.2], dtype=torch.float64)
    y = 1.0 + 2.0 * t + 3.0 * t * t
    vel, acc = finite_difference_state(y[0], y[1], y[2], 0.1)
    assert abs(float(acc) - 6.0) < 1e-9
    assert abs(float(vel) - (2.0 + 6.0 * 0.1 - 3.0 * 0.1)) < 1e-9  # backward difference
    with pytest.raises(ValueError, match="dt"):
        finite_difference_state(y[0], y[1], y[2], 0.0)


@pytest.fixture(scope="module")
def strip_observations():
    problem = spring_strip_problem()
    truth = rollout(problem, torch.tensor([50.0], dtype=torch.float64), 40, substeps=8)[:, 0]
    noise = 1e-5 * torch.randn(
        truth.shape, generator=torch.Generator().manual_seed(0), dtype=truth.dtype
    )
    return problem, truth + noise


def test_ukf_recovers_spring_stiffness(strip_observations):
    """Mass-spring strip under gravity, k = 50 N/m; guesses 4x too low and 2.4x too high."""
    problem, obs = strip_observations
    settings = UKFSettings(measurement_std=5e-5)
    filters = [
        UnscentedKalmanFilter(torch.tensor([math.log(g)]), torch.tensor([[0.5]]), settings)
        for g in (12.0, 120.0)
    ]
    measure = FrameMeasurement(problem, obs)
    measure.group_size = 3
    history = estimate_sequence(filters, measure, obs, passes=2)
    for f, h in zip(filters, history, strict=True):
        k = math.exp(float(f.mean[0]))
        assert abs(k / 50.0 - 1.0) < 0.03, k
        assert float(f.cov[0, 0]) < 0.5 * 1e-3  # the posterior shrank
        assert len(h) > 0


def test_lockstep_filters_equal_single_runs(strip_observations):
    problem, obs = strip_observations
    obs = obs[:8]
    settings = UKFSettings(measurement_std=5e-5)

    def make(g):
        return UnscentedKalmanFilter(torch.tensor([math.log(g)]), torch.tensor([[0.5]]), settings)

    both = [make(20.0), make(90.0)]
    measure = FrameMeasurement(problem, obs)
    measure.group_size = 3
    estimate_sequence(both, measure, obs, passes=1)
    for g, f in zip((20.0, 90.0), both, strict=True):
        single = make(g)
        estimate_sequence(single, FrameMeasurement(problem, obs), obs, passes=1)
        assert_close(f.mean, single.mean, f"lockstep mean (guess {g})", rtol=1e-9, atol=1e-12)


def test_bad_input_names_field():
    with pytest.raises(ValueError, match="cov"):
        UnscentedKalmanFilter(torch.tensor([0.0]), torch.tensor([[-1.0]]))
    with pytest.raises(ValueError, match="measurement_std"):
        UKFSettings(measurement_std=0.0)
    with pytest.raises(ValueError, match="alpha"):
        UKFSettings(alpha=-1.0)
    problem = spring_strip_problem()
    with pytest.raises(ValueError, match="observations"):
        FrameMeasurement(problem, torch.zeros(5, 3, 3))
    ukf = UnscentedKalmanFilter(torch.tensor([0.0]), torch.tensor([[1.0]]))
    with pytest.raises(ValueError, match="at least 3 frames"):
        estimate_sequence(ukf, lambda s, n: s, torch.zeros(2, 1))
    with pytest.raises(ValueError, match="measure must return"):
        ukf.update(lambda s: torch.zeros(3, 2), torch.zeros(5))


def test_ground_plane_energy_derivatives():
    mesh = crossed_grid(2)
    model = SimModel(
        mesh,
        (),
        (),
        torch.ones(1, mesh.vert_count, dtype=torch.float64),
        torch.zeros(0, dtype=torch.int64),
    )
    pos = mesh.vert_pos[None].clone()
    pos[..., 2] = torch.linspace(-0.01, 0.01, mesh.vert_count, dtype=torch.float64)
    e = EnergyGroundPlane(1e3)
    x = pos.clone().requires_grad_(True)
    (auto,) = torch.autograd.grad(e.energy(model, x).sum(), x)
    assert_close(e.gradient(model, pos), auto, "ground gradient")
    d = torch.randn(pos.shape, dtype=torch.float64)
    blocks = e.hessian_blocks(model, pos).matvec(d.reshape(-1, 3)).view_as(pos)
    assert_close(blocks, e.hessian_product(model, pos, d), "ground hessian blocks")
    with pytest.raises(ValueError, match="stiffness"):
        EnergyGroundPlane(0.0)


@pytest.mark.slow
def test_table41_beam_recovers_modulus_within_3_percent():
    rows = ukf_table41(moduli_kpa=(80,), trials=2)
    assert rows[0]["avg_rel_err_pct"] < 3.0, rows


@pytest.mark.slow
def test_dropped_ball_recovers_modulus_within_3_percent():
    out = ukf_dropped_ball(trials=2)
    assert out["avg_rel_err_pct"] < 3.0, out
