"""Real footage in the simulated clips' format (e.g. Bouman et al. 2013's fabric videos).

A folder holds ``labels.csv`` and the videos (mp4/avi/..., or one sub-folder of image frames
per video), either beside ``labels.csv`` or in a ``videos/`` sub-folder. ``labels.csv`` has a
``video`` column, the measured columns to correlate (by default ``stiffness`` and ``density``;
any numeric columns can be chosen, e.g. ``bending_rigidity``) and optionally ``wind`` (any
label, e.g. W1/W2/W3), ``fps`` (frame rate of a frame folder; video files carry their own)
and a group column. Each video has exactly one row: a repeated row is refused, never merged.

Groups: the videos of one fabric (filmed at several wind levels) are not independent samples.
They form a group given by the ``group`` column when named, else by a ``fabric`` column when
there is one, else by identical label rows (every column but video, wind and fps); without
repeats every video is a group of its own. Correlations resample groups (``models.correlation``).

Each video is resized (shorter side to ``size``), centre-cropped to ``size x size``,
resampled in time to ``target_fps`` (every ``round(video_fps / target_fps)``-th frame, so
motion has the speed of the simulated clips) and cut into clips of ``clip_len`` frames that
start every ``clip_stride`` resampled frames. A video too short for one clip is skipped with a
warning naming it and listed in :attr:`RealVideoDataset.skipped`, so reports can count it.

Samples match :class:`~datasets.clip_dataset.ClothClipDataset`'s clip mode: ``video``
float (T, 3, H, W) in [0, 1], ``label`` = -1 (unknown class), one float per measured column
(e.g. ``stiffness``, ``density``), ``wind`` (str, "" when absent), ``group``, ``video_name``,
``start_frame``.
"""

from __future__ import annotations

import csv
import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from common.checks import check_float, check_int
from common.errors import InputError

from .clip_dataset import clip_tensor

__all__ = [
    "DEFAULT_COLUMNS",
    "REQUIRED_COLUMNS",
    "VIDEO_SUBFOLDER",
    "LabelRow",
    "RealVideoDataset",
    "SkippedVideo",
    "clip_starts",
    "fabric_groups",
    "footage_files",
    "read_labels",
]

log = logging.getLogger(__name__)

DEFAULT_COLUMNS = ("stiffness", "density")
"""Measured columns correlated when the user names none (thesis Table 7.3)."""
REQUIRED_COLUMNS = ("video", *DEFAULT_COLUMNS)
VIDEO_SUBFOLDER = "videos"
"""Sub-folder of the real folder that may hold the videos instead of its top level."""
AUTO_GROUP_COLUMN = "fabric"
"""Group column used without being named, when ``labels.csv`` has it."""
BOOKKEEPING_COLUMNS = ("video", "wind", "fps")
"""Columns that describe a recording, not the fabric (left out of label-row grouping)."""
RESERVED_KEYS = ("video", "label", "wind", "fps", "group", "video_name", "start_frame")
"""Sample keys that a measured column may not be named."""
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
DEFAULT_FOLDER_FPS = 30.0


@dataclasses.dataclass(frozen=True)
class LabelRow:
    """One row of ``labels.csv``: its line in the file (header = 1) and its stripped fields."""

    line: int
    fields: dict[str, str]


@dataclasses.dataclass(frozen=True)
class SkippedVideo:
    """A listed video too short for one clip."""

    name: str
    frame_count: int
    frames_needed: int


@dataclasses.dataclass(frozen=True)
class _Video:
    name: str
    path: Path
    values: dict[str, float]
    group: str
    wind: str
    fps: float
    frame_count: int

    @property
    def stiffness(self) -> float:
        """Measured stiffness (the ``stiffness`` column, when it was chosen)."""
        return self.values["stiffness"]

    @property
    def density(self) -> float:
        """Measured density (the ``density`` column, when it was chosen)."""
        return self.values["density"]


POSITIVE_COLUMNS = ("stiffness", "density")
"""Measured magnitudes that are > 0 by their nature (the thesis's Table 7.3 columns)."""


