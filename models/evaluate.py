"""Evaluate a trained classifier: simulated test split (Table 7.2) and real videos (Table 7.3).

``python -m models.evaluate ckpt_path=RUN/checkpoints/best.ckpt data_dir=DATASET
real_dir=FOLDER`` (configs/evaluate.yaml) writes, into ``out_dir`` (default ``RUN/eval``):

* ``sim_<split>.json`` / ``.md``: top-1 and top-5 accuracy over the 54 classes, stretch- and
  bend-factor accuracy, 6 x 9 grid MAE, the same per wind level, and
  ``confusion_<split>.png``;
* ``real.json`` / ``.md`` / ``real_videos.csv``: per video the clip-averaged class
  probabilities turned into scores (:mod:`models.scores`), and Pearson / Spearman r with
  bootstrap 95 % intervals against measured stiffness and density, for all videos and per
  wind label.
"""

from __future__ import annotations

import csv
import io
import logging
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig
from torch.utils.data import DataLoader, Dataset
from tqdm.auto import tqdm

from datasets.clip_dataset import ClothClipDataset
from datasets.real_video import RealVideoDataset
from simulator.sequence import atomic_write_bytes

from .correlation import correlate
from .material_classifier import MaterialClassifierModule, load_classifier
from .metrics import BREAKDOWNS, breakdown_metrics, classification_metrics, confusion_matrix
from .report import confusion_png, markdown_table, write_json, write_text
from .scores import material_scores

__all__ = ["evaluate_real", "evaluate_simulated", "pick_device", "predict"]

log = logging.getLogger(__name__)

THESIS_TABLE_73 = {"stiffness": (0.47, 0.43, 0.50), "density": (0.55, 0.62, 0.64)}
"""Thesis Table 7.3, CNN+LSTM on all 30 fabrics, W1/W2/W3 videos."""


def pick_device() -> torch.device:
    """CUDA when present, else CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


@torch.no_grad()
def predict(
    module: MaterialClassifierModule,
    dataset: Dataset,
    *,
    batch_size: int = 16,
    device: torch.device | None = None,
    desc: str = "predict",
) -> tuple[torch.Tensor, list[dict]]:
    """Logits (N, 54) of every clip of ``dataset`` and each sample's metadata (no pixels)."""
    device = device or pick_device()
    module = module.to(device).eval()
    logits, meta = [], []
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False, num_workers=0)
    for batch in tqdm(loader, desc=desc, unit="batch", leave=False):
        logits.append(module(batch["video"].to(device)).float().cpu())
        size = batch["video"].shape[0]
        for i in range(size):
            meta.append({k: _item(v[i]) for k, v in batch.items() if k != "video"})
    return torch.cat(logits), meta


def _item(value):
    return value.item() if isinstance(value, torch.Tensor) else value


def _pct(value: float) -> str:
    return f"{100 * value:.1f}"


def _metrics_row(label: str, m: dict) -> list:
    """One row of the simulated-split report: clips, top-1/top-5, stretch, bend, grid MAE."""
    return [
        label, m["clips"], _pct(m["acc"]), _pct(m["top5"]), _pct(m["stretch_acc"]),
        _pct(m["bend_acc"]), f"{m['grid_mae']:.2f}",
    ]  # fmt: skip


