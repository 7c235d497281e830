"""Look at a generated dataset: a labelled contact sheet (PNG) and a class-grid video (mp4).

``python -m datasets.preview data/wind-L1-random-small-s0 [more dirs] --out outputs/preview``

* ``<name>_sheet.png``: one row per class (stretch x bend multipliers in the label), a few
  clips per class from different simulations, a few frames of each clip;
* ``<name>_grid.mp4``: all classes at once, 6 stretch rows x 9 bend columns, each cell
  playing the clips of the class's first simulation back to back.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from .clip_dataset import ClothClipDataset

__all__ = ["contact_sheet", "grid_video", "main"]

_LABEL_WIDTH = 150


def _label(image: np.ndarray, text: str, origin: tuple[int, int], scale: float = 0.4) -> None:
    cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(
        image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA
    )


def _by_class(data: ClothClipDataset) -> dict[int, list[int]]:
    out: dict[int, list[int]] = {}
    for i, record in enumerate(data.records):
        out.setdefault(int(record["class_id"]), []).append(i)
    return dict(sorted(out.items()))


def contact_sheet(
    data: ClothClipDataset, *, clips_per_class: int = 3, frames_per_clip: int = 4
) -> np.ndarray:
    """RGB image: a labelled row per class, ``clips_per_class`` clips of distinct simulations."""
    rows = []
    for class_id, indices in _by_class(data).items():
        chosen, seen = [], set()
        for i in indices:
            sim = data.records[i]["sim_id"]
            if sim not in seen:
                chosen.append(i)
                seen.add(sim)
            if len(chosen) == clips_per_class:
                break
        tiles = []
        for i in chosen:
            _, frames = data.read(i)
            pick = np.linspace(0, len(frames) - 1, min(frames_per_clip, len(frames))).round()
            clip = np.concatenate([frames[int(t)] for t in pick], axis=1)
            tiles.append(np.pad(clip, ((0, 0), (0, 4), (0, 0)), constant_values=255))
        row = np.concatenate(tiles, axis=1)
        record = data.records[chosen[0]]
        label = np.full((row.shape[0], _LABEL_WIDTH, 3), 40, np.uint8)
        _label(label, f"class {class_id}", (6, 18), 0.5)
        _label(label, f"p {record['stretch_mult']:g}  k {record['bend_mult']:g}", (6, 38))
        rows.append(np.concatenate([label, row], axis=1))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 2), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.concatenate(rows, axis=0)


def grid_video(data: ClothClipDataset, *, columns: int = 9) -> np.ndarray:
    """Frames (N, H, W, 3): one cell per class playing its first simulation's clips."""
    per_class = _by_class(data)
    cells = []
    for class_id, indices in per_class.items():
        first_sim = data.records[indices[0]]["sim_id"]
        same = [i for i in indices if data.records[i]["sim_id"] == first_sim]
        same.sort(key=lambda i: data.records[i]["clip_index"])
        frames = np.concatenate([data.read(i)[1] for i in same]).copy()
        for frame in frames:
            _label(frame, str(class_id), (3, 12), 0.35)
        cells.append(frames)
    length = max(len(c) for c in cells)
    cells = [np.concatenate([c, np.repeat(c[-1:], length - len(c), 0)]) for c in cells]
    blank = np.zeros_like(cells[0])
    while len(cells) % columns:
        cells.append(blank)
    rows = [np.concatenate(cells[r : r + columns], axis=2) for r in range(0, len(cells), columns)]
    return np.concatenate(rows, axis=1)


def _write_png(path: Path, image: np.ndarray) -> None:
    ok, data = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise RuntimeError(f"PNG encoding failed for {path}")
    from simulator.sequence import atomic_write_bytes

    atomic_write_bytes(path, data.tobytes())


def _write_mp4(path: Path, frames: np.ndarray, fps: float) -> None:
    height, width = frames.shape[1:3]
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp.mp4")
    os.close(fd)
    try:
        writer = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
        if not writer.isOpened():
            raise RuntimeError("OpenCV cannot write mp4 (mp4v) here")
        for frame in frames:
            writer.write(np.ascontiguousarray(frame[..., ::-1]))
        writer.release()
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)


def main(argv: list[str] | None = None) -> list[Path]:
    """Write the sheet and the video of each dataset; returns the written paths."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path, help="dataset directories")
    parser.add_argument("--out", type=Path, default=Path("outputs/preview"))
    parser.add_argument("--split", default=None, help="train/val/test (default: all)")
    parser.add_argument("--clips-per-class", type=int, default=3)
    parser.add_argument("--frames-per-clip", type=int, default=4)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    written = []
    for root in args.datasets:
        data = ClothClipDataset(root, args.split, verify=True)
        name = root.resolve().name
        sheet = contact_sheet(
            data, clips_per_class=args.clips_per_class, frames_per_clip=args.frames_per_clip
        )
        _write_png(args.out / f"{name}_sheet.png", sheet)
        video = grid_video(data)
        _write_mp4(args.out / f"{name}_grid.mp4", video, float(data.records[0]["fps"]))
        written += [args.out / f"{name}_sheet.png", args.out / f"{name}_grid.mp4"]
        print(
            f"{name}: {written[-2]} ({sheet.shape[1]}x{sheet.shape[0]}), {written[-1]} "
            f"({len(video)} frames)"
        )
    return written


if __name__ == "__main__":
    main()
