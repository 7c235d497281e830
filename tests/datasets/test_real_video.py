"""The real-video loader on a small generated folder of mp4s and frame folders."""

import logging

import cv2
import numpy as np
import pytest
import torch

from common.errors import InputError
from datasets.real_video import RealVideoDataset, SkippedVideo

from .conftest import write_mp4


def _frames(count: int, seed: int, height: int = 48, width: int = 64) -> np.ndarray:
    base = np.random.default_rng(seed).integers(0, 255, size=(height, width, 3), dtype=np.uint8)
    return np.stack([np.roll(base, 2 * t, axis=1) for t in range(count)])


@pytest.fixture
def folder(tmp_path):
    write_mp4(tmp_path / "silk.mp4", _frames(45, 0), 30.0)
    write_mp4(tmp_path / "denim.mp4", _frames(25, 1), 15.0)
    frames_dir = tmp_path / "wool"
    frames_dir.mkdir()
    for t, frame in enumerate(_frames(12, 2)):
        cv2.imwrite(str(frames_dir / f"{t:04d}.png"), frame)
    (tmp_path / "labels.csv").write_text(
        "video,stiffness,density,wind\nsilk.mp4,1.5,0.8,W1\ndenim,6.0,2.5,W3\nwool,3.0,1.2,W2\n"
    )
    return tmp_path


def test_reads_videos_and_frame_folders_into_clips(folder):
    data = RealVideoDataset(folder, clip_len=10, clip_stride=5, size=32)
    by_video = {}
    for video, _ in data.clips:
        by_video[data.videos[video].name] = by_video.get(data.videos[video].name, 0) + 1
    # silk: 45 frames at 30 fps -> step 2, span 19, starts every 10 -> 0, 10, 20
    # denim: 25 frames at 15 fps -> step 1, span 10, starts every 5 -> 0, 5, 10, 15
    # wool: 12 frames at the default 30 fps -> step 2, span 19 > 12 -> none
    assert by_video == {"silk.mp4": 3, "denim": 4}
    sample = data[0]
    assert sample["video"].shape == (10, 3, 32, 32) and sample["video"].dtype == torch.float32
    assert sample["stiffness"] == 1.5 and sample["density"] == 0.8 and sample["wind"] == "W1"
    assert sample["label"] == -1
    batch = next(iter(torch.utils.data.DataLoader(data, batch_size=4)))
    assert batch["video"].shape == (4, 10, 3, 32, 32)
    assert list(batch["wind"]) == ["W1", "W1", "W1", "W3"]


def test_frame_folder_with_its_own_fps_and_crop(folder):
    labels = folder / "labels.csv"
    labels.write_text("video,stiffness,density,fps\nwool,3.0,1.2,15\n")
    data = RealVideoDataset(folder, clip_len=4, clip_stride=4, size=24)
    assert len(data) == 3
    frames = data.read_frames(1)
    assert frames.shape == (4, 24, 24, 3) and frames.dtype == np.uint8
    assert not np.array_equal(frames[0], frames[1]), "frames of a moving clip are identical"


def test_errors_name_the_problem(folder):
    (folder / "labels.csv").write_text("video,density\nsilk.mp4,0.8\n")
    with pytest.raises(ValueError, match="stiffness"):
        RealVideoDataset(folder)
    (folder / "labels.csv").write_text("video,stiffness,density\nnope.mp4,1,1\n")
    with pytest.raises(FileNotFoundError, match=r"nope\.mp4"):
        RealVideoDataset(folder)
    (folder / "labels.csv").write_text("video,stiffness,density\nsilk.mp4,stiff,1\n")
    with pytest.raises(ValueError, match="stiffness"):
        RealVideoDataset(folder)
    (folder / "labels.csv").unlink()
    with pytest.raises(FileNotFoundError, match=r"labels\.csv"):
        RealVideoDataset(folder)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        RealVideoDataset(folder / "missing")


def _fabrics(root, names, frames=12, fps=15.0):
    """mp4 videos ``names`` (moving noise) under ``root``."""
    root.mkdir(parents=True, exist_ok=True)
    for k, name in enumerate(names):
        write_mp4(root / name, _frames(frames, k, 24, 32), fps)


def test_videos_in_a_videos_subfolder_are_found(tmp_path):
    _fabrics(tmp_path / "videos", ["a.mp4", "b.mp4"])
    _fabrics(tmp_path, ["c.mp4"])  # beside labels.csv works too, in the same folder
    (tmp_path / "labels.csv").write_text(
        "video,stiffness,density\na.mp4,1,0.1\nb,2,0.2\nc.mp4,3,0.3\n"
    )
    data = RealVideoDataset(tmp_path, clip_len=4, clip_stride=4, size=16)
    assert [v.path for v in data.videos] == [
        tmp_path / "videos" / "a.mp4",
        tmp_path / "videos" / "b.mp4",
        tmp_path / "c.mp4",
    ]
    assert (data.used_count, data.skipped_count) == (3, 0)
    assert data[len(data) - 1]["video_name"] == "c.mp4"
    _fabrics(tmp_path / "videos", ["c.mp4"])  # the same name in both places is ambiguous
    with pytest.raises(
        InputError, match=r"'c.mp4' .*\(line 4\) is both .*c.mp4 and .*videos/c.mp4"
    ):
        RealVideoDataset(tmp_path, clip_len=4, size=16)
    (tmp_path / "labels.csv").write_text("video,stiffness,density\nd.mp4,1,0.1\n")
    with pytest.raises(
        FileNotFoundError, match=r"'d.mp4' .*\(line 2\) not found in .* or .*videos"
    ):
        RealVideoDataset(tmp_path)


