"""Evaluate a trained classifier: simulated test split (Table 7.2) and real videos (Table 7.3).

``python -m models.evaluate ckpt_path=RUN/checkpoints/best.ckpt data_dir=DATASET
real_dir=FOLDER [real.columns=[stiffness,density,bending_rigidity]] [real.group=fabric]``
(configs/evaluate.yaml). Each evaluation gets a folder of its own::

    OUT/<dataset>-<split>+<real folder>-<hash>/     OUT = out_dir, default RUN/eval

(``<dataset>-<split>`` or ``<real folder>`` alone when only one is evaluated). ``<hash>`` is
the first 10 hex digits of the sha256 of every input that decides the numbers: the
checkpoint's bytes, the dataset's manifest, the real folder's ``labels.csv`` and file list
(names, sizes, modification times), split and protocol, clip cutting, columns, group rule and
bootstrap. The same inputs always map to the same folder and different inputs never share one, so
neither the training run's ``RUN/eval/sim_test.json`` (read by :mod:`benchmarks.thesis.table72`) nor
an earlier report is overwritten. A folder whose evaluation finished (it holds ``evaluation.json``,
the hashed inputs) is refused unless ``overwrite=true``; an evaluation that fails removes the folder
it created. The folder holds:

* ``sim_<split>.json`` / ``.md``: top-1 and top-5 accuracy over the classes (54 of the 6 x 9
  grid for the thesis's material set), stretch- and bend-factor accuracy, grid MAE, the same per
  wind level (W1, W2, W3), and ``confusion_<split>.png``;
* ``real.json`` / ``.md`` / ``real_videos.csv``: per video the clip-averaged class
  probabilities turned into scores (:mod:`models.scores`); each score's Pearson r and
  Spearman rho, with group-bootstrap 95 % intervals and p-values (:mod:`models.correlation`),
  against each chosen measured column, for all videos and per wind label; the counts of
  videos listed, used and skipped (too short for one clip); and
  ``scatter_<score>_vs_<column>.png`` (predicted vs measured, coloured by wind).

The classes come with the data, never from the simulator: a dataset's from its manifest's
material set, real footage's from the checkpoint's ``class_grid`` hyper-parameter (checkpoints
without one predict the 54 classes of ``wang54``, see
:func:`~models.material_classifier.load_classifier`). The checkpoint's class count is checked
against them before anything is predicted. Predictions run through Lightning's test loop
(``trainer.test`` over :class:`~models.material_classifier.ClipOutputsModule`, :func:`predict`),
the same path for ``train.py``'s final test and this command; real footage comes from its
datamodule, :class:`~datasets.real_datamodule.RealVideoDataModule`.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import re
import shutil
import sys
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback, TQDMProgressBar
from lightning.pytorch.callbacks.progress.tqdm_progress import Tqdm
from omegaconf import DictConfig, OmegaConf
from torch import nn
from torch.utils.data import DataLoader, Dataset

from common.checks import check_choice, check_float, check_int
from common.commands import hydra_command
from common.errors import InputError
from common.files import atomic_write_bytes
from common.grid import ClassGrid
from common.paths import check_output_dir
from datasets.clip_dataset import ClothClipDataset
from datasets.manifest import SPLIT_PROTOCOLS, Manifest, legacy_class_grid
from datasets.real_datamodule import RealVideoDataModule
from datasets.real_video import DEFAULT_COLUMNS, RealVideoDataset, footage_files
from datasets.spec import SPLITS

from .correlation import MIN_SAMPLES, correlate
from .material_classifier import ClipOutputsModule, MaterialClassifierModule, load_classifier
from .metrics import (
    BREAKDOWNS,
    breakdown_metrics,
    classification_metrics,
    confusion_matrix,
)
from .report import confusion_png, markdown_table, scatter_png, wind_label, write_json, write_text
from .scores import SCORE_NAMES, correlated_scores, material_scores

__all__ = [
    "check_class_count",
    "checkpoint_class_count",
    "dataset_grid",
    "evaluate_real",
    "evaluate_simulated",
    "evaluation_folder",
    "module_grid",
    "pick_device",
    "predict",
    "run",
]

log = logging.getLogger(__name__)

THESIS_TABLE_73 = {"stiffness": (0.47, 0.43, 0.50), "density": (0.55, 0.62, 0.64)}
"""Thesis Table 7.3, CNN+LSTM on all 30 fabrics, W1/W2/W3 videos."""
FINISHED = "evaluation.json"
"""Written last into an evaluation folder: its inputs; its presence marks the folder done."""
HASH_DIGITS = 10


def pick_device() -> torch.device:
    """CUDA when present, else CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def checkpoint_class_count(module: MaterialClassifierModule) -> int | None:
    """Classes the module predicts, read from its net (``None`` when the net does not say)."""
    head = getattr(module.net, "classifier", None)
    if isinstance(head, nn.Linear):
        return int(head.out_features)
    config = module.hparams.get("net_config") or {}
    count = config.get("num_classes") if hasattr(config, "get") else None
    return None if count is None else int(count)


