"""ClothRenderer over EGL: where the cloth appears, two-sidedness, textures, capsules, effects.

Every test here renders (marker ``render``); none skips: an EGL failure is a test failure.
"""

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from render.camera import CameraSpec
from render.capsules import capsule_pose
from render.effects import EFFECT_NAMES, RENDER_EFFECTS, VisualEffects
from render.lights import LightFrame, LightSpec
from render.renderer import ClothRenderer
from render.textures import make_texture
from simulator.sequence import MeshSequence

from .shapes import IMAGE_SIZE, blown, crumpled

pytestmark = pytest.mark.render

WHITE = np.full((16, 16, 3), 255, np.uint8)
BACKGROUND_RGB = (0, 90, 200)


def _background(size=IMAGE_SIZE):
    return np.broadcast_to(np.array(BACKGROUND_RGB, np.uint8), (size, size, 3)).copy()


def _rng(seed=0):
    return np.random.default_rng(seed)


def _cloth_mask(frame):
    return np.abs(frame.astype(int) - np.array(BACKGROUND_RGB)).sum(-1) > 0


@pytest.fixture(scope="module")
def renderer():
    camera = CameraSpec(
        position=(0.0, -1.2, 0.75), look_at=(0.0, 0.0, 0.75), width=IMAGE_SIZE, height=IMAGE_SIZE
    )
    with ClothRenderer(camera, LightSpec()) as r:
        yield r


def _render(renderer, pos, tri, uv, texture=WHITE, **kwargs):
    pos = pos[None] if pos.ndim == 2 else pos
    kwargs.setdefault("rng", _rng())
    return renderer.render_clip(pos, tri, uv, texture, _background(), **kwargs)


def test_flat_cloth_fills_the_centre_and_leaves_the_corners(renderer, cloth):
    pos, tri, uv = cloth
    frame = _render(renderer, pos, tri, uv)[0]
    assert frame.shape == (IMAGE_SIZE, IMAGE_SIZE, 3) and frame.dtype == np.uint8
    mask = _cloth_mask(frame)
    c = IMAGE_SIZE // 2
    assert mask[c - 6 : c + 6, c - 6 : c + 6].all()
    for corner in (frame[:4, :4], frame[:4, -4:], frame[-4:, :4], frame[-4:, -4:]):
        np.testing.assert_array_equal(corner, _background(4))
    # The silhouette sits where the camera model projects the cloth (within a pixel).
    px, _ = renderer.camera.project(pos)
    rows, cols = np.nonzero(mask)
    assert abs(cols.min() - px[:, 0].min()) <= 1.0 and abs(cols.max() + 1 - px[:, 0].max()) <= 1.0
    assert abs(rows.min() - px[:, 1].min()) <= 1.0 and abs(rows.max() + 1 - px[:, 1].max()) <= 1.0
    # Antialiased silhouette: some edge pixels blend cloth and background (red is 0 in the
    # background and high on the lit white cloth).
    red = frame[..., 0].astype(int)
    interior = np.median(red[c - 6 : c + 6, c - 6 : c + 6])
    assert ((red > 0) & (red < 0.75 * interior)).sum() >= 4


def test_different_shapes_render_differently(renderer, cloth):
    pos, tri, uv = cloth
    texture = make_texture("grid", _rng(), size=64)
    flat = _render(renderer, pos, tri, uv, texture)[0]
    folded = _render(renderer, crumpled(pos), tri, uv, texture)[0]
    lifted = _render(renderer, blown(pos, 70.0), tri, uv, texture)[0]
    for other in (folded, lifted):
        changed = np.abs(flat.astype(int) - other).sum(-1) > 30
        assert changed.mean() > 0.08
    assert _cloth_mask(lifted).sum() < 0.6 * _cloth_mask(flat).sum()  # foreshortened


