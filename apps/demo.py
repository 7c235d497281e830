"""The main job (configs/demo.yaml): simulate a few classes, render them, and show them.

``python -m apps.demo`` simulates three classes that span the stretch x bend grid in the
wind scene on the coarsest mesh, renders every instance the way dataset generation does
(:func:`datasets.generation.simulate_unit` and :func:`~datasets.generation.render_frames`:
same textures, backgrounds, camera and solver settings) and writes into the run folder
(``logs/demo/runs/<time>/``):

* ``sequence.npz``: the mesh sequence (format in :mod:`simulator.sequence`);
* ``classes.mp4``: the classes side by side, each labelled with its class id and its
  stretch and bend multipliers;
* ``contact_sheet.png``: one labelled row per class, a few frames each.

It ends with a short summary naming the three files and the wall time: about a minute
on a 2-core CPU the first time (the solver's kernels are compiled and cached), about 30 s
after that. The full-size mesh is one override away: ``level=3 classes=[0,13,26,40,53]``
(and ``record_time=8`` records longer). Every field is checked before anything is
simulated: a bad value ends the command with one line ``error: <field> must be ...``
(:mod:`common.commands`), and nothing is written.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from apps.recording import check_app_fields, render_shown
from common.checks import check_int
from common.commands import hydra_command
from common.paths import check_output_dir
from datasets.generate import spec_from_config
from datasets.generation import simulate_unit
from datasets.plan import WorkUnit, plan_units
from datasets.preview import (
    class_lines,
    draw_label,
    frame_strip,
    label_height,
    label_panel,
    labelled_rows,
    tile_grid,
    write_mp4,
    write_png,
)
from datasets.spec import DatasetSpec
from simulator.cloth.material import class_summary
from simulator.threads import use_process_threads

__all__ = ["VIDEO_COLUMNS", "DemoOutputs", "class_sheet", "class_video", "run"]

_GAP = 4  # px of white between the video's tiles
VIDEO_COLUMNS = 9
"""Most tiles in one row of the video (all 54 classes: 6 rows of 9, as the class grid)."""


@dataclasses.dataclass(frozen=True)
class DemoOutputs:
    """What one demo run wrote, and how long it took."""

    sheet: Path
    """Labelled contact sheet (PNG)."""
    video: Path
    """Classes side by side (mp4)."""
    sequence: Path
    """Mesh sequence (npz)."""
    seconds: float
    """Wall time of the run [s] (simulation, rendering and writing)."""


def _checked(cfg: DictConfig) -> tuple[DatasetSpec, WorkUnit, dict]:
    """The dataset spec and the one work unit of the demo, plus its own fields.

    Raises:
        InputError: naming the first bad field and its allowed values.
    """
    threads, recording, sheet_frames = check_app_fields(cfg)
    spec = spec_from_config(cfg, preset=recording.preset("demo"))
    recording.check_memory(spec, len(spec.classes))
    speeds = getattr(spec.scenario, "wind_speeds", None)
    wind_level = check_int(cfg.wind_level, "wind_level", 0, len(speeds) - 1 if speeds else None)
    (unit,) = plan_units(spec)
    sims = tuple(dataclasses.replace(sim, wind_level=wind_level) for sim in unit.sims)
    check_output_dir(cfg.out_dir, "out_dir")
    fields = {"threads": threads, "sheet_frames": sheet_frames, "out_dir": Path(cfg.out_dir)}
    return spec, dataclasses.replace(unit, sims=sims), fields


def run(cfg: DictConfig) -> DemoOutputs:
    """Simulate, render and write the demo's sequence, video and contact sheet."""
    start = time.perf_counter()
    spec, unit, fields = _checked(cfg)
    use_process_threads(fields["threads"], name="threads")
    out_dir = fields["out_dir"]
    classes = [sim.class_id for sim in unit.sims]

    with _progress("simulate", "step") as on_step:
        seq = simulate_unit(spec, unit, None, on_step=on_step)
    seq.meta["classes"] = [class_summary(c) for c in classes]
    sequence_path = seq.save(out_dir / "sequence.npz")
    simulated = time.perf_counter()

    first, stop = spec.lead_in_frames, spec.frames_per_sim
    with _progress("render", "frame") as on_frames:
        clips = render_shown(spec, seq, unit, on_frames)

    fps = spec.preset.fps
    video_path = out_dir / "classes.mp4"
    write_mp4(video_path, class_video(clips, classes), fps)
    times = (first + np.arange(stop - first)) / fps
    sheet_path = out_dir / "contact_sheet.png"
    write_png(sheet_path, class_sheet(clips, classes, times, fields["sheet_frames"]))

    seconds = time.perf_counter() - start
    outputs = DemoOutputs(sheet_path, video_path, sequence_path, seconds)
    wind = f", wind W{unit.sims[0].wind_level + 1}" if spec.motion == "wind" else ""
    print(
        f"demo: {spec.motion} scene{wind}, level {spec.scenario.resolution_level}, classes "
        f"{', '.join(map(str, classes))}, {stop - first} frames at {fps:g} fps in {seconds:.1f} s "
        f"(simulate {simulated - start:.1f} s)\n"
        f"  contact sheet  {sheet_path}\n"
        f"  video          {video_path}\n"
        f"  mesh sequence  {sequence_path}"
    )
    return outputs


def class_video(clips: list[np.ndarray], classes: list[int]) -> np.ndarray:
    """Video frames (K, H', W', 3): the clips (K, H, W, 3) as labelled tiles, side by side.

    Each tile has its class's label above it; more than :data:`VIDEO_COLUMNS` classes wrap
    into further rows. The size is padded to even numbers, which some mp4 players need.
    """
    strip = label_height(len(class_lines(classes[0])))
    tiles = []
    for frames, class_id in zip(clips, classes, strict=True):
        label = label_panel(class_lines(class_id), strip, frames.shape[2])
        tile = np.concatenate([np.broadcast_to(label, (len(frames), *label.shape)), frames], 1)
        tiles.append(np.pad(tile, ((0, 0), (0, _GAP), (0, _GAP), (0, 0)), constant_values=255))
    video = tile_grid(tiles, min(VIDEO_COLUMNS, len(tiles)))[:, :-_GAP, :-_GAP]
    height, width = video.shape[1:3]
    return np.pad(video, ((0, 0), (0, height % 2), (0, width % 2), (0, 0)), constant_values=255)


def class_sheet(
    clips: list[np.ndarray], classes: list[int], times: np.ndarray, count: int
) -> np.ndarray:
    """Contact sheet: one labelled row per class, ``count`` evenly spaced frames each.

    Each frame carries its time [s] since the recording started (at rest, after settling).
    """
    stamped = []
    for frames in clips:
        frames = frames.copy()
        for frame, t in zip(frames, times, strict=True):
            draw_label(frame, f"{t:.2f} s", (5, frame.shape[0] - 7))
        stamped.append(frames)
    return labelled_rows(
        [(class_lines(c), frame_strip(f, count)) for f, c in zip(stamped, classes, strict=True)]
    )


@contextlib.contextmanager
def _progress(desc: str, unit: str) -> Iterator[Callable[[int, int], None]]:
    """A tqdm bar driven by an ``on_step(done, total)`` callback, closed when the block ends."""
    from tqdm import tqdm

    bar = tqdm(desc=desc, unit=unit, smoothing=0.0)

    def update(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    try:
        yield update
    finally:
        bar.close()


main = hydra_command(run, config_name="demo")
"""The command line: ``python -m apps.demo`` (``configs/demo.yaml``)."""


if __name__ == "__main__":
    main()