def _score_definition(grid: ClassGrid) -> str:
    """The scores' definitions in one sentence (``real.json``'s ``score_definition``)."""
    ids = f"stretch_index * {grid.bend_count} + bend_index"
    if grid.density_count > 1:
        ids = f"({ids}) * {grid.density_count} + density_index"
    text = (
        f"material_score = sum_c p_c * c over the {grid.num_classes} classes (class id = {ids}, "
        f"a stiffness ordering); stretch_score, bend_score = expected stretch "
        f"(0..{grid.stretch_count - 1}) and bend (0..{grid.bend_count - 1}) index"
    )
    if grid.density_count > 1:
        text += f"; density_score = expected density index (0..{grid.density_count - 1})"
    return text + "; p averaged over a video's clips"


def dataset_grid(data_dir: str | Path) -> ClassGrid:
    """The class grid of a generated dataset: its manifest's material set."""
    return Manifest.load(data_dir).material_set.grid


def module_grid(module: MaterialClassifierModule) -> ClassGrid:
    """The class grid a module was trained on: its ``class_grid``, else ``wang54``'s.

    A module without one predates the grids in checkpoints (:func:`load_classifier` fills
    theirs the same way); every dataset of that time had the 54 classes of ``wang54``.
    """
    return module.class_grid or ClassGrid.from_json(legacy_class_grid())


def check_class_count(
    module: MaterialClassifierModule,
    *,
    checkpoint: str | Path | None,
    dataset: str | Path,
    grid: ClassGrid,
) -> None:
    """Refuse a checkpoint whose classes are not ``grid``'s, the data's (one line, both).

    The class counts must agree; a checkpoint that records its grid must have this one.
    """
    name = checkpoint or "(in memory)"
    count = checkpoint_class_count(module)
    if count is not None and count != grid.num_classes:
        raise InputError(
            f"checkpoint {name} predicts {count} classes but {dataset} has {grid.describe()}; "
            "use a checkpoint trained on them"
        )
    if module.class_grid is not None and module.class_grid != grid:
        theirs, ours = module.class_grid.to_json(), grid.to_json()
        raise InputError(
            f"checkpoint {name} was trained on the class grid stretch "
            f"{theirs['stretch_multipliers']} x bend {theirs['bend_multipliers']} but {dataset} "
            f"has stretch {ours['stretch_multipliers']} x bend {ours['bend_multipliers']}; use "
            "a checkpoint trained on its material set"
        )


class _WidthCheck(Callback):
    """Refuse logits whose width is not ``class_count`` at the first batch."""

    def __init__(self, class_count: int):
        self.class_count = class_count

    def on_test_batch_end(self, trainer, pl_module, outputs, batch, batch_idx, *_) -> None:
        """Check the first batch's logits."""
        width = outputs["logits"].shape[-1]
        if batch_idx == 0 and width != self.class_count:
            raise InputError(
                f"the checkpoint predicts {width} classes but the dataset has {self.class_count}"
            )


