"""Render passes and re-texturing: a re-textured clip matches a render with that texture.

Figures measured when this was written (96 x 96, crumpled moving cloth, random textures):
re-texturing with the clip's own texture is off by 0.7-0.9 / 255 on average, with another
texture by 2.0-2.5 / 255, while the two textures' renders differ by 8.6-15.5 / 255; plain
colours are within 2 / 255 wherever the arm's silhouette does not cross the cloth.
"""

import dataclasses

import numpy as np
import pytest

from render.camera import CameraSpec
from render.effects import VisualEffects
from render.lights import LightSpec
from render.passes import PASS_NAMES, RAMP_SIZE, retexture, uv_ramp_texture
from render.renderer import ClothRenderer
from render.textures import make_texture

from .shapes import crumpled, grid_cloth

pytestmark = pytest.mark.render

SIZE = 96


@pytest.fixture(scope="module")
def renderer():
    camera = CameraSpec(
        position=(0.0, -1.2, 0.75), look_at=(0.0, 0.0, 0.75), width=SIZE, height=SIZE
    )
    with ClothRenderer(camera, LightSpec()) as r:
        yield r


def _scene(arm: bool):
    pos, tri, uv = grid_cloth()
    clip = np.stack([crumpled(pos) + np.array([0.03 * k, 0.0, 0.0]) for k in range(3)])
    capsules = np.array([[[-0.3, -0.15, 0.8, 0.3, -0.15, 0.8, 0.04]]]).repeat(3, 0)
    background = np.random.default_rng(0).integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
    return clip, tri, uv, (capsules if arm else None), background


def _render(renderer, scene, texture, **kwargs):
    clip, tri, uv, capsules, background = scene
    return renderer.render_clip(
        clip,
        tri,
        uv,
        texture,
        background,
        capsules=capsules,
        rng=np.random.default_rng(0),
        **kwargs,
    )


@pytest.mark.parametrize("arm", [False, True])
def test_retexturing_matches_a_render_with_that_texture(renderer, arm):
    scene = _scene(arm)
    first, second = (make_texture("random", np.random.default_rng(s), 256) for s in (1, 5))
    frames, coverage, passes = _render(renderer, scene, first, passes=True)
    assert set(passes) == set(PASS_NAMES)
    plain, plain_coverage = _render(renderer, scene, first, coverage=True)
    np.testing.assert_array_equal(frames, plain)  # the passes leave the frames as they were
    np.testing.assert_array_equal(coverage, plain_coverage)
    other = _render(renderer, scene, second)
    background = scene[-1]
    spread = np.abs(frames.astype(int) - other).max(-1).mean()
    for texture, reference, bound in ((first, frames, 1.5), (second, other, 3.5)):
        out = retexture(*(passes[n] for n in PASS_NAMES), coverage, background, texture)
        error = np.abs(out.astype(int) - reference).max(-1)
        assert error.mean() < bound and error.mean() < 0.3 * spread, (error.mean(), spread)
        empty = coverage == 0
        np.testing.assert_array_equal(out[empty], np.broadcast_to(background, out.shape)[empty])


def test_plain_colours_are_reproduced_exactly(renderer):
    scene = _scene(arm=True)
    white = np.full((64, 64, 3), 255, np.uint8)
    _, coverage, passes = _render(renderer, scene, white, passes=True)
    for value in (0, 90, 200, 255):
        texture = np.full((32, 32, 3), value, np.uint8)
        out = retexture(*(passes[n] for n in PASS_NAMES), coverage, scene[-1], texture)
        error = np.abs(out.astype(int) - _render(renderer, scene, texture)).max(-1)
        no_arm = passes["uvm"][..., 2] == coverage  # cloth alone, or nothing, in the pixel
        assert error[no_arm].max() <= 2 and (~no_arm).any()  # 2: antialiased silhouettes
        assert error.mean() < 0.3


def test_uv_pass_reads_the_texture_coordinates_linearly(renderer):
    pos, tri, uv = grid_cloth()
    white = np.full((8, 8, 3), 255, np.uint8)
    rng = np.random.default_rng(0)
    _, coverage, passes = renderer.render_clip(
        pos[None], tri, uv, white, None, rng=rng, passes=True
    )
    uvm = passes["uvm"][0].astype(float)
    inside = coverage[0] == 255
    assert (uvm[..., 2][inside] == 255).all()
    row = uvm[SIZE // 2, :, 0][inside[SIZE // 2]]  # u grows steadily left to right
    steps = np.diff(row)
    assert (steps > 0).all() and np.ptp(steps) <= 1  # a constant step, rounded to integers
    column = uvm[:, SIZE // 2, 1][inside[:, SIZE // 2]]  # v (texture row) grows downwards
    assert (np.diff(column) > 0).all()
    ramp = uv_ramp_texture()
    assert ramp.shape == (RAMP_SIZE, RAMP_SIZE, 4) and ramp[3, 7, 0] == 7 and ramp[3, 7, 1] == 3


def test_passes_refuse_resampled_frames_and_retexture_checks_shapes(cloth):
    pos, tri, uv = cloth
    effects = dataclasses.replace(VisualEffects(), frame_rate=True)
    camera = CameraSpec(position=(0.0, -1.2, 0.75), look_at=(0.0, 0.0, 0.75), width=16, height=16)
    with ClothRenderer(camera, effects=effects) as r, pytest.raises(ValueError, match="frame_rate"):
        r.render_clip(
            np.stack([pos, pos]),
            tri,
            uv,
            np.zeros((8, 8, 3), np.uint8),
            None,
            rng=np.random.default_rng(0),
            passes=True,
        )
    clip = np.zeros((2, 4, 4, 3), np.uint8)
    cover = np.zeros((2, 4, 4), np.uint8)
    texture = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(ValueError, match="uvm must be uint8"):
        retexture(clip, clip, clip[:1], cover, clip[0], texture)
    with pytest.raises(ValueError, match="texture must be uint8"):
        retexture(clip, clip, clip, cover, clip[0], texture[..., 0])
    assert retexture(clip, clip, clip, cover, clip[0] + 7, texture).max() == 7  # background only
