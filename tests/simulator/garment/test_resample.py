"""Carrying a drape between mesh resolutions of one pattern."""

import numpy as np
import pytest

from simulator.garment.patterns import PatternTopology, default_params
from simulator.garment.resample import resample_positions

AFFINE = np.array([[0.3, 1.1], [0.9, -0.2], [0.5, 0.4]])
SHIFT = np.array([0.1, 0.2, 0.3])


def _meshes(garment):
    coarse, fine = PatternTopology.build(garment, 0.08), PatternTopology.build(garment, 0.04)
    g = default_params(garment)
    return coarse, coarse.coords(g), fine, fine.coords(g)


@pytest.mark.parametrize("garment", ["skirt", "pants", "tshirt"])
def test_an_affine_embedding_is_carried_exactly_inside_the_outline(garment):
    """A garment laid flat and moved affinely stays that map on the other mesh: exact where a
    vertex lies inside the other mesh's outline, within the chord's sag on curved outlines."""
    coarse, cc, fine, fc = _meshes(garment)
    moved = resample_positions(coarse, cc, cc @ AFFINE.T + SHIFT, fine, fc)
    err = np.linalg.norm(moved - (fc @ AFFINE.T + SHIFT), axis=1)
    assert np.median(err) < 1e-12
    assert err.max() < 0.01  # curved outlines: a fine vertex past a coarse chord


def _smooth(coords):
    u, v = coords[:, 0], coords[:, 1]
    return np.stack([np.sin(3 * u), np.cos(2 * v), 4 * u * v], axis=1)


@pytest.mark.parametrize("garment", ["skirt", "pants", "tshirt"])
def test_a_smooth_shape_converges_at_second_order(garment):
    """Linear interpolation of a smooth field: halving the source's edge length cuts the
    median error on a fine mesh about fourfold (measured 4.0-4.5)."""
    g = default_params(garment)
    ref = PatternTopology.build(garment, 0.02)
    rc = ref.coords(g)
    errors = []
    for h in (0.08, 0.04):
        src = PatternTopology.build(garment, h)
        sc = src.coords(g)
        moved = resample_positions(src, sc, _smooth(sc), ref, rc)
        errors.append(np.median(np.linalg.norm(moved - _smooth(rc), axis=1)))
    assert errors[0] / errors[1] > 3.0


def test_the_same_resolution_is_the_identity():
    topo = PatternTopology.build("tshirt", 0.08)
    coords = topo.coords(default_params("tshirt"))
    pos = np.random.default_rng(1).normal(size=(topo.vert_count, 3))
    again = PatternTopology.build("tshirt", 0.08)
    assert np.array_equal(resample_positions(topo, coords, pos, again, coords), pos)


def test_another_garment_is_refused():
    skirt = PatternTopology.build("skirt", 0.08)
    pants = PatternTopology.build("pants", 0.08)
    with pytest.raises(ValueError, match="cannot resample a skirt onto a pants"):
        resample_positions(skirt, np.zeros((skirt.vert_count, 2)), None, pants, None)
