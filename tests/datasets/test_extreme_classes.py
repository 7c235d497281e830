"""The softest and the stiffest class, same seed and look, give visibly different videos."""

import numpy as np
import pytest

from render.backgrounds import make_background
from render.camera import CameraSpec
from render.textures import make_texture
from simulator.cloth.material import ClothMaterial
from simulator.cloth.rollout import SimSettings, simulate
from simulator.cloth.scenes import ScenarioWind

pytestmark = pytest.mark.render


def test_extreme_classes_render_differently():
    from render.renderer import ClothRenderer

    seq = simulate(
        ScenarioWind(resolution_level=1, settle_time=0.2),
        ClothMaterial.from_classes([0, 53]),
        seeds=[5, 5],
        wind_levels=[2, 2],
        fps=15.0,
        record_time=1.0,
        settings=SimSettings(dtype="float32"),
    )
    camera = CameraSpec.wind(48, 48)
    texture = make_texture("grid", np.random.default_rng(0), 64)
    background = make_background(np.random.default_rng(0), 48, 48)
    with ClothRenderer(camera) as renderer:
        clips = [
            renderer.render_sequence(seq, b, texture, background, np.random.default_rng(0))
            for b in (0, 1)
        ]
    cloth = [np.abs(c.astype(int) - background.astype(int)).sum(-1) > 30 for c in clips]
    for mask in cloth:
        coverage = mask.mean(axis=(1, 2))
        assert (coverage > 0.05).all(), f"cloth covers too little of the frame: {coverage}"
    last = -1
    union = (cloth[0][last] | cloth[1][last]).sum()
    iou = (cloth[0][last] & cloth[1][last]).sum() / union
    assert iou < 0.9, f"soft and stiff silhouettes nearly coincide (IoU {iou:.2f})"
    motion = [np.abs(np.diff(c.astype(float), axis=0)).mean() for c in clips]
    assert motion[0] != pytest.approx(motion[1], rel=0.1), motion
