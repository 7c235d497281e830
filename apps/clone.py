"""Material cloning (thesis 7.7.3, Fig. 7.9): predict a video's cloth class, then show it draped.

``python -m apps.clone video=<file or folder> run=<training run or checkpoint>``
(configs/clone.yaml) recovers the material class of the cloth in a video with a trained
classifier and "clones" it onto another piece of cloth: a square cloth draped over the arm
scene's bending arm (:class:`simulator.cloth.scenes.ScenarioArmBend`; ``motion=wind`` shows the
wind scene instead), or, with ``target=skirt``, onto a skirt on the mannequin blown by a gusty
wind, as the thesis does (:func:`apps.garment.tryon.clone_skirt`).

1. **Read.** The video is a video file (mp4, avi, ...; OpenCV) or a folder of image frames
   (``video_fps``, default 30), cut into clips exactly as :class:`~datasets.real_video.
   RealVideoDataset` cuts each of its videos (:class:`VideoClips`): shorter side resized and
   centre-cropped to the training frames' size, resampled to the training fps, clips of the
   training clip length every ``clip_stride`` resampled frames. These come from the run's
   training data spec (``<data_dir>/spec.json``).
2. **Predict.** The run's classifier gives each clip's class probabilities; their mean over
   the clips is the video's distribution. Its argmax is the predicted class, and
   :func:`models.scores.material_scores` gives the scalar scores that evaluation correlates.
3. **Compare.** Beside the predicted class come its two most likely *grid neighbours*: of
   the classes one stretch or one bend step away in the stretch x bend grid (6 x 9 for the
   thesis's material set; the run's training data names its set), the two with the highest
   mean probability (ties: lower class id). A corner class has exactly two.
   So the comparison shows what one step stiffer or softer looks like, in the directions
   the model itself found most plausible (:func:`comparison_classes`).
4. **Simulate and render** the three classes as the datasets do
   (:func:`datasets.generation.simulate_unit`, :func:`~datasets.generation.render_frames`),
   all three with one scene seed: same arm placement, texture and background, so only the
   material differs.

Written into the run folder (``logs/clone/runs/<time>/``), all at the end (staged in a
hidden folder there and moved into place, so a failure leaves none of them):

* ``prediction.json``: the video and its clips, the mean probability of each class (54 for
  the thesis's set) and the top 5,
  the predicted class with its stretch and bend multipliers, the material scores, and the
  comparison classes with the rule that chose them;
* ``clone.mp4``: the input beside the three simulated classes (input resampled to ``fps``,
  its first ``record_time`` seconds), each tile labelled with its class id, multipliers and
  probability; the predicted class's label is outlined;
* ``contact_sheet.png``: labelled rows (input, predicted, the two neighbours), a few frames
  each;
* ``sequence.npz``: the three classes' mesh sequence (:mod:`simulator.sequence`; export it
  with ``python -m simulator.export``).

Every field is checked, the checkpoint loaded and the video probed before anything is
predicted or simulated: a bad value ends the command with one line ``error: <field> ...``
(:mod:`common.commands`). This module is an application on top of both the datasets and the
models package (it imports :mod:`models`, which imports datasets' loaders); nothing in
``datasets`` imports it.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import shutil
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf, open_dict

from apps.recording import check_app_fields, render_shown
from common.checks import check_choice, check_device, check_float, check_int
from common.commands import hydra_command
from common.errors import InputError
from common.paths import check_output_dir
from datasets.generate import spec_from_config
from datasets.generation import simulate_unit
from datasets.manifest import write_json
from datasets.plan import WorkUnit, plan_units
from datasets.preview import (
    LABEL_WIDTH,
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
from datasets.real_video import (
    IMAGE_SUFFIXES,
    VIDEO_SUFFIXES,
    LabelRow,
    RealVideoDataset,
    clip_starts,
)
from datasets.runs import RUN_HELP, TrainedRun, find_run
from datasets.spec import DatasetSpec
from models.evaluate import check_class_count, module_grid, predict
from models.material_classifier import MaterialClassifierModule, load_classifier
from models.scores import material_scores
from simulator.cloth.material import WANG54, MaterialSet
from simulator.threads import use_process_threads

__all__ = [
    "COMPARISON_RULE",
    "CloneOutputs",
    "Prediction",
    "TrainedRun",
    "VideoClips",
    "clone_sheet",
    "clone_video",
    "comparison_classes",
    "comparison_rule",
    "display_frames",
    "find_run",
    "grid_neighbours",
    "load_checked_classifier",
    "predict_video",
    "run",
]


def comparison_rule(material_set: MaterialSet = WANG54) -> str:
    """How :func:`comparison_classes` chooses in ``material_set``'s grid, in words."""
    grid = f"{material_set.stretch_count} x {material_set.bend_count}"
    steps = "one stretch or one bend step"
    if material_set.density_count > 1:
        grid += f" x {material_set.density_count}"
        steps = "one stretch, bend or density step"
    return (
        "the predicted class (argmax of the clip-averaged probabilities) and, of its grid "
        f"neighbours ({steps} away in the {grid} grid), the two with the "
        "highest probability (ties: lower class id)"
    )


