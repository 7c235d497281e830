"""Look candidates: the cloth's texture family and the backdrop, re-rendered on cached meshes."""

import dataclasses

import numpy as np
import pytest

import render.backgrounds as backgrounds
import sim2real.domains as domains
from datasets.generation import _BACKGROUND_STREAM, sim_look
from datasets.plan import plan_units
from datasets.spec import PRESETS, DatasetSpec
from render.backgrounds import BACKDROPS, backdrop_kinds, make_background
from render.camera import CameraSpec
from sim2real.candidates import candidate_library, select_candidates
from sim2real.domains import simulated_clips
from sim2real.study.seal import _base_spec
from simulator.cloth.scenes import ScenarioArmBend, ScenarioWind

SPEC = DatasetSpec(
    motion="wind", scenario=ScenarioWind(resolution_level=1), preset=PRESETS["small"]
)
LOOKS = ("look.texture_mode", "look.backdrop")


def test_the_library_lists_texture_family_and_backdrop_as_appearance_candidates():
    library = candidate_library(SPEC)
    texture, backdrop = library["look.texture_mode"], library["look.backdrop"]
    for candidate, field in ((texture, "texture_mode"), (backdrop, "backdrop")):
        assert (candidate.stage, candidate.registry, candidate.field) == (
            "appearance",
            "look",
            field,
        )
    assert texture.strengths(3) == ("grid", "color") and texture.default == "random"
    assert backdrop.strengths(3) == ("plain", "dark", "gradient") and backdrop.default == "bank"
    assert not texture.needs_simulation and not backdrop.needs_simulation
    assert not texture.binary and texture.neutral is None
    # the strengths are the choices other than the training data's
    grid = candidate_library(dataclasses.replace(SPEC, texture_mode="grid", backdrop="dark"))
    assert grid["look.texture_mode"].strengths(5) == ("color", "random")
    assert grid["look.backdrop"].strengths(5) == ("bank", "plain", "gradient")
    appearance = [c.name for c in select_candidates(library, ["appearance"])]
    assert appearance[:2] == list(LOOKS) and len(appearance) > 2
    arm = DatasetSpec(motion="arm", scenario=ScenarioArmBend(), preset=PRESETS["small"])
    assert set(LOOKS) <= set(candidate_library(arm))


def test_apply_changes_only_that_field_and_keeps_the_meshes():
    library = candidate_library(SPEC)
    for name, field in (("look.texture_mode", "texture_mode"), ("look.backdrop", "backdrop")):
        candidate = library[name]
        for value in candidate.strengths(3):
            changed = candidate.apply(SPEC, value)
            assert changed == dataclasses.replace(SPEC, **{field: value})
            assert changed.physics_key() == SPEC.physics_key()  # re-render, no simulation
            assert changed.key() != SPEC.key()
            assert candidate.label(value) == f"{name}({field}={value})"


def test_a_default_spec_keeps_the_key_it_had_before_the_backdrop():
    # Keys computed on main before the field existed (commit 96ff00d).
    arm = DatasetSpec(
        motion="arm", scenario=ScenarioArmBend(), preset=PRESETS["full"], texture_mode="grid"
    )
    assert (SPEC.key(), SPEC.physics_key()) == ("4258f236f4b63453", "a8c6c5c6be4e0dfc")
    assert _base_spec(None, 1).key() == "e29dd8acde6bb87b"
    assert (arm.key(), arm.physics_key()) == ("ddff94441adb4921", "ba249c210e2201bf")
    assert "backdrop" not in SPEC.to_json()
    plain = dataclasses.replace(SPEC, backdrop="plain")
    assert plain.to_json()["backdrop"] == "plain"
    assert DatasetSpec.from_json(plain.to_json()) == plain
    assert DatasetSpec.from_json(SPEC.to_json()).backdrop == "bank"  # an old spec.json


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda: dataclasses.replace(SPEC, backdrop="studio"), "backdrop"),
        (lambda: dataclasses.replace(SPEC, backdrop=["plain"]), "backdrop"),
        (lambda: dataclasses.replace(SPEC, texture_mode="plaid"), "texture_mode"),
        (lambda: backdrop_kinds("studio"), "backdrop"),
        (
            lambda: candidate_library(SPEC)["look.backdrop"].apply(SPEC, "studio"),
            "strength of look.backdrop",
        ),
        (
            lambda: candidate_library(SPEC)["look.texture_mode"].check_strength(None),
            "strength of look.texture_mode",
        ),
    ],
)
def test_bad_values_give_one_line_naming_the_field_and_the_allowed_values(call, field):
    with pytest.raises(ValueError) as error:
        call()
    message = str(error.value)
    assert message.startswith(field) and "\n" not in message
    allowed = BACKDROPS if "backdrop" in field else ("grid", "color", "random")
    assert all(repr(a) in message for a in allowed), message


