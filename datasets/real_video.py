"""Real footage in the simulated clips' format (e.g. Bouman et al. 2013's fabric videos).

A folder holds the videos (mp4/avi, or one sub-folder of image frames per video) and
``labels.csv`` with columns ``video, stiffness, density`` and optionally ``wind`` (any
label, e.g. W1/W2/W3) and ``fps`` (frame rate of a frame folder; video files carry their
own). Each video is resized (shorter side to ``size``), centre-cropped to ``size x size``,
resampled in time to ``target_fps`` (every ``round(video_fps / target_fps)``-th frame, so
motion has the speed of the simulated clips) and cut into clips of ``clip_len`` frames
that start every ``clip_stride`` resampled frames.

Samples match :class:`~datasets.clip_dataset.ClothClipDataset`'s clip mode: ``video``
float (T, 3, H, W) in [0, 1], ``label`` = -1 (unknown class), ``stiffness``, ``density``,
``wind`` (str, "" when absent), ``video_name``, ``start_frame``.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from .clip_dataset import clip_tensor
from .spec import check_int

__all__ = ["REQUIRED_COLUMNS", "RealVideoDataset", "clip_starts", "read_labels"]

REQUIRED_COLUMNS = ("video", "stiffness", "density")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
DEFAULT_FOLDER_FPS = 30.0


@dataclasses.dataclass(frozen=True)
class _Video:
    name: str
    path: Path
    stiffness: float
    density: float
    wind: str
    fps: float
    frame_count: int


def _number(value: str, column: str, row: int, path: Path) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(
            f"{path} row {row}: column {column!r} must be a number, got {value!r}"
        ) from None
    if not math.isfinite(out):
        raise ValueError(f"{path} row {row}: column {column!r} must be finite, got {value!r}")
    return out


def clip_starts(frame_count: int, clip_len: int, clip_stride: int, step: int = 1) -> range:
    """First source frames of the clips cut from a video of ``frame_count`` frames.

    A clip takes every ``step``-th frame ``clip_len`` times; clips start every
    ``clip_stride`` resampled frames. Simulated videos are cut by the same rule (``step`` 1).
    """
    span = (clip_len - 1) * step + 1
    return range(0, frame_count - span + 1, clip_stride * step)


def read_labels(root: Path) -> list[dict]:
    """Rows of ``root/labels.csv``; errors name the file and the missing column or bad row."""
    path = root / "labels.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found (columns: video, stiffness, density[, wind])")
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        columns = [c.strip() for c in (reader.fieldnames or [])]
        missing = [c for c in REQUIRED_COLUMNS if c not in columns]
        if missing:
            raise ValueError(f"{path} lacks column(s) {missing}; it has {columns}")
        rows = [{k.strip(): (v or "").strip() for k, v in row.items() if k} for row in reader]
    if not rows:
        raise ValueError(f"{path} lists no videos")
    return rows


def _frame_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def _resolve(root: Path, name: str) -> Path:
    path = root / name
    if path.exists():
        return path
    for suffix in VIDEO_SUFFIXES:
        if path.with_suffix(suffix).is_file():
            return path.with_suffix(suffix)
    raise FileNotFoundError(f"video {name!r} listed in {root / 'labels.csv'} not found in {root}")


class RealVideoDataset(Dataset):
    """Clips of real videos with measured stiffness and density.

    Args:
        root: Folder with ``labels.csv`` and the videos.
        clip_len: Frames per clip (10 like the simulated clips).
        clip_stride: Resampled frames between clip starts.
        target_fps: Frame rate of the clips [1/s] (the simulated datasets use 15).
        size: Output side [px] (square, like the simulated frames).
        max_clips_per_video: Keep only the first clips of each video (``None``: all).
        transform: Called on each ``video`` tensor.
    """

    def __init__(
        self,
        root: str | Path,
        *,
        clip_len: int = 10,
        clip_stride: int = 10,
        target_fps: float = 15.0,
        size: int = 112,
        max_clips_per_video: int | None = None,
        transform: Callable[[torch.Tensor], torch.Tensor] | None = None,
    ):
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"real-video folder {root} does not exist")
        for name, value in (("clip_len", clip_len), ("clip_stride", clip_stride), ("size", size)):
            check_int(name, value)
        if not target_fps > 0:
            raise ValueError(f"target_fps must be > 0, got {target_fps}")
        self.root, self.clip_len, self.clip_stride = root, clip_len, clip_stride
        self.target_fps, self.size, self.transform = float(target_fps), size, transform
        self.videos = [self._probe(row, i + 2) for i, row in enumerate(read_labels(root))]
        self.clips: list[tuple[int, int]] = []
        for v, video in enumerate(self.videos):
            starts = clip_starts(video.frame_count, clip_len, clip_stride, self.frame_step(video))
            if max_clips_per_video is not None:
                starts = starts[:max_clips_per_video]
            self.clips.extend((v, s) for s in starts)
        if not self.clips:
            raise ValueError(f"no video in {root} is long enough for one clip of {clip_len} frames")

    def _probe(self, row: dict, line: int) -> _Video:
        labels = self.root / "labels.csv"
        path = _resolve(self.root, row["video"])
        if path.is_dir():
            frames = _frame_files(path)
            fps = _number(row.get("fps") or DEFAULT_FOLDER_FPS, "fps", line, labels)
            count = len(frames)
        else:
            cap = cv2.VideoCapture(str(path))
            if not cap.isOpened():
                raise ValueError(f"cannot open video {path}")
            fps = cap.get(cv2.CAP_PROP_FPS) or DEFAULT_FOLDER_FPS
            count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            if count <= 0:
                count = 0
                while cap.grab():
                    count += 1
            cap.release()
        return _Video(
            name=row["video"],
            path=path,
            stiffness=_number(row["stiffness"], "stiffness", line, labels),
            density=_number(row["density"], "density", line, labels),
            wind=row.get("wind", ""),
            fps=float(fps),
            frame_count=count,
        )

    def frame_step(self, video: _Video) -> int:
        """Source frames per clip frame."""
        return max(1, round(video.fps / self.target_fps))

    def __len__(self) -> int:
        return len(self.clips)

    def _prepare(self, image: np.ndarray) -> np.ndarray:
        height, width = image.shape[:2]
        scale = self.size / min(height, width)
        resized = cv2.resize(
            image,
            (max(self.size, round(width * scale)), max(self.size, round(height * scale))),
            interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR,
        )
        top = (resized.shape[0] - self.size) // 2
        left = (resized.shape[1] - self.size) // 2
        return resized[top : top + self.size, left : left + self.size, ::-1]  # BGR -> RGB

    def read_frames(self, index: int) -> np.ndarray:
        """uint8 RGB frames (T, size, size, 3) of clip ``index``."""
        v, start = self.clips[index]
        video = self.videos[v]
        wanted = [start + t * self.frame_step(video) for t in range(self.clip_len)]
        if video.path.is_dir():
            files = _frame_files(video.path)
            images = [cv2.imread(str(files[i]), cv2.IMREAD_COLOR) for i in wanted]
        else:
            cap = cv2.VideoCapture(str(video.path))
            images, position = [], 0
            try:
                for target in wanted:
                    while position < target:
                        cap.grab()
                        position += 1
                    ok, image = cap.read()
                    position += 1
                    images.append(image if ok else None)
            finally:
                cap.release()
        if any(image is None for image in images):
            raise ValueError(f"could not read frames {wanted} of {video.path}")
        return np.stack([self._prepare(image) for image in images])

    def __getitem__(self, index: int) -> dict:
        v, start = self.clips[index]
        video = self.videos[v]
        clip = clip_tensor(self.read_frames(index))
        if self.transform is not None:
            clip = self.transform(clip)
        return {
            "video": clip,
            "label": -1,
            "stiffness": video.stiffness,
            "density": video.density,
            "wind": video.wind,
            "video_name": video.name,
            "start_frame": start,
        }