def evaluate_simulated(
    module: MaterialClassifierModule,
    data_dir: str | Path,
    out_dir: str | Path,
    *,
    split: str = "test",
    split_protocol: str = "simulation",
    batch_size: int = 16,
    extra: dict | None = None,
) -> dict:
    """Metrics of ``module`` on one split of a generated dataset; writes JSON, MD and PNG.

    ``split_protocol`` must be the one the model was trained under (see
    :data:`datasets.manifest.SPLIT_PROTOCOLS`). ``extra`` entries (e.g. training time and
    device) are stored in the JSON as they are.
    """
    dataset = ClothClipDataset(data_dir, split, verify=True, split_protocol=split_protocol)
    logits, meta = predict(module, dataset, batch_size=batch_size, desc=f"{split} clips")
    labels = torch.tensor([m["label"] for m in meta])
    result = {
        "method": module.hparams.get("method", ""),
        "data_dir": str(data_dir),
        "split": split,
        "split_protocol": split_protocol,
        "clips": len(meta),
        **classification_metrics(logits, labels),
        **(extra or {}),
    }
    result.update(breakdown_metrics(logits, labels, meta))
    out = Path(out_dir)
    matrix = confusion_matrix(labels, logits.argmax(1)).numpy()
    result["confusion"] = matrix.tolist()
    write_json(out / f"sim_{split}.json", result)
    title = f"{result['method']} on {Path(data_dir).name} ({split}): top-1 {_pct(result['acc'])} %"
    confusion_png(out / f"confusion_{split}.png", matrix, title)
    rows = [_metrics_row(result["method"], result)]
    for key, field in BREAKDOWNS.items():
        for value, sub in result.get(key, {}).items():
            rows.append(_metrics_row(f"{field.replace('_', ' ')} {value}", sub))
    header = ["method", "clips", "top-1 %", "top-5 %", "stretch %", "bend %", "grid MAE"]
    text = (
        f"# {Path(data_dir).name}: {split} split ({split_protocol} protocol)\n\n"
        + markdown_table(header, rows)
        + f"\n![confusion matrix](confusion_{split}.png)\n"
    )
    write_text(out / f"sim_{split}.md", text)
    log.info("%s %s: top-1 %.3f, top-5 %.3f", data_dir, split, result["acc"], result["top5"])
    return result


def _fmt_r(corr: dict) -> str:
    if corr["pearson"] is None:
        return "n/a"
    ci = corr["pearson_ci"]
    return f"{corr['pearson']:.2f}" + (f" [{ci[0]:.2f}, {ci[1]:.2f}]" if ci else "")


def _fmt_rho(corr: dict) -> str:
    return "n/a" if corr["spearman"] is None else f"{corr['spearman']:.2f}"