def _measured(value: str, column: str, line: int, path: Path) -> float:
    """A measured column's value: a finite number, and > 0 for :data:`POSITIVE_COLUMNS`."""
    out = _number(value, column, line, path)
    if column in POSITIVE_COLUMNS and not out > 0:
        raise InputError(f"{path} line {line}: column {column!r} must be > 0, got {value!r}")
    return out


def _number(value: str, column: str, line: int, path: Path) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(
            f"{path} line {line}: column {column!r} must be a number, got {value!r}"
        ) from None
    if not math.isfinite(out):
        raise InputError(f"{path} line {line}: column {column!r} must be finite, got {value!r}")
    return out


def clip_starts(frame_count: int, clip_len: int, clip_stride: int, step: int = 1) -> range:
    """First source frames of the clips cut from a video of ``frame_count`` frames.

    A clip takes every ``step``-th frame ``clip_len`` times; clips start every
    ``clip_stride`` resampled frames. Simulated videos are cut by the same rule (``step`` 1).
    """
    span = (clip_len - 1) * step + 1
    return range(0, frame_count - span + 1, clip_stride * step)


def _check_columns(columns: Sequence[str]) -> tuple[str, ...]:
    if isinstance(columns, str) or not all(isinstance(c, str) and c.strip() for c in columns):
        raise InputError(f"columns must be a list of column names, got {columns!r}")
    out = tuple(c.strip() for c in columns)
    if not out:
        raise InputError("columns must name at least one measured column of labels.csv")
    if len(set(out)) != len(out):
        raise InputError(f"columns lists a column twice: {list(out)}")
    reserved = [c for c in out if c in RESERVED_KEYS]
    if reserved:
        raise InputError(f"columns {reserved} are not measured values; reserved: {RESERVED_KEYS}")
    return out


def read_labels(root: str | Path, columns: Sequence[str] = DEFAULT_COLUMNS) -> list[LabelRow]:
    """Rows of ``root/labels.csv``, one per video.

    Errors name the file and the missing column (with the columns it has), or the lines of a
    video listed twice.
    """
    columns = _check_columns(columns)
    path = Path(root) / "labels.csv"
    if not path.is_file():
        raise FileNotFoundError(
            f"{path} not found (columns: video, {', '.join(columns)}[, wind, fps, fabric])"
        )
    rows = []
    try:  # utf-8-sig: a spreadsheet's byte-order mark is not part of the first column's name
        with open(path, newline="", encoding="utf-8-sig") as handle:
            reader = csv.DictReader(handle)
            header = [c.strip() for c in (reader.fieldnames or [])]
            missing = [c for c in ("video", *columns) if c not in header]
            if missing:
                raise InputError(f"{path} lacks column(s) {missing}; it has {header}")
            for row in reader:
                extra = row.get(None)  # type: ignore[call-overload]
                if extra and any(v.strip() for v in extra):
                    raise InputError(
                        f"{path} line {reader.line_num}: {len(header) + len(extra)} fields but "
                        f"the header names {len(header)}"
                    )
                fields = {k.strip(): (v or "").strip() for k, v in row.items() if k}
                if any(fields.values()):  # a blank line is not a video
                    rows.append(LabelRow(reader.line_num, fields))
    except UnicodeDecodeError as error:
        bad = error.object[error.start : error.start + 1]
        raise InputError(
            f"{path} is not UTF-8 text (byte {error.start} is {bad!r}); save it as UTF-8 CSV"
        ) from None
    except csv.Error as error:
        raise InputError(f"{path} is not a readable CSV file ({error})") from None
    if not rows:
        raise InputError(f"{path} lists no videos")
    lines: dict[str, list[int]] = {}
    for row in rows:
        if not row.fields["video"]:
            raise InputError(f"{path} line {row.line}: column 'video' is empty")
        lines.setdefault(row.fields["video"], []).append(row.line)
    for name, found in lines.items():
        if len(found) > 1:
            raise InputError(
                f"{path}: video {name!r} is listed more than once (lines "
                f"{', '.join(map(str, found))}); give each video exactly one row"
            )
    return rows


