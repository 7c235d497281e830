"""apps.clone (material cloning) end to end on a tiny trained run, and its refusals.

The run is trained in the test (one epoch on the tiny wind dataset, a narrow CNN+LSTM); the
input video is two of that dataset's rendered clips back to back (8 frames at 15 fps, two
4-frame clips), as a frame folder and as an mp4. The clones are simulated at mesh level 1
and rendered at 32 x 32. Every test that needs the run or the videos is marked ``render``
(the tiny dataset is rendered).
"""

import itertools
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf

import apps.clone as clone
from common.errors import InputError
from datasets.clip_dataset import ClothClipDataset
from datasets.preview import LABEL_WIDTH, label_height
from models.material_classifier import MaterialClassifierModule
from simulator.cloth.material import CLASS_COUNT, multipliers_from_class
from tests.conftest import subprocess_env
from tests.datasets.conftest import write_mp4

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = str(ROOT / "configs")
SIZE = 32  # px, side of the simulated tiles
FRAMES = 4  # shown: round(0.2 s x 15 fps) + 1
TINY = [
    "level=1",
    "scenario.settle_time=0.1",
    "fps=15",
    "record_time=0.2",
    "texture_size=32",
    f"render.camera.width={SIZE}",
    f"render.camera.height={SIZE}",
    "sheet_frames=3",
    "video_fps=15",
]
OUTPUTS = ["clone.mp4", "contact_sheet.png", "prediction.json", "sequence.npz"]


def _compose(*overrides):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name="clone", overrides=list(overrides))


@pytest.fixture(scope="module")
def trained(tiny_dataset, tmp_path_factory):
    """A run trained for one epoch on the tiny dataset, its config saved as Hydra saves it."""
    import models.training as train_entry

    run = tmp_path_factory.mktemp("clone") / "logs" / "train" / "tiny"
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose(
            config_name="train",
            overrides=[
                f"dataset.dir={tiny_dataset}",
                f"paths.output_dir={run}",
                f"paths.log_dir={run.parent}",
                f"paths.work_dir={run}",
                "encoder.width=0.25",
                "encoder.feature_dim=16",
                "model.net.hidden_size=16",
                "data.batch_size=2",
                "data.num_workers=0",
                "trainer.max_epochs=1",
                "~logger",
                "callbacks.progress_bar=null",
                "callbacks.lr_monitor=null",
                "test=false",
                "trainer.log_every_n_steps=1",
            ],
        )
    (run / ".hydra").mkdir(parents=True)
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
    train_entry.train(cfg)
    assert (run / "checkpoints" / "best.ckpt").is_file()
    return run


@pytest.fixture(scope="module")
def videos(tiny_dataset, tmp_path_factory):
    """Two rendered clips back to back: a folder of PNG frames and an mp4, both 15 fps."""
    data = ClothClipDataset(tiny_dataset, None)
    frames = np.concatenate([data.read(i)[1] for i in range(2)])  # RGB (8, 32, 32, 3)
    root = tmp_path_factory.mktemp("videos")
    folder = root / "frames"
    folder.mkdir()
    for t, frame in enumerate(frames):
        cv2.imwrite(str(folder / f"frame_{t:04d}.png"), frame[..., ::-1])
    write_mp4(root / "cloth.mp4", np.ascontiguousarray(frames[..., ::-1]), 15.0)
    return {"folder": folder, "mp4": root / "cloth.mp4", "frames": frames}


def _clone(out, video, run, *extra):
    return clone.run(
        _compose(f"paths.output_dir={out}", f"video={video}", f"run={run}", *TINY, *extra)
    )