def test_back_face_is_lit_and_winding_does_not_matter(cloth, back_camera, front_camera):
    pos, tri, uv = cloth
    with ClothRenderer(back_camera) as back:
        seen_from_back = _render(back, pos, tri, uv)[0]
        flipped = _render(back, pos, tri[:, ::-1].copy(), uv)[0]
    mask = _cloth_mask(seen_from_back)
    assert mask.sum() > 200
    # Camera-side key light: the back face is lit like a front face, not black.
    assert seen_from_back[mask].mean() > 120
    assert np.abs(seen_from_back.astype(int) - flipped).max() <= 2
    # A world-fixed light in front of the cloth lights the front face fully and leaves the
    # back face to the ambient light only: darker, yet not black.
    light = LightSpec(direction=(0.0, 1.0, 0.0), frame=LightFrame.WORLD)
    with ClothRenderer(front_camera, light) as front, ClothRenderer(back_camera, light) as back:
        front_lit = _render(front, pos, tri, uv)[0]
        back_dim = _render(back, pos, tri, uv)[0]
    front_mean = front_lit[_cloth_mask(front_lit)].mean()
    back_mean = back_dim[_cloth_mask(back_dim)].mean()
    assert front_mean > back_mean + 60
    assert back_mean > 40


def test_texture_modes_render_differently_and_deterministically(renderer, cloth):
    pos, tri, uv = cloth
    frames = {}
    for mode in ("grid", "color", "random"):
        texture = make_texture(mode, _rng(3), size=64)
        frames[mode] = _render(renderer, pos, tri, uv, texture)[0]
        again = _render(renderer, pos, tri, uv, make_texture(mode, _rng(3), size=64))[0]
        np.testing.assert_array_equal(frames[mode], again)
    assert not np.array_equal(frames["grid"], frames["color"])
    assert not np.array_equal(frames["color"], frames["random"])
    assert not np.array_equal(frames["grid"], frames["random"])


def test_capsules_appear_in_skin_colour(renderer, cloth):
    pos, tri, uv = cloth
    # A horizontal capsule 0.2 m in front of the cloth, across its middle.
    capsule = np.array([[[-0.3, -0.2, 0.75, 0.3, -0.2, 0.75, 0.04]]])
    without = _render(renderer, pos, tri, uv)[0]
    with_arm = _render(renderer, pos, tri, uv, capsules=capsule)[0]
    c = IMAGE_SIZE // 2
    band = with_arm[c - 1 : c + 2, 4:-4].reshape(-1, 3).astype(int)
    assert np.abs(band - without[c - 1 : c + 2, 4:-4].reshape(-1, 3)).mean() > 20
    r, g, b = band.mean(0)
    assert r > g > b  # skin tone, not the white cloth or the blue background
    np.testing.assert_array_equal(with_arm[:3, :3], _background(3))


def _moving_clip(cloth):
    pos, tri, uv = cloth
    # Folded, so that glossy highlights and self-shadows have slopes to work with.
    clip = np.stack([crumpled(pos) + np.array([0.03 * k, 0.0, 0.0]) for k in range(3)])
    capsules = np.array([[[-0.3, -0.15, 0.8, 0.3, -0.15, 0.8, 0.04]]]).repeat(3, 0)
    return clip, tri, uv, capsules


@pytest.mark.parametrize("name", RENDER_EFFECTS)
def test_each_renderer_effect_changes_the_frames(name, cloth, front_camera):
    clip, tri, uv, capsules = _moving_clip(cloth)
    texture = make_texture("grid", _rng(), size=64)
    outputs = []
    for effects in (VisualEffects(), VisualEffects(**{name: True})):
        with ClothRenderer(front_camera, effects=effects) as r:
            outputs.append(
                r.render_clip(clip, tri, uv, texture, _background(), capsules=capsules, rng=_rng(5))
            )
    base, changed = outputs
    assert changed.dtype == np.uint8 and changed.shape == base.shape
    assert np.abs(changed.astype(int) - base).mean() > 0.3, name


