"""Look at a generated dataset: a labelled contact sheet (PNG) and a class-grid video (mp4).

``python -m datasets.preview data/wind-L1-random-small-s0 [more dirs] --out outputs/preview``

* ``<name>_sheet.png``: one row per class (stretch x bend multipliers in the label), a few
  clips per class from different simulations, a few frames of each clip;
* ``<name>_grid.mp4``: all classes at once, 6 stretch rows x 9 bend columns, each cell
  playing the clips of the class's first simulation back to back.
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from common.checks import check_choice, check_int
from common.commands import report_user_errors
from common.errors import InputError
from common.files import atomic_write_bytes
from common.paths import check_output_dir
from simulator.cloth.material import WANG54, MaterialSet

from .clip_dataset import ClothClipDataset
from .spec import SPLITS

__all__ = [
    "class_lines",
    "contact_sheet",
    "draw_label",
    "frame_strip",
    "grid_video",
    "label_height",
    "label_panel",
    "labelled_rows",
    "main",
    "tile_grid",
    "write_mp4",
    "write_png",
]

LABEL_WIDTH = 150
"""Width [px] of the label panel left of each contact-sheet row."""
_GAP = 4  # px of white after each frame strip (rows get 2 px)
_LINE_STEP = 20  # px between label lines


def draw_label(image: np.ndarray, text: str, origin: tuple[int, int], scale: float = 0.4) -> None:
    """Write ``text`` into ``image`` (uint8 RGB, in place): white on a black outline.

    The outline keeps it readable over any texture or background. It is the thin text drawn
    shifted by one pixel each way: OpenCV spaces thick text wider, so a thick outline would
    drift away from the white letters along the line.
    """
    x, y = origin
    font, line = cv2.FONT_HERSHEY_SIMPLEX, cv2.LINE_AA
    for dx, dy in ((-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)):
        cv2.putText(image, text, (x + dx, y + dy), font, scale, (0, 0, 0), 1, line)
    cv2.putText(image, text, origin, font, scale, (255, 255, 255), 1, line)


def class_lines(class_id: int, material_set: MaterialSet = WANG54) -> tuple[str, ...]:
    """Label lines of a class of ``material_set``.

    Its id, its stretch and bend multipliers and, in a set of several densities, its density
    multiplier.
    """
    stretch, bend = material_set.multipliers(int(class_id))
    lines = (f"class {int(class_id)}", f"stretch x{stretch:g}", f"bend x{bend:g}")
    if material_set.density_count > 1:
        lines += (f"density x{material_set.density_mult(int(class_id)):g}",)
    return lines


def label_panel(lines: Sequence[str], height: int, width: int) -> np.ndarray:
    """A dark uint8 RGB panel of shape (height, width, 3) with ``lines`` written top-down.

    The first line (the class) is written larger than the rest.
    """
    panel = np.full((height, width, 3), 40, np.uint8)
    for i, text in enumerate(lines):
        draw_label(panel, text, (6, 18 + _LINE_STEP * i), 0.5 if i == 0 else 0.4)
    return panel


def label_height(line_count: int) -> int:
    """Height [px] of a :func:`label_panel` that shows ``line_count`` lines whole."""
    return 12 + _LINE_STEP * line_count


def frame_strip(frames: np.ndarray, count: int) -> np.ndarray:
    """``count`` evenly spaced frames of ``frames`` (K, H, W, 3) side by side.

    The strip ends in a white gap, so that strips put next to each other stay apart.
    """
    pick = np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int)
    strip = np.concatenate([frames[t] for t in pick], axis=1)
    return np.pad(strip, ((0, 0), (0, _GAP), (0, 0)), constant_values=255)


def labelled_rows(rows: Sequence[tuple[Sequence[str], np.ndarray]]) -> np.ndarray:
    """A contact sheet: each ``(lines, image)`` row with its label panel on the left.

    Rows are stacked top to bottom, padded white to the widest one.
    """
    out = [
        np.concatenate([label_panel(lines, image.shape[0], LABEL_WIDTH), image], axis=1)
        for lines, image in rows
    ]
    width = max(r.shape[1] for r in out)
    out = [np.pad(r, ((0, 2), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in out]
    return np.concatenate(out, axis=0)


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
        strips = [frame_strip(data.read(i)[1], frames_per_clip) for i in chosen]
        lines = class_lines(class_id, data.manifest.material_set)
        rows.append((lines, np.concatenate(strips, axis=1)))
    return labelled_rows(rows)


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
            draw_label(frame, str(class_id), (3, 12), 0.35)
        cells.append(frames)
    return tile_grid(cells, columns)


def tile_grid(cells: Sequence[np.ndarray], columns: int) -> np.ndarray:
    """Frames (N, H', W', 3): same-sized videos (N_i, H, W, 3) in a grid, row by row.

    A shorter video holds its last frame; the last row is filled up with black cells.
    """
    length = max(len(c) for c in cells)
    cells = [np.concatenate([c, np.repeat(c[-1:], length - len(c), 0)]) for c in cells]
    blank = np.zeros_like(cells[0])
    while len(cells) % columns:
        cells.append(blank)
    rows = [np.concatenate(cells[r : r + columns], axis=2) for r in range(0, len(cells), columns)]
    return np.concatenate(rows, axis=1)


def write_png(path: Path, image: np.ndarray) -> None:
    """Write an RGB uint8 image as a PNG, atomically (no half file on failure)."""
    ok, data = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise RuntimeError(f"PNG encoding failed for {path}")
    atomic_write_bytes(path, data.tobytes())


def write_mp4(path: Path, frames: np.ndarray, fps: float) -> None:
    """Write RGB uint8 frames (N, H, W, 3) as an mp4 (mp4v), atomically.

    OpenCV writes into a private temporary folder; the finished file is then put in place
    by :func:`common.files.atomic_write_bytes`, with the usual file mode.
    """
    height, width = frames.shape[1:3]
    with tempfile.TemporaryDirectory(prefix="clothsense-mp4-") as folder:
        tmp = Path(folder) / "video.mp4"
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
        if not writer.isOpened():
            raise RuntimeError("OpenCV cannot write mp4 (mp4v) here")
        for frame in frames:
            writer.write(np.ascontiguousarray(frame[..., ::-1]))
        writer.release()
        atomic_write_bytes(path, tmp.read_bytes())


@report_user_errors
def main(argv: list[str] | None = None) -> list[Path]:
    """Write the sheet and the video of each dataset; returns the written paths."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path, help="dataset directories")
    parser.add_argument("--out", type=Path, default=Path("outputs/preview"))
    parser.add_argument("--split", default=None, help="train/val/test (default: all)")
    parser.add_argument("--clips-per-class", type=int, default=3)
    parser.add_argument("--frames-per-clip", type=int, default=4)
    args = parser.parse_args(argv)
    check_int(args.clips_per_class, "--clips-per-class", 1)
    check_int(args.frames_per_clip, "--frames-per-clip", 1)
    if args.split is not None:
        check_choice(args.split, "--split", SPLITS)
    check_output_dir(args.out, "--out")
    datasets = []
    for root in args.datasets:  # every dataset read before anything is written
        if not root.is_dir():
            raise InputError(f"datasets: {root} is not a folder (give generated dataset folders)")
        try:
            datasets.append(ClothClipDataset(root, args.split, verify=True))
        except (FileNotFoundError, ValueError) as error:
            raise InputError(f"datasets: {root}: {error}") from None
    args.out.mkdir(parents=True, exist_ok=True)
    written = []
    for root, data in zip(args.datasets, datasets, strict=True):
        name = root.resolve().name
        sheet = contact_sheet(
            data, clips_per_class=args.clips_per_class, frames_per_clip=args.frames_per_clip
        )
        write_png(args.out / f"{name}_sheet.png", sheet)
        video = grid_video(data)
        write_mp4(args.out / f"{name}_grid.mp4", video, float(data.records[0]["fps"]))
        written += [args.out / f"{name}_sheet.png", args.out / f"{name}_grid.mp4"]
        print(
            f"{name}: {written[-2]} ({sheet.shape[1]}x{sheet.shape[0]}), {written[-1]} "
            f"({len(video)} frames)"
        )
    return written


if __name__ == "__main__":
    main()
