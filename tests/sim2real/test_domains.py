"""Simulated clip sets: the shared render before the image effects is the whole render's bytes."""

import dataclasses

import numpy as np
import pytest

import sim2real.domains as domains
from datasets.generation import simulate_unit
from datasets.plan import plan_units
from datasets.spec import DatasetSpec
from render.effects import IMAGE_EFFECT_ORDER
from sim2real.candidates import candidate_library
from sim2real.domains import simulated_clips
from sim2real.pipeline import spanning_classes
from simulator.cloth.material import (
    BASIS_MATERIAL,
    BEND_MULTIPLIERS,
    STRETCH_MULTIPLIERS,
    WANG54,
    MaterialSet,
    load_wang_material,
)


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


def test_simulated_clips_adds_its_simulation_and_render_seconds_to_a_timing(nominal, tmp_path):
    timing = {"simulate": 1.0}
    clips = simulated_clips(nominal, tmp_path, clip_len=4, clip_stride=4, timing=timing)
    _same(clips, simulated_clips(nominal, tmp_path, clip_len=4, clip_stride=4))
    assert set(timing) == {"simulate", "render"}
    assert timing["simulate"] > 1.0 and timing["render"] > 0.0


DENSE = MaterialSet("dense", BASIS_MATERIAL, STRETCH_MULTIPLIERS, BEND_MULTIPLIERS, (0.4, 0.7, 1.2))


def test_a_one_density_set_draws_stretch_and_bend_as_before_and_no_density(nominal):
    (unit,) = plan_units(nominal)
    p, k, q = domains.prior_materials(nominal, unit)
    # the draws of the two-axis prior (log-uniform over the training span, stream 11)
    span = np.log([WANG54.multipliers(c) for c in nominal.classes])
    for b, sim in enumerate(unit.sims):
        draw = np.random.default_rng([sim.seed, 11]).uniform(span.min(0), span.max(0))
        assert (p[b], k[b]) == tuple(np.exp(draw))
    assert q.tolist() == [1.0] * len(unit.sims)


def test_spanning_classes_span_stretch_and_bend_in_either_set():
    corners = {(s, b) for s in (0, 2, 5) for b in (0, 4, 8)}
    assert spanning_classes(tuple(range(54)), (3, 3)) == tuple(
        sorted(s * 9 + b for s, b in corners)
    )
    dense = spanning_classes(tuple(range(DENSE.num_classes)), (3, 3), DENSE)
    assert {DENSE.position(c) for c in dense} == {(s, b, 0) for s, b in corners}


def test_a_density_set_draws_each_cloths_density_over_the_sets_span(nominal, tmp_path):
    spec = dataclasses.replace(nominal, material_set=DENSE, classes=(0, 161))
    (unit,) = plan_units(spec)
    p, k, q = domains.prior_materials(spec, unit)
    p_nominal, k_nominal, _ = domains.prior_materials(nominal, unit)
    assert np.array_equal(p, p_nominal) and np.array_equal(k, k_nominal)  # same span
    assert ((q >= 0.4) & (q <= 1.2)).all() and len(set(q.tolist())) == len(q)
    clips = simulated_clips(spec, tmp_path / "meshes", clip_len=4, clip_stride=4)
    basis = load_wang_material(BASIS_MATERIAL).density
    by_sim = dict(zip([s.sim_id for s in unit.sims], q, strict=True))
    assert clips.density.tolist() == pytest.approx([basis * by_sim[g] for g in clips.groups])
    # the density moves the cloth; density 1 everywhere is the two-list form and its cache file
    cache = tmp_path / "cache"
    moved = simulate_unit(spec, unit, cache, multipliers=(p, k, q))
    light = simulate_unit(spec, unit, cache, multipliers=(p, k, np.ones_like(q)))
    assert not np.allclose(moved.pos, light.pos, atol=1e-4)
    files = sorted(cache.rglob("*.npz"))
    assert len(files) == 2
    assert np.array_equal(simulate_unit(spec, unit, cache, multipliers=(p, k)).pos, light.pos)
    assert sorted(cache.rglob("*.npz")) == files


def test_a_density_variation_candidate_labels_each_cloth_with_the_density_it_was_given(
    nominal, tmp_path
):
    candidate = candidate_library(nominal)["physics.density_variation"]
    spec = candidate.apply(nominal, 1.0)
    (unit,) = plan_units(spec)
    clips = simulated_clips(spec, tmp_path / "meshes", clip_len=4, clip_stride=4)
    factors = dict(
        zip(
            [s.sim_id for s in unit.sims],
            spec.physics.density_factors([s.seed for s in unit.sims]),
            strict=True,
        )
    )
    basis = load_wang_material(BASIS_MATERIAL).density
    assert clips.density.tolist() == pytest.approx([basis * factors[g] for g in clips.groups])
    assert np.ptp(clips.density) > 0.01
