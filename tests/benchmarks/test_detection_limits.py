"""The detection-limit bench's pieces: effect sizes against a twin, power, effect parsing."""

import numpy as np
import pytest

from benchmarks.detection_limits import (
    frames_digest,
    label_design,
    needed_effect_size,
    paired_effect_size,
    parse_effect,
)
from datasets.spec import DatasetSpec, SizePreset
from sim2real.candidates import candidate_library
from sim2real.ladder import LadderFeatures
from simulator.cloth.scenes import ScenarioWind

SPEC = DatasetSpec(
    motion="wind",
    scenario=ScenarioWind(resolution_level=1),
    preset=SizePreset(
        "t", sims_per_class=2, clips_per_sim=1, val_sims_per_class=0, test_sims_per_class=0
    ),
)


def _features(rows: dict[str, np.ndarray], videos: int, clips: int) -> LadderFeatures:
    groups = np.repeat([f"v{i:03d}" for i in range(videos)], clips)
    n = videos * clips
    return LadderFeatures(
        rungs=rows, groups=groups, class_id=np.full(n, -1), stiffness=np.ones(n), density=np.ones(n)
    )


def test_a_planted_shift_gives_its_size_in_between_video_sds_on_its_own_feature():
    rng = np.random.default_rng(0)
    videos, clips = 400, 3
    per_video = rng.normal(size=(videos, 4))
    jitter = 0.01 * rng.normal(size=(videos * clips, 4))
    twin = {
        "pixel": np.repeat(per_video, clips, axis=0) + jitter,
        "enc.fc6": rng.normal(size=(videos * clips, 2)),
    }
    planted = {k: v.copy() for k, v in twin.items()}
    planted["pixel"][:, 2] += 0.3  # a third of the between-video spread
    size = paired_effect_size(_features(planted, videos, clips), _features(twin, videos, clips))
    assert size["rung"] == "pixel" and size["feature"] == 2
    assert size["d"] == pytest.approx(0.3, rel=0.1)
    assert size["per_rung"]["enc.fc6"] == 0.0
    same = paired_effect_size(_features(twin, videos, clips), _features(twin, videos, clips))
    assert same["d"] == 0.0 and same["rung"] is None


def test_a_feature_the_twin_holds_constant_is_measured_by_the_planted_sets_spread():
    twin = {"motion": np.zeros((12, 2))}
    planted = {"motion": np.zeros((12, 2))}
    planted["motion"][:, 1] = 1e-3  # a constant shift: no spread on either side
    size = paired_effect_size(_features(planted, 4, 3), _features(twin, 4, 3))
    assert size["d"] == np.inf and size["feature"] == 1
    planted["motion"][:6, 0] = 1.0  # two of four videos move: d = 0.5 / sqrt(1/3 / 2)
    size = paired_effect_size(_features(planted, 4, 3), _features(twin, 4, 3))
    assert size["per_rung"]["motion"] == np.inf
    assert paired_effect_size(
        _features({"motion": planted["motion"][:, :1]}, 4, 3),
        _features({"motion": twin["motion"][:, :1]}, 4, 3),
    )["d"] == pytest.approx(0.5 / np.sqrt(1 / 6))


def test_the_twin_must_hold_the_same_videos():
    twin = _features({"pixel": np.zeros((12, 1))}, 4, 3)
    other = _features({"pixel": np.zeros((15, 1))}, 5, 3)
    with pytest.raises(ValueError, match="different videos"):
        paired_effect_size(other, twin)


def test_the_needed_effect_size_is_the_two_sample_power_formula():
    assert needed_effect_size(90, 108) == pytest.approx(0.400, abs=0.002)
    assert needed_effect_size(360, 432) < needed_effect_size(90, 108) / 1.9


def test_effects_parse_with_their_strengths_checked_by_the_library():
    library = candidate_library(SPEC)
    effect = parse_effect("visual.rolling_shutter=1.0", library)
    assert effect == {
        "name": "visual.rolling_shutter",
        "stage": "camera",
        "strength": 1.0,
        "library": True,
    }
    assert parse_effect("visual.shadows", library)["strength"] is None
    assert parse_effect("visual.compression=20", library)["strength"] == 20
    with pytest.raises(ValueError, match=r"not a candidate; allowed: \["):
        parse_effect("visual.rain=1", library)
    with pytest.raises(ValueError, match=r"must be in \[0.2, 1"):
        parse_effect("visual.rolling_shutter=2", library)


def test_the_frames_digest_sees_a_changed_byte_and_ignores_the_labels(tmp_path):
    for name in ("a", "b"):
        (tmp_path / name / "v000").mkdir(parents=True)
        (tmp_path / name / "v000" / "0000.png").write_bytes(b"\x89PNG same")
        (tmp_path / name / "labels.csv").write_text(f"video,stiffness\nv000,{name}\n")
    assert frames_digest(tmp_path / "a") == frames_digest(tmp_path / "b")
    (tmp_path / "b" / "v000" / "0000.png").write_bytes(b"\x89PNG diff")
    assert frames_digest(tmp_path / "a") != frames_digest(tmp_path / "b")


def test_taking_out_the_labelled_materials_leaves_the_shift_over_the_residual_spread(tmp_path):
    rng = np.random.default_rng(1)
    videos, clips = 300, 2
    stiffness = np.exp(rng.uniform(-1, 2, videos))
    density = rng.uniform(0.1, 0.4, videos)
    winds = rng.choice(["W1", "W2", "W3"], videos)
    labels = zip(stiffness, density, winds, strict=True)
    rows = "\n".join(f"v{i:03d},{s:.6g},{d:.6g},{w},15" for i, (s, d, w) in enumerate(labels))
    (tmp_path / "labels.csv").write_text("video,stiffness,density,wind,fps\n" + rows + "\n")
    design = label_design(tmp_path / "labels.csv")
    assert design.shape == (videos, 8) and np.all(design[:, 0] == 1.0)
    # The feature is mostly the material (SD 3) plus a per-video residual (SD 1).
    material = 3.0 * np.log(stiffness) / np.log(stiffness).std() + 2.0 * (winds == "W3")
    per_video = material + rng.normal(size=videos)
    twin = {"motion": np.repeat(per_video[:, None], clips, axis=0)}
    planted = {"motion": twin["motion"] + 0.3}
    size = paired_effect_size(
        _features(planted, videos, clips), _features(twin, videos, clips), design
    )
    assert size["d"] < 0.12  # 0.3 over the whole spread, about 3.5
    assert size["d_adjusted"] == pytest.approx(0.3, rel=0.15)  # 0.3 over the residual 1
    assert "d_adjusted" not in paired_effect_size(
        _features(planted, videos, clips), _features(twin, videos, clips)
    )
    with pytest.raises(ValueError, match="covariates"):
        paired_effect_size(
            _features(planted, videos, clips), _features(twin, videos, clips), design[:-1]
        )
