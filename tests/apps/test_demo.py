"""apps.demo (the main job) end to end on a tiny setting, and its checks of bad fields."""

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import apps.demo as demo
from common.errors import InputError
from datasets.preview import LABEL_WIDTH, label_height
from simulator.sequence import MeshSequence
from tests.conftest import subprocess_env

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = str(ROOT / "configs")
SIZE = 32  # px, frame side
TINY = [
    "classes=[0,53]",
    "level=1",
    "scenario.settle_time=0.1",
    "fps=15",
    "record_time=0.2",
    f"render.camera.width={SIZE}",
    f"render.camera.height={SIZE}",
    "texture_size=32",
    "sheet_frames=3",
]
FRAMES = 4  # round(0.2 s x 15 fps) + 1: frame 0 is the rest state


def _compose(*overrides):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name="demo", overrides=list(overrides))


@pytest.mark.render
def test_tiny_demo_writes_a_labelled_sheet_a_video_and_the_sequence(tmp_path, capsys):
    out = demo.run(_compose(f"paths.output_dir={tmp_path}", *TINY))
    assert (out.sheet, out.video, out.sequence) == (
        tmp_path / "contact_sheet.png",
        tmp_path / "classes.mp4",
        tmp_path / "sequence.npz",
    )
    # Nothing else: no temporary files are left behind.
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "classes.mp4",
        "contact_sheet.png",
        "sequence.npz",
    ]

    sequence = MeshSequence.load(out.sequence)
    assert sequence.labels == [0, 53] and sequence.pos.shape[1] == FRAMES
    assert sequence.wind_levels == [2, 2]

    sheet = cv2.imread(str(out.sheet))
    assert sheet is not None
    assert sheet.shape[1] == LABEL_WIDTH + 3 * SIZE + 4  # label panel, 3 frames, white gap
    assert sheet.shape[0] == 2 * (SIZE + 2)  # one row per class
    label = sheet[:SIZE, :LABEL_WIDTH]
    assert (label > 200).any(), "the class label is not drawn"

    video = cv2.VideoCapture(str(out.video))
    assert video.isOpened()
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == FRAMES
    assert int(video.get(cv2.CAP_PROP_FRAME_WIDTH)) == 2 * SIZE + 4  # two tiles side by side
    strip = label_height(3)
    assert int(video.get(cv2.CAP_PROP_FRAME_HEIGHT)) == strip + SIZE
    ok, frame = video.read()
    assert ok and (frame[:strip] > 200).any(), "the tiles' labels are not drawn"
    assert np.ptp(frame[strip:]) > 0, "the rendered frames are blank"

    printed = capsys.readouterr().out
    for path in (out.sheet, out.video, out.sequence):
        assert str(path) in printed
    assert "classes 0, 53" in printed


def _refuse_to_simulate(*args, **kwargs):
    raise AssertionError("the simulation ran although a field was bad")


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("classes=[1.7]", r"classes[0] must be an integer class id in [0, 53], got 1.7"),
        ("classes=[0,0]", "classes must not repeat a class id"),
        ("level=4", "level must be an integer in [1, 3], got 4"),
        ("wind_level=3", "wind_level must be an integer in [0, 2], got 3"),
        ("fps=abc", "fps must be a finite number > 0, got 'abc'"),
        ("record_time=0.01", "record_time must span at least one frame interval"),
        ("sheet_frames=0", "sheet_frames must be an integer >= 1, got 0"),
        ("texture=plaid", "texture must be one of grid, color, random"),
        ("threads=0", "threads must be an integer >= 1 or null"),
        ("render.camera.width=abc", "render.camera.width must be an integer, got 'abc'"),
    ],
)
def test_bad_fields_are_refused_before_anything_runs(override, message, tmp_path, monkeypatch):
    monkeypatch.setattr(demo, "simulate_unit", _refuse_to_simulate)
    with pytest.raises(InputError) as info:
        demo.run(_compose(f"paths.output_dir={tmp_path}", override))
    assert str(info.value).startswith(message)
    assert list(tmp_path.iterdir()) == []


def test_the_command_prints_one_line_for_a_bad_field(tmp_path):
    env = subprocess_env()
    done = subprocess.run(
        [sys.executable, "-m", "apps.demo", "classes=[1.7]", f"paths.root_dir={tmp_path}"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        "error: classes[0] must be an integer class id in [0, 53], got 1.7"
    ]
    written = [p for p in tmp_path.rglob("*") if p.is_file() and ".hydra" not in p.parts]
    assert [p for p in written if p.suffix != ".log"] == []


def test_default_config_passes_the_field_checks():
    spec, unit, fields = demo._checked(_compose("paths.output_dir=/tmp/unused"))
    assert spec.classes == (0, 26, 53) and spec.scenario.resolution_level == 1
    assert [sim.wind_level for sim in unit.sims] == [2, 2, 2]
    assert spec.frames_per_sim == 121 and fields["threads"] == 1