def _frame_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def _find(folder: Path, name: str) -> Path | None:
    path = folder / name
    if path.exists():
        return path
    for suffix in VIDEO_SUFFIXES:
        if (folder / (name + suffix)).is_file():
            return folder / (name + suffix)
    return None


def _resolve(root: Path, row: LabelRow) -> Path:
    """The file or frame folder of a row, beside ``labels.csv`` or in ``videos/``."""
    name = row.fields["video"]
    if "\x00" in name:
        raise InputError(f"{root / 'labels.csv'} line {row.line}: video {name!r} holds a NUL byte")
    if Path(name).is_absolute() or ".." in Path(name).parts:
        raise InputError(
            f"{root / 'labels.csv'} line {row.line}: video {name!r} must be a name inside {root} "
            "(no absolute path, no '..')"
        )
    places = (root, root / VIDEO_SUBFOLDER)
    found = [p for p in (_find(folder, name) for folder in places) if p is not None]
    if not found:
        raise FileNotFoundError(
            f"video {name!r} listed in {root / 'labels.csv'} (line {row.line}) not found in "
            f"{root} or {root / VIDEO_SUBFOLDER}"
        )
    if len(found) > 1 and found[0].resolve() != found[1].resolve():
        raise InputError(
            f"video {name!r} listed in {root / 'labels.csv'} (line {row.line}) is both "
            f"{found[0]} and {found[1]}; keep one"
        )
    if not found[0].resolve().is_relative_to(root.resolve()):
        raise InputError(
            f"{root / 'labels.csv'} line {row.line}: video {name!r} is a link to "
            f"{found[0].resolve()}, outside {root}; the footage must lie inside its folder"
        )
    return found[0]


def footage_files(root: str | Path, columns: Sequence[str] = DEFAULT_COLUMNS) -> list[Path]:
    """Every file an evaluation of a footage folder reads, all inside ``root``.

    ``labels.csv``, then each listed video (a frame folder's image files) in its order.
    """
    root = Path(root)
    files = [root / "labels.csv"]
    for row in read_labels(root, columns):
        path = _resolve(root, row)
        files.extend(_frame_files(path) if path.is_dir() else [path])
    return files


def fabric_groups(rows: list[LabelRow], header: list[str], group: str | None, path: Path):
    """Group label per row, the group column used (``None``: label rows) and a description."""
    if group is None and AUTO_GROUP_COLUMN in header:
        group = AUTO_GROUP_COLUMN
    if group is not None:
        if group not in header:
            raise InputError(f"{path} has no group column {group!r}; it has {header}")
        for row in rows:
            if not row.fields.get(group):
                raise InputError(f"{path} line {row.line}: group column {group!r} is empty")
        return [row.fields[group] for row in rows], group, f"column `{group}`"
    label_columns = [c for c in header if c not in BOOKKEEPING_COLUMNS]
    keys = ["|".join(row.fields.get(c, "") for c in label_columns) for row in rows]
    if len(set(keys)) == len(keys):
        return keys, None, "none (no label row repeats: every video is its own group)"
    return keys, None, f"identical label rows ({', '.join(label_columns)})"