@pytest.mark.render
def test_clone_of_a_frame_folder_writes_prediction_video_and_sheet(
    trained, videos, tmp_path, capsys
):
    out = _clone(tmp_path, videos["folder"], trained)
    assert sorted(p.name for p in tmp_path.iterdir()) == OUTPUTS  # no staging folder left
    assert all(p.stat().st_size > 0 for p in tmp_path.iterdir())
    printed = capsys.readouterr().out
    for path in (out.prediction, out.video, out.sheet, out.sequence):
        assert str(path) in printed

    report = json.loads(out.prediction.read_text())
    assert report["video"] == str(videos["folder"])
    assert report["clips"] == {
        "count": 2,
        "start_frames": [0, 4],
        "clip_len": 4,
        "clip_stride": 4,
        "target_fps": 15.0,
        "size": 32,
    }
    assert report["run"]["checkpoint"] == str(trained / "checkpoints" / "best.ckpt")
    probs = np.array(report["probabilities"])
    assert probs.shape == (CLASS_COUNT,) and abs(probs.sum() - 1) < 1e-9
    top = report["top5"]
    assert [e["class"] for e in top] == list(np.argsort(-probs, kind="stable")[:5])
    assert all(a["probability"] >= b["probability"] for a, b in itertools.pairwise(top))
    predicted = report["predicted"]
    assert predicted["class"] == int(np.argmax(probs)) == top[0]["class"]
    assert (predicted["stretch_multiplier"], predicted["bend_multiplier"]) == (
        multipliers_from_class(predicted["class"])
    )
    assert report["scores"]["predicted_class"] == predicted["class"]
    assert 0 <= report["scores"]["material_score"] <= CLASS_COUNT - 1

    chosen = [e["class"] for e in report["comparison"]["classes"]]
    assert tuple(chosen) == out.classes and len(set(chosen)) == 3
    assert chosen[0] == predicted["class"]
    neighbours = clone.grid_neighbours(chosen[0])
    assert set(chosen[1:]) <= set(neighbours)
    others = [probs[c] for c in neighbours if c not in chosen]
    assert all(probs[c] >= max(others, default=0.0) for c in chosen[1:])
    assert [e["role"] for e in report["comparison"]["classes"]] == [
        "predicted",
        "neighbour",
        "neighbour",
    ]
    assert report["simulation"]["motion"] == "arm" and report["simulation"]["frames"] == FRAMES

    video = cv2.VideoCapture(str(out.video))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == FRAMES
    assert int(video.get(cv2.CAP_PROP_FRAME_WIDTH)) == 4 * SIZE + 3 * 4  # input + 3 classes
    strip = label_height(4)
    assert int(video.get(cv2.CAP_PROP_FRAME_HEIGHT)) == strip + SIZE
    ok, frame = video.read()
    assert ok and (frame[:strip] > 200).any(), "the tiles' labels are not drawn"
    for tile in range(4):
        pixels = frame[strip:, tile * (SIZE + 4) : tile * (SIZE + 4) + SIZE]
        assert np.ptp(pixels) > 0, f"tile {tile} is blank"

    sheet = cv2.imread(str(out.sheet))
    assert sheet.shape[:2] == (4 * (SIZE + 2), LABEL_WIDTH + 3 * SIZE + 4)  # 4 labelled rows
    marked = sheet[SIZE + 2, : LABEL_WIDTH // 2]  # top edge of the predicted row's label
    assert (marked[:, 2] > 200).all() and (marked[:, 0] < 100).all(), "prediction not outlined"


@pytest.mark.render
def test_clone_of_an_mp4_and_the_same_input_gives_the_same_prediction(trained, videos, tmp_path):
    first = _clone(tmp_path / "a", videos["mp4"], trained)
    again = _clone(tmp_path / "b", videos["mp4"], trained)
    report = json.loads(first.prediction.read_text())
    assert report["video_fps"] == 15.0 and report["video_frames"] == 8
    assert report["clips"]["count"] == 2
    assert first.prediction.read_bytes() == again.prediction.read_bytes()
    assert first.classes == again.classes


@pytest.mark.render
def test_a_failure_while_writing_leaves_no_output(trained, videos, tmp_path, monkeypatch):
    def fail(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(clone, "write_png", fail)  # after prediction.json and clone.mp4
    with pytest.raises(RuntimeError, match="disk full"):
        _clone(tmp_path, videos["folder"], trained)
    assert list(tmp_path.iterdir()) == []  # neither the staged files nor their folder


@pytest.mark.render
def test_prediction_is_deterministic_and_sees_the_training_clips(trained, videos):
    found = clone.find_run(trained)
    assert found.checkpoint == trained / "checkpoints" / "best.ckpt"
    assert found.spec.preset.frames_per_clip == 4 and found.spec.camera.height == 32
    module = clone.load_checked_classifier(found)
    clips = clone.VideoClips(
        videos["folder"], fps=15, clip_len=4, clip_stride=2, target_fps=15, size=32
    )
    assert [start for _, start in clips.clips] == [0, 2, 4]
    np.testing.assert_array_equal(clips.read_frames(2), videos["frames"][4:])
    one = clone.predict_video(module, clips, device=torch.device("cpu"))
    two = clone.predict_video(module, clips, batch_size=1, device=torch.device("cpu"))
    np.testing.assert_allclose(one.probabilities, two.probabilities, rtol=0, atol=1e-6)
    assert one.predicted_class == two.predicted_class
    assert one.start_frames == (0, 2, 4)


@pytest.mark.render
def test_display_frames_play_the_video_in_real_time(videos):
    clips = clone.VideoClips(
        videos["folder"], fps=15, clip_len=4, clip_stride=4, target_fps=15, size=32
    )
    slow = clone.display_frames(clips, 6, 30.0, 32)  # 15 fps shown at 30: each frame twice
    np.testing.assert_array_equal(slow, videos["frames"][[0, 0, 1, 1, 2, 2]])
    long = clone.display_frames(clips, 10, 15.0, 32)  # longer than the video: holds the last
    np.testing.assert_array_equal(long, videos["frames"][[0, 1, 2, 3, 4, 5, 6, 7, 7, 7]])


def test_grid_neighbours_are_one_step_away():
    assert clone.grid_neighbours(0) == (1, 9)
    assert clone.grid_neighbours(53) == (44, 52)
    assert clone.grid_neighbours(8) == (7, 17)
    assert clone.grid_neighbours(22) == (13, 21, 23, 31)
    for c in range(CLASS_COUNT):
        for n in clone.grid_neighbours(c):
            (s, b), (t, d) = divmod(c, 9), divmod(n, 9)
            assert abs(s - t) + abs(b - d) == 1


def test_comparison_takes_the_two_most_probable_neighbours():
    probs = np.full(CLASS_COUNT, 0.01)
    probs[22], probs[31], probs[40], probs[5] = 0.3, 0.1, 0.2, 0.25  # 40, 5: not neighbours
    assert clone.comparison_classes(probs / probs.sum()) == (22, 31, 13)  # 13 ties 21, 23
    assert clone.comparison_classes(np.full(CLASS_COUNT, 1 / CLASS_COUNT)) == (0, 1, 9)


def _refuse_to_work(*args, **kwargs):
    raise AssertionError("the video was predicted or simulated although an input was bad")


@pytest.fixture
def bad(tmp_path, trained, videos, tiny_dataset):
    """Bad inputs of each kind, built in ``tmp_path/in`` (outputs go to ``tmp_path/out``)."""
    root = tmp_path / "in"
    root.mkdir()
    (root / "garbage.mp4").write_bytes(b"not a video at all" * 100)
    (root / "notes.txt").write_text("hello")
    (root / "empty").mkdir()
    short = root / "short"
    short.mkdir()
    for name in sorted(os.listdir(videos["folder"]))[:3]:
        shutil.copy(videos["folder"] / name, short / name)
    no_config = root / "no_config" / "checkpoints"
    no_config.mkdir(parents=True)
    shutil.copy(trained / "checkpoints" / "best.ckpt", no_config / "last.ckpt")
    (root / "empty_run").mkdir()
    (root / "broken.ckpt").write_bytes(b"\x00" * 64)
    config = {
        "_target_": "models.components.video_nets.CNNLSTMNet",
        "num_classes": 2,
        "encoder": {
            "_target_": "models.components.frame_encoder.FrameEncoder",
            "name": "alexnet5",
            "feature_dim": 16,
            "width": 0.25,
        },
        "hidden_size": 16,
    }
    module = MaterialClassifierModule(instantiate(config), net_config=config)
    torch.save(
        {"hyper_parameters": {"net_config": config}, "state_dict": module.state_dict()},
        root / "two_classes.ckpt",
    )
    return {"in": root, "run": trained, "video": videos["folder"], "data": tiny_dataset}


@pytest.mark.render
@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["video={in}/missing.mp4"], "video: {in}/missing.mp4 does not exist; give a video file"),
        (["video={in}/garbage.mp4"], "video: cannot open video {in}/garbage.mp4"),
        (["video={in}/notes.txt"], "video: {in}/notes.txt is not a video file; give a video"),
        (["video={in}/empty"], "video: folder {in}/empty holds no frames"),
        (["video={in}/short"], "video: {in}/short has 3 frames at 15 fps; one clip of 4 frames"),
        (["run={in}/missing"], "run: {in}/missing does not exist; give a training run folder"),
        (["run={in}/empty_run"], "run: {in}/empty_run has no checkpoints/best.ckpt or"),
        (["run={in}/no_config"], "run: {in}/no_config has no .hydra/config.yaml"),
        (
            ["run={in}/broken.ckpt", "data_dir={data}"],
            "run: {in}/broken.ckpt is not a torch checkpoint",
        ),
        (
            ["run={in}/two_classes.ckpt", "data_dir={data}"],
            "run: checkpoint {in}/two_classes.ckpt predicts 2 classes but {data} has 54",
        ),
        (["data_dir={in}"], "data_dir: {in}/spec.json not found"),
        (["video_fps=0"], "video_fps must be a number > 0, got 0"),
        (["clip_stride=0"], "clip_stride must be an integer >= 1, got 0"),
        (["max_clips=0"], "max_clips must be an integer >= 1, got 0"),
        (["device=tpu"], "device must be one of auto, cpu, cuda, cuda:N; got 'tpu'"),
        (["render.camera.width=48"], "render.camera.width and render.camera.height must be equal"),
        (["record_time=0.01"], "record_time must span at least one frame interval"),
        (["level=4"], "level must be an integer in [1, 3], got 4"),
    ],
)
def test_bad_inputs_are_refused_naming_the_field(overrides, message, bad, tmp_path, monkeypatch):
    monkeypatch.setattr(clone, "predict", _refuse_to_work)
    monkeypatch.setattr(clone, "simulate_unit", _refuse_to_work)
    places = {k: str(v) for k, v in bad.items()}
    out = tmp_path / "out"
    with pytest.raises(InputError) as info:
        clone.run(
            _compose(
                f"paths.output_dir={out}",
                f"video={bad['video']}",
                f"run={bad['run']}",
                *TINY,
                *[o.format(**places) for o in overrides],
            )
        )
    assert str(info.value).startswith(message.format(**places))
    assert not out.exists()


