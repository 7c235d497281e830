"""The seal's out-of-library effects: the lens model, flicker, tone curve, rendered sets."""

import dataclasses
import math

import cv2
import numpy as np
import pytest

from datasets.plan import SimulationPlan
from datasets.spec import DatasetSpec, SizePreset
from render.camera import CameraSpec
from sim2real.candidates import candidate_library
from sim2real.study.open_set import (
    OPEN_SET_EFFECTS,
    apply_exposure_flicker,
    apply_tone_curve,
    barrel_image,
    barrel_points,
    flicker_frequency,
    render_sealed_video,
)
from sim2real.study.seal import draw_answer
from simulator.cloth.material import BASIS_MATERIAL, ClothMaterial, load_wang_material
from simulator.cloth.rollout import SimSettings, simulate
from simulator.cloth.scenes import ScenarioWind

SPEC = DatasetSpec(motion="wind", scenario=ScenarioWind(), preset=SizePreset("t", 2, 1, 0, 0))
CAMERA = CameraSpec.wind(64, 48)


def _normalised(camera, points):
    """(u, v) in [-1, 1] across the frame and the depth of world points."""
    pixels, depth = camera.project(points)
    u = (pixels[:, 0] - camera.width / 2) / (camera.width / 2)
    v = (pixels[:, 1] - camera.height / 2) / (camera.height / 2)
    return u, v, depth


@pytest.mark.parametrize("strength", [0.1, 0.25])
def test_barrel_points_land_where_the_lens_images_them(strength):
    rng = np.random.default_rng(0)
    points = np.asarray(CAMERA.look_at) + rng.uniform(-0.4, 0.4, size=(200, 3))
    u, v, depth = _normalised(CAMERA, points)
    ud, vd, depth_d = _normalised(CAMERA, barrel_points(points, CAMERA, strength))
    # The pixel at (ud, vd) shows what a pinhole shows at (ud, vd) (1 + k rho_d²).
    scale = 1 + strength * (ud * ud + vd * vd) / 2
    np.testing.assert_allclose(ud * scale, u, atol=1e-9)
    np.testing.assert_allclose(vd * scale, v, atol=1e-9)
    np.testing.assert_allclose(depth_d, depth, rtol=1e-12)
    assert np.all(ud * ud + vd * vd <= u * u + v * v)  # barrel: pulled towards the centre


def test_barrel_points_and_barrel_image_model_one_lens():
    # A bright blob where a pinhole images a point moves, under the image map, to where the
    # moved point is imaged (sub-pixel: bilinear here so that the centroid is continuous).
    point = np.asarray(CAMERA.look_at) + np.array([[0.5, 0.1, -0.3]])  # at (21, 79) px
    camera = dataclasses.replace(CAMERA, width=128, height=96)
    x, y = camera.project(point)[0][0]
    yy, xx = np.mgrid[0:96, 0:128] + 0.5
    blob = np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 1.5**2))
    image = np.repeat((255 * blob)[..., None], 3, -1).astype(np.float32)
    moved = barrel_image(image, 0.25, cv2.INTER_LINEAR)[..., 0]
    centroid = np.array([(moved * xx).sum(), (moved * yy).sum()]) / moved.sum()
    expected = camera.project(barrel_points(point, camera, 0.25))[0][0]
    np.testing.assert_allclose(centroid, expected, atol=0.1)
    assert np.hypot(*(expected - [x, y])) > 2.0  # the lens moved it by several pixels


def test_barrel_image_keeps_the_background_grain_where_a_bilinear_remap_smooths_it():
    rng = np.random.default_rng(1)
    grain = rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8)
    lap = lambda x: np.var(cv2.Laplacian(x.astype(np.float32).mean(-1), cv2.CV_32F))  # noqa: E731
    assert 0.9 < lap(barrel_image(grain, 0.2)) / lap(grain) < 1.1
    assert lap(barrel_image(grain, 0.2, cv2.INTER_LINEAR)) / lap(grain) < 0.7


def test_tone_curve_maps_each_value():
    frames = np.array([[[[0, 64, 255]]]], np.uint8)
    out = apply_tone_curve(frames, 0.5)
    np.testing.assert_array_equal(out, [[[[0, round(255 * math.sqrt(64 / 255)), 255]]]])