class RealVideoDataset(Dataset):
    """Clips of real videos with measured values.

    Args:
        root: Folder with ``labels.csv`` and the videos (beside it or in ``videos/``).
        columns: Measured ``labels.csv`` columns carried by each sample (numbers).
        group: Column whose equal values make one group of videos (one fabric); ``None``:
            ``fabric`` if present, else identical label rows (see the module doc).
        clip_len: Frames per clip (10 like the simulated clips).
        clip_stride: Resampled frames between clip starts.
        target_fps: Frame rate of the clips [1/s] (the simulated datasets use 15).
        size: Output side [px] (square, like the simulated frames).
        max_clips_per_video: Keep only the first clips of each video (``None``: all).
        transform: Called on each ``video`` tensor.

    Attributes:
        videos: Every listed video, in ``labels.csv`` order (skipped ones included).
        skipped: The videos too short for one clip.
        group_column: The group column used, ``None`` when groups come from label rows.
        group_rule: How groups were formed, for reports.
    """

    def __init__(
        self,
        root: str | Path,
        *,
        columns: Sequence[str] = DEFAULT_COLUMNS,
        group: str | None = None,
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
        self.root = root
        self.columns = _check_columns(columns)
        self.clip_len = check_int(clip_len, "clip_len", 1)
        self.clip_stride = check_int(clip_stride, "clip_stride", 1)
        self.size = check_int(size, "size", 1)
        self.target_fps = check_float(target_fps, "target_fps", 0.0, low_open=True)
        if max_clips_per_video is not None:
            max_clips_per_video = check_int(max_clips_per_video, "max_clips_per_video", 1)
        self.transform = transform
        rows = read_labels(root, self.columns)
        header = list(rows[0].fields)
        labels = root / "labels.csv"
        groups, self.group_column, self.group_rule = fabric_groups(rows, header, group, labels)
        self.videos = [self.probe(row, g) for row, g in zip(rows, groups, strict=True)]
        by_path: dict[Path, int] = {}
        for row, video in zip(rows, self.videos, strict=True):
            first = by_path.setdefault(video.path.resolve(), row.line)
            if first != row.line:
                raise InputError(
                    f"{labels}: lines {first} and {row.line} name the same video {video.path}; "
                    "give each video exactly one row"
                )
        self.clips: list[tuple[int, int]] = []
        skipped = []
        for v, video in enumerate(self.videos):
            step = self.frame_step(video)
            starts = clip_starts(video.frame_count, self.clip_len, self.clip_stride, step)
            if not starts:
                needed = (self.clip_len - 1) * step + 1
                skipped.append(SkippedVideo(video.name, video.frame_count, needed))
                log.warning(
                    "real video %s has %d frames at %.4g fps; one clip of %d frames at %.4g fps "
                    "needs %d: SKIPPED, it will be missing from the correlations",
                    video.path,
                    video.frame_count,
                    video.fps,
                    self.clip_len,
                    self.target_fps,
                    needed,
                )
            if max_clips_per_video is not None:
                starts = starts[:max_clips_per_video]
            self.clips.extend((v, s) for s in starts)
        self.skipped = tuple(skipped)
        if not self.clips:
            raise InputError(
                f"no video in {root} is long enough for one clip of {self.clip_len} frames "
                f"({len(self.videos)} listed, all skipped)"
            )

    @property
    def used_count(self) -> int:
        """Videos that give at least one clip."""
        return len(self.videos) - len(self.skipped)

    @property
    def skipped_count(self) -> int:
        """Listed videos too short for one clip."""
        return len(self.skipped)

    def probe(self, row: LabelRow, group: str) -> _Video:
        """One listed video: its path, frame count, frame rate and measured values."""
        labels = self.root / "labels.csv"
        path = _resolve(self.root, row)
        if path.is_dir():
            frames = _frame_files(path)
            fps = _number(row.fields.get("fps") or DEFAULT_FOLDER_FPS, "fps", row.line, labels)
            count = len(frames)
        else:
            cap = cv2.VideoCapture(str(path))
            if not cap.isOpened():
                raise InputError(f"cannot open video {path}")
            fps = cap.get(cv2.CAP_PROP_FPS) or DEFAULT_FOLDER_FPS
            count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            if count <= 0:
                count = 0
                while cap.grab():
                    count += 1
            cap.release()
        if not fps > 0:
            raise InputError(f"{labels} line {row.line}: fps must be > 0, got {fps}")
        return _Video(
            name=row.fields["video"],
            path=path,
            values={c: _measured(row.fields[c], c, row.line, labels) for c in self.columns},
            group=group,
            wind=row.fields.get("wind", ""),
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
            **video.values,
            "wind": video.wind,
            "group": video.group,
            "video_name": video.name,
            "start_frame": start,
        }