@pytest.mark.render
def test_unreadable_frames_are_refused_and_nothing_is_written(bad, tmp_path, videos):
    broken = tmp_path / "broken"
    shutil.copytree(videos["folder"], broken)
    (broken / "frame_0005.png").write_bytes(b"not a png")
    out = tmp_path / "out"
    with pytest.raises(InputError, match=r"^video: could not read frames"):
        clone.run(
            _compose(f"paths.output_dir={out}", f"video={broken}", f"run={bad['run']}", *TINY)
        )
    assert not out.exists()


def test_video_and_run_are_required(tmp_path):
    for given, missing in (([], "video"), (["video=clip.mp4"], "run")):
        with pytest.raises(InputError, match=rf"^{missing} is required: give {missing}=<"):
            clone.run(_compose(f"paths.output_dir={tmp_path}", *given))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.render
def test_the_command_prints_one_line_and_exits_2(trained, tmp_path):
    env = subprocess_env()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "apps.clone",
            f"video={tmp_path}/none.mp4",
            f"run={trained}",
            f"paths.root_dir={tmp_path}",
        ],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"error: video: {tmp_path}/none.mp4 does not exist; give {clone.VIDEO_HELP}"
    ]
    written = [p for p in tmp_path.rglob("*") if p.is_file() and ".hydra" not in p.parts]
    assert [p for p in written if p.suffix != ".log"] == []
