"""Scenes, rollouts, effects, batch consistency, determinism and monotone material response."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from simulator.cloth.effects import PHYSICS_EFFECT_NAMES, PhysicsEffects
from simulator.cloth.material import CLASS_COUNT, ClothMaterial, load_wang_material
from simulator.cloth.model import build_cloth_model
from simulator.cloth.rollout import SimSettings, replay_capsules, simulate, with_capsules
from simulator.cloth.scenes import (
    RESOLUTION_LEVELS,
    WIND_POSES,
    ScenarioArmBend,
    ScenarioWind,
    stroke_profile,
)
from simulator.cloth.sensitivity import bend_test, stretch_test
from simulator.integrators import IntegratorBackwardEuler, SimulationDiverged
from simulator.mesh import TriMesh
from simulator.model import SimControl, SimState
from simulator.sequence import MeshSequence
from tests.conftest import assert_close

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
FAST = {"resolution_level": 1, "settle_time": 0.1}


def _scenario(name, **kw):
    cfg = yaml.safe_load((CONFIGS / "scene" / f"{name}.yaml").read_text())
    target = cfg.pop("_target_")
    cls = {
        "simulator.cloth.scenes.ScenarioWind": ScenarioWind,
        "simulator.cloth.scenes.ScenarioArmBend": ScenarioArmBend,
    }[target]
    return cls(**{**cfg, **kw})


def _run(
    scenario, classes, *, record_time=0.2, seeds=None, effects=None, settings=None, levels=None
):
    return simulate(
        scenario,
        ClothMaterial.from_classes(classes),
        seeds=seeds if seeds is not None else list(range(len(classes))),
        wind_levels=levels if levels is not None else [2] * len(classes),
        fps=30,
        record_time=record_time,
        effects=effects,
        settings=settings,
        labels=classes,
    )


@pytest.mark.parametrize("name", sorted(p.stem for p in (CONFIGS / "scene").glob("*.yaml")))
def test_every_scenario_config_runs_and_stays_sane(name):
    scene = _scenario(name, **FAST)
    seq = _run(scene, [0, 53], record_time=0.3)
    pos = seq.pos
    assert np.isfinite(pos).all()
    assert pos[..., 2].min() > 0.2, "cloth fell through the floor level"
    assert np.abs(pos[..., :2]).max() < 1.0, "cloth left the scene's bounding box"
    assert seq.frame_count == 10


def test_scenes_settle_before_recording():
    scene = _scenario("wind", resolution_level=1, settle_time=1.0)
    seq = _run(scene, [0, 53], record_time=1 / 30)
    speed = np.linalg.norm(seq.pos[:, 1] - seq.pos[:, 0], axis=-1).max() * 30
    assert speed < 0.05, f"cloth still moving at {speed:.3f} m/s after settling"


def test_batch_of_54_equals_single_runs_and_is_permutation_invariant():
    scene = ScenarioWind(resolution_level=1, settle_time=0.05)
    classes = list(range(CLASS_COUNT))
    levels = [c % 3 for c in classes]
    seeds = [100 + c for c in classes]
    batch = _run(scene, classes, record_time=0.1, seeds=seeds, levels=levels)
    for c in (0, 31, 53):
        alone = _run(scene, [c], record_time=0.1, seeds=[seeds[c]], levels=[levels[c]])
        assert_close(
            batch.pos[c], alone.pos[0], f"class {c} batched vs alone", rtol=1e-6, atol=1e-7
        )
    perm = [53, 0, 31]
    permuted = _run(
        scene,
        perm,
        record_time=0.1,
        seeds=[seeds[c] for c in perm],
        levels=[levels[c] for c in perm],
    )
    assert_close(permuted.pos, batch.pos[perm], "permuted batch", rtol=1e-6, atol=1e-7)


def test_same_seed_same_bytes(tmp_path):
    scene = ScenarioWind(resolution_level=1, settle_time=0.05)
    effects = PhysicsEffects(gusty_wind=True)
    a = _run(scene, [5, 40], effects=effects, seeds=[1, 2]).save(tmp_path / "a.npz")
    b = _run(scene, [5, 40], effects=effects, seeds=[1, 2]).save(tmp_path / "b.npz")
    assert a.read_bytes() == b.read_bytes()
    c = _run(scene, [5, 40], effects=effects, seeds=[1, 3])
    assert not np.array_equal(MeshSequence.load(a).pos, c.pos)


def test_sequence_round_trip_and_export(tmp_path):
    seq = _run(ScenarioWind(resolution_level=1, settle_time=0.05), [7], record_time=0.1)
    path = seq.save(tmp_path / "seq.npz")
    loaded = MeshSequence.load(path)
    assert np.array_equal(loaded.pos, seq.pos)
    assert loaded.labels == [7] and loaded.meta["scene"] == "wind"
    assert loaded.meta["effects"] == dataclasses.asdict(PhysicsEffects())
    files = loaded.export(tmp_path / "obj", fmt="obj")
    assert len(files) == seq.frame_count and files[0].read_text().count("\nv ") == 256
    from simulator.export import main as export_main

    files = export_main([str(path), str(tmp_path / "ply"), "--format", "ply"])
    assert len(files) == seq.frame_count and files[-1].stat().st_size > 0
    bad = dataclasses.replace(seq, pos=seq.pos * np.nan)
    with pytest.raises(ValueError, match="NaN"):
        bad.save(tmp_path / "nan.npz")
    assert not (tmp_path / "nan.npz").exists()


def test_arm_sequences_carry_the_capsules_the_driver_moved(tmp_path):
    """The recorded obstacles equal a replay of the scene's driver at the frame times (the
    reference), survive a round trip, and wind sequences have none."""
    scene = ScenarioArmBend(resolution_level=1, settle_time=0.1)
    seq = _run(scene, [3, 50], record_time=0.3)
    assert seq.capsules.shape == (2, seq.frame_count, 2, 7) and seq.capsules.dtype == np.float32
    replayed = replay_capsules(seq)
    np.testing.assert_array_equal(seq.capsules, replayed)
    assert not np.array_equal(seq.capsules[:, 0], seq.capsules[:, -1])  # the arm moved
    loaded = MeshSequence.load(seq.save(tmp_path / "arm.npz"))
    np.testing.assert_array_equal(loaded.capsules, seq.capsules)
    older = dataclasses.replace(seq, capsules=None)  # a file written before capsules were kept
    np.testing.assert_array_equal(with_capsules(older).capsules, seq.capsules)
    wind = _run(ScenarioWind(resolution_level=1, settle_time=0.05), [7], record_time=0.1)
    assert wind.capsules is None and replay_capsules(wind) is None
    with pytest.raises(ValueError, match="capsules"):
        dataclasses.replace(seq, capsules=seq.capsules[:, :1]).save(tmp_path / "bad.npz")
    assert not (tmp_path / "bad.npz").exists()


def test_replayed_capsules_follow_the_arm_stroke():
    scenario = ScenarioArmBend(resolution_level=1)
    mesh = scenario.mesh()
    pos = mesh.vert_pos.float().numpy()
    seq = MeshSequence(
        pos=np.broadcast_to(pos, (1, 11, *pos.shape)).copy(),
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
    capsules = replay_capsules(seq)
    assert capsules.shape == (1, 11, 2, 7)
    np.testing.assert_allclose(capsules[0, 0, 1, 3:6], [0.28, 0.0, 1.0], atol=1e-5)  # straight
    np.testing.assert_allclose(capsules[0, -1, 1, 3:6], [0.0, 0.0, 1.28], atol=1e-5)  # flexed
    np.testing.assert_allclose(capsules[0, :, 0, 6], 0.045, atol=1e-7)


@pytest.mark.parametrize("effect", [e for e in PHYSICS_EFFECT_NAMES if e != "self_collision"])
def test_each_effect_switch_changes_the_motion(effect):
    scene = ScenarioWind(resolution_level=1, settle_time=0.05)
    base = _run(scene, [20], record_time=0.2)
    default = getattr(PhysicsEffects(), effect)
    effects = PhysicsEffects(**{effect: not default})
    changed = _run(scene, [20], record_time=0.2, effects=effects)
    assert np.isfinite(changed.pos).all()
    assert np.abs(changed.pos - base.pos).max() > 1e-6, f"{effect} had no effect"


def test_self_collision_keeps_folded_layers_apart():
    """A sheet folded in half: the free top layer falls onto the pinned bottom layer."""
    n = 9
    grid = TriMesh.grid(n, size_u=0.1)
    u, v = grid.uv[:, 0], grid.uv[:, 1]
    top = v > 0.05 + 1e-9
    pos = torch.stack([u, torch.where(top, 0.1 - v, v), torch.where(top, 0.015, 0.0)], -1)
    mesh = TriMesh.from_arrays(pos.numpy(), grid.tri_indices.numpy(), grid.uv.numpy())
    pins = torch.nonzero(v <= 0.05 + 1e-9).flatten()
    results = {}
    for on in (False, True):
        effects = PhysicsEffects(self_collision=on, self_collision_radius=0.008)
        model = build_cloth_model(mesh, ClothMaterial.from_classes([20]), pins, effects=effects)
        state = SimState(
            pos[None].clone(),
            torch.zeros(1, n * n, 3, dtype=torch.float64),
            torch.zeros(1, dtype=torch.float64),
        )
        control = SimControl(pin_pos=pos[None, pins])
        integ = IntegratorBackwardEuler()
        for _ in range(60):
            state, _ = integ.step(model, state, control, 0.005)
        results[on] = state.pos[0, top, 2].min().item()
    assert results[False] < -0.003, results  # passes through the bottom layer
    assert results[True] > 0.004, results  # held about one radius above it


def test_divergence_is_reported_with_instance_and_step():
    scene = ScenarioWind(resolution_level=1, settle_time=0.0)
    with pytest.raises(SimulationDiverged, match=r"instance \d+ .* at step \d+"):
        _run(scene, [0, 1], settings=SimSettings(max_speed=1e-4))


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"resolution_level": 7}, "resolution_level"),
        ({"pose": "hung"}, "pose"),
        ({"wind_speeds": [3.0, 1.0]}, "wind_speeds"),
        ({"size": -1.0}, "size"),
    ],
)
def test_bad_scenario_values_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        ScenarioWind(**kwargs)


def test_wind_poses_pin_corners_clips_or_the_edge():
    n = RESOLUTION_LEVELS[1]
    pins = {p: ScenarioWind(resolution_level=1, pose=p).pin_indices().tolist() for p in WIND_POSES}
    assert pins == {
        "corners": [0, n - 1],
        "clips": [0, (n - 1) // 2, n - 1],
        "edge": list(range(n)),
    }
    # The middle clip holds the top edge up: a quarter along it, it sags less than when it
    # hangs between the two corners alone.
    sag = {}
    for pose in ("corners", "clips"):
        scene = ScenarioWind(resolution_level=1, pose=pose, settle_time=0.3)
        seq = _run(scene, [20], record_time=0.05)
        sag[pose] = scene.height - float(seq.pos[0, 0, n // 4, 2])
    assert 0 <= sag["clips"] < 0.5 * sag["corners"], sag


@pytest.mark.parametrize("strokes", [0, -1, 1.5, True])
def test_bad_arm_strokes_name_the_field(strokes):
    with pytest.raises(ValueError, match=r"scenario\.strokes"):
        ScenarioArmBend(strokes=strokes)


@pytest.mark.parametrize("strokes", [1, 2, 3])
def test_stroke_profile_is_c1_with_its_analytic_rate(strokes):
    phases = np.linspace(-0.5, strokes + 0.5, 2001)
    values = np.array([stroke_profile(p, strokes)[0] for p in phases])
    rates = np.array([stroke_profile(p, strokes)[1] for p in phases])
    h = 1e-6
    fd = np.array(
        [
            (stroke_profile(p + h, strokes)[0] - stroke_profile(p - h, strokes)[0]) / (2 * h)
            for p in phases
        ]
    )
    assert np.abs(fd - rates).max() < 1e-5, "rate is not the derivative of the profile"
    assert np.abs(np.diff(values)).max() < 0.01, "profile jumps"
    assert values.min() == 0.0 and values.max() == 1.0
    # rests at the end of every stroke: fully flexed after odd strokes, straight after even
    for k in range(1, strokes + 1):
        assert stroke_profile(float(k), strokes) == (float(k % 2), 0.0)
    assert stroke_profile(strokes + 3.0, strokes)[0] == strokes % 2


def test_one_stroke_is_the_single_flexion_and_more_strokes_extend_the_arm():
    once = ScenarioArmBend(resolution_level=1, settle_time=0.0, bend_time=0.5)
    thrice = dataclasses.replace(once, strokes=3)
    material = ClothMaterial.from_classes([0])
    pos = torch.zeros(1, 0, 3, dtype=torch.float64)

    def wrist_height(scene, time):
        driver = scene.build(material, seeds=[0])[2]
        return float(driver.control(time, pos).capsules[0, 1, 5])

    top = once.arm_height + once.forearm_length  # 90 degrees: the wrist straight above
    assert wrist_height(once, 0.5) == pytest.approx(top)
    assert wrist_height(once, 1.0) == pytest.approx(top)
    assert wrist_height(thrice, 0.5) == pytest.approx(top)
    assert wrist_height(thrice, 1.0) == pytest.approx(once.arm_height)  # extended again
    assert wrist_height(thrice, 1.5) == pytest.approx(top)
    for t in (0.1, 0.25, 0.4):  # the first stroke is the single flexion
        assert wrist_height(thrice, t) == pytest.approx(wrist_height(once, t))


def test_bad_settings_and_effects_name_the_field():
    with pytest.raises(ValueError, match="max_dt"):
        SimSettings(max_dt=0)
    with pytest.raises(ValueError, match="unknown"):
        PhysicsEffects.from_dict({"magnetism": True})
    with pytest.raises(ValueError, match="wind_level"):
        _run(ScenarioWind(resolution_level=1), [0], levels=[5])


def test_sag_decreases_with_stretch_and_curvature_with_bend():
    basis = load_wang_material("camel-ponte-roma")
    mults = [0.5, 1, 2, 3, 10, 20]
    sag = stretch_test(ClothMaterial.from_wang(basis, stretch_mult=mults)).numpy()
    assert (np.diff(sag) < 0).all(), sag
    curv = bend_test(ClothMaterial.from_wang(basis, bend_mult=mults)).numpy()
    assert (np.diff(curv) < 0).all(), curv


def test_mass_spring_model_runs_and_differs():
    scene = ScenarioWind(resolution_level=1, settle_time=0.05)
    shell = _run(scene, [10], record_time=0.2)
    springs = _run(scene, [10], record_time=0.2, settings=SimSettings(cloth_model="mass_spring"))
    assert np.isfinite(springs.pos).all()
    assert np.abs(springs.pos - shell.pos).max() > 1e-4
    with pytest.raises(ValueError, match="cloth model"):
        _run(scene, [10], settings=SimSettings(cloth_model="fem"))


GRID_CORNERS = [0, 8, 45, 53]
"""Softest/stiffest stretch x softest/stiffest bend: where instabilities show first."""


@pytest.mark.parametrize(
    "classes",
    [GRID_CORNERS, pytest.param(list(range(CLASS_COUNT)), marks=pytest.mark.slow, id="all54")],
    ids=lambda c: "corners" if c == GRID_CORNERS else None,
)
@pytest.mark.parametrize(("name", "extra"), [("wind", {}), ("arm_bend", {"bend_time": 0.4})])
def test_class_sweep_is_stable(name, extra, classes):
    scene = _scenario(name, resolution_level=1, settle_time=0.2, **extra)
    seq = _run(scene, classes, record_time=0.5, seeds=classes)
    assert np.isfinite(seq.pos).all()
    speed = np.linalg.norm(np.diff(seq.pos, axis=1), axis=-1).max() * 30
    assert speed < 20.0, f"max frame-to-frame speed {speed:.1f} m/s"


def test_cuda_matches_cpu_when_available():
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    scene = ScenarioWind(resolution_level=1, settle_time=0.05)
    cpu = _run(scene, [3, 44], settings=SimSettings(device="cpu"))
    gpu = _run(scene, [3, 44], settings=SimSettings(device="cuda"))
    assert_close(gpu.pos, cpu.pos, "cuda vs cpu", rtol=1e-5, atol=1e-6)


def test_float32_matches_float64():
    scene = ScenarioWind(resolution_level=1, settle_time=0.05)
    f64 = _run(scene, [3, 44], record_time=0.2)
    f32 = _run(scene, [3, 44], record_time=0.2, settings=SimSettings(dtype="float32"))
    assert np.isfinite(f32.pos).all()
    assert np.abs(f32.pos - f64.pos).max() < 2e-3, np.abs(f32.pos - f64.pos).max()


def test_density_scales_like_inverse_stiffness_at_rest_and_lighter_cloth_flutters_more():
    # Static hang under gravity alone: K(x) = rho g, so rho x q sags as stiffness / q does.
    basis = load_wang_material("camel-ponte-roma")
    heavy = stretch_test(ClothMaterial.from_wang(basis, density_mult=[1.0, 2.0, 4.0])).numpy()
    soft = stretch_test(
        ClothMaterial.from_wang(basis, stretch_mult=[1.0, 0.5, 0.25], bend_mult=[1.0, 0.5, 0.25])
    ).numpy()
    assert (np.diff(heavy) > 0).all(), heavy
    np.testing.assert_allclose(heavy, soft, rtol=1e-3)
    # In wind (a force per area, not per mass) the lighter cloth moves more.
    scene = ScenarioWind(resolution_level=1, settle_time=0.05)
    seq = simulate(
        scene,
        ClothMaterial.from_wang(basis, density_mult=[0.4, 1.2]),
        seeds=[3, 3],
        wind_levels=[2, 2],
        fps=30,
        record_time=0.4,
        labels=[0, 1],
    )
    speed = np.linalg.norm(np.diff(seq.pos, axis=1), axis=-1).mean(axis=(1, 2))
    assert speed[0] > 1.2 * speed[1], speed


def test_density_variation_is_the_cloth_at_its_seeds_density_factor():
    # The effect re-weighs each cloth; simulating that density directly gives the same bytes.
    basis = load_wang_material("camel-ponte-roma")
    effects = PhysicsEffects(density_variation=True, density_spread=0.8)
    seeds = [3, 11]
    factors = effects.density_factors(seeds)
    assert np.all(np.abs(np.log(factors)) <= 0.4) and abs(np.log(factors[0] / factors[1])) > 0.01
    for scene in (
        ScenarioWind(resolution_level=1, settle_time=0.05),
        ScenarioArmBend(resolution_level=1, settle_time=0.05, bend_time=0.1),
    ):
        run = {"seeds": seeds, "wind_levels": [2, 2], "fps": 30, "record_time": 0.2}
        one = ClothMaterial.from_wang(basis, density_mult=[1.0, 1.0])
        weighed = ClothMaterial.from_wang(basis, density_mult=factors.tolist())
        varied = simulate(scene, one, effects=effects, labels=[0, 1], **run)
        direct = simulate(scene, weighed, labels=[0, 1], **run)
        np.testing.assert_array_equal(varied.pos, direct.pos)


def test_density_factors_are_log_uniform_per_seed_and_ones_when_off():
    effects = PhysicsEffects(density_variation=True, density_spread=0.6)
    logs = np.log(effects.density_factors(range(4000)))
    assert logs.min() >= -0.3 and logs.max() <= 0.3
    assert abs(logs.mean()) < 0.01 and abs(logs.var() - 0.6**2 / 12) < 0.002  # uniform's moments
    # one draw per seed, whatever else is in the batch
    assert effects.density_factors([7, 8])[1] == effects.density_factors([8])[0]
    np.testing.assert_array_equal(PhysicsEffects().density_factors([1, 2]), [1.0, 1.0])
    with pytest.raises(ValueError, match=r"effects\.density_spread must be >= 0"):
        PhysicsEffects(density_spread=-0.1)
