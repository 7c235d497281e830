"""Learned references: how much class information a feature carries, read by a small MLP.

The 1-NN references of :mod:`benchmarks.thesis.geometry_oracle` cannot discount nuisances (wind
level, wind yaw, background) that change a clip more than its class does, so a 1-NN on the
simulated meshes understates what the simulations say about the material. Here the same features
train a one-hidden-layer MLP on the training clips (fixed schedule, no test-time selection) and
are scored on the test clips of held-out simulations. The mesh features are split three ways, so
the report says *where* the class information lies:

* ``geometry``: vertex positions of all frames (what the 1-NN geometry reference reads);
* ``geometry_shape``: the clip's mean vertex positions (the cloth's shape, no motion);
* ``geometry_motion``: the frame-to-frame vertex displacements (motion, no shape);
* ``pixels`` and ``motion``: the 1-NN references' image features (mean frame, frame
  differences).

With ``--by-clip-index`` the geometry MLP is also trained and scored on the clips of each
position in the recording separately (clip k of every simulation), which says *when* the
information lies (e.g. during the arm's flexion rather than in the drape that follows).

::

    python -m benchmarks.thesis.feature_probe data/wind-L1-random-full-s0 --out reports/oracle

``--features geometry --by-clip-index`` skips the slow image features (they decode every
frame) and adds each clip position's class separation (:func:`class_separation`).

Writes ``<name>-mlp.json`` and ``<name>-mlp.md`` (atomically) in ``--out``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from benchmarks.thesis.geometry_oracle import FEATURES as ORACLE_FEATURES
from benchmarks.thesis.geometry_oracle import clip_geometry, clip_motion, clip_pixels, write_report
from datasets.manifest import SPLIT_PROTOCOLS, Manifest
from simulator.cloth.material import BEND_MULTIPLIERS, CLASS_COUNT

__all__ = [
    "FEATURES",
    "by_clip_index",
    "class_separation",
    "mlp_accuracy",
    "probe_markdown",
    "run_probe",
]

FEATURES = {
    "geometry": "vertex positions of all frames",
    "geometry_shape": "mean vertex positions over the clip (shape only)",
    "geometry_motion": "frame-to-frame vertex displacements (motion only)",
    "pixels": ORACLE_FEATURES["pixels"],
    "motion": ORACLE_FEATURES["motion"],
}


def _per_frame(x: np.ndarray, frames: int) -> np.ndarray:
    return x.reshape(frames, -1)


def _features(
    manifest: Manifest, cache_dir: str | Path, kinds: tuple[str, ...]
) -> dict[str, dict[str, np.ndarray]]:
    """The features named in ``kinds`` (pixels and motion decode every frame: the slow ones)."""
    frames = {r["key"]: int(r["frame_count"]) for r in manifest.clips}
    derived: dict[str, Callable[[np.ndarray, int], np.ndarray]] = {
        "geometry_shape": lambda x, t: _per_frame(x, t).mean(0),
        "geometry_motion": lambda x, t: np.diff(_per_frame(x, t), axis=0).reshape(-1),
    }
    images = {"pixels": clip_pixels, "motion": clip_motion}
    needs_geometry = any(kind not in images for kind in kinds)
    geometry = clip_geometry(manifest, cache_dir) if needs_geometry else {}
    out = {}
    for kind in kinds:
        if kind in images:
            out[kind] = images[kind](manifest)
        elif kind in derived:
            out[kind] = {
                k: derived[kind](v, frames[k]).astype(np.float32) for k, v in geometry.items()
            }
        else:
            out[kind] = geometry
    return out


def _kinds_error(kinds: tuple[str, ...], per_clip_index: bool) -> str | None:
    """Why ``kinds`` (with or without the per-position probe) cannot be probed, or ``None``."""
    if not kinds or any(k not in FEATURES for k in kinds):
        return f"features must be a non-empty subset of {','.join(FEATURES)}, got {kinds}"
    if per_clip_index and "geometry" not in kinds:
        return "the per-clip-position probe reads the geometry feature: add geometry"
    return None


def mlp_accuracy(
    train: list[dict],
    test: list[dict],
    features: dict[str, np.ndarray],
    *,
    hidden: int = 512,
    epochs: int = 200,
    seed: int = 0,
) -> dict:
    """Top-1, stretch-factor and bend-factor accuracy of an MLP trained on ``train``.

    Features are z-scored with the training clips' statistics; AdamW (lr 1e-3, weight decay
    1e-2), batches of 128, dropout 0.3, a fixed number of epochs (nothing is selected on the
    test clips). Seeded: the same inputs give the same figures.
    """
    generator = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    x_train = torch.from_numpy(np.stack([features[r["key"]] for r in train]))
    x_test = torch.from_numpy(np.stack([features[r["key"]] for r in test]))
    y_train = torch.tensor([int(r["class_id"]) for r in train])
    y_test = torch.tensor([int(r["class_id"]) for r in test])
    mean, std = x_train.mean(0), x_train.std(0) + 1e-6
    x_train, x_test = (x_train - mean) / std, (x_test - mean) / std
    net = torch.nn.Sequential(
        torch.nn.Linear(x_train.shape[1], hidden),
        torch.nn.ReLU(),
        torch.nn.Dropout(0.3),
        torch.nn.Linear(hidden, CLASS_COUNT),
    )
    optimiser = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=1e-2)
    for _ in range(epochs):
        net.train()
        order = torch.randperm(len(x_train), generator=generator)
        for start in range(0, len(order), 128):
            batch = order[start : start + 128]
            loss = torch.nn.functional.cross_entropy(net(x_train[batch]), y_train[batch])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
    net.eval()
    with torch.no_grad():
        predicted = net(x_test).argmax(1)
        fitted = (net(x_train).argmax(1) == y_train).float().mean()
    bends = len(BEND_MULTIPLIERS)  # class id = stretch_index * bends + bend_index

    def agree(a: torch.Tensor, b: torch.Tensor) -> float:
        return float((a == b).float().mean())

    return {
        "clips": len(test),
        "acc": agree(predicted, y_test),
        "stretch_acc": agree(predicted // bends, y_test // bends),
        "bend_acc": agree(predicted % bends, y_test % bends),
        "train_acc": float(fitted),
    }


def by_clip_index(
    train: list[dict], test: list[dict], features: dict[str, np.ndarray], *, epochs: int = 200
) -> dict[int, dict]:
    """:func:`mlp_accuracy` trained and scored on the clips of one position at a time."""
    positions = sorted({int(r["clip_index"]) for r in test})
    out = {}
    for k in tqdm(positions, desc="geometry MLP per clip position"):
        train_k = [r for r in train if int(r["clip_index"]) == k]
        test_k = [r for r in test if int(r["clip_index"]) == k]
        out[k] = {
            **mlp_accuracy(train_k, test_k, features, epochs=epochs),
            **class_separation(train_k + test_k, features),
        }
    return out


def class_separation(records: list[dict], features: dict[str, np.ndarray]) -> dict:
    """How far simulations of one class scatter against how far apart the classes lie.

    ``spread``: root mean square, over the clips and feature coordinates, of each clip's
    deviation from its class mean. ``spacing``: median over classes of the root mean square
    (per coordinate) distance from the class mean to the nearest other class mean. Both are
    in the features' unit (metres for geometry). Where the spread exceeds the spacing, the
    simulations of one class differ more than neighbouring classes do, and a classifier of
    these features must read a small part of the variation (or fail on held-out ones).
    """
    by_class: dict[int, list[np.ndarray]] = {}
    for r in records:
        by_class.setdefault(int(r["class_id"]), []).append(features[r["key"]].astype(np.float64))
    if len(by_class) < 2:
        raise ValueError(f"class_separation needs clips of at least 2 classes, got {len(by_class)}")
    means = {c: np.mean(x, axis=0) for c, x in by_class.items()}
    deviations = np.concatenate([np.stack(x) - means[c] for c, x in by_class.items()])
    centres = np.stack(list(means.values()))
    distance = np.sqrt(((centres[:, None] - centres[None]) ** 2).mean(-1))
    np.fill_diagonal(distance, np.inf)
    return {
        "spread": float(np.sqrt((deviations**2).mean())),
        "spacing": float(np.median(distance.min(1))),
    }


def run_probe(
    data_dir: str | Path,
    cache_dir: str | Path,
    out_dir: str | Path,
    *,
    protocol: str = "simulation",
    epochs: int = 200,
    per_clip_index: bool = False,
    kinds: tuple[str, ...] = tuple(FEATURES),
) -> dict:
    """An MLP per feature; writes ``<name>-mlp.json`` / ``.md``; returns ``{feature: result}``.

    ``kinds``: the features to probe (names of :data:`FEATURES`; the per-position geometry
    MLP needs ``geometry``). With ``per_clip_index`` the geometry MLP per clip position is
    added to both reports (JSON key ``geometry_by_clip_index``).
    """
    if (error := _kinds_error(tuple(kinds), per_clip_index)) is not None:
        raise ValueError(error)
    manifest = Manifest.load(data_dir)
    train, test = manifest.clips_of("train", protocol), manifest.clips_of("test", protocol)
    features = _features(manifest, cache_dir, tuple(kinds))
    results = {
        kind: mlp_accuracy(train, test, x, epochs=epochs)
        for kind, x in tqdm(features.items(), desc="MLP per feature", total=len(features))
    }
    positions = (
        by_clip_index(train, test, features["geometry"], epochs=epochs) if per_clip_index else {}
    )
    name = Path(data_dir).name
    payload = {
        "data_dir": str(data_dir),
        "protocol": protocol,
        "epochs": epochs,
        "results": results,
        "features": FEATURES,
    }
    if positions:
        payload["geometry_by_clip_index"] = {str(k): r for k, r in positions.items()}
    table = probe_markdown(name, protocol, epochs, results, positions, _clip_starts(manifest))
    write_report(out_dir, f"{name}-mlp", payload, table)
    return results


def _clip_starts(manifest: Manifest) -> dict[int, tuple[int, float]]:
    """Clip position -> (first recorded frame, its time after recording starts [s])."""
    return {
        int(r["clip_index"]): (int(r["start_frame"]), int(r["start_frame"]) / float(r["fps"]))
        for r in manifest.clips
    }


def probe_markdown(
    name: str,
    protocol: str,
    epochs: int,
    results: dict,
    positions: dict[int, dict] | None = None,
    starts: dict[int, tuple[int, float]] | None = None,
) -> str:
    """The Markdown report of :func:`run_probe`'s ``results`` (and per-position results)."""
    what = {kind: text.replace("|", r"\|") for kind, text in FEATURES.items()}  # table-safe
    rows = [
        f"| {kind} | {what[kind]} | {r['clips']} | "
        f"{100 * r['acc']:.1f} | {100 * r['stretch_acc']:.1f} | {100 * r['bend_acc']:.1f} | "
        f"{100 * r['train_acc']:.1f} |"
        for kind, r in results.items()
    ]
    return "\n".join(
        [
            f"# MLP references: {name} ({protocol} split)",
            "",
            f"One-hidden-layer MLP (512 units) per feature, {epochs} epochs on the training clips, "
            "scored on the test clips.",
            "",
            "| features | what | test clips | top-1 % | stretch % | bend % | train fit % |",
            "|---|---|---|---|---|---|---|",
            *rows,
            "",
            *_positions_markdown(positions or {}, starts or {}),
        ]
    )


