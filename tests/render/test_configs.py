"""Every configs/render/*.yaml composes and instantiates into working renderer parts."""

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from render.camera import CameraSpec
from render.effects import VisualEffects
from render.lights import LightSpec

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.mark.parametrize("name", sorted(p.stem for p in (CONFIGS / "render").glob("*.yaml")))
def test_render_config_instantiates(name):
    with initialize_config_dir(config_dir=str(CONFIGS / "render"), version_base="1.3"):
        cfg = compose(config_name=name)
    camera = instantiate(cfg.camera)
    assert isinstance(camera, CameraSpec) and camera.width > 0
    assert isinstance(instantiate(cfg.lights), LightSpec)
    effects = instantiate(cfg.effects)
    assert isinstance(effects, VisualEffects)
    assert not any(getattr(effects, n) for n in ("motion_blur", "sensor_noise", "shadows"))
    assert cfg.texture_mode in ("grid", "color", "random")
