"""The real-video loader on a small generated folder of mp4s and frame folders."""

import cv2
import numpy as np
import pytest
import torch

from datasets.real_video import RealVideoDataset

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