def test_flicker_is_the_lights_100_hz_aliased_by_the_frame_rate():
    assert flicker_frequency(15.0) == pytest.approx(5.0)  # 105 = 7 x 15: a 3-frame period
    assert flicker_frequency(30.0) == pytest.approx(10.0)
    assert flicker_frequency(25.0) == pytest.approx(0.0)  # 100 = 4 x 25: a steady level
    frames = np.full((6, 4, 4, 3), 100, np.uint8)
    out = apply_exposure_flicker(frames, 0.1, 15.0, phase=np.pi / 2)
    gains = out[:, 0, 0, 0] / 100.0
    np.testing.assert_allclose(gains, 1 + 0.1 * np.cos(2 * np.pi * np.arange(6) / 3), atol=0.006)
    np.testing.assert_array_equal(out[:3], out[3:])  # periodic in three frames
    assert np.all(out == out[:, :1, :1])  # the whole frame alike


def test_no_open_set_effect_is_a_library_effect():
    library = candidate_library(SPEC)
    short = {name.split(".", 1)[1] for name in library}
    assert not short & set(OPEN_SET_EFFECTS)
    assert "visual.vignetting" in library  # it joined the library after blind round 8
    assert "visual.rolling_shutter" in library  # and the rolling shutter after round 17
    drawn = {draw_answer(seed, library, "open")["effects"][0]["name"] for seed in range(40)}
    assert drawn == set(OPEN_SET_EFFECTS)


# --- rendered: a short simulation of the wind scene at 64 px ---------------------------------


@pytest.fixture(scope="module")
def cloth():
    spec = DatasetSpec(
        motion="wind",
        scenario=ScenarioWind(resolution_level=1, settle_time=0.2),
        preset=SizePreset("tiny", 3, 1, 1, 1, frames_per_clip=6),
        classes=(0, 20, 33, 53),
        lead_in=0.2,
        sim=SimSettings(dtype="float32", max_dt=0.00834, settle_max_dt=0.0167),
        camera=CameraSpec.wind(64, 64),
        texture_size=128,
        texture_mode="grid",
    )
    material = ClothMaterial.from_wang(
        load_wang_material(BASIS_MATERIAL),
        stretch_mult=[1.0],
        bend_mult=[1.0],
        dtype=spec.sim.torch_dtype(),
    )
    stop = spec.lead_in_frames + 6
    seq = simulate(
        spec.scenario,
        material,
        seeds=[3],
        wind_levels=[2],
        fps=spec.preset.fps,
        record_time=stop / spec.preset.fps,
        effects=spec.physics,
        settings=spec.sim,
    )
    return spec, seq, SimulationPlan(-1, 0, 3, 2, "test"), stop


def _render(cloth, *effects, seq=None):
    spec, recorded, plan, stop = cloth
    entries = [{"name": n, "strength": s, "library": False} for n, s in effects]
    return render_sealed_video(
        spec, seq or recorded, 0, plan, spec.lead_in_frames, stop, rng_seed=[5], effects=entries
    )


def _laplacian_energy(frames):
    return float(
        np.mean([np.var(cv2.Laplacian(f.astype(np.float32).mean(-1), cv2.CV_32F)) for f in frames])
    )


@pytest.fixture
def flat_background(monkeypatch):
    """The cloth before a uniform grey background, so that a measure sees the cloth alone."""
    import datasets.generation as generation

    look = generation.sim_look
    monkeypatch.setattr(
        generation,
        "sim_look",
        lambda spec, plan: (
            look(spec, plan)[0],
            np.full((spec.camera.height, spec.camera.width, 3), 128, np.uint8),
        ),
    )


def test_barrel_distortion_moves_the_cloth_inwards_without_blurring_it(cloth, flat_background):
    plain = _render(cloth)
    lens = _render(cloth, ("barrel_distortion", 0.25))
    stand_in = np.stack([barrel_image(f, 0.25, cv2.INTER_LINEAR) for f in plain])
    # Measured: the lens keeps 97 % of the cloth's Laplacian energy; the image-space
    # stand-in of blind rounds 11-15 kept 69 % (a 0.6 px defocus keeps 71 %).
    assert _laplacian_energy(lens) > 0.93 * _laplacian_energy(plain)
    assert _laplacian_energy(stand_in) < 0.8 * _laplacian_energy(plain)

    def spread(frames):  # mean distance of cloth pixels from the frame's centre
        y, x = np.nonzero(np.any(frames[0] != 128, axis=-1))
        return np.mean(np.hypot(x + 0.5 - 32, y + 0.5 - 32))

    assert spread(lens) < 0.97 * spread(plain)


