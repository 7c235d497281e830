"""Counterfactual stage swaps: camera signatures and matching, AdaBN."""

import numpy as np
import pytest
import torch
from torch import nn

from sim2real.counterfactuals import (
    _invert,
    batchnorm_swap,
    camera_signatures,
    clip_statistics,
    match_camera,
    statistic_names,
    swap_closure,
)
from sim2real.diagnosis import rung_gaps
from sim2real.features import MOTION_FEATURE_NAMES, PIXEL_FEATURE_NAMES
from sim2real.ladder import LadderFeatures
from sim2real.network import adapt_batchnorm, layer_features
from sim2real.tracks import TRACK_FEATURE_NAMES
from simulator.cloth.material import WANG54

GROUPS, CLIPS = 18, 3
NOISE = PIXEL_FEATURE_NAMES.index("noise_sigma_luma")
SHARP = PIXEL_FEATURE_NAMES.index("laplacian_std")


def _domain(seed, noise=0.0, blur=0.0, groups=GROUPS):
    """The hand-made rungs; 'noise' raises the noise feature, 'blur' lowers sharpness."""
    rng = np.random.default_rng(seed)
    ids = np.repeat([f"g{i}" for i in range(groups)], CLIPS)
    pixel = np.repeat(rng.normal(0, 0.3, (groups, len(PIXEL_FEATURE_NAMES))), CLIPS, 0)
    pixel += rng.normal(size=pixel.shape)
    motion = rng.normal(size=(len(ids), len(MOTION_FEATURE_NAMES)))
    tracks = rng.normal(size=(len(ids), len(TRACK_FEATURE_NAMES)))
    pixel[:, NOISE] += noise
    pixel[:, SHARP] -= blur
    return LadderFeatures(
        rungs={"pixel": pixel, "motion": motion, "tracks": tracks},
        groups=ids,
        class_id=np.zeros(len(ids), int),
        stiffness=np.ones(len(ids)),
        density=np.ones(len(ids)),
    )


@pytest.fixture(scope="module")
def camera():
    sim = _domain(0)
    strengths = (1.0, 2.0, 4.0)
    effects = {
        "visual.sensor_noise": (strengths, [_domain(0, noise=s) for s in strengths], None),
        "visual.defocus_blur": (strengths, [_domain(0, blur=s) for s in strengths], None),
    }
    return sim, effects, camera_signatures(sim, effects, rng=np.random.default_rng(0))


def test_statistics_are_named_medians_and_spreads():
    sim = _domain(0)
    stats = clip_statistics(sim)
    names = statistic_names()
    assert stats.shape == (1, len(names)) == (1, 2 * (35 + 56 + 6))
    assert names[NOISE] == "median(pixel.noise_sigma_luma)"
    column = sim.rungs["pixel"][:, NOISE]
    assert stats[0, NOISE] == pytest.approx(np.quantile(column, 0.5, method="inverted_cdf"))
    weights = np.ones((len(sim.groups), 2))
    assert np.allclose(clip_statistics(sim, weights), np.repeat(stats, 2, 0))


def test_each_camera_effect_gets_the_statistic_it_moves_and_others_do_not(camera):
    _, _, signatures = camera
    assert signatures["visual.sensor_noise"]["statistic"] == "median(pixel.noise_sigma_luma)"
    assert signatures["visual.defocus_blur"]["statistic"] == "median(pixel.laplacian_std)"
    assert signatures["visual.sensor_noise"]["z"] > 3


def test_a_statistic_that_other_stages_also_move_loses_specificity(camera):
    sim, effects, alone = camera
    physics = {"physics.rival": [_domain(0, noise=s) for s in (2.0, 4.0)]}  # moves it too
    shared = camera_signatures(sim, effects, physics, rng=np.random.default_rng(0))
    noise = "visual.sensor_noise"
    assert shared[noise]["specificity"] < 0.5 * alone[noise]["specificity"]
    assert shared["visual.defocus_blur"]["statistic"] == alone["visual.defocus_blur"]["statistic"]


def test_an_effect_that_moves_nothing_has_no_signature():
    sim = _domain(0)
    effects = {"visual.inert": ((1.0, 2.0), [_domain(0), _domain(0)], None)}
    assert (
        camera_signatures(sim, effects, rng=np.random.default_rng(0))["visual.inert"]["statistic"]
        is None
    )


def test_r_s_camera_is_matched_at_its_strength_and_absent_effects_stay_off(camera):
    sim, _, signatures = camera
    real = _domain(5, noise=3.0)  # other videos, noise between the 2.0 and 4.0 sets
    matched = match_camera(signatures, real, sim, rng=np.random.default_rng(1))
    noise = matched["visual.sensor_noise"]
    assert noise["present"] and 2.2 < noise["strength"] < 3.8
    assert not matched["visual.defocus_blur"]["present"]
    assert matched["visual.defocus_blur"]["strength"] is None
    # the opposite direction (a sharper R) is not the blur effect
    sharper = match_camera(signatures, _domain(6, blur=-3.0), sim, rng=np.random.default_rng(1))
    assert not sharper["visual.defocus_blur"]["present"]


