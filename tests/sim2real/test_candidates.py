"""The candidate library follows the registries: every switch is a candidate, new ones too."""

import dataclasses

import pytest

from datasets.spec import DatasetSpec, SizePreset
from render.effects import EFFECT_NAMES, VisualEffects
from sim2real.candidates import STAGES, candidate_library, select_candidates
from simulator.cloth.effects import PHYSICS_EFFECT_NAMES, PhysicsEffects, strength
from simulator.cloth.scenes import ScenarioWind

SPEC = DatasetSpec(
    motion="wind",
    scenario=ScenarioWind(resolution_level=1),
    preset=SizePreset(
        "t", sims_per_class=2, clips_per_sim=1, val_sims_per_class=0, test_sims_per_class=0
    ),
)


def test_every_switch_of_both_registries_is_a_candidate_with_a_known_stage():
    library = candidate_library(SPEC)
    names = {n for n in library if not n.startswith("scene.")}
    expected = (
        {f"physics.{n}" for n in PHYSICS_EFFECT_NAMES}
        | {f"visual.{n}" for n in EFFECT_NAMES}
        | {"look.texture_mode", "look.backdrop"}
    )  # the spec's fields with choices
    assert names == expected
    assert {c.stage for c in library.values()} <= set(STAGES)
    assert library["visual.sensor_noise"].stage == "camera"
    assert library["visual.specular"].stage == "appearance"
    assert library["physics.air_damping"].stage == "physics"
    assert library["scene.size"].stage == "scene"
    # default-on switches: the candidate is the effect's absence
    assert library["physics.anisotropic_stiffness"].value is False
    assert library["physics.anisotropic_stiffness"].binary


def test_strength_grids_lie_in_the_plausible_range_and_apply_to_the_spec():
    library = candidate_library(SPEC)
    for candidate in library.values():
        for value in candidate.strengths(4):
            changed = candidate.apply(SPEC, value)
            assert changed != SPEC, candidate.name
            if candidate.low is not None:
                assert candidate.low <= value <= candidate.high
    noisy = library["visual.sensor_noise"].apply(SPEC, 3.0)
    assert noisy.visual.sensor_noise and noisy.visual.noise_read_sigma == 3.0
    assert noisy.physics_key() == SPEC.physics_key()  # re-renders, no re-simulation
    damped = library["physics.air_damping"].apply(SPEC, 0.1)
    assert damped.physics.air_damping_coefficient == 0.1
    assert damped.physics_key() != SPEC.physics_key()
    assert library["scene.pose"].strengths(3) == ("clips", "edge")
    # a neutral strength inside the range gets points on both sides, near it too
    frame_rate = library["visual.frame_rate"].strengths(3)
    assert frame_rate == pytest.approx([0.5, 0.63, 0.794, 1.26, 1.587, 2.0], rel=1e-3)
    assert library["scene.wind_yaw_jitter_deg"].strengths(3) == (0, 5, 10, 25, 35, 45)
    assert library["visual.sensor_noise"].strengths(3) == (0.5, 2.0, 8.0)  # neutral below


def test_a_new_switch_in_a_registry_becomes_a_candidate_without_changes_in_sim2real():
    @dataclasses.dataclass(frozen=True)
    class PhysicsWithRain(PhysicsEffects):
        rain: bool = False
        rain_rate: float = strength(1.0, "rain", 0.1, 5.0)

    @dataclasses.dataclass(frozen=True)
    class VisualWithGlare(VisualEffects):
        lens_glare: bool = False

    library = candidate_library(SPEC, PhysicsWithRain, VisualWithGlare)
    rain = library["physics.rain"]
    assert (rain.stage, rain.param, rain.low, rain.high) == ("physics", "rain_rate", 0.1, 5.0)
    assert library["visual.lens_glare"].binary
    assert library["visual.lens_glare"].stage == "appearance"  # undeclared render effect


def test_selection_by_name_stage_or_all_and_clear_errors():
    library = candidate_library(SPEC)
    assert len(select_candidates(library, "all")) == len(library)
    camera = select_candidates(library, ["camera"])
    assert camera and all(c.stage == "camera" for c in camera)
    picked = select_candidates(library, ["visual.sensor_noise", "physics.air_damping"])
    assert [c.name for c in picked] == ["physics.air_damping", "visual.sensor_noise"]
    with pytest.raises(ValueError, match=r"candidates: unknown \['visual.rain'\]"):
        select_candidates(library, ["visual.rain"])
    with pytest.raises(ValueError, match=r"noise_read_sigma.*\[0.5, 8.0\]"):
        library["visual.sensor_noise"].check_strength(50.0)
    with pytest.raises(ValueError, match="without strength"):
        library["visual.shadows"].check_strength(1.0)