def test_a_video_listed_twice_is_refused(tmp_path):
    _fabrics(tmp_path, ["a.mp4", "b.mp4"])
    labels = tmp_path / "labels.csv"
    labels.write_text("video,stiffness,density\na.mp4,1,0.1\nb.mp4,2,0.2\na.mp4,1,0.1\n")
    with pytest.raises(InputError) as info:
        RealVideoDataset(tmp_path, clip_len=4, size=16)
    message = str(info.value)
    assert str(labels) in message and "'a.mp4' is listed more than once (lines 2, 4)" in message
    # two spellings of one file are the same video too
    labels.write_text("video,stiffness,density\na.mp4,1,0.1\nb.mp4,2,0.2\na,1,0.1\n")
    with pytest.raises(InputError, match=r"lines 2 and 4 name the same video .*a\.mp4"):
        RealVideoDataset(tmp_path, clip_len=4, size=16)


def test_a_short_video_is_warned_about_and_counted(tmp_path, caplog):
    _fabrics(tmp_path, ["long.mp4"], frames=12)
    _fabrics(tmp_path, ["short.mp4"], frames=5)
    (tmp_path / "labels.csv").write_text(
        "video,stiffness,density\nlong.mp4,1,0.1\nshort.mp4,2,0.2\n"
    )
    with caplog.at_level(logging.WARNING, logger="datasets.real_video"):
        data = RealVideoDataset(tmp_path, clip_len=6, clip_stride=3, size=16)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert "short.mp4 has 5 frames" in warnings[0] and "needs 6" in warnings[0]
    assert data.skipped == (SkippedVideo("short.mp4", 5, 6),)
    assert (len(data.videos), data.used_count, data.skipped_count) == (2, 1, 1)
    assert {data.videos[v].name for v, _ in data.clips} == {"long.mp4"}


def test_chosen_columns_are_read_and_a_missing_one_is_named(tmp_path):
    _fabrics(tmp_path, ["a.mp4", "b.mp4"])
    labels = tmp_path / "labels.csv"
    labels.write_text("video,stiffness,density,bending_rigidity\na.mp4,1,0.1,7.5\nb.mp4,2,0.2,9\n")
    data = RealVideoDataset(tmp_path, columns=["bending_rigidity"], clip_len=4, size=16)
    sample = data[0]
    assert sample["bending_rigidity"] == 7.5 and "stiffness" not in sample
    assert data.videos[1].values == {"bending_rigidity": 9.0}
    with pytest.raises(InputError) as info:
        RealVideoDataset(tmp_path, columns=["stiffness", "bend"], clip_len=4, size=16)
    assert "lacks column(s) ['bend']" in str(info.value)
    assert "['video', 'stiffness', 'density', 'bending_rigidity']" in str(info.value)
    with pytest.raises(InputError, match="reserved"):
        RealVideoDataset(tmp_path, columns=["wind"])


def test_videos_of_one_fabric_form_a_group(tmp_path):
    names = [f"v{i}.mp4" for i in range(4)]
    _fabrics(tmp_path, names)
    labels = tmp_path / "labels.csv"
    # a fabric column groups by itself ...
    labels.write_text(
        "video,fabric,stiffness,density,wind\n"
        "v0.mp4,silk,1,0.1,W1\nv1.mp4,silk,1,0.1,W2\nv2.mp4,wool,3,0.3,W1\nv3.mp4,denim,3,0.3,W1\n"
    )
    data = RealVideoDataset(tmp_path, clip_len=4, size=16)
    assert data.group_column == "fabric"
    assert [v.group for v in data.videos] == ["silk", "silk", "wool", "denim"]
    assert data[0]["group"] == "silk"
    # ... another column only when named, and a named column must exist
    data = RealVideoDataset(tmp_path, group="stiffness", clip_len=4, size=16)
    assert [v.group for v in data.videos] == ["1", "1", "3", "3"]
    with pytest.raises(InputError, match=r"no group column 'cloth'; it has \['video', 'fabric'"):
        RealVideoDataset(tmp_path, group="cloth", clip_len=4, size=16)
    # without one, identical label rows (wind aside) are one fabric
    labels.write_text(
        "video,stiffness,density,wind\n"
        "v0.mp4,1,0.1,W1\nv1.mp4,1,0.1,W2\nv2.mp4,3,0.3,W1\nv3.mp4,3,0.4,W1\n"
    )
    data = RealVideoDataset(tmp_path, clip_len=4, size=16)
    groups = [v.group for v in data.videos]
    assert data.group_column is None and "identical label rows" in data.group_rule
    assert groups[0] == groups[1] and len(set(groups)) == 3


def test_the_datamodule_tests_every_clip_in_labels_order(folder):
    from datasets.real_datamodule import RealVideoDataModule

    footage = RealVideoDataModule(folder, clip_len=10, clip_stride=5, size=32, batch_size=3)
    data = footage.dataset
    assert [s.name for s in data.skipped] == ["wool"]  # read when made, before any clip
    batches = list(footage.test_dataloader())
    assert [len(b["video_name"]) for b in batches] == [3, 3, 1]
    names = [n for b in batches for n in b["video_name"]]
    starts = [int(s) for b in batches for s in b["start_frame"]]
    assert names == ["silk.mp4"] * 3 + ["denim"] * 4
    assert starts == [0, 10, 20, 0, 5, 10, 15]
    torch.testing.assert_close(batches[1]["video"][0], data[3]["video"])
    assert [float(x) for b in batches for x in b["stiffness"]] == [1.5] * 3 + [6.0] * 4
    assert list(batches[0]["wind"]) == ["W1"] * 3