def _positions_markdown(
    positions: dict[int, dict], starts: dict[int, tuple[int, float]]
) -> list[str]:
    if not positions:
        return []
    rows = [
        f"| {k} | {starts[k][0]} | {starts[k][1]:.2f} | {r['clips']} | {100 * r['acc']:.1f} | "
        f"{100 * r['stretch_acc']:.1f} | {100 * r['bend_acc']:.1f} | {100 * r['train_acc']:.1f} "
        f"| {100 * r['spread']:.2f} | {100 * r['spacing']:.2f} |"
        for k, r in positions.items()
    ]
    return [
        "## When: the geometry MLP per clip position",
        "",
        "Trained and scored on clip k of every simulation only (fewer training clips than the "
        "table above). *Spread*: how far one class's clips scatter about their class mean; "
        "*spacing*: how far a class mean lies from the nearest other one (rms per vertex "
        "coordinate, cm, all clips of the position; `class_separation`). A spread above the "
        "spacing means simulations of one class differ more than neighbouring classes do.",
        "",
        "| clip | first frame | at [s] | test clips | top-1 % | stretch % | bend % "
        "| train fit % | spread cm | spacing cm |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]


def main(argv: list[str] | None = None) -> dict:
    """Command line: ``python -m benchmarks.thesis.feature_probe DATA_DIR [options]``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_dir", type=Path)
    parser.add_argument("--mesh-cache", type=Path, default=Path("data/mesh_cache"))
    parser.add_argument("--out", type=Path, default=Path("reports/oracle"))
    parser.add_argument("--protocol", default="simulation", choices=SPLIT_PROTOCOLS)
    parser.add_argument("--epochs", type=int, default=200)
    parser.add_argument(
        "--by-clip-index",
        action="store_true",
        help="also the geometry MLP per clip position in the recording",
    )
    parser.add_argument(
        "--features",
        default=",".join(FEATURES),
        help=f"comma-separated subset of {','.join(FEATURES)} (default: all)",
    )
    args = parser.parse_args(argv)
    if args.epochs < 1:
        parser.error(f"--epochs must be >= 1, got {args.epochs}")
    kinds = tuple(k for k in args.features.split(",") if k)
    if (error := _kinds_error(kinds, args.by_clip_index)) is not None:
        parser.error(f"--features: {error}")
    results = run_probe(
        args.data_dir,
        args.mesh_cache,
        args.out,
        protocol=args.protocol,
        epochs=args.epochs,
        per_clip_index=args.by_clip_index,
        kinds=kinds,
    )
    for kind, r in results.items():
        print(
            f"{kind:>16}: top-1 {100 * r['acc']:.1f} %, stretch {100 * r['stretch_acc']:.1f} %, "
            f"bend {100 * r['bend_acc']:.1f} % (train fit {100 * r['train_acc']:.1f} %)"
        )
    return results


if __name__ == "__main__":
    main()
