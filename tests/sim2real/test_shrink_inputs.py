"""The shrink command's own fields: one line naming the field, before any work."""

import subprocess
import sys

import pytest


@pytest.mark.parametrize(
    ("override", "field"),
    [
        ("columns=[]", "columns"),
        ("columns=stiffness", "columns"),
        ("group=[a]", "group"),
        ("data_preset=huge", "data_preset"),
        ("control=maybe", "control"),
        ("lr_scale=0", "lr_scale"),
        ("lr_scale=2", "lr_scale"),
        ("init=random", "init"),
        ("use_effects=[a]", "use_effects"),
        ("retrain_material_set=wang999", "retrain_material_set"),
        ("retrain_material_set=../wang162", "retrain_material_set"),
    ],
)
def test_shrink_names_a_bad_field(tmp_path, override, field):
    done = subprocess.run(
        [sys.executable, "-m", "sim2real.shrink", f"report={tmp_path}", override],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode != 0
    assert done.stderr.strip().splitlines()[-1].startswith(f"error: {field} must be")
    assert "Traceback" not in done.stderr


def test_the_documented_effects_override_reaches_the_command(tmp_path):
    """``use_effects`` is a plain key (``effects`` would collide with the config group)."""
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "sim2real.shrink",
            f"report={tmp_path}",
            'use_effects="visual.sensor_noise=3.0,physics.air_damping=0.05"',
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode != 0
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("error: report") and "Traceback" not in done.stderr, done.stderr


@pytest.mark.parametrize(
    ("shrink", "words"),
    [
        (
            {"epochs": 8, "lr_scale": 0.1, "control": {"is_the_run": False}},
            "model fine-tuned for 8 epochs from the run's weights at 0.1 of its training rate; "
            "as a control, fine-tuned as long from the same weights on the nominal data.",
        ),
        (
            {"epochs": 20, "init": "scratch", "lr_scale": 1.0, "control": {"is_the_run": True}},
            "a fresh model trained for 20 epochs with the run's recipe; its control is the run "
            "itself (trained as long on the nominal data).",
        ),
        (
            {"epochs": 5, "init": "scratch", "lr_scale": 1.0, "control": {"is_the_run": False}},
            "a fresh model trained for 5 epochs with the run's recipe; as a control, one trained "
            "as long afresh on the nominal data.",
        ),
        (
            {"epochs": 5, "init": "scratch", "control": None},
            "a fresh model trained for 5 epochs with the run's recipe.",
        ),
    ],
)
def test_the_report_says_how_the_model_after_was_trained(shrink, words):
    from sim2real.report import _retrain_words

    assert _retrain_words(shrink) == words


def test_a_density_axis_keeps_the_runs_cells_at_every_density():
    import dataclasses

    from datasets.spec import PRESETS, DatasetSpec
    from sim2real.shrink import on_material_set
    from simulator.cloth.material import WANG54, MaterialSet
    from simulator.cloth.scenes import ScenarioWind

    spec = DatasetSpec(motion="wind", scenario=ScenarioWind(), preset=PRESETS["small"])
    spec = dataclasses.replace(spec, classes=(0, 20, 53))
    dense = dataclasses.replace(WANG54, name="dense", density_multipliers=(0.5, 1.0, 2.0))
    every = on_material_set(spec, dense)
    assert every.material_set == dense and len(every.classes) == 9
    assert [dense.position(c) for c in every.classes[3:6]] == [(2, 2, d) for d in range(3)]
    first = on_material_set(spec, dense, every_density=False)
    assert first.classes == (0, 60, 159)
    other = MaterialSet("other", WANG54.basis, (1.0, 2.0), WANG54.bend_multipliers, (1.0, 2.0))
    with pytest.raises(ValueError, match="must keep the run's basis and stretch x bend grid"):
        on_material_set(spec, other)