def test_inversion_reads_the_strength_off_curves_of_either_direction():
    # off below the range: a value between off and the weakest set is the weakest strength
    assert _invert([1.0, 2.0, 4.0], [10.0, 20.0, 40.0], 0.0, 30.0) == pytest.approx(3.0)
    assert _invert([1.0, 2.0, 4.0], [10.0, 20.0, 40.0], 0.0, 5.0) == 1.0
    assert _invert([1.0, 2.0, 4.0], [10.0, 20.0, 40.0], 0.0, 90.0) == 4.0
    # neutral above the range (JPEG quality 100): lower quality, larger statistic
    assert _invert([10, 50, 90], [9.0, 5.0, 1.0], 0.0, 7.0, neutral=100) == pytest.approx(30.0)
    # neutral inside (frame-rate ratio 1): both sides, the crossing on the target's side
    curve = ([0.5, 2.0], [-4.0, 4.0])
    assert _invert(*curve, 0.0, 2.0, neutral=1.0) == pytest.approx(1.5)
    assert _invert(*curve, 0.0, -2.0, neutral=1.0) == pytest.approx(0.75)


def test_the_swap_closes_the_gap_of_the_emulated_stage_only():
    sim = _domain(0)
    real = _domain(5, noise=3.0)
    gaps = rung_gaps(sim, real, n_perm=99, n_boot=49, n_floor=6, seed=0)
    closed = swap_closure(
        sim, real, gaps, sim_after=_domain(0, noise=3.0), rng=np.random.default_rng(0)
    )
    assert closed["pixel"]["closure"] > 0.7
    assert closed["pixel"]["mmd2_after"] < closed["pixel"]["mmd2_before"]
    wrong = swap_closure(
        sim, real, gaps, sim_after=_domain(0, blur=3.0), rng=np.random.default_rng(0)
    )
    assert wrong["pixel"]["closure"] < 0.1


class _TinyNet(nn.Module):
    """A clip net with one conv + BatchNorm per frame, pooled over time."""

    def __init__(self, norm=True):
        super().__init__()
        self.conv = nn.Conv2d(3, 4, 3, padding=1)
        self.norm = nn.BatchNorm2d(4) if norm else nn.Identity()
        self.head = nn.Linear(4, 54)

    def forward(self, video):
        b, t = video.shape[:2]
        maps = torch.relu(self.norm(self.conv(video.flatten(0, 1))))
        return self.head(maps.mean((2, 3)).reshape(b, t, -1).mean(1))


def _clips(seed, gain=1.0, count=12):
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 160, size=(count, 3, 8, 8, 3)) * gain
    return np.clip(frames, 0, 255).astype(np.uint8)


def test_adabn_re_estimates_the_statistics_on_the_target_and_leaves_the_net_alone():
    torch.manual_seed(0)
    net = _TinyNet().eval()
    before = {k: v.clone() for k, v in net.state_dict().items()}
    target = _clips(1, gain=1.5)
    adapted = adapt_batchnorm(net, target, batch_size=4)
    for key, value in net.state_dict().items():
        assert torch.equal(value, before[key])  # the original is untouched
    with torch.no_grad():
        video = torch.from_numpy(target).permute(0, 1, 4, 2, 3).float() / 255
        maps = net.conv(video.flatten(0, 1))
    assert torch.allclose(adapted.norm.running_mean, maps.mean((0, 2, 3)), atol=1e-5)
    assert not adapted.training
    assert torch.equal(adapted.conv.weight, net.conv.weight)
    assert adapt_batchnorm(_TinyNet(norm=False), target) is None
    with pytest.raises(ValueError, match="2 clips"):
        adapt_batchnorm(net, target[:1])


def test_batchnorm_swap_closes_a_brightness_gap_in_the_layers():
    torch.manual_seed(0)
    net = _TinyNet().eval()
    source = _clips(2, count=24)
    adapt_source = adapt_batchnorm(net, source, batch_size=8)  # S's own statistics
    target = _clips(3, gain=1.6, count=24)

    def ladder(model, clips):
        layers = layer_features(model, clips, batch_size=8)
        groups = np.repeat([f"v{i}" for i in range(len(clips) // 2)], 2)
        return LadderFeatures(
            rungs={"pixel": clips.reshape(len(clips), -1)[:, :6].astype(float), **layers},
            groups=groups,
            class_id=np.zeros(len(clips), int),
            stiffness=np.arange(len(clips), dtype=float),
            density=np.ones(len(clips)),
        )

    sim = ladder(adapt_source, source)
    real = ladder(adapt_source, target)
    gaps = rung_gaps(sim, real, n_perm=99, n_boot=49, n_floor=4, seed=0)
    swap = batchnorm_swap(
        sim,
        real,
        ladder(adapt_batchnorm(net, target, batch_size=8), target),
        gaps,
        WANG54.grid,
        rng=np.random.default_rng(0),
    )
    assert swap["available"]
    assert "pixel" not in swap["layers"]
    assert swap["layers"]["logits"]["mmd2_after"] < swap["layers"]["logits"]["mmd2_before"]
    assert set(swap["correlations"]["before"]) == {
        f"{s}~{t}"
        for s in ("material_score", "stretch_score", "bend_score")
        for t in ("stiffness", "density")
    }
    assert batchnorm_swap(sim, real, None, gaps, WANG54.grid, rng=np.random.default_rng(0)) == {
        "available": False,
        "reason": "the network has no batch-norm layer",
    }
