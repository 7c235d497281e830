"""Hydra configs of dataset generation and the preview command."""

from pathlib import Path

import cv2
import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import InstantiationException, MissingConfigException

from datasets.generate import spec_from_config
from datasets.preview import main as preview_main

CONFIGS = str(Path(__file__).resolve().parents[2] / "configs")


def _compose(*overrides):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name="generate", overrides=list(overrides))


def test_default_and_override_configs_build_specs():
    spec = spec_from_config(_compose())
    assert spec.motion == "wind" and spec.preset.name == "small"
    assert spec.scenario.resolution_level == 1 and spec.sim.dtype == "float32"
    arm = spec_from_config(
        _compose(
            "motion=arm",
            "preset=full",
            "level=3",
            "texture=grid",
            "classes=[0,53]",
            "render.effects.motion_blur=true",
            "effects.gusty_wind=true",
        )
    )
    assert type(arm.scenario).__name__ == "ScenarioArmBend"
    assert arm.scenario.resolution_level == 3 and arm.preset.clips_per_class == 48
    assert arm.camera.position != spec.camera.position, "arm must use the arm camera"
    assert arm.visual.motion_blur and arm.physics.gusty_wind
    assert arm.enabled_effects() == ["physics.gusty_wind=on", "visual.motion_blur=on"]
    assert spec.backdrop == "bank"
    assert spec_from_config(_compose("backdrop=dark")).backdrop == "dark"


def test_unknown_motion_is_named():
    with pytest.raises(MissingConfigException, match="motion"):
        _compose("motion=swing")


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        (["+render.effects.fog=true"], "fog"),
        (["+effects.rain=true"], "rain"),
        (["preset.sims_per_class=-4"], "sims_per_class"),
        (["texture=plaid"], "texture must be one of grid, color, random"),
        (["backdrop=studio"], "backdrop must be one of bank, plain, dark, gradient"),
        (["level=7"], r"level must be an integer in \[1, 3\]"),
        (["classes=[0,1.7]"], r"classes\[1\] must be an integer class id in \[0, 53\]"),
        (["classes=[0,0]"], "classes must not repeat"),
        (["seed=abc"], "seed must be an integer >= 0, got 'abc'"),
        (["render.camera.width=abc"], "render.camera.width must be an integer, got 'abc'"),
        (["sim.max_dt=fast"], "sim.max_dt must be a number, got 'fast'"),
        (["scenario=arm_bend"], r"scenario must be a scene's fields .* motion=wind or motion=arm"),
    ],
)
def test_bad_values_are_named(overrides, field):
    # Hydra wraps errors raised inside instantiate; the message still names the field.
    with pytest.raises((ValueError, InstantiationException), match=field):
        spec_from_config(_compose(*overrides))


@pytest.mark.render
def test_preview_writes_a_sheet_and_a_video(tiny_dataset, tmp_path):
    paths = preview_main([str(tiny_dataset), "--out", str(tmp_path)])
    sheet = cv2.imread(str(paths[0]))
    assert sheet is not None and sheet.shape[0] >= 2 * 32
    cap = cv2.VideoCapture(str(paths[1]))
    assert cap.isOpened() and int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 4
