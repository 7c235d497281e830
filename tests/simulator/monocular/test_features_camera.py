"""Feature anchoring and eq. 21 selection; camera and material validation (errors name fields)."""

import numpy as np
import pytest
import torch

from simulator.monocular.camera import PinholeCamera, look_at
from simulator.monocular.features import FeatureSet, locate_features, select_features
from simulator.monocular.image_fit import EnergyImageFit
from simulator.monocular.material import SheetMaterial
from simulator.monocular.sheet import crossed_grid, element_count_to_cells
from tests.conftest import assert_close


def test_select_features_respects_tau_and_score_order():
    gen = np.random.default_rng(0)
    pts = gen.uniform(0, 0.1, size=(400, 2))
    scores = gen.uniform(0, 1, size=400)
    tau = 0.012
    kept = select_features(torch.as_tensor(pts), torch.as_tensor(scores), tau).numpy()
    sel = pts[kept]
    dist = np.linalg.norm(sel[:, None] - sel[None], axis=-1) + np.eye(len(kept)) * 1e9
    assert dist.min() >= tau
    assert np.all(np.diff(scores[kept]) <= 0), "kept features must come in decreasing score order"
    assert kept[0] == int(np.argmax(scores))
    # Maximality: every rejected feature is closer than tau to a kept one with a higher score.
    rejected = np.setdiff1d(np.arange(400), kept)
    for i in rejected:
        d = np.linalg.norm(sel - pts[i], axis=1)
        assert np.any((d < tau) & (scores[kept] >= scores[i]))


def test_select_features_tau_zero_keeps_all_and_bad_tau_fails():
    pts = torch.rand(10, 3, dtype=torch.float64)
    assert len(select_features(pts, torch.rand(10, dtype=torch.float64), 0.0)) == 10
    with pytest.raises(ValueError, match="tau"):
        select_features(pts, torch.rand(10, dtype=torch.float64), -1.0)
    with pytest.raises(ValueError, match="points"):
        select_features(torch.zeros(0, 3), torch.zeros(0), 0.01)


def test_locate_features_barycentric_reproduces_points():
    mesh = crossed_grid(4)
    uv = torch.rand(50, 2, dtype=torch.float64) * 0.1
    feats = locate_features(mesh, uv)
    assert_close(
        feats.points(mesh, mesh.vert_pos[None])[0, :, :2], uv, "feature points", atol=1e-12
    )
    assert_close(feats.bary.sum(1), torch.ones(50, dtype=torch.float64), "bary sums")
    with pytest.raises(ValueError, match="outside"):
        locate_features(mesh, torch.tensor([[0.2, 0.05]], dtype=torch.float64))


def test_empty_feature_set_is_refused():
    with pytest.raises(ValueError, match="features"):
        FeatureSet(torch.zeros(0, dtype=torch.int64), torch.zeros(0, 3))
    with pytest.raises(ValueError, match="features"):
        locate_features(crossed_grid(2), torch.zeros(0, 2))


def test_camera_projection_and_validation():
    cam = look_at([0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], focal=500.0)
    pix = cam.project(torch.tensor([[0.1, 0.0, 0.0]], dtype=torch.float64))
    assert abs(abs(float(pix[0, 0])) - 50.0) < 1e-9
    pts = torch.rand(5, 3, dtype=torch.float64)
    _, jac = cam.project_jacobian(pts)
    auto = torch.autograd.functional.jacobian(lambda p: cam.project(p).sum(0), pts).permute(1, 0, 2)
    assert_close(jac, auto, "projection jacobian")
    k = torch.diag(torch.tensor([0.0, 500.0, 1.0], dtype=torch.float64))
    with pytest.raises(ValueError, match="focal fx"):
        PinholeCamera(k, torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64))
    k = torch.diag(torch.tensor([500.0, -1.0, 1.0], dtype=torch.float64))
    with pytest.raises(ValueError, match="focal fy"):
        PinholeCamera(k, torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64))
    with pytest.raises(ValueError, match="rotation"):
        PinholeCamera(
            torch.eye(3, dtype=torch.float64),
            2 * torch.eye(3, dtype=torch.float64),
            torch.zeros(3, dtype=torch.float64),
        )


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"youngs_modulus": 0.0}, "youngs_modulus"),
        ({"youngs_modulus": -5.0}, "youngs_modulus"),
        ({"poisson_ratio": 0.5}, "poisson_ratio"),
        ({"poisson_ratio": -1.0}, "poisson_ratio"),
        ({"thickness": 0.0}, "thickness"),
    ],
)
def test_material_validation_names_field(kwargs, field):
    args = {"youngs_modulus": 0.25e6, "poisson_ratio": 0.45, "thickness": 0.01, **kwargs}
    with pytest.raises(ValueError, match=field):
        SheetMaterial(**args)


def test_feature_stiffness_and_element_count_validation():
    mesh = crossed_grid(2)
    feats = locate_features(mesh, torch.tensor([[0.05, 0.05]], dtype=torch.float64))
    cam = look_at([0.05, 0.05, 0.3], [0.05, 0.05, 0.0], [0.0, 1.0, 0.0])
    with pytest.raises(ValueError, match="stiffness"):
        EnergyImageFit.build(mesh, feats, cam, torch.zeros(1, 2), stiffness=0.0)
    assert element_count_to_cells(1600) == 20
    with pytest.raises(ValueError, match="element_count"):
        element_count_to_cells(1000)