def test_each_backdrop_draws_its_kinds_from_the_simulations_seed(monkeypatch):
    monkeypatch.setattr(backgrounds, "photos_available", lambda: False)  # as on any machine
    spec = dataclasses.replace(SPEC, camera=CameraSpec.wind(48, 48))
    sims = [s for unit in plan_units(spec) for s in unit.sims][:6]
    looks = {
        b: [sim_look(dataclasses.replace(spec, backdrop=b), s)[1] for s in sims] for b in BACKDROPS
    }
    for sim, bank in zip(sims, looks["bank"], strict=True):  # the bank's bytes of before
        rng = np.random.default_rng([sim.seed, _BACKGROUND_STREAM])
        assert np.array_equal(bank, make_background(rng, 48, 48))
        rng = np.random.default_rng([sim.seed, _BACKGROUND_STREAM])
        gradient = make_background(rng, 48, 48, kinds=["gradient"])
        assert np.array_equal(looks["gradient"][sims.index(sim)], gradient)
    for name in ("plain", "dark"):
        images = np.stack(looks[name]).astype(float)
        assert images.std(axis=(1, 2)).max() < 4.0  # uniform up to the grain
        means = images.mean(axis=(1, 2))
        assert len({tuple(m.round()) for m in means}) == len(sims)  # one colour per simulation
    assert np.stack(looks["dark"]).mean() < 40 < np.stack(looks["plain"]).mean()
    assert np.stack(looks["bank"]).astype(float).std(axis=(1, 2)).max() > 4.0
    # the texture family is the spec's too; the background does not depend on it
    grid = dataclasses.replace(spec, texture_mode="grid")
    texture, background = sim_look(grid, sims[0])
    assert np.array_equal(background, looks["bank"][0])
    assert not np.array_equal(texture, sim_look(spec, sims[0])[0])


@pytest.mark.render
def test_a_plain_backdrop_renders_a_uniform_background_around_the_cloth(nominal, tmp_path):
    library = candidate_library(nominal)
    plain = simulated_clips(library["look.backdrop"].apply(nominal, "plain"), tmp_path, clip_len=4)
    bank = simulated_clips(nominal, tmp_path, clip_len=4)
    assert len(list(tmp_path.iterdir())) == 1  # one mesh folder: the look re-renders
    for clips, uniform in ((plain, True), (bank, False)):
        for frames, coverage in zip(clips.frames, clips.coverage, strict=True):
            outside = frames[coverage == 0].astype(float)  # (pixels, 3) over the clip's frames
            assert len(outside) > 0.3 * coverage.size  # the cloth leaves a margin
            assert (outside.std(axis=0).max() < 4.0) == uniform
            assert (coverage == 255).sum() > 0.05 * coverage.size  # the cloth is there
    # the cloth itself is the same in front of another backdrop
    inside = (plain.coverage == 255) & (bank.coverage == 255)
    assert np.array_equal(plain.coverage, bank.coverage)
    assert np.abs(plain.frames[inside].astype(int) - bank.frames[inside]).mean() < 3.0


@pytest.mark.render
def test_the_render_cache_never_serves_the_render_of_another_look(nominal, tmp_path, monkeypatch):
    meshes, renders = tmp_path / "meshes", tmp_path / "renders"
    library = candidate_library(nominal)
    noisy = library["visual.sensor_noise"].apply(nominal, 4.0)  # shares the render before noise
    specs = {
        "nominal": noisy,
        "plain": library["look.backdrop"].apply(noisy, "plain"),
        "dark": library["look.backdrop"].apply(noisy, "dark"),
        "color": library["look.texture_mode"].apply(noisy, "color"),
    }
    cached = {
        n: simulated_clips(s, meshes, clip_len=4, render_cache=renders) for n, s in specs.items()
    }
    assert len(list(meshes.iterdir())) == 1  # every look re-renders the same meshes
    assert len(list(renders.iterdir())) == 2 * len(specs)  # a render per look and simulation
    for name, spec in specs.items():
        whole = simulated_clips(spec, meshes, clip_len=4)  # rendered whole, no cache
        assert np.array_equal(cached[name].frames, whole.frames), name
    frames = [c.frames for c in cached.values()]
    assert all(not np.array_equal(a, b) for i, a in enumerate(frames) for b in frames[i + 1 :])
    # a second pass reads every look's own render back, rendering nothing

    def no_render(*args, **kwargs):
        raise AssertionError("rendered again although the render is stored")

    monkeypatch.setattr(domains, "render_frames", no_render)
    again = {
        n: simulated_clips(s, meshes, clip_len=4, render_cache=renders) for n, s in specs.items()
    }
    assert len(list(renders.iterdir())) == 2 * len(specs)
    assert all(np.array_equal(again[n].frames, cached[n].frames) for n in specs)


def test_the_library_listing_prints_and_writes_nothing(tmp_path):
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "sim2real.candidates", "texture=grid"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        check=True,
    )
    assert "look.texture_mode" in done.stdout
    assert list(tmp_path.iterdir()) == []  # no log file, no run folder