class _Progress(TQDMProgressBar):
    """Lightning's progress bar, named after what is predicted, on stderr and gone when done."""

    def __init__(self, desc: str):
        super().__init__()
        self.desc = desc

    @property
    def test_description(self) -> str:
        """The bar's name."""
        return self.desc

    def init_test_tqdm(self) -> Tqdm:
        """A bar that leaves stdout to the command's own output."""
        return Tqdm(
            desc=self.desc,
            disable=self.is_disabled,
            leave=False,
            dynamic_ncols=True,
            file=sys.stderr,
            smoothing=0,
            unit="batch",
        )


@contextmanager
def _quiet_lightning() -> Iterator[None]:
    """Silence Lightning's per-trainer banners (devices, loader workers) around a prediction."""
    names = ("lightning.pytorch.utilities.rank_zero", "lightning.pytorch.accelerators.cuda")
    loggers = [logging.getLogger(name) for name in names]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*does not have many workers.*")
            warnings.filterwarnings("ignore", message=".*treespec, LeafSpec.*")  # Lightning's own
            yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


def predict(
    module: MaterialClassifierModule,
    data: Dataset | L.LightningDataModule,
    *,
    batch_size: int = 16,
    device: torch.device | None = None,
    desc: str = "predict",
    class_count: int | None = None,
) -> tuple[torch.Tensor, list[dict]]:
    """Logits (N, classes) of every clip of ``data`` and each sample's metadata (no pixels).

    Lightning's test loop (``trainer.test``) runs the module inside
    :class:`~models.material_classifier.ClipOutputsModule` over the clips in order: those of
    a datamodule's ``test_dataloader``, or of a dataset in batches of ``batch_size``. It runs
    on ``device`` (default :func:`pick_device`), in full precision without gradients. With
    ``class_count``, logits of another width are refused at the first batch.
    """
    device = device or pick_device()
    callbacks: list[Callback] = [_Progress(desc)]
    if class_count is not None:
        callbacks.append(_WidthCheck(class_count))
    clips = ClipOutputsModule(module)
    with _quiet_lightning():
        trainer = L.Trainer(
            accelerator=device.type,
            devices=[device.index] if device.index is not None else 1,
            precision="32-true",
            logger=False,
            enable_checkpointing=False,
            enable_model_summary=False,
            inference_mode=False,
            callbacks=callbacks,
        )
        if isinstance(data, L.LightningDataModule):
            trainer.test(clips, datamodule=data, verbose=False)
        else:
            loader = DataLoader(data, batch_size=batch_size, shuffle=False, num_workers=0)
            trainer.test(clips, dataloaders=loader, verbose=False)
    logits, meta = [], []
    for out in clips.outputs:
        logits.append(out["logits"])
        for i in range(out["logits"].shape[0]):
            meta.append({k: _item(v[i]) for k, v in out["meta"].items()})
    return torch.cat(logits), meta


def _item(value):
    return value.item() if isinstance(value, torch.Tensor) else value


def _pct(value: float) -> str:
    return f"{100 * value:.1f}"


def _metrics_row(label: str, m: dict) -> list:
    """One row of the simulated-split report: clips, top-1/top-5, stretch, bend, grid MAE."""
    return [
        label,
        m["clips"],
        _pct(m["acc"]),
        _pct(m["top5"]),
        _pct(m["stretch_acc"]),
        _pct(m["bend_acc"]),
        f"{m['grid_mae']:.2f}",
    ]


def _breakdown_label(field: str, value: str) -> str:
    if field == "wind_level":
        return f"wind {wind_label(value)}"
    return f"{field.replace('_', ' ')} {value}"


