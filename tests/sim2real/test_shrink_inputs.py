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
