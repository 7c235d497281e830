"""The thesis PSO variant on standard test functions, with fixed seeds."""

import numpy as np
import pytest

from simulator.calibrate.pso import PSO_C, PSO_W, ParticleSwarm, pso_minimize


def sphere(x):
    return (x**2).sum(1)


def rosenbrock(x):
    return (100 * (x[:, 1:] - x[:, :-1] ** 2) ** 2 + (1 - x[:, :-1]) ** 2).sum(1)


def rastrigin(x):
    return 10 * x.shape[1] + (x**2 - 10 * np.cos(2 * np.pi * x)).sum(1)


def test_constants_are_the_thesis_ones():
    assert abs(PSO_W - 0.7213475204) < 1e-9 and abs(PSO_C - 1.1931471806) < 1e-9


@pytest.mark.parametrize("dim", [2, 3, 4])
def test_sphere(dim):
    res = pso_minimize(sphere, [-5] * dim, [5] * dim, max_iters=300, seed=0)
    assert res.best_f < 1e-10
    np.testing.assert_allclose(res.best_x, 0.0, atol=1e-5)


@pytest.mark.parametrize(("dim", "tol"), [(2, 1e-8), (3, 1e-3), (4, 1e-2)])
def test_rosenbrock(dim, tol):
    res = pso_minimize(rosenbrock, [-2] * dim, [2] * dim, max_iters=3000, seed=0)
    assert res.best_f < tol
    np.testing.assert_allclose(res.best_x, 1.0, atol=0.1)


@pytest.mark.parametrize("dim", [2, 3, 4])
def test_rastrigin_finds_the_global_minimum(dim):
    found = min(
        pso_minimize(rastrigin, [-5.12] * dim, [5.12] * dim, max_iters=2000, seed=s).best_f
        for s in range(3)
    )
    assert found < 1e-6


def test_whole_swarm_is_one_batched_call_and_deterministic():
    calls = []

    def objective(x):
        calls.append(x.shape)
        return sphere(x)

    a = pso_minimize(objective, [-1, -1], [1, 1], swarm_size=40, max_iters=25, seed=7)
    assert calls == [(40, 2)] * 25 and a.evaluations == 1000
    b = pso_minimize(sphere, [-1, -1], [1, 1], swarm_size=40, max_iters=25, seed=7)
    np.testing.assert_array_equal(a.best_x, b.best_x)
    np.testing.assert_array_equal(a.history, b.history)
    assert np.all(np.diff(a.history) <= 0)


def test_positions_stay_in_bounds():
    swarm = ParticleSwarm([0.0, 10.0], [1.0, 20.0], seed=1)
    for _ in range(30):
        x = swarm.ask()
        assert np.all(x >= [0.0, 10.0]) and np.all(x <= [1.0, 20.0])
        swarm.tell(-x.sum(1))  # pushes towards the upper corner


@pytest.mark.parametrize(("lower", "upper"), [([0.0, 1.0], [1.0, 1.0]), ([2.0], [1.0])])
def test_bounds_min_not_below_max_is_an_error(lower, upper):
    with pytest.raises(ValueError, match=r"bounds: lower\[\d\].*min >= max"):
        pso_minimize(sphere, lower, upper)


def test_bad_sizes():
    with pytest.raises(ValueError, match="swarm_size"):
        ParticleSwarm([0], [1], swarm_size=1)
    with pytest.raises(ValueError, match="informants"):
        ParticleSwarm([0], [1], swarm_size=3, informants=3)