def evaluate_real(
    module: MaterialClassifierModule,
    real_dir: str | Path,
    out_dir: str | Path,
    *,
    clip_len: int = 10,
    clip_stride: int = 10,
    target_fps: float = 15.0,
    size: int = 112,
    batch_size: int = 16,
    rounds: int = 2000,
    seed: int = 0,
) -> dict:
    """Correlation of per-video material scores with measured stiffness and density."""
    dataset = RealVideoDataset(
        real_dir, clip_len=clip_len, clip_stride=clip_stride, target_fps=target_fps, size=size
    )
    logits, meta = predict(module, dataset, batch_size=batch_size, desc="real clips")
    probs = logits.softmax(dim=1)
    videos: dict[str, dict] = {}
    for i, m in enumerate(meta):
        entry = videos.setdefault(
            m["video_name"],
            {"stiffness": m["stiffness"], "density": m["density"], "wind": m["wind"], "rows": []},
        )
        entry["rows"].append(i)
    names = list(videos)
    mean_probs = torch.stack([probs[videos[n]["rows"]].mean(0) for n in names])
    scores = {k: v.tolist() for k, v in material_scores(mean_probs).items()}
    per_video = []
    for i, name in enumerate(names):
        v = videos[name]
        per_video.append({
            "video": name, "wind": v["wind"], "stiffness": v["stiffness"], "density": v["density"],
            "clips": len(v["rows"]), **{k: scores[k][i] for k in scores},
        })  # fmt: skip
    groups = {"all": list(range(len(names)))}
    winds = sorted({v["wind"] for v in per_video if v["wind"]})
    for wind in winds:
        groups[wind] = [i for i, v in enumerate(per_video) if v["wind"] == wind]
    pairs = {
        "stiffness": ("material_score", "stiffness"),
        "density": ("material_score", "density"),
        "stiffness_vs_bend_score": ("bend_score", "stiffness"),
    }
    correlations = {}
    for group, idx in groups.items():
        correlations[group] = {
            name: correlate(
                [per_video[i][score] for i in idx], [per_video[i][target] for i in idx],
                rounds=rounds, seed=seed,
            ).to_json()
            for name, (score, target) in pairs.items()
        }  # fmt: skip
    method = module.hparams.get("method", "")
    result = {
        "method": method,
        "real_dir": str(real_dir),
        "videos": len(names),
        "clips": len(meta),
        "bootstrap_rounds": rounds,
        "score_definition": "material_score = sum_c p_c * c over the 54 classes (class id = "
        "stretch_index * 9 + bend_index, a stiffness ordering), p averaged over a video's clips",
        "correlations": correlations,
        "per_video": per_video,
    }
    out = Path(out_dir)
    write_json(out / "real.json", result)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(per_video[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(per_video)
    atomic_write_bytes(out / "real_videos.csv", buffer.getvalue().encode())
    rows = []
    for group, idx in groups.items():
        c = correlations[group]
        label = f"{len(idx)} videos" if group == "all" else f"{len(idx)} {group}-videos"
        rows.append([
            method, label, _fmt_r(c["stiffness"]), _fmt_r(c["density"]),
            _fmt_rho(c["stiffness"]), _fmt_rho(c["density"]), _fmt_r(c["stiffness_vs_bend_score"]),
        ])  # fmt: skip
    header = [
        "method", "input", "stiffness r [95% CI]", "density r [95% CI]", "stiffness rho",
        "density rho", "stiffness r (bend score)",
    ]  # fmt: skip
    thesis = [
        ["CNN+LSTM (thesis)", f"30 W{k + 1}-videos", f"{THESIS_TABLE_73['stiffness'][k]:.2f}",
         f"{THESIS_TABLE_73['density'][k]:.2f}", "", "", ""]
        for k in range(3)
    ]  # fmt: skip
    text = (
        f"# Real videos: {Path(real_dir).name} (Table 7.3 style)\n\n"
        "Scores: per video, clip probabilities averaged; `material_score` = expected class id "
        "(stiffness ordering). r = Pearson with percentile-bootstrap 95 % interval over videos "
        f"({rounds} rounds); rho = Spearman.\n\n" + markdown_table(header, rows + thesis)
    )
    write_text(out / "real.md", text)
    return result


def _default_out_dir(ckpt_path: Path) -> Path:
    run = ckpt_path.parent.parent if ckpt_path.parent.name == "checkpoints" else ckpt_path.parent
    return run / "eval"


def run(cfg: DictConfig) -> dict:
    """Evaluate the configured checkpoint; returns ``{"sim": ..., "real": ...}``."""
    if cfg.data_dir is None and cfg.real_dir is None:
        raise ValueError("evaluate needs data_dir (a generated dataset) and/or real_dir")
    for key in ("data_dir", "real_dir"):
        if cfg[key] is not None and not Path(cfg[key]).is_dir():
            raise FileNotFoundError(f"{key} {cfg[key]} does not exist")
    ckpt = Path(cfg.ckpt_path)
    module = load_classifier(ckpt)
    out_dir = Path(cfg.out_dir) if cfg.out_dir else _default_out_dir(ckpt)
    results = {}
    if cfg.data_dir is not None:
        results["sim"] = evaluate_simulated(
            module, cfg.data_dir, out_dir, split=str(cfg.split),
            split_protocol=str(cfg.split_protocol), batch_size=int(cfg.batch_size),
        )  # fmt: skip
    if cfg.real_dir is not None:
        results["real"] = evaluate_real(
            module, cfg.real_dir, out_dir, batch_size=int(cfg.batch_size),
            clip_len=int(cfg.real.clip_len), clip_stride=int(cfg.real.clip_stride),
            target_fps=float(cfg.real.target_fps), size=int(cfg.real.size),
            rounds=int(cfg.bootstrap.rounds), seed=int(cfg.bootstrap.seed),
        )  # fmt: skip
    log.info("evaluation written to %s", out_dir)
    return results


@hydra.main(version_base="1.3", config_path="../configs", config_name="evaluate")
def main(cfg: DictConfig) -> None:
    """Hydra wrapper around :func:`run`."""
    run(cfg)


if __name__ == "__main__":
    main()
