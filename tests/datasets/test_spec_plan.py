"""Dataset spec validation, the simulation plan and its splits."""

import dataclasses

import pytest

from datasets.plan import plan_units
from datasets.spec import PRESETS, DatasetSpec, SizePreset
from simulator.cloth.scenes import ScenarioArmBend, ScenarioWind

from .conftest import tiny_spec


def test_full_preset_has_the_thesis_sizes():
    spec = DatasetSpec(motion="wind", scenario=ScenarioWind(), preset=PRESETS["full"])
    assert spec.clip_count == 2592
    sims = [s for unit in plan_units(spec) for s in unit.sims]
    test_clips = sum(s.split == "test" for s in sims) * spec.preset.clips_per_sim
    assert test_clips == 432
    assert len(sims) == 54 * 12


@pytest.mark.parametrize("preset", ["full", "small"])
def test_no_simulation_in_two_splits_and_every_class_in_every_split(preset):
    spec = DatasetSpec(motion="arm", scenario=ScenarioArmBend(), preset=PRESETS[preset])
    sims = [s for unit in plan_units(spec) for s in unit.sims]
    ids = [s.sim_id for s in sims]
    assert len(ids) == len(set(ids)), "a simulation is planned twice"
    for class_id in spec.classes:
        mine = [s for s in sims if s.class_id == class_id]
        counts = {split: sum(s.split == split for s in mine) for split in ("train", "val", "test")}
        assert counts["test"] == spec.preset.test_sims_per_class
        assert counts["val"] == spec.preset.val_sims_per_class
        assert counts["train"] >= 1


def test_plan_is_deterministic_and_seed_dependent():
    spec = tiny_spec()
    assert plan_units(spec) == plan_units(spec)
    seeds = [s.seed for u in plan_units(spec) for s in u.sims]
    other = [s.seed for u in plan_units(dataclasses.replace(spec, seed=1)) for s in u.sims]
    assert other != seeds


def test_unit_size_batches_simulations():
    spec = tiny_spec(sims_per_unit=1)
    units = plan_units(spec)
    assert len(units) == 6 and all(len(u.sims) == 1 for u in units)


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"motion": "swing"}, "motion"),
        ({"texture_mode": "plaid"}, "texture_mode"),
        ({"backdrop": "studio"}, r"backdrop must be one of \['bank', 'plain', 'dark', 'grad"),
        ({"classes": (0, 54)}, "classes"),
        ({"classes": ()}, "classes"),
        ({"classes": (0, 1.7)}, r"classes must be integer class ids in \[0, 53\], got \[0, 1.7\]"),
        ({"classes": (0, "1")}, "classes must be integer class ids"),
        ({"seed": -1}, "seed"),
        ({"lead_in": -0.1}, "lead_in"),
        ({"supersample": 0}, "supersample"),
    ],
)
def test_bad_spec_values_name_the_field(changes, field):
    with pytest.raises(ValueError, match=field):
        tiny_spec(**changes)


def test_motion_and_scenario_must_agree():
    with pytest.raises(ValueError, match="ScenarioArmBend"):
        tiny_spec(motion="arm")


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"sims_per_class": -2}, "sims_per_class"),
        ({"clips_per_sim": 0}, "clips_per_sim"),
        ({"frames_per_clip": 0}, "frames_per_clip"),
        ({"test_sims_per_class": -1}, "test_sims_per_class"),
        ({"test_sims_per_class": 3}, "sims_per_class"),
        ({"fps": 0.0}, "fps"),
    ],
)
def test_bad_preset_values_name_the_field(changes, field):
    base = {
        "name": "x",
        "sims_per_class": 3,
        "clips_per_sim": 1,
        "val_sims_per_class": 1,
        "test_sims_per_class": 1,
    }
    with pytest.raises(ValueError, match=field):
        SizePreset(**(base | changes))


def test_keys_separate_physics_from_rendering():
    spec = tiny_spec()
    regrid = tiny_spec(texture_mode="grid")
    assert spec.physics_key() == regrid.physics_key()
    assert spec.key() != regrid.key()
    plain = tiny_spec(backdrop="plain")
    assert spec.physics_key() == plain.physics_key() and spec.key() != plain.key()
    assert tiny_spec(seed=3).physics_key() != spec.physics_key()


def test_visual_effects_added_later_leave_old_keys_alone():
    """A spec with the later effects at their defaults writes the JSON (and key) of before."""
    from render.effects import VisualEffects

    plain = tiny_spec().to_json()
    assert "vignetting" not in plain["visual"] and "vignetting_strength" not in plain["visual"]
    on = tiny_spec(visual=VisualEffects(vignetting=True)).to_json()
    assert on["visual"]["vignetting"] is True and on["visual"]["vignetting_strength"] == 0.3
    stronger = tiny_spec(visual=VisualEffects(vignetting_strength=0.5))
    assert stronger.to_json()["visual"]["vignetting_strength"] == 0.5
    assert (
        len(
            {
                tiny_spec().key(),
                stronger.key(),
                tiny_spec(visual=VisualEffects(vignetting=True)).key(),
            }
        )
        == 3
    )
    assert stronger.physics_key() == tiny_spec().physics_key()
    # Each later group is left out on its own: a vignetting set keeps its key when the
    # rolling shutter (added after it) is at its defaults.
    assert "rolling_shutter" not in on["visual"] and "rolling_shutter_readout" not in on["visual"]
    shutter = tiny_spec(visual=VisualEffects(rolling_shutter=True)).to_json()["visual"]
    assert shutter["rolling_shutter"] is True and shutter["rolling_shutter_readout"] == 0.6
    assert shutter["rolling_shutter_bands"] == 8
    assert "vignetting" not in shutter


def test_spec_round_trips_through_its_json_form():
    import json

    from render.camera import CameraSpec
    from render.effects import VisualEffects
    from simulator.cloth.effects import PhysicsEffects

    specs = [
        tiny_spec(),
        tiny_spec(visual=VisualEffects(vignetting=True, vignetting_strength=0.45)),
        tiny_spec(visual=VisualEffects(rolling_shutter=True, rolling_shutter_readout=0.3)),
        tiny_spec(
            visual=VisualEffects(motion_blur=True, frame_rate_mode="drop"),
            physics=PhysicsEffects(aero_lift=True, anisotropic_stiffness=False),
        ),
        DatasetSpec(
            motion="arm",
            scenario=ScenarioArmBend(),
            preset=PRESETS["small"],
            camera=CameraSpec.arm(),
        ),
    ]
    for spec in specs:
        back = DatasetSpec.from_json(json.loads(json.dumps(spec.to_json())))
        assert back == spec and back.key() == spec.key()
    broken = specs[0].to_json() | {"scenario_class": "ScenarioRain"}
    with pytest.raises(ValueError, match="scenario_class must be one of"):
        DatasetSpec.from_json(broken)
    with pytest.raises(ValueError, match=r"unknown \['colour'\]"):
        DatasetSpec.from_json(specs[0].to_json() | {"colour": 1})