def evaluate_simulated(
    module: MaterialClassifierModule,
    data_dir: str | Path,
    out_dir: str | Path,
    *,
    split: str = "test",
    split_protocol: str = "simulation",
    batch_size: int = 16,
    extra: dict | None = None,
    checkpoint: str | Path | None = None,
) -> dict:
    """Metrics of ``module`` on one split of a generated dataset; writes JSON, MD and PNG.

    ``split_protocol`` must be the one the model was trained under (see
    :data:`datasets.manifest.SPLIT_PROTOCOLS`). ``extra`` entries (e.g. training time and
    device) are stored in the JSON as they are. The JSON keeps wind levels as stored (0, 1,
    2: the results ledger reads them); the Markdown names them W1, W2, W3.
    """
    grid = dataset_grid(data_dir)
    check_class_count(module, checkpoint=checkpoint, dataset=data_dir, grid=grid)
    dataset = ClothClipDataset(data_dir, split, verify=True, split_protocol=split_protocol)
    logits, meta = predict(
        module,
        dataset,
        batch_size=batch_size,
        desc=f"{split} clips",
        class_count=grid.num_classes,
    )
    labels = torch.tensor([m["label"] for m in meta])
    result = {
        "method": module.hparams.get("method", ""),
        "data_dir": str(data_dir),
        "split": split,
        "split_protocol": split_protocol,
        "clips": len(meta),
        **classification_metrics(logits, labels, grid),
        **(extra or {}),
    }
    result.update(breakdown_metrics(logits, labels, meta, grid))
    out = Path(out_dir)
    matrix = confusion_matrix(labels, logits.argmax(1), grid.num_classes).numpy()
    result["confusion"] = matrix.tolist()
    write_json(out / f"sim_{split}.json", result)
    title = f"{result['method']} on {Path(data_dir).name} ({split}): top-1 {_pct(result['acc'])} %"
    confusion_png(out / f"confusion_{split}.png", matrix, title, grid)
    rows = [_metrics_row(result["method"], result)]
    for key, field in BREAKDOWNS.items():
        for value, sub in result.get(key, {}).items():
            rows.append(_metrics_row(_breakdown_label(field, value), sub))
    header = ["method", "clips", "top-1 %", "top-5 %", "stretch %", "bend %", "grid MAE"]
    text = (
        f"# {Path(data_dir).name}: {split} split ({split_protocol} protocol)\n\n"
        + markdown_table(header, rows)
        + f"\n![confusion matrix](confusion_{split}.png)\n"
    )
    write_text(out / f"sim_{split}.md", text)
    log.info("%s %s: top-1 %.3f, top-5 %.3f", data_dir, split, result["acc"], result["top5"])
    return result


def _fmt_corr(corr: dict, kind: str) -> str:
    """``r [low, high]`` of ``kind`` (pearson or spearman), ``n/a`` when undefined."""
    value, ci = corr[kind], corr[f"{kind}_ci"]
    if value is None:
        return "n/a"
    return f"{value:.2f}" + (f" [{ci[0]:.2f}, {ci[1]:.2f}]" if ci else "")


def _fmt_p(p: float | None) -> str:
    if p is None:
        return "n/a"
    return "<0.001" if p < 0.001 else f"{p:.3f}"


def _file_slugs(names: Sequence[str]) -> dict[str, str]:
    """File-name-safe, distinct versions of ``names``."""
    out: dict[str, str] = {}
    for name in names:
        slug = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_") or "column"
        while slug in out.values():
            slug += "_"
        out[name] = slug
    return out


