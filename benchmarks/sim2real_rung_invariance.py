"""How far an image-only change moves each hand-made rung, beside a change of the motion.

The diagnosis places a gap at "physics or scene" when a rung that reads the cloth's motion
shows it. A rung can only carry that weight if a change of the picture alone (the cloth's
texture, the backdrop, a sharpening filter) leaves it at its floor while a change of the
motion (gusty wind) moves it. Here the nominal simulated domain S of a dataset (the
diagnosis's quick budget: 9 classes x 6 simulations x 3 clips) is rendered as it is and
with each change; for every rung a grouped-CV logistic domain classifier tells S's clips
from the changed ones. The simulations are split in halves at random, S's half against the
changed set's other half, so no simulation sits on both sides (a paired design would let
the classifier learn the pairs); each cell is the mean AUC over ``--splits`` splits, ± their
standard deviation. The
``nominal`` row (S against S, halves) is the floor. Meshes come from ``--mesh-cache`` or
are simulated once (about 2 min for 54 cloths at mesh level 1); rendering and features
take about 20 s a set on 2 cores.

Usage: ``python -m benchmarks.sim2real_rung_invariance --data-dir data/<dataset>
[--mesh-cache DIR] [--sims-per-class 6] [--splits 8] [--out invariance.json]``. Prints a
table and, as the last line, the JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections.abc import Callable

import numpy as np

from common.checks import check_int
from common.commands import report_user_errors
from common.files import atomic_write_bytes
from common.paths import check_output_file
from datasets.runs import dataset_spec
from sim2real.domains import diagnosis_spec, simulated_clips
from sim2real.features import roi_box
from sim2real.pipeline import SIM_SEED_OFFSET, spanning_classes
from sim2real.rungs import HAND_RUNGS, clip_features
from sim2real.stats.classifier import domain_auc
from simulator.threads import use_process_threads

__all__ = ["IMAGE_CHANGES", "halves_auc", "main", "sharpen"]

IMAGE_CHANGES = ("texture_random", "texture_color", "backdrop_plain", "sharpen")
"""The changes of the picture alone; ``gusty_wind`` is the change of the motion."""


def sharpen(frames: np.ndarray, amount: float = 1.5, sigma: float = 1.0) -> np.ndarray:
    """Unsharp masking of every frame: ``f + amount (f - G_sigma * f)``, clipped to uint8."""
    import cv2

    out = np.empty_like(frames)
    for index in np.ndindex(frames.shape[:-3]):
        frame = frames[index].astype(np.float32)
        blurred = cv2.GaussianBlur(frame, (0, 0), sigma)
        out[index] = np.clip(frame + amount * (frame - blurred), 0, 255).astype(np.uint8)
    return out


def halves_auc(
    before: np.ndarray, after: np.ndarray, groups: np.ndarray, *, splits: int, seed: int = 0
) -> tuple[float, float]:
    """Mean and standard deviation over splits of the AUC of S's half against the other, changed.

    ``before`` and ``after`` hold the same simulations' clips (rows in ``groups`` order);
    features are standardised on ``before``.
    """
    sims = np.unique(groups)
    mean, std = before.mean(0), before.std(0) + 1e-9
    values = []
    for s in range(splits):
        order = np.random.default_rng([seed, s]).permutation(sims)
        first = np.isin(groups, order[: len(sims) // 2])
        second = np.isin(groups, order[len(sims) // 2 :])
        values.append(
            domain_auc(
                (before[first] - mean) / std,
                (after[second] - mean) / std,
                groups[first],
                groups[second],
                rng=np.random.default_rng([seed, s, 1]),
            )
        )
    return float(np.mean(values)), float(np.std(values))


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    """Command line (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-dir", required=True, help="a training dataset folder")
    parser.add_argument("--mesh-cache", default="data/mesh_cache")
    parser.add_argument("--sims-per-class", type=int, default=6)
    parser.add_argument("--splits", type=int, default=8)
    parser.add_argument("--out", default=None, help="write the JSON here too")
    args = parser.parse_args(argv)
    check_int(args.sims_per_class, "--sims-per-class", 2)
    check_int(args.splits, "--splits", 1)
    out = None if args.out is None else check_output_file(args.out, "--out")
    use_process_threads(1)
    train = dataset_spec(args.data_dir)
    spec = diagnosis_spec(
        train,
        classes=spanning_classes(train.classes, [3, 3], train.material_set),
        sims_per_class=args.sims_per_class,
        clips_per_sim=3,
        seed_offset=SIM_SEED_OFFSET,
    )
    start = time.perf_counter()
    nominal = simulated_clips(spec, args.mesh_cache)
    box = tuple(int(v) for v in roi_box(nominal.coverage))

    def rendered(**changes) -> Callable[[], np.ndarray]:
        return lambda: simulated_clips(dataclasses.replace(spec, **changes), args.mesh_cache).frames

    gusty = dataclasses.replace(spec.physics, gusty_wind=True, gust_amplitude=0.4)
    changes: dict[str, Callable[[], np.ndarray]] = {
        "nominal": lambda: nominal.frames,
        "texture_random": rendered(texture_mode="random"),
        "texture_color": rendered(texture_mode="color"),
        "backdrop_plain": rendered(backdrop="plain"),
        "sharpen": lambda: sharpen(nominal.frames),
        "gusty_wind": rendered(physics=gusty),
    }
    before = clip_features(nominal.frames, box)
    table = {}
    print(f"{'change':16s} " + " ".join(f"{r.name:>15s}" for r in HAND_RUNGS), flush=True)
    for name, make in changes.items():
        after = clip_features(make(), box)
        table[name] = {
            r.name: halves_auc(before[r.name], after[r.name], nominal.groups, splits=args.splits)
            for r in HAND_RUNGS
        }
        cells = (f"{mean:.3f} ± {std:.3f}" for mean, std in table[name].values())
        print(f"{name:16s} " + " ".join(f"{c:>15s}" for c in cells), flush=True)
    result = {
        "auc": {n: {r: v[0] for r, v in row.items()} for n, row in table.items()},
        "auc_std": {n: {r: v[1] for r, v in row.items()} for n, row in table.items()},
        "image_changes": list(IMAGE_CHANGES),
        "simulations": len(np.unique(nominal.groups)),
        "clips": len(nominal),
        "splits": args.splits,
        "seconds": time.perf_counter() - start,
    }
    text = json.dumps(result)
    if out is not None:
        atomic_write_bytes(out, (json.dumps(result, indent=1) + "\n").encode())
    print(text)


if __name__ == "__main__":
    main()
