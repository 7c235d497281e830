"""Texture and background banks: shapes, determinism per seed, variety, optional photos."""

import sys
import types

import numpy as np
import pytest

from render import backgrounds, patterns, textures
from render.backgrounds import (
    PROCEDURAL_BACKGROUND_KINDS,
    available_background_kinds,
    make_background,
)
from render.textures import PROCEDURAL_TEXTURE_KINDS, TextureMode, make_texture


def _rng(seed):
    return np.random.default_rng(seed)


@pytest.mark.parametrize("mode", list(TextureMode))
def test_texture_modes_shape_dtype_and_determinism(mode):
    a = make_texture(mode, _rng(3), size=64)
    b = make_texture(mode, _rng(3), size=64)
    assert a.dtype == np.uint8 and a.shape == (64, 64, 3)
    np.testing.assert_array_equal(a, b)


def test_texture_modes_differ_and_vary_with_the_seed():
    grid, colour, rand = (make_texture(m, _rng(0), size=64) for m in TextureMode)
    assert not np.array_equal(grid, colour) and not np.array_equal(colour, rand)
    assert np.unique(colour.reshape(-1, 3), axis=0).shape[0] == 1  # solid colour
    assert not np.array_equal(make_texture("color", _rng(1), 64), colour)
    assert not np.array_equal(make_texture("random", _rng(1), 64), rand)
    # grid is one fixed checkerboard, whatever the seed
    np.testing.assert_array_equal(make_texture("grid", _rng(1), 64), grid)


@pytest.mark.parametrize("kind", PROCEDURAL_TEXTURE_KINDS)
def test_each_procedural_texture_kind_has_structure(kind):
    texture = make_texture("random", _rng(5), size=96, kinds=[kind])
    assert texture.dtype == np.uint8 and texture.shape == (96, 96, 3)
    assert texture.astype(float).std() > 5.0, f"{kind} texture is nearly flat"


def test_random_mode_draws_many_kinds():
    signatures = {make_texture("random", _rng(s), size=32).tobytes() for s in range(12)}
    assert len(signatures) == 12


def test_texture_errors():
    with pytest.raises(ValueError, match="mode"):
        make_texture("plaid", _rng(0))
    with pytest.raises(ValueError, match="size"):
        make_texture("grid", _rng(0), size=4)
    with pytest.raises(ValueError, match="kinds"):
        make_texture("random", _rng(0), kinds=["velvet"])


def test_photo_kinds_need_scikit_image(monkeypatch):
    monkeypatch.setattr(textures, "photos_available", lambda: False)
    monkeypatch.setattr(backgrounds, "photos_available", lambda: False)
    assert "photo" not in textures.available_texture_kinds()
    assert available_background_kinds() == PROCEDURAL_BACKGROUND_KINDS
    with pytest.raises(ValueError, match="scikit-image"):
        make_texture("random", _rng(0), kinds=["photo"])
    with pytest.raises(ValueError, match="scikit-image"):
        make_background(_rng(0), 32, 32, kinds=["photo"])


@pytest.fixture
def fake_skimage(monkeypatch):
    """A stand-in ``skimage.data`` whose photos are seeded noise images."""

    def photo(seed, shape):
        return lambda: np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)

    data = types.ModuleType("skimage.data")
    for i, name in enumerate(patterns.PHOTO_NAMES):
        setattr(data, name, photo(i, (120, 160, 3) if i % 2 else (90, 90)))
    package = types.ModuleType("skimage")
    package.data = data
    monkeypatch.setitem(sys.modules, "skimage", package)
    monkeypatch.setitem(sys.modules, "skimage.data", data)
    patterns.photos_available.cache_clear()
    patterns._load_photo_cached.cache_clear()
    yield
    patterns.photos_available.cache_clear()
    patterns._load_photo_cached.cache_clear()


def test_photo_textures_and_backgrounds_with_scikit_image(fake_skimage):
    assert "photo" in textures.available_texture_kinds()
    assert "photo" in available_background_kinds()
    a = make_texture("random", _rng(2), size=48, kinds=["photo"])
    b = make_texture("random", _rng(2), size=48, kinds=["photo"])
    assert a.shape == (48, 48, 3) and a.dtype == np.uint8
    np.testing.assert_array_equal(a, b)
    background = make_background(_rng(2), 40, 30, kinds=["photo"])
    assert background.shape == (30, 40, 3) and background.dtype == np.uint8


@pytest.mark.parametrize("kind", PROCEDURAL_BACKGROUND_KINDS)
def test_background_kinds_shape_determinism_structure(kind):
    a = make_background(_rng(4), 64, 48, kinds=[kind])
    b = make_background(_rng(4), 64, 48, kinds=[kind])
    assert a.dtype == np.uint8 and a.shape == (48, 64, 3)
    np.testing.assert_array_equal(a, b)
    assert a.astype(float).std() > 2.0


def test_backgrounds_vary_with_the_seed_and_reject_bad_sizes():
    images = {make_background(_rng(s), 32, 32).tobytes() for s in range(8)}
    assert len(images) == 8
    with pytest.raises(ValueError, match="width"):
        make_background(_rng(0), 0, 32)
    with pytest.raises(ValueError, match="kinds"):
        make_background(_rng(0), 32, 32, kinds=["beach"])