def evaluate_real(
    module: MaterialClassifierModule,
    real_dir: str | Path,
    out_dir: str | Path,
    *,
    columns: Sequence[str] = DEFAULT_COLUMNS,
    group: str | None = None,
    clip_len: int = 10,
    clip_stride: int = 10,
    target_fps: float = 15.0,
    size: int = 112,
    batch_size: int = 16,
    rounds: int = 2000,
    seed: int = 0,
    checkpoint: str | Path | None = None,
) -> dict:
    """Correlate each per-video score with each measured column; writes JSON, MD, CSV, PNGs.

    ``columns`` are the measured ``labels.csv`` columns; ``group`` the column whose equal
    values form one fabric (``None``: see :mod:`datasets.real_video`). ``correlations`` in the
    result holds the thesis's Table 7.3 figures (``material_score`` against each column, per
    input) and ``score_correlations[input][score][column]`` every pair.
    """
    grid = module_grid(module)
    check_class_count(module, checkpoint=checkpoint, dataset=real_dir, grid=grid)
    clashes = [c for c in columns if c in (*SCORE_NAMES, "clips")]
    if clashes:
        raise InputError(f"columns {clashes} clash with report fields; rename them in labels.csv")
    footage = RealVideoDataModule(
        real_dir,
        columns=columns,
        group=group,
        clip_len=clip_len,
        clip_stride=clip_stride,
        target_fps=target_fps,
        size=size,
        batch_size=batch_size,
    )
    dataset = footage.dataset
    columns = dataset.columns
    _check_correlatable(dataset, Path(real_dir))
    logits, meta = predict(module, footage, desc="real clips", class_count=grid.num_classes)
    probs = logits.softmax(dim=1)
    rows_of: dict[str, list[int]] = {}
    for i, m in enumerate(meta):
        rows_of.setdefault(m["video_name"], []).append(i)
    used = [v for v in dataset.videos if v.name in rows_of]  # labels.csv order
    mean_probs = torch.stack([probs[rows_of[v.name]].mean(0) for v in used])
    scores = {k: v.tolist() for k, v in material_scores(mean_probs, grid).items()}
    per_video = [
        {
            "video": v.name,
            "group": v.group,
            "wind": v.wind,
            "clips": len(rows_of[v.name]),
            **v.values,
            **{k: scores[k][i] for k in scores},
        }
        for i, v in enumerate(used)
    ]
    inputs = {"all": list(range(len(per_video)))}
    for wind in sorted({v["wind"] for v in per_video if v["wind"]}):
        inputs[wind] = [i for i, v in enumerate(per_video) if v["wind"] == wind]
    score_correlations = {}
    for name, idx in inputs.items():
        groups = [per_video[i]["group"] for i in idx]
        score_correlations[name] = {
            score: {
                column: correlate(
                    [per_video[i][score] for i in idx],
                    [per_video[i][column] for i in idx],
                    groups=groups,
                    rounds=rounds,
                    seed=seed,
                ).to_json()
                for column in columns
            }
            for score in correlated_scores(grid)
        }
    correlations = {
        name: {column: by_score["material_score"][column] for column in columns}
        for name, by_score in score_correlations.items()
    }
    method = module.hparams.get("method", "")
    out = Path(out_dir)
    slugs = _file_slugs(columns)
    scatter = {}
    winds = [v["wind"] for v in per_video]
    for score in correlated_scores(grid):
        for column in columns:
            c = score_correlations["all"][score][column]
            path = out / f"scatter_{score}_vs_{slugs[column]}.png"
            scatter_png(
                path,
                [v[column] for v in per_video],
                [v[score] for v in per_video],
                winds,
                xlabel=f"measured {column}",
                ylabel=f"predicted {score}",
                title=f"{method or 'model'} on {Path(real_dir).name}: r = {_fmt_corr(c, 'pearson')}"
                f", {c['count']} videos, {c['group_count']} groups",
            )
            scatter.setdefault(score, {})[column] = path.name
    skipped = [
        {"video": s.name, "frame_count": s.frame_count, "frames_needed": s.frames_needed}
        for s in dataset.skipped
    ]
    result = {
        "method": method,
        "checkpoint": None if checkpoint is None else str(checkpoint),
        "real_dir": str(real_dir),
        "columns": list(columns),
        "scores": list(correlated_scores(grid)),
        "videos": dataset.used_count,
        "videos_listed": len(dataset.videos),
        "videos_used": dataset.used_count,
        "videos_skipped": dataset.skipped_count,
        "skipped": skipped,
        "clips": len(meta),
        "groups": score_correlations["all"]["material_score"][columns[0]]["group_count"],
        "group_column": dataset.group_column,
        "group_rule": dataset.group_rule,
        "bootstrap_rounds": rounds,
        "bootstrap_seed": seed,
        "bootstrap_unit": "group",
        "p_value": "two-sided t-test of r with groups - 2 degrees of freedom",
        "score_definition": _score_definition(grid),
        "correlations": correlations,
        "score_correlations": score_correlations,
        "scatter": scatter,
        "per_video": per_video,
    }
    write_json(out / "real.json", result)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(per_video[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(per_video)
    atomic_write_bytes(out / "real_videos.csv", buffer.getvalue().encode())
    write_text(out / "real.md", _real_markdown(result, dataset, inputs, grid))
    log.info(
        "%s: %d of %d videos used, %d skipped; report in %s",
        real_dir,
        result["videos_used"],
        result["videos_listed"],
        result["videos_skipped"],
        out,
    )
    return result


def _check_correlatable(dataset: RealVideoDataset, real_dir: Path) -> None:
    """Refuse footage on which no correlation can be computed, saying why in one line.

    A correlation needs at least :data:`~models.correlation.MIN_SAMPLES` videos with clips and
    a measured column whose values differ; a column that is constant is reported as n/a with
    a warning when another column can be correlated.
    """
    skipped = {s.name for s in dataset.skipped}
    used = [v for v in dataset.videos if v.name not in skipped]
    if len(used) < MIN_SAMPLES:
        raise InputError(
            f"real_dir: {len(used)} of the {len(dataset.videos)} videos listed in "
            f"{real_dir / 'labels.csv'} are long enough for a clip; a correlation needs at "
            f"least {MIN_SAMPLES}"
        )
    constant = {
        c: used[0].values[c] for c in dataset.columns if len({v.values[c] for v in used}) == 1
    }
    if len(constant) == len(dataset.columns):
        raise InputError(
            f"real_dir: every measured column of {real_dir / 'labels.csv'} has one value for "
            f"all {len(used)} videos ({', '.join(f'{c} = {v:g}' for c, v in constant.items())}); "
            "a correlation needs measured values that differ"
        )
    for column, value in constant.items():
        log.warning(
            "%s: column %r is %g for every video, so its correlations are n/a",
            real_dir / "labels.csv",
            column,
            value,
        )


def _real_markdown(
    result: dict, dataset: RealVideoDataset, inputs: dict[str, list], grid: ClassGrid
) -> str:
    """``real.md``: counts, skipped videos, the correlation table, thesis reference, plots."""
    columns, lines = result["columns"], []
    lines.append(f"# Real videos: {Path(result['real_dir']).name} (Table 7.3 style)\n")
    if result["checkpoint"]:
        lines.append(f"Checkpoint `{result['checkpoint']}` (method `{result['method']}`).\n")
    lines.append(
        f"Videos: {result['videos_listed']} listed in labels.csv, {result['videos_used']} used "
        f"({result['clips']} clips), {result['videos_skipped']} skipped as too short for one "
        f"clip of {dataset.clip_len} frames at {dataset.target_fps:g} fps.\n"
    )
    if result["skipped"]:
        rows = [[s["video"], s["frame_count"], s["frames_needed"]] for s in result["skipped"]]
        lines.append(markdown_table(["skipped video", "frames", "frames needed"], rows))
    lines.append(
        f"Groups: {result['groups']} independent groups, formed by {result['group_rule']}. "
        "Intervals are percentile-bootstrap 95 % intervals that resample groups "
        f"({result['bootstrap_rounds']} rounds); p-values are two-sided t-tests with groups - 2 "
        "degrees of freedom.\n"
    )
    lines.append(
        "Scores, per video from its clips' averaged class probabilities: `material_score` = "
        f"expected class id 0..{grid.num_classes - 1} (stretch-major stiffness ordering: the "
        "thesis's predicted class number), `stretch_score` = expected stretch index "
        f"0..{grid.stretch_count - 1}, `bend_score` = expected bend index "
        f"0..{grid.bend_count - 1}"
        + (
            f", `density_score` = expected density index 0..{grid.density_count - 1}.\n"
            if grid.density_count > 1
            else ".\n"
        )
    )
    header = [
        "input",
        "score",
        "measured",
        "videos",
        "groups",
        "Pearson r [95% CI]",
        "p",
        "Spearman rho [95% CI]",
        "p",
    ]
    rows = []
    for name, by_score in result["score_correlations"].items():
        for score, by_column in by_score.items():
            for column in columns:
                c = by_column[column]
                rows.append(
                    [
                        name,
                        score,
                        column,
                        c["count"],
                        c["group_count"],
                        _fmt_corr(c, "pearson"),
                        _fmt_p(c["pearson_p"]),
                        _fmt_corr(c, "spearman"),
                        _fmt_p(c["spearman_p"]),
                    ]
                )
    lines.append(markdown_table(header, rows))
    thesis = [
        [
            f"W{k + 1}",
            f"{THESIS_TABLE_73['stiffness'][k]:.2f}",
            f"{THESIS_TABLE_73['density'][k]:.2f}",
        ]
        for k in range(3)
    ]
    lines.append(
        "Thesis Table 7.3 for reference (CNN+LSTM, 30 fabrics, one video per wind level, "
        "Pearson r of the predicted class number):\n"
    )
    lines.append(markdown_table(["input", "stiffness r", "density r"], thesis))
    lines.append("## Predicted vs measured (colour: wind)\n")
    for score, by_column in result["scatter"].items():
        for column, file in by_column.items():
            lines.append(f"![{score} vs {column}]({file})\n")
    return "\n".join(lines)


def _default_out_dir(ckpt_path: Path) -> Path:
    run_dir = (
        ckpt_path.parent.parent if ckpt_path.parent.name == "checkpoints" else ckpt_path.parent
    )
    return run_dir / "eval"


def _sha256(path: Path) -> str | None:
    if not path.is_file():
        return None
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def _footage_sha256(root: Path, columns: Sequence[str]) -> str:
    """sha256 over the bytes and paths of every file the evaluation reads.

    ``labels.csv`` and each listed video (:func:`~datasets.real_video.footage_files`).
    """
    digest = hashlib.sha256()
    for path in footage_files(root, columns):
        digest.update(f"{path.relative_to(root)}:{_sha256(path)}\n".encode())
    return digest.hexdigest()


def _settings(cfg: DictConfig) -> dict:
    """The configured values, type- and range-checked (errors name the field)."""
    real = cfg.real
    columns = OmegaConf.to_container(real.columns) if "columns" in real else list(DEFAULT_COLUMNS)
    if isinstance(columns, str):
        columns = [columns]
    if not isinstance(columns, list) or not columns or not all(isinstance(c, str) for c in columns):
        raise InputError(f"real.columns must be a list of labels.csv column names, got {columns}")
    group = real.get("group")
    if group is not None and not isinstance(group, str):
        raise InputError(f"real.group must be a labels.csv column name or null, got {group!r}")
    return {
        "split": check_choice(cfg.split, "split", SPLITS),
        "split_protocol": check_choice(cfg.split_protocol, "split_protocol", SPLIT_PROTOCOLS),
        "batch_size": check_int(cfg.batch_size, "batch_size", 1),
        "clip_len": check_int(real.clip_len, "real.clip_len", 1),
        "clip_stride": check_int(real.clip_stride, "real.clip_stride", 1),
        "target_fps": check_float(real.target_fps, "real.target_fps", 0.0, low_open=True),
        "size": check_int(real.size, "real.size", 1),
        "columns": columns,
        "group": group,
        "rounds": check_int(cfg.bootstrap.rounds, "bootstrap.rounds", 0),
        "seed": check_int(cfg.bootstrap.seed, "bootstrap.seed", 0),
        "overwrite": check_choice(cfg.get("overwrite", False), "overwrite", (False, True)),
    }


def evaluation_folder(
    parent: Path, ckpt: Path, data_dir: Path | None, real_dir: Path | None, settings: dict
) -> tuple[Path, dict]:
    """The evaluation's own folder under ``parent`` and the inputs hashed into its name."""
    inputs: dict = {"checkpoint": str(ckpt.resolve()), "checkpoint_sha256": _sha256(ckpt)}
    parts = []
    if data_dir is not None:
        inputs["sim"] = {
            "data_dir": str(data_dir.resolve()),
            "manifest_sha256": _sha256(Manifest.path(data_dir)),
            **{k: settings[k] for k in ("split", "split_protocol")},
        }
        parts.append(f"{data_dir.resolve().name}-{settings['split']}")
    if real_dir is not None:
        keys = (
            "clip_len",
            "clip_stride",
            "target_fps",
            "size",
            "columns",
            "group",
            "rounds",
            "seed",
        )
        inputs["real"] = {
            "real_dir": str(real_dir.resolve()),
            "labels_sha256": _sha256(real_dir / "labels.csv"),
            "files_sha256": _footage_sha256(real_dir, settings["columns"]),
            **{k: settings[k] for k in keys},
        }
        parts.append(real_dir.resolve().name)
    text = json.dumps(inputs, sort_keys=True)
    digest = hashlib.sha256(text.encode()).hexdigest()[:HASH_DIGITS]
    name = re.sub(r"[^A-Za-z0-9._+-]+", "_", "+".join(parts))
    return parent / f"{name}-{digest}", inputs


def run(cfg: DictConfig) -> dict:
    """Evaluate the configured checkpoint into its own folder.

    Returns ``{"sim": ..., "real": ..., "out_dir": folder}`` (the parts that were asked for).
    """
    if cfg.data_dir is None and cfg.real_dir is None:
        raise InputError(
            "evaluate needs data_dir (a generated dataset) and/or real_dir (a folder of real "
            "videos with labels.csv)"
        )
    settings = _settings(cfg)
    if not isinstance(cfg.ckpt_path, str) or not cfg.ckpt_path.strip():
        raise InputError(f"ckpt_path must be a checkpoint file, got {cfg.ckpt_path!r}")
    ckpt = Path(cfg.ckpt_path)
    module = load_classifier(ckpt, field="ckpt_path")  # first: a bad checkpoint is named
    for key in ("data_dir", "real_dir"):
        if cfg[key] is not None and not Path(cfg[key]).is_dir():
            raise FileNotFoundError(f"{key} {cfg[key]} does not exist")
    data_dir = None if cfg.data_dir is None else Path(cfg.data_dir)
    real_dir = None if cfg.real_dir is None else Path(cfg.real_dir)
    grid = module_grid(module) if data_dir is None else dataset_grid(data_dir)
    check_class_count(module, checkpoint=ckpt, dataset=data_dir or real_dir, grid=grid)
    parent = check_output_dir(cfg.out_dir or _default_out_dir(ckpt), "out_dir")
    folder, inputs = evaluation_folder(parent, ckpt, data_dir, real_dir, settings)
    if (folder / FINISHED).is_file() and not settings["overwrite"]:
        raise InputError(
            f"{folder} already holds the evaluation of these exact inputs; read it there, or "
            "pass overwrite=true to redo it"
        )
    created = not folder.exists()
    results: dict = {}
    try:
        if data_dir is not None:
            results["sim"] = evaluate_simulated(
                module,
                data_dir,
                folder,
                split=settings["split"],
                split_protocol=settings["split_protocol"],
                batch_size=settings["batch_size"],
                checkpoint=ckpt,
            )
        if real_dir is not None:
            results["real"] = evaluate_real(
                module,
                real_dir,
                folder,
                columns=settings["columns"],
                group=settings["group"],
                clip_len=settings["clip_len"],
                clip_stride=settings["clip_stride"],
                target_fps=settings["target_fps"],
                size=settings["size"],
                batch_size=settings["batch_size"],
                rounds=settings["rounds"],
                seed=settings["seed"],
                checkpoint=ckpt,
            )
        write_json(folder / FINISHED, inputs)
    except BaseException:
        if created:
            shutil.rmtree(folder, ignore_errors=True)  # nothing half-written left behind
        raise
    results["out_dir"] = str(folder)
    log.info("evaluation written to %s", folder)
    return results


def _command(cfg: DictConfig) -> None:
    """Hydra wrapper around :func:`run`; prints where the reports are."""
    results = run(cfg)
    print(f"evaluation written to {results['out_dir']}")


main = hydra_command(_command, config_name="evaluate")


if __name__ == "__main__":
    main()