COMPARISON_RULE = comparison_rule()
"""How :func:`comparison_classes` chooses in the thesis's 6 x 9 grid; ``prediction.json``
holds the rule of the run's own material set."""
TOP_COUNT = 5
_GAP = 4  # px of white between the video's tiles
_ACCENT = (255, 170, 0)  # RGB outline of the predicted class's label
_NAME_CHARS = 20  # characters of the video's name that fit a label line
VIDEO_HELP = (
    f"a video file ({' '.join(VIDEO_SUFFIXES)}) or a folder of frames ({' '.join(IMAGE_SUFFIXES)})"
)


@dataclasses.dataclass(frozen=True)
class Prediction:
    """The classifier's verdict on one video."""

    probabilities: np.ndarray
    """Class probabilities averaged over the clips, shape (classes,) (54 for ``wang54``)."""
    start_frames: tuple[int, ...]
    """First source frame of each clip used."""
    scores: dict[str, float]
    """:func:`models.scores.material_scores` of the mean probabilities."""

    @property
    def predicted_class(self) -> int:
        """The most probable class (the lowest id among equals)."""
        return int(np.argmax(self.probabilities))

    def top(self, count: int = TOP_COUNT) -> list[tuple[int, float]]:
        """The ``count`` most probable classes and their probabilities, most probable first."""
        order = np.argsort(-self.probabilities, kind="stable")[:count]
        return [(int(c), float(self.probabilities[c])) for c in order]


@dataclasses.dataclass(frozen=True)
class CloneOutputs:
    """What one clone run wrote, what it found, and how long it took."""

    prediction: Path
    """``prediction.json``."""
    video: Path
    """Input beside the three simulated classes (mp4)."""
    sheet: Path
    """Labelled contact sheet (PNG)."""
    sequence: Path
    """Mesh sequence of the three classes (npz)."""
    classes: tuple[int, int, int]
    """Predicted class, then its two chosen grid neighbours."""
    seconds: float
    """Wall time of the run [s]."""


def load_checked_classifier(trained: TrainedRun) -> MaterialClassifierModule:
    """The run's classifier, refused (naming ``run``) unless it predicts its data's classes."""
    module = load_classifier(trained.checkpoint, map_location="cpu", field="run")
    try:
        grid = trained.spec.material_set.grid
        check_class_count(
            module, checkpoint=trained.checkpoint, dataset=trained.data_dir, grid=grid
        )
    except InputError as err:
        raise InputError(f"run: {err}") from None
    return module


