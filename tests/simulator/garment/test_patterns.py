"""Sewing patterns: geometry against closed forms, meshing, seams, export and bad input."""

import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from common.errors import InputError
from simulator.garment.patterns import (
    GARMENT_TYPES,
    PatternError,
    PatternTopology,
    build_pattern,
    check_params,
    closed_form,
    default_params,
    from_search,
    param_specs,
    search_box,
    to_search,
)


def _random_params(garment, rng):
    _, lo, hi = search_box(garment)
    return from_search(garment, rng.uniform(lo, hi))


@pytest.mark.parametrize("garment", GARMENT_TYPES)
def test_areas_and_seams_match_closed_forms(garment):
    rng = np.random.default_rng(1)
    for params in [default_params(garment), _random_params(garment, rng)]:
        pattern = build_pattern(garment, params, edge_length=0.02)
        exact = closed_form(garment, params)
        areas = pattern.panel_areas()
        for panel, area in exact["areas"].items():
            # Arcs are meshed as chords: a relative error of O(h² / r²).
            assert areas[panel] == pytest.approx(area, rel=2e-3), panel
        lengths = pattern.seam_lengths()
        for seam, (la, lb) in exact["seams"].items():
            assert lengths[seam][0] == pytest.approx(la, rel=2e-3), seam
            assert lengths[seam][1] == pytest.approx(lb, rel=2e-3), seam


def test_sector_area_converges_at_second_order():
    params = default_params("skirt")
    exact = closed_form("skirt", params)["areas"]["flare_front"]
    errors = []
    for h in (0.08, 0.04, 0.02):
        area = build_pattern("skirt", params, edge_length=h).panel_areas()["flare_front"]
        errors.append(abs(area - exact) / exact)
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert errors[-1] < 1e-3
    assert (rates > 1.6).all(), rates


@pytest.mark.parametrize("garment", GARMENT_TYPES)
def test_topology_is_shared_and_triangles_stay_positive(garment):
    topology = PatternTopology.build(garment, 0.05)
    rng = np.random.default_rng(0)
    tri = topology.tri_indices
    for _ in range(40):
        params = _random_params(garment, rng)
        pattern = build_pattern(garment, params, topology=topology)
        assert pattern.coords.shape == (topology.vert_count, 2)
        x = pattern.coords
        d1, d2 = x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]]
        area = 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
        assert area.min() > 0, params


@pytest.mark.parametrize("garment", GARMENT_TYPES)
def test_seams_pair_equal_lengths(garment):
    pattern = build_pattern(garment, edge_length=0.03)
    for name, pairs in pattern.topology.seam_pairs.items():
        assert pairs.shape[1] == 2 and len(pairs) >= 2, name
        la, lb = pattern.seam_lengths()[name]
        # The pants' back inseam is 3 % longer than the front's (crotch extensions differ).
        assert la == pytest.approx(lb, rel=0.035), name
        assert not np.any(pairs[:, 0] == pairs[:, 1]), name


def test_search_box_round_trips_and_holds_only_valid_skirts():
    rng = np.random.default_rng(3)
    for garment in GARMENT_TYPES:
        _, lo, hi = search_box(garment)
        for _ in range(50):
            params = from_search(garment, rng.uniform(lo, hi))
            check_params(garment, params)  # valid everywhere in the box
        params = default_params(garment)
        point = to_search(garment, params)
        np.testing.assert_allclose(to_search(garment, from_search(garment, point)), point)


@pytest.mark.parametrize("garment", GARMENT_TYPES)
def test_svg_and_json_export(garment):
    pattern = build_pattern(garment)
    root = ET.fromstring(pattern.to_svg())
    polygons = root.findall("{http://www.w3.org/2000/svg}polygon")
    assert len(polygons) == len(pattern.topology.panel_names)
    data = json.loads(json.dumps(pattern.to_json({"bend": 5.0, "stretch": 1.0})))
    assert data["garment"] == garment
    assert {k: v["value"] for k, v in data["params"].items()} == pattern.params
    for panel in pattern.topology.panel_names:
        loop = np.asarray(data["panels"][panel]["outline"])
        # Shoelace area of the exported outline equals the panel's area (outline is CCW).
        x, y = loop[:, 0], loop[:, 1]
        area = 0.5 * (x * np.roll(y, -1) - np.roll(x, -1) * y).sum()
        assert area == pytest.approx(pattern.panel_areas()[panel], rel=0.02)


def test_bad_params_name_field_and_range():
    with pytest.raises(PatternError, match=r"params\.l1 .*\[0\.3, 0\.55\] m"):
        check_params("skirt", {"l1": 2.0})
    with pytest.raises(PatternError, match=r"unknown \['w9'\]"):
        check_params("pants", {"w9": 1.0})
    with pytest.raises(PatternError, match="back rise h2"):
        check_params("pants", {"h2": 0.25, "h3": 0.30})
    with pytest.raises(PatternError, match="hip half-girth"):
        check_params("skirt", {"r1": 2.5, "alpha": 1.4})
    with pytest.raises(InputError, match="garment must be one of skirt, pants, tshirt"):
        build_pattern("dress")
    with pytest.raises(PatternError, match="must be a number"):
        check_params("tshirt", {"r": "wide"})


def test_every_parameter_is_documented():
    for garment in GARMENT_TYPES:
        for spec in param_specs(garment):
            assert spec.low < spec.default < spec.high and spec.unit in ("m", "rad") and spec.doc
            assert math.isfinite(spec.default)