def test_rolling_shutter_shows_each_band_of_rows_at_its_readout_time(cloth, front_camera):
    from render.effects import rolling_shutter_offsets
    from render.renderer import _interpolate

    clip, tri, uv, _ = _moving_clip(cloth)  # 3 frames, 3 cm apart; the first is the lead
    texture = make_texture("grid", _rng(), size=64)
    effects = VisualEffects(rolling_shutter=True, rolling_shutter_readout=1.0)
    offsets = rolling_shutter_offsets(effects)
    # Top band first, bottom band last, centred on the frame's time.
    np.testing.assert_allclose(offsets, (np.arange(8) + 0.5) / 8 - 0.5)
    bands = effects.rolling_shutter_bands
    edges = np.linspace(0, IMAGE_SIZE, bands + 1).round().astype(int)
    with ClothRenderer(front_camera, effects=effects) as r:
        skewed = r.render_clip(clip, tri, uv, texture, _background(), rng=_rng(), lead=1)
        clamped = r.render_clip(clip[1:], tri, uv, texture, _background(), rng=_rng())
        # The frame after the clip, read but not rendered, gives its last frame's lower rows.
        inner = r.render_clip(clip, tri, uv, texture, _background(), rng=_rng(), lead=1, trail=1)
    assert skewed.shape[0] == 2  # the lead frame is read, not rendered
    np.testing.assert_array_equal(inner, skewed[:1])
    with ClothRenderer(front_camera) as r:
        for j in (0, bands - 1):
            # The cloth at band j's time, rendered whole: its rows of band j are the frame's.
            at = np.stack([_interpolate(clip, k + 1 + offsets[j]) for k in range(2)])
            whole = r.render_clip(at, tri, uv, texture, _background(), rng=_rng())
            rows = slice(edges[j], edges[j + 1])
            np.testing.assert_array_equal(skewed[:, rows], whole[:, rows])
        plain = r.render_clip(clip[1:], tri, uv, texture, _background(), rng=_rng())
    # Without the lead frame the first frame's upper bands cannot look back: they are plain.
    upper = slice(0, edges[bands // 2])
    np.testing.assert_array_equal(clamped[0, upper], plain[0, upper])
    assert np.abs(skewed[0].astype(int) - plain[0]).mean() > 0.3
    with ClothRenderer(front_camera, effects=effects) as r, pytest.raises(ValueError, match="lead"):
        r.render_clip(clip[:2], tri, uv, texture, _background(), rng=_rng(), lead=1, trail=1)


FAST_PATH_CASES = {
    "plain": ({}, 1, False),
    "rolling shutter": ({"rolling_shutter": True}, 1, False),
    "rolling shutter, blur, shake, supersampled": (
        {
            "rolling_shutter": True,
            "motion_blur": True,
            "motion_blur_samples": 2,
            "camera_shake": True,
        },
        2,
        False,
    ),
    "rolling shutter with shadows": ({"rolling_shutter": True, "shadows": True}, 1, False),
    "rolling shutter with passes": ({"rolling_shutter": True, "lighting_variation": True}, 1, True),
}


@pytest.mark.parametrize("case", FAST_PATH_CASES)
def test_fast_paths_give_the_reference_bytes(case, cloth, front_camera):
    """Band scissor and in-place vertex upload against whole frames and a new mesh a frame."""
    switches, supersample, passes = FAST_PATH_CASES[case]
    clip, tri, uv, capsules = _moving_clip(cloth)
    texture = make_texture("grid", _rng(), size=64)
    outputs = []
    for fast in (False, True):
        with ClothRenderer(
            front_camera, effects=VisualEffects(**switches), supersample=supersample
        ) as r:
            r.band_scissor = r.update_in_place = fast
            outputs.append(
                r.render_clip(
                    clip,
                    tri,
                    uv,
                    texture,
                    _background(),
                    capsules=capsules,
                    rng=_rng(3),
                    lead=1,
                    passes=passes,
                )
            )
    reference, fast = outputs
    if passes:
        np.testing.assert_array_equal(fast[0], reference[0])
        np.testing.assert_array_equal(fast[1], reference[1])
        for name, image in reference[2].items():
            np.testing.assert_array_equal(fast[2][name], image, err_msg=name)
    else:
        np.testing.assert_array_equal(fast, reference)


def test_interleaved_renderers_keep_their_own_buffers_and_scissor(cloth, front_camera):
    """Two contexts in one process: each in-place upload and scissor box lands in its own."""
    clip, tri, uv, _ = _moving_clip(cloth)
    texture = make_texture("grid", _rng(), size=64)
    shutter = VisualEffects(rolling_shutter=True)
    with ClothRenderer(front_camera, effects=shutter) as a, ClothRenderer(front_camera) as b:
        alone = [r.render_clip(clip, tri, uv, texture, _background(), rng=_rng()) for r in (a, b)]
        crumpled_clip = clip[::-1].copy()
        for _ in range(2):  # the other renderer's clip in between, twice
            mixed_a = a.render_clip(clip, tri, uv, texture, _background(), rng=_rng())
            b.render_clip(crumpled_clip, tri, uv, texture, _background(), rng=_rng())
            mixed_b = b.render_clip(clip, tri, uv, texture, _background(), rng=_rng())
            a.render_clip(crumpled_clip, tri, uv, texture, _background(), rng=_rng())
            np.testing.assert_array_equal(mixed_a, alone[0])
            np.testing.assert_array_equal(mixed_b, alone[1])


def test_full_pipeline_deterministic_per_seed(cloth, front_camera):
    clip, tri, uv, capsules = _moving_clip(cloth)
    texture = make_texture("random", _rng(1), size=64)
    effects = VisualEffects(
        **{name: True for name in EFFECT_NAMES if name != "frame_rate"}
        | {"shadows": False, "motion_blur_samples": 2}
    )
    with ClothRenderer(front_camera, effects=effects, supersample=2) as r:
        a = r.render_clip(clip, tri, uv, texture, _background(), capsules=capsules, rng=_rng(9))
        b = r.render_clip(clip, tri, uv, texture, _background(), capsules=capsules, rng=_rng(9))
        c = r.render_clip(clip, tri, uv, texture, _background(), capsules=capsules, rng=_rng(10))
    assert a.shape == (3, IMAGE_SIZE, IMAGE_SIZE, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_closing_one_renderer_leaves_others_working(cloth, front_camera):
    pos, tri, uv = cloth
    first = ClothRenderer(front_camera)
    second = ClothRenderer(front_camera)
    before = _render(second, pos, tri, uv)
    first.close()
    first.close()  # idempotent
    np.testing.assert_array_equal(_render(second, pos, tri, uv), before)
    second.close()
    with pytest.raises(RuntimeError, match="closed"):
        _render(second, pos, tri, uv)


def test_input_validation(renderer, cloth):
    pos, tri, uv = cloth
    with pytest.raises(ValueError, match="pos"):
        renderer.render_clip(pos, tri, uv, WHITE, None, rng=_rng())
    with pytest.raises(ValueError, match="tri_indices"):
        _render(renderer, pos, tri + len(pos), uv)
    with pytest.raises(ValueError, match="texture"):
        _render(renderer, pos, tri, uv, WHITE.astype(np.float32))
    with pytest.raises(ValueError, match="capsules"):
        _render(renderer, pos, tri, uv, capsules=np.zeros((2, 1, 7)))
    with pytest.raises(TypeError, match="rng"):
        _render(renderer, pos, tri, uv, rng=0)
    with pytest.raises(ValueError, match="supersample"):
        ClothRenderer(renderer.camera, supersample=0)
    # A background of another size is resized; None gives black.
    frame = renderer.render_clip(pos[None], tri, uv, WHITE, _background(20), rng=_rng())[0]
    np.testing.assert_array_equal(frame[0, 0], BACKGROUND_RGB)
    black = renderer.render_clip(pos[None], tri, uv, WHITE, None, rng=_rng())[0]
    np.testing.assert_array_equal(black[0, 0], [0, 0, 0])


def test_coverage_is_the_alpha_each_frame_was_composited_with(renderer, cloth):
    pos, tri, uv = cloth
    clip = np.stack([pos, pos + np.array([0.05, 0.0, 0.0])])
    frames, cover = renderer.render_clip(
        clip, tri, uv, WHITE, _background(), rng=_rng(), coverage=True
    )
    np.testing.assert_array_equal(
        frames, renderer.render_clip(clip, tri, uv, WHITE, _background(), rng=_rng())
    )
    assert cover.dtype == np.uint8 and cover.shape == frames.shape[:3]
    assert (cover == 255).mean() > 0.1 and (cover == 0).mean() > 0.1
    assert not np.array_equal(cover[0], cover[1]), "coverage moves with the cloth"
    # Premultiplied compositing: frame = cloth over black + (1 - alpha) * background.
    black = renderer.render_clip(clip, tri, uv, WHITE, None, rng=_rng())
    alpha = cover[..., None] / 255.0
    expected = black + (1.0 - alpha) * np.array(BACKGROUND_RGB)
    assert np.abs(frames - expected).max() <= 1.01


def _arm_sequence(frame_count=11):
    from simulator.cloth.scenes import ScenarioArmBend

    scenario = ScenarioArmBend(resolution_level=1)
    mesh = scenario.mesh()
    pos = mesh.vert_pos.float().numpy()
    return MeshSequence(
        pos=np.broadcast_to(pos, (1, frame_count, *pos.shape)).copy(),
        tri_indices=mesh.tri_indices.numpy(),
        uv=mesh.uv.float().numpy(),
        fps=10.0,
        seeds=[0],
        labels=[-1],
        wind_levels=[0],
        meta={
            "scene": "arm",
            "scenario": dataclasses.asdict(scenario),
            "sim": {"dt": 0.005, "substeps": 20},
            "settle_time": scenario.settle_time,
        },
    )


def test_render_sequence_draws_the_arm():
    from simulator.cloth.rollout import with_capsules

    bare_seq = _arm_sequence(3)
    seq = with_capsules(bare_seq)
    with ClothRenderer(CameraSpec.arm(48, 48)) as r:
        frames = r.render_sequence(seq, 0, WHITE, _background(), _rng())
        given = r.render_sequence(bare_seq, 0, WHITE, _background(), _rng(), capsules=seq.capsules)
        np.testing.assert_array_equal(given, frames)
        with pytest.raises(ValueError, match="carries no capsules"):
            r.render_sequence(bare_seq, 0, WHITE, _background(), _rng())
        bare = r.render_clip(seq.pos[0], seq.tri_indices, seq.uv, WHITE, _background(), rng=_rng())
        with pytest.raises(ValueError, match="instance"):
            r.render_sequence(seq, 1, WHITE, None, _rng())
    assert frames.shape == (3, 48, 48, 3)
    assert np.abs(frames.astype(int) - bare).sum(-1).astype(bool).sum() > 20


def test_capsule_pose_maps_the_axis_onto_the_segment():
    p0, p1 = np.array([0.1, -0.2, 1.0]), np.array([0.4, 0.2, 1.5])
    pose = capsule_pose(p0, p1)
    half = np.linalg.norm(p1 - p0) / 2
    ends = (pose @ np.array([[0, 0, -half, 1], [0, 0, half, 1]]).T).T[:, :3]
    np.testing.assert_allclose(ends, [p0, p1], atol=1e-12)
    flipped = capsule_pose(np.array([0, 0, 1.0]), np.array([0, 0, 0.0]))
    np.testing.assert_allclose(flipped[:3, :3] @ [0, 0, 1], [0, 0, -1], atol=1e-12)


def test_import_is_light_and_the_renderer_needs_no_environment_variable():
    code = (
        "import os, sys\n"
        "import render\n"
        "assert 'pyrender' not in sys.modules and 'OpenGL' not in sys.modules\n"
        "from render import CameraSpec, ClothRenderer\n"
        "assert os.environ['PYOPENGL_PLATFORM'] == 'egl'\n"
        "with ClothRenderer(CameraSpec(width=8, height=8)):\n"
        "    pass\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    result = subprocess.run(
        [sys.executable, "-c", code],
        cwd=Path(__file__).resolve().parents[2],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr


@pytest.mark.render
def test_torch_compiler_import_after_rendering_does_not_crash():
    """Mesa's llvmpipe and triton both bundle LLVM; the renderer loads triton first."""
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "from render.camera import CameraSpec\n"
        "from render.renderer import ClothRenderer\n"
        "from simulator.mesh import TriMesh\n"
        "grid = TriMesh.grid(4, size_u=0.5)\n"
        "pos = np.stack([grid.uv[:, 0].numpy() - 0.25, np.zeros(16), 1 - grid.uv[:, 1].numpy()],"
        " -1)[None].astype(np.float32)\n"
        "r = ClothRenderer(CameraSpec.wind())\n"
        "r.render_clip(pos, grid.tri_indices.numpy(), grid.uv.numpy(),"
        " np.full((8, 8, 3), 200, np.uint8), None, rng=np.random.default_rng(0))\n"
        "import torch._dynamo\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=300)
    assert done.returncode == 0, done.stderr.decode()[-2000:]


def test_pyglet_is_headless_under_egl():
    """pyrender imports pyglet's window module; outside headless mode that loads X11
    libraries, which a bare GPU server lacks (seen on an H100)."""
    import pyglet

    assert os.environ["PYOPENGL_PLATFORM"] != "egl" or pyglet.options["headless"]