class VideoClips(RealVideoDataset):
    """The clips of one video, cut and read as :class:`RealVideoDataset` cuts a listed video.

    Only the listing differs: the video is given directly, without ``labels.csv`` and its
    measured columns (samples carry none). Probing (frame count, fps), clip cutting
    (:func:`~datasets.real_video.clip_starts`), reading, resizing and cropping are the
    dataset's own.

    Args:
        path: A video file or a folder of image frames.
        fps: Frame rate of a frame folder [1/s] (``None``: 30); a video file carries its own.
        clip_len: Frames per clip.
        clip_stride: Resampled frames between clip starts.
        target_fps: Frame rate of the clips [1/s].
        size: Side of the square frames [px].
        max_clips: Keep only the first clips (``None``: all).

    Raises:
        InputError: naming ``video``: missing, of another kind, unreadable, or too short for
            one clip (with the frames it has and the frames one clip needs).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        fps: float | None = None,
        clip_len: int,
        clip_stride: int,
        target_fps: float,
        size: int,
        max_clips: int | None = None,
    ):
        path = _check_video_path(path)
        self.root = path.parent
        self.columns = ()
        self.group_column, self.group_rule = None, "one video"
        self.transform = None
        self.clip_len = check_int(clip_len, "clip_len", 1)
        self.clip_stride = check_int(clip_stride, "clip_stride", 1)
        self.size = check_int(size, "size", 1)
        self.target_fps = check_float(target_fps, "target_fps", 0.0, low_open=True)
        fields = {"video": path.name}
        if fps is not None:
            fields["fps"] = repr(check_float(fps, "video_fps", 0.0, low_open=True))
        try:
            video = self.probe(LabelRow(0, fields), path.name)
        except InputError as err:  # OpenCV cannot open it
            raise InputError(f"video: {err}; give {VIDEO_HELP}") from None
        if video.frame_count == 0:
            raise InputError(f"video: OpenCV reads no frame of {path}; give {VIDEO_HELP}")
        self.videos = [video]
        step = self.frame_step(video)
        starts = clip_starts(video.frame_count, self.clip_len, self.clip_stride, step)
        if not starts:
            raise InputError(
                f"video: {path} has {video.frame_count} frames at {video.fps:g} fps; one clip of "
                f"{self.clip_len} frames at {self.target_fps:g} fps (the run's training clips) "
                f"needs {(self.clip_len - 1) * step + 1}"
            )
        if max_clips is not None:
            starts = starts[:max_clips]
        self.clips = [(0, start) for start in starts]
        self.skipped = ()

    @property
    def video(self):
        """The probed video (name, path, fps [1/s], frame_count)."""
        return self.videos[0]

    def read_frames(self, index: int) -> np.ndarray:
        """uint8 RGB frames (T, size, size, 3) of clip ``index``.

        Raises:
            InputError: naming ``video`` when a frame cannot be read.
        """
        try:
            return super().read_frames(index)
        except InputError:
            raise
        except ValueError as err:
            raise InputError(f"video: {err}") from None


def _check_video_path(value) -> Path:
    if not isinstance(value, str | Path) or not str(value).strip():
        raise InputError(f"video must be {VIDEO_HELP}, got {value!r}")
    path = Path(value)
    if path.is_dir():
        if not any(p.suffix.lower() in IMAGE_SUFFIXES for p in path.iterdir()):
            raise InputError(f"video: folder {path} holds no frames; give {VIDEO_HELP}")
    elif path.is_file():
        if path.suffix.lower() not in VIDEO_SUFFIXES:
            raise InputError(f"video: {path} is not a video file; give {VIDEO_HELP}")
    else:
        raise InputError(f"video: {path} does not exist; give {VIDEO_HELP}")
    return path


def display_frames(clips: VideoClips, count: int, fps: float, size: int) -> np.ndarray:
    """The video's first ``count`` frames at ``fps``, uint8 (count, size, size, 3).

    For showing beside the simulations: read at the video's own rate (every source frame),
    then each display time takes the source frame it falls in, so a video slower than
    ``fps`` is slowed to real time rather than sped up. A video shorter than ``count``
    frames holds its last one.
    """
    video = clips.video
    ratio = video.fps / fps
    needed = min(video.frame_count, math.floor((count - 1) * ratio + 1e-9) + 1)
    reader = VideoClips(
        video.path,
        fps=video.fps,
        clip_len=needed,
        clip_stride=1,
        target_fps=video.fps,
        size=size,
    )
    frames = reader.read_frames(0)
    index = np.minimum(np.floor(np.arange(count) * ratio + 1e-9).astype(int), needed - 1)
    return frames[index]


def predict_video(
    module: MaterialClassifierModule,
    clips: VideoClips,
    *,
    batch_size: int = 16,
    device: torch.device | None = None,
) -> Prediction:
    """Class probabilities of every clip, averaged, and their scores (the module's class grid)."""
    grid = module_grid(module)
    logits, _ = predict(
        module,
        clips,
        batch_size=batch_size,
        device=device,
        desc="clips",
        class_count=grid.num_classes,
    )
    probs = logits.double().softmax(dim=1).mean(dim=0)
    scores = {k: float(v[0]) for k, v in material_scores(probs[None], grid).items()}
    scores["predicted_class"] = int(scores["predicted_class"])
    return Prediction(
        probabilities=probs.numpy(),
        start_frames=tuple(start for _, start in clips.clips),
        scores=scores,
    )


def grid_neighbours(class_id: int, material_set: MaterialSet = WANG54) -> tuple[int, ...]:
    """Classes one stretch, bend or density step from ``class_id`` in the set's grid, ascending."""
    grid = material_set.grid
    here = grid.position(int(class_id))
    counts = (grid.stretch_count, grid.bend_count, grid.density_count)
    out = []
    for axis in range(3):
        for step in (-1, 1):
            there = list(here)
            there[axis] += step
            if 0 <= there[axis] < counts[axis]:
                out.append(grid.class_id(*there))
    return tuple(sorted(out))


def comparison_classes(
    probabilities: np.ndarray, material_set: MaterialSet = WANG54
) -> tuple[int, int, int]:
    """The predicted class and its two most probable grid neighbours (:func:`comparison_rule`).

    Args:
        probabilities: Class probabilities, shape (classes,) of ``material_set``.
        material_set: The classes' set (the run's training data's).
    """
    probs = np.asarray(probabilities, dtype=np.float64)
    count = material_set.num_classes
    if probs.shape != (count,):
        raise ValueError(f"probabilities must have shape ({count},), got {probs.shape}")
    predicted = int(np.argmax(probs))
    neighbours = grid_neighbours(predicted, material_set)
    first, second = sorted(neighbours, key=lambda c: (-probs[c], c))[:2]
    return predicted, first, second


def _checked(cfg: DictConfig) -> dict:
    """Every field, the run, the classifier and the video, checked before any work.

    Raises:
        InputError: naming the first bad field and its allowed values.
    """
    for field, allowed in (("video", VIDEO_HELP), ("run", RUN_HELP)):
        if OmegaConf.is_missing(cfg, field):
            raise InputError(f"{field} is required: give {field}=<{allowed}>")
    threads, recording, sheet_frames = check_app_fields(cfg)
    target = check_choice(cfg.get("target", "cloth"), "target", CLONE_TARGETS)
    batch_size = check_int(cfg.batch_size, "batch_size", 1)
    device = check_device(cfg.device, "device")
    video_fps = None
    if cfg.video_fps is not None:
        video_fps = check_float(cfg.video_fps, "video_fps", 0, low_open=True)
    max_clips = None if cfg.max_clips is None else check_int(cfg.max_clips, "max_clips", 1)
    check_output_dir(cfg.out_dir, "out_dir")
    spec_cfg = copy.deepcopy(cfg)  # the classes come from the prediction
    with open_dict(spec_cfg):
        spec_cfg.classes = None
    spec = spec_from_config(spec_cfg, preset=recording.preset("clone"))
    recording.check_memory(spec, 3)  # the predicted class and two neighbours
    if spec.camera.width != spec.camera.height:
        raise InputError(
            "render.camera.width and render.camera.height must be equal (square tiles beside "
            f"the square-cropped input), got {spec.camera.width} x {spec.camera.height}"
        )

    trained = find_run(cfg.run, cfg.data_dir)
    clip_len = trained.spec.preset.frames_per_clip
    clip_stride = clip_len if cfg.clip_stride is None else cfg.clip_stride
    clip_stride = check_int(clip_stride, "clip_stride", 1)
    clips = VideoClips(
        cfg.video,
        fps=video_fps,
        clip_len=clip_len,
        clip_stride=clip_stride,
        target_fps=trained.spec.preset.fps,
        size=trained.spec.camera.height,
        max_clips=max_clips,
    )
    module = load_checked_classifier(trained)
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    return {
        "spec": spec,
        "trained": trained,
        "clips": clips,
        "module": module,
        "device": torch.device(device),
        "batch_size": batch_size,
        "threads": threads,
        "sheet_frames": sheet_frames,
        "out_dir": Path(cfg.out_dir),
        "target": target,
    }


CLONE_TARGETS = ("cloth", "skirt")
"""What the classes are shown on: the motion scene's square cloth, or a skirt on the
mannequin (*thesis* Fig. 7.9; :func:`apps.garment.tryon.clone_skirt`)."""


def _skirt_clone(spec: DatasetSpec, classes, material_set: MaterialSet, unit: WorkUnit, on_step):
    """The classes on a skirt in wind: the mesh sequence and the rendered tiles."""
    from apps.garment.tryon import clone_skirt

    fps = spec.preset.fps
    return clone_skirt(
        material_set.materials(list(classes)),
        level=spec.scenario.resolution_level,
        seconds=(spec.frames_per_sim - 1) / fps,
        fps=fps,
        size=spec.camera.height,
        seed=unit.sims[0].seed,
        on_frame=on_step,
    )


def _one_scene(spec: DatasetSpec) -> WorkUnit:
    """The spec's one work unit, every class with the first class's seed (one scene)."""
    (unit,) = plan_units(spec)
    seed = unit.sims[0].seed
    return dataclasses.replace(
        unit, sims=tuple(dataclasses.replace(sim, seed=seed) for sim in unit.sims)
    )


def _class_entry(class_id: int, probability: float, material_set: MaterialSet, **extra) -> dict:
    stretch, bend = material_set.multipliers(class_id)
    density = (
        {"density_multiplier": material_set.density_mult(class_id)}
        if material_set.density_count > 1
        else {}
    )
    return {
        "class": int(class_id),
        "probability": float(probability),
        "stretch_multiplier": stretch,
        "bend_multiplier": bend,
        **density,
        **extra,
    }


def _report(
    prediction: Prediction,
    classes: Sequence[int],
    clips: VideoClips,
    trained: TrainedRun,
    spec: DatasetSpec,
    unit: WorkUnit,
) -> dict:
    """The contents of ``prediction.json``."""
    probs = prediction.probabilities
    video = clips.video
    roles = ["predicted"] + ["neighbour"] * (len(classes) - 1)
    material_set = trained.spec.material_set
    return {
        "video": str(video.path),
        "video_fps": video.fps,
        "video_frames": video.frame_count,
        "clips": {
            "count": len(clips),
            "start_frames": list(prediction.start_frames),
            "clip_len": clips.clip_len,
            "clip_stride": clips.clip_stride,
            "target_fps": clips.target_fps,
            "size": clips.size,
        },
        "run": {"checkpoint": str(trained.checkpoint), "data_dir": str(trained.data_dir)},
        "probabilities": [float(p) for p in probs],
        "top5": [_class_entry(c, p, material_set) for c, p in prediction.top(TOP_COUNT)],
        "predicted": _class_entry(
            prediction.predicted_class, probs[prediction.predicted_class], material_set
        ),
        "scores": prediction.scores,
        "comparison": {
            "rule": comparison_rule(material_set),
            "classes": [
                _class_entry(c, probs[c], material_set, role=r)
                for c, r in zip(classes, roles, strict=True)
            ],
        },
        "simulation": {
            "motion": spec.motion,
            "level": spec.scenario.resolution_level,
            "fps": spec.preset.fps,
            "frames": spec.frames_per_sim - spec.lead_in_frames,
            "seed": unit.sims[0].seed,
            "texture": spec.texture_mode,
        },
    }


def run(cfg: DictConfig) -> CloneOutputs:
    """Predict the video's class, simulate it and two neighbours, write the outputs."""
    start = time.perf_counter()
    checked = _checked(cfg)
    use_process_threads(checked["threads"], name="threads")
    clips: VideoClips = checked["clips"]
    trained: TrainedRun = checked["trained"]

    prediction = predict_video(
        checked["module"], clips, batch_size=checked["batch_size"], device=checked["device"]
    )
    material_set = trained.spec.material_set  # the classes the run was trained on
    classes = comparison_classes(prediction.probabilities, material_set)
    spec = dataclasses.replace(checked["spec"], classes=classes, material_set=material_set)
    unit = _one_scene(spec)
    predicted = time.perf_counter()

    from tqdm import tqdm

    bar = tqdm(desc="simulate", unit="step", smoothing=0.0)

    def on_step(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    first, stop = spec.lead_in_frames, spec.frames_per_sim
    try:
        if checked["target"] == "skirt":
            seq, skirt_frames = _skirt_clone(spec, classes, material_set, unit, on_step)
        else:
            seq = simulate_unit(spec, unit, None, on_step=on_step)
    finally:
        bar.close()
    seq.meta["classes"] = [material_set.summary(c) for c in classes]
    seq.meta["clone"] = {"video": str(clips.video.path), "checkpoint": str(trained.checkpoint)}
    simulated = time.perf_counter()

    if checked["target"] == "skirt":
        rendered = [skirt_frames[b, first:stop] for b in range(len(unit.sims))]
    else:
        rendered = render_shown(spec, seq, unit)
    fps = spec.preset.fps
    shown = stop - first
    source = display_frames(clips, shown, fps, spec.camera.height)

    probs = prediction.probabilities
    video = clips.video
    name = video.name if len(video.name) <= _NAME_CHARS else video.name[: _NAME_CHARS - 2] + ".."
    labels = [
        ("input video", name, f"{len(clips)} clips, {video.fps:g} fps", f"-> class {classes[0]}")
    ]
    labels += [
        (
            *class_lines(c, material_set),
            f"{'predicted' if i == 0 else 'neighbour'}, p={probs[c]:.2f}",
        )
        for i, c in enumerate(classes)
    ]
    tiles = [source, *rendered]
    times = np.arange(shown) / fps
    report = _report(prediction, classes, clips, trained, spec, unit)
    report["simulation"]["target"] = checked["target"]

    out_dir = checked["out_dir"]
    names = ("prediction.json", "clone.mp4", "contact_sheet.png", "sequence.npz")
    out_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".clone-", dir=out_dir))
    try:
        write_json(staging / names[0], report)
        write_mp4(staging / names[1], clone_video(tiles, labels, marked=1), fps)
        sheet = clone_sheet(tiles, labels, times, checked["sheet_frames"], marked=1)
        write_png(staging / names[2], sheet)
        seq.save(staging / names[3])
        for name in names:
            os.replace(staging / name, out_dir / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    paths = [out_dir / name for name in names]

    seconds = time.perf_counter() - start
    c = classes[0]
    stretch, bend = material_set.multipliers(c)
    print(
        f"clone: {video.path} -> class {c} (stretch x{stretch:g}, bend x{bend:g}, "
        f"p={probs[c]:.2f}) from {len(clips)} clips; shown beside classes {classes[1]} and "
        f"{classes[2]} in the {spec.motion} scene, level {spec.scenario.resolution_level}, "
        f"{shown} frames at {fps:g} fps in {seconds:.1f} s (predict {predicted - start:.1f} s, "
        f"simulate {simulated - predicted:.1f} s)\n"
        f"  prediction     {paths[0]}\n"
        f"  video          {paths[1]}\n"
        f"  contact sheet  {paths[2]}\n"
        f"  mesh sequence  {paths[3]}"
    )
    return CloneOutputs(*paths, classes=classes, seconds=seconds)


def _outline(image: np.ndarray, top: int, height: int, width: int) -> None:
    """Outline a label panel (rows ``[top, top + height)``, columns ``[0, width)``) in place."""
    corner = (width - 1, top + height - 1)
    cv2.rectangle(image, (0, top), corner, _ACCENT, 2)


def clone_video(
    clips: Sequence[np.ndarray], labels: Sequence[Sequence[str]], *, marked: int
) -> np.ndarray:
    """Video frames (K, H', W', 3): same-sized clips (K, H, W, 3) side by side, labelled.

    Each tile has its label lines above it; the label of tile ``marked`` is outlined. The
    size is padded to even numbers, which some mp4 players need.
    """
    strip = label_height(max(len(lines) for lines in labels))
    tiles = []
    for i, (frames, lines) in enumerate(zip(clips, labels, strict=True)):
        label = label_panel(lines, strip, frames.shape[2])
        if i == marked:
            _outline(label, 0, strip, frames.shape[2])
        tile = np.concatenate([np.broadcast_to(label, (len(frames), *label.shape)), frames], 1)
        tiles.append(np.pad(tile, ((0, 0), (0, _GAP), (0, _GAP), (0, 0)), constant_values=255))
    video = tile_grid(tiles, len(tiles))[:, :-_GAP, :-_GAP]
    height, width = video.shape[1:3]
    return np.pad(video, ((0, 0), (0, height % 2), (0, width % 2), (0, 0)), constant_values=255)


def clone_sheet(
    clips: Sequence[np.ndarray],
    labels: Sequence[Sequence[str]],
    times: np.ndarray,
    count: int,
    *,
    marked: int,
) -> np.ndarray:
    """Contact sheet: one labelled row per clip (K, H, W, 3), ``count`` evenly spaced frames.

    Each frame carries its time [s] since the recording started; the label of row
    ``marked`` is outlined.
    """
    stamped = []
    for frames in clips:
        frames = frames.copy()
        for frame, t in zip(frames, times, strict=True):
            draw_label(frame, f"{t:.2f} s", (5, frame.shape[0] - 7))
        stamped.append(frames)
    sheet = labelled_rows(
        [(lines, frame_strip(f, count)) for f, lines in zip(stamped, labels, strict=True)]
    )
    height = clips[0].shape[1]
    _outline(sheet, marked * (height + 2), height, LABEL_WIDTH)  # rows are 2 px apart
    return sheet


main = hydra_command(run, config_name="clone")
"""The command line: ``python -m apps.clone`` (``configs/clone.yaml``)."""


if __name__ == "__main__":
    main()
