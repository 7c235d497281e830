"""Geometry oracle: how much class information the simulated meshes of a dataset carry.

Each test clip is classified by 1-nearest-neighbour on the *simulated vertex positions* of
its frames (relative to the first vertex of the first frame, each coordinate z-scored with
the training clips' statistics) against the training clips. No pixels are involved, so the
figure is a reference for video models trained on the same splits: if the oracle is near
chance, the simulations themselves do not separate the classes; if it is far above a network,
the information is lost between mesh and pixels (framing, resolution, textures). It is not a
bound in either direction (a network can beat 1-NN; pixels can hide what vertices show).

The same 1-NN on *pixels* (each clip's mean frame, area-downsampled to 32 x 32 RGB) is the
opposite reference: it can only match appearance (texture, background, framing). Run under
both split protocols (``datasets.manifest.SPLIT_PROTOCOLS``) the two show how much the
thesis's sub-sequence split lets test clips be matched to their own simulations.

The third reference, *motion*, is the same 1-NN on the clip's frame differences (grey,
``sqrt |frame[t + 1] - frame[t]|``, area-downsampled to 16 x 16 per step): static texture and
background cancel, the moving cloth remains: the ``cnn_lstm_diff`` model's input, in grey::

    python -m benchmarks.thesis.geometry_oracle data/wind-L1-random-full-s0 --out reports/oracle

Writes ``<name>.json`` and ``<name>.md`` (atomically) in ``--out``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from common.files import atomic_write_bytes
from datasets.clip_dataset import ClothClipDataset, clip_tensor
from datasets.manifest import SPLIT_PROTOCOLS, Manifest
from datasets.spec import physics_key_of
from simulator.sequence import MeshSequence

__all__ = [
    "clip_geometry",
    "clip_motion",
    "clip_pixels",
    "oracle_accuracy",
    "run_oracle",
    "write_report",
]

PIXEL_SIZE = 32
"""Side of the downsampled mean frame of the pixel reference [px]."""
MOTION_SIZE = 16
"""Side of each downsampled frame difference of the motion reference [px]."""
FEATURES = {
    "geometry": "simulated vertex positions of the clip's frames",
    "pixels": f"mean frame, {PIXEL_SIZE} x {PIXEL_SIZE} RGB",
    "motion": f"sqrt |grey frame difference|, {MOTION_SIZE} x {MOTION_SIZE} per step",
}


def _unit_of(record: dict) -> str:
    """``train-unit-0003.tar`` -> ``unit-0003`` (the mesh cache file of the clip's unit)."""
    return record["shard"].split("-", 1)[1].removesuffix(".tar")


def clip_geometry(manifest: Manifest, cache_dir: str | Path) -> dict[str, np.ndarray]:
    """``clip key -> float32 (frames * V * 3,)`` positions relative to the first vertex."""
    folder = Path(cache_dir) / physics_key_of(manifest.spec)
    by_unit: dict[str, list[dict]] = {}
    for record in manifest.clips:
        by_unit.setdefault(_unit_of(record), []).append(record)
    out = {}
    for unit, records in sorted(by_unit.items()):
        path = folder / f"{unit}.npz"
        if not path.is_file():
            raise FileNotFoundError(
                f"mesh cache {path} not found: the oracle reads the simulated meshes of "
                f"{manifest.root} (regenerate with mesh_cache={cache_dir}, or pass --mesh-cache)"
            )
        seq = MeshSequence.load(path)
        index = {
            (int(label), int(seed)): b
            for b, (label, seed) in enumerate(zip(seq.labels, seq.seeds, strict=True))
        }
        for record in records:
            b = index[(int(record["class_id"]), int(record["seed"]))]
            start = int(record["start_frame"])
            frames = seq.pos[b, start : start + int(record["frame_count"])]
            out[record["key"]] = (frames - frames[:1, :1]).reshape(-1).astype(np.float32)
    return out


def _clip_features(manifest: Manifest, feature) -> dict[str, np.ndarray]:
    """``clip key -> float32 feature(frames (T, 3, H, W) in [0, 1]) flattened``."""
    clips = ClothClipDataset(manifest.root, None, verify=False)
    return {
        record["key"]: feature(clip_tensor(clips.read(i)[1])).reshape(-1).numpy()
        for i, record in enumerate(clips.records)
    }


def clip_pixels(manifest: Manifest, size: int = PIXEL_SIZE) -> dict[str, np.ndarray]:
    """``clip key -> float32 (3 * size * size,)``: the clip's mean frame, area-downsampled."""

    def mean_frame(frames: torch.Tensor) -> torch.Tensor:
        mean = frames.mean(0, keepdim=True)
        return torch.nn.functional.interpolate(mean, size=(size, size), mode="area")

    return _clip_features(manifest, mean_frame)


def clip_motion(manifest: Manifest, size: int = MOTION_SIZE) -> dict[str, np.ndarray]:
    """``clip key -> float32 ((T - 1) * size * size,)``: sqrt |grey frame differences|."""

    def motion(frames: torch.Tensor) -> torch.Tensor:
        change = frames.mean(1, keepdim=True).diff(dim=0).abs().sqrt()
        return torch.nn.functional.interpolate(change, size=(size, size), mode="area")

    return _clip_features(manifest, motion)


def oracle_accuracy(train: list[dict], test: list[dict], geometry: dict[str, np.ndarray]) -> dict:
    """1-NN top-1, stretch-factor and bend-factor accuracy of ``test`` against ``train``."""
    x_train = torch.from_numpy(np.stack([geometry[r["key"]] for r in train]))
    x_test = torch.from_numpy(np.stack([geometry[r["key"]] for r in test]))
    mean, std = x_train.mean(0), x_train.std(0) + 1e-6
    distances = torch.cdist((x_test - mean) / std, (x_train - mean) / std)
    nearest = [train[i] for i in distances.argmin(1).tolist()]

    def agree(field: str) -> float:
        return float(np.mean([a[field] == b[field] for a, b in zip(nearest, test, strict=True)]))

    return {
        "clips": len(test),
        "acc": agree("class_id"),
        "stretch_acc": agree("stretch_index"),
        "bend_acc": agree("bend_index"),
        "same_simulation": agree("sim_id"),
    }


def run_oracle(data_dir: str | Path, cache_dir: str | Path, out_dir: str | Path) -> dict:
    """All three references under every split protocol; writes JSON and Markdown, returns them.

    Returns ``{"geometry" | "pixels" | "motion": {protocol: accuracies}}``.
    """
    manifest = Manifest.load(data_dir)
    features = {
        "geometry": clip_geometry(manifest, cache_dir),
        "pixels": clip_pixels(manifest),
        "motion": clip_motion(manifest),
    }
    results = {
        kind: {
            protocol: oracle_accuracy(
                manifest.clips_of("train", protocol), manifest.clips_of("test", protocol), x
            )
            for protocol in SPLIT_PROTOCOLS
        }
        for kind, x in features.items()
    }
    name = Path(data_dir).name
    payload = {"data_dir": str(data_dir), "results": results, "features": FEATURES}
    rows = [
        f"| {kind} | {p} | {r['clips']} | {100 * r['acc']:.1f} | {100 * r['stretch_acc']:.1f} | "
        f"{100 * r['bend_acc']:.1f} | {100 * r['same_simulation']:.1f} |"
        for kind, by_protocol in results.items()
        for p, r in by_protocol.items()
    ]
    table = "\n".join(
        [
            f"# 1-NN references: {name}",
            "",
            "1-nearest-neighbour of each test clip among the training clips, on:",
            "",
            *[f"* {kind}: {text}" for kind, text in FEATURES.items()],
            "",
            "| features | split protocol | test clips | top-1 % | stretch % | bend % | "
            "NN from own sim % |",
            "|---|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    write_report(out_dir, name, payload, table)
    return results


def write_report(out_dir: str | Path, stem: str, payload: dict, markdown: str) -> None:
    """``<stem>.json`` (``payload``) and ``<stem>.md`` in ``out_dir``, each written atomically."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    text = json.dumps(payload, indent=1, sort_keys=True, allow_nan=False) + "\n"
    atomic_write_bytes(out / f"{stem}.json", text.encode())
    atomic_write_bytes(out / f"{stem}.md", markdown.encode())


def main(argv: list[str] | None = None) -> dict:
    """Command line: ``python -m benchmarks.thesis.geometry_oracle DATA_DIR [options]``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_dir", type=Path)
    parser.add_argument("--mesh-cache", type=Path, default=Path("data/mesh_cache"))
    parser.add_argument("--out", type=Path, default=Path("reports/oracle"))
    args = parser.parse_args(argv)
    results = run_oracle(args.data_dir, args.mesh_cache, args.out)
    for kind, protocol, r in [(k, p, r) for k, v in results.items() for p, r in v.items()]:
        print(
            f"{kind:>8} {protocol:>10}: top-1 {100 * r['acc']:.1f} %, "
            f"stretch {100 * r['stretch_acc']:.1f} %, bend {100 * r['bend_acc']:.1f} %, "
            f"NN from own simulation {100 * r['same_simulation']:.1f} %"
        )
    return results


if __name__ == "__main__":
    main()