def test_exposure_flicker_scales_whole_frames_of_the_plain_render(cloth):
    plain = _render(cloth).astype(float)
    flicker = _render(cloth, ("exposure_flicker", 0.1)).astype(float)
    lit = (plain > 40) & (plain < 220)  # away from rounding at the dark end and clipping
    ratios = [np.median(flicker[k][lit[k]] / plain[k][lit[k]]) for k in range(len(plain))]
    assert max(ratios) - min(ratios) > 0.1  # the level swings by about twice the amplitude
    for k, ratio in enumerate(ratios):  # one gain per frame, to the rounding of uint8
        assert np.abs(flicker[k][lit[k]] - ratio * plain[k][lit[k]]).max() <= 1.5


def _seal_single(spec, out, effects, stage, clip_len):
    """Seal a four-video set (seed 4) withholding ``effects`` [(name, strength)] of ``stage``."""
    from sim2real.study.seal import seal_set

    effects = [{"name": n, "stage": stage, "strength": s, "library": True} for n, s in effects]
    answer = {"seed": 4, "kind": "single", "effects": effects}
    return seal_set(
        out, base=spec, seed=4, videos=4, clips_per_video=1, clip_len=clip_len, answer=answer
    )


def test_a_sealed_rolling_shutter_set_has_the_frames_of_a_plain_one(cloth, tmp_path):
    # The library's rolling shutter reads the frames beside each clip; the set it writes has
    # as many frames as a plain one, and they differ from the plain ones.
    written = {}
    for name, effects in (("plain", []), ("rolling", [("visual.rolling_shutter", 1.0)])):
        _seal_single(cloth[0], tmp_path / name, effects, "camera", clip_len=4)
        written[name] = sorted(p.relative_to(tmp_path / name) for p in (tmp_path / name).rglob("*"))
    assert written["plain"] == written["rolling"]
    first = [cv2.imread(str(tmp_path / n / "v000" / "frame_0001.png")) for n in written]
    assert np.abs(first[0].astype(int) - first[1]).mean() > 0.1


def test_a_withheld_density_variation_is_in_the_labels_and_every_answer_has_its_range(
    cloth, tmp_path
):
    # The labels give each cloth's density as simulated: the fabric's own draw times the
    # withheld effect's factor; the answer records the fabrics' range for the scoring.
    import json

    densities = {}
    for name, effects in (("plain", []), ("varied", [("physics.density_variation", 1.0)])):
        path, _ = _seal_single(cloth[0], tmp_path / name, effects, "physics", clip_len=2)
        assert json.loads(path.read_text())["density_range"] == [0.8, 1.25]
        rows = (tmp_path / name / "labels.csv").read_text().splitlines()[1:]
        densities[name] = np.array([float(r.split(",")[2]) for r in rows])
    ratio = np.log(densities["varied"] / densities["plain"])
    assert np.all(np.abs(ratio) <= 0.5 + 1e-6) and np.ptp(ratio) > 0.05, ratio


def test_a_sealed_video_can_take_its_image_effects_from_the_twins(cloth):
    spec, recorded, plan, stop = cloth
    library = candidate_library(spec)
    noisy = library["visual.sensor_noise"].apply(spec, 6.0)

    def render(spec, twins):
        return render_sealed_video(
            spec,
            recorded,
            0,
            plan,
            spec.lead_in_frames,
            stop,
            rng_seed=[5],
            effects=[],
            image_twins=twins,
        )

    plain = render(spec, False).astype(float)
    by_renderer = render(noisy, False).astype(float)
    by_twins = render(noisy, True).astype(float)
    assert not np.array_equal(by_renderer, by_twins)
    # the same noise level from either implementation (read 6 and shot noise), not the same draw
    level = np.std(by_renderer - plain)
    assert np.std(by_twins - plain) == pytest.approx(level, rel=0.1) and level > 5
    assert np.array_equal(render(spec, True), render(spec, False))  # nothing to twin: identical
