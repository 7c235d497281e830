"""Simulated clip sets: the shared render before the image effects is the whole render's bytes."""

import dataclasses

import numpy as np

import sim2real.domains as domains
from datasets.spec import DatasetSpec
from render.effects import IMAGE_EFFECT_ORDER
from sim2real.candidates import candidate_library
from sim2real.domains import simulated_clips


def _same(a, b):
    assert np.array_equal(a.frames, b.frames) and np.array_equal(a.coverage, b.coverage)
    assert np.array_equal(a.groups, b.groups) and np.array_equal(a.stiffness, b.stiffness)


def _effect_specs(spec: DatasetSpec) -> dict[str, DatasetSpec]:
    library = candidate_library(spec)
    out = {}
    for name in IMAGE_EFFECT_ORDER:
        if name == "frame_rate":  # renders whole (see the next test)
            continue
        candidate = library[f"visual.{name}"]
        out[name] = candidate.apply(spec, candidate.strengths(3)[-1])
    # An image effect on top of render effects that draw randomness of their own.
    shaken = library["visual.camera_shake"].apply(spec, 0.004)
    lit = library["visual.lighting_variation"].apply(shaken, 0.3)
    out["noise over shake and lighting"] = library["visual.sensor_noise"].apply(lit, 4.0)
    return out


def test_image_effects_over_the_shared_render_give_the_whole_renders_bytes(
    nominal, tmp_path, monkeypatch
):
    meshes, renders = tmp_path / "meshes", tmp_path / "renders"
    specs = _effect_specs(nominal)
    whole = {n: simulated_clips(s, meshes, clip_len=4, clip_stride=4) for n, s in specs.items()}
    for name, spec in specs.items():
        _same(
            simulated_clips(spec, meshes, clip_len=4, clip_stride=4, render_cache=renders),
            whole[name],
        )
    # Two renders of two simulations: the nominal one, which every single image effect
    # reads, and the shaken and lit one.
    assert len(list(renders.iterdir())) == 4

    def no_render(*args, **kwargs):
        raise AssertionError("rendered again although the render is stored")

    monkeypatch.setattr(domains, "render_frames", no_render)
    for name, spec in specs.items():
        _same(
            simulated_clips(spec, meshes, clip_len=4, clip_stride=4, render_cache=renders),
            whole[name],
        )


def test_without_image_effects_or_with_a_frame_rate_change_a_set_renders_whole(nominal, tmp_path):
    meshes, renders = tmp_path / "meshes", tmp_path / "renders"
    shaken = dataclasses.replace(
        nominal, visual=dataclasses.replace(nominal.visual, camera_shake=True)
    )
    slower = candidate_library(nominal)["visual.frame_rate"].apply(nominal, 0.5)
    for spec in (nominal, shaken, slower):
        _same(
            simulated_clips(spec, meshes, clip_len=4, clip_stride=4, render_cache=renders),
            simulated_clips(spec, meshes, clip_len=4, clip_stride=4),
        )
    assert not renders.exists()
