"""The body fit of the garment recovery alone, on the scenes of *thesis* Fig. 6.11.

For every scene of :data:`apps.garment.scenes.SCENES` the scene is draped and rendered as
in :mod:`.garment_tables` (kept in ``--work``, default ``outputs/garment_pose/``, so a rerun
only fits), then :func:`apps.garment.recovery.fit_body` fits the body to the image, the
person's silhouette and the garment masks, with the settings of the tables (defaults). Printed:
per scene and joint the angle error [deg] against the truth (geodesic angle of the local
rotation; ``*``: occluded, as in the tables), the fit's seconds and the largest error over the
joints not occluded; the last line is the summary as JSON (*thesis* Table 6.3: 0-9 deg, target
3 deg). Only the body fit: the tables' joint errors also include Alg. 4's refinement.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from apps.garment.recovery import RecoverySettings, fit_body, skin_mask
from apps.garment.scenes import SCENES, scene_camera
from simulator.garment.body import JOINTS, Pose, joint_angle_errors
from simulator.threads import use_process_threads

from .garment_tables import scenes_by_name, stage_scene


def staged_scene(scene, edge_length: float, work: Path) -> dict:
    """Image, person, garment masks, truth pose and occlusion of a scene (cached in ``work``)."""
    path = work / f"{scene.name}_{edge_length:g}.npz"
    if path.exists():
        with np.load(path) as data:
            garments = [str(g) for g in data["garments"]]
            return {
                "image": data["image"],
                "person": data["person"],
                "masks": dict(zip(garments, data["masks"], strict=True)),
                "truth": Pose(data["truth"]),
                "occluded": dict(zip(JOINTS, data["occluded"].tolist(), strict=True)),
            }
    staged = stage_scene(scene, edge_length)
    garments = list(staged["draped"])
    work.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        path,
        image=staged["image"],
        person=staged["person"],
        masks=np.stack(staged["masks"]),
        garments=np.array(garments),
        truth=staged["truth_pose"].angles,
        occluded=np.array([staged["occluded"][j] for j in JOINTS]),
    )
    return staged_scene(scene, edge_length, work)


def main(argv: list[str] | None = None) -> dict:
    """Fit the body on every scene, print the errors; returns the summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", help="scene names (default: all ten)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--work",
        type=Path,
        default=Path("outputs/garment_pose"),
        help="staged scenes (default outputs/garment_pose)",
    )
    parser.add_argument(
        "--skin-only",
        action="store_true",
        help="fit without the garment masks (the skin mask alone tells the bare body)",
    )
    args = parser.parse_args(argv)
    use_process_threads(1, name="threads")
    settings = RecoverySettings(seed=args.seed)
    names = args.scenes or [s.name for s in SCENES]
    by_name = scenes_by_name(parser, names)
    camera = scene_camera()
    rows = []
    for name in names:
        st = staged_scene(by_name[name], settings.edge_length, args.work)
        tick = time.perf_counter()
        fit = fit_body(
            st["person"],
            skin_mask(st["image"], st["person"]),
            camera,
            settings,
            garments=None if args.skin_only else list(st["masks"].values()),
        )
        seconds = time.perf_counter() - tick
        errors = joint_angle_errors(fit.pose, st["truth"])
        visible = [e for j, e in errors.items() if not st["occluded"][j]]
        rows.append(
            {
                "scene": name,
                "seconds": seconds,
                "loss": fit.loss,
                "joint_err_deg": errors,
                "occluded": st["occluded"],
                "max_visible_deg": max(visible, default=0.0),
            }
        )
        print(f"{name}: fit {seconds:.1f} s, loss {fit.loss:.4f}", flush=True)
    print(f"{'joint':12s}" + "".join(f"{r['scene'][:9]:>10s}" for r in rows))
    for j in JOINTS:
        cells = [f"{r['joint_err_deg'][j]:9.1f}{'*' if r['occluded'][j] else ' '}" for r in rows]
        print(f"{j:12s}" + "".join(cells))
    print(f"{'max visible':12s}" + "".join(f"{r['max_visible_deg']:9.1f} " for r in rows))
    print(f"{'seconds':12s}" + "".join(f"{r['seconds']:9.1f} " for r in rows))
    summary = {
        "scenes": len(rows),
        "joint_angle_err_max_deg": max(r["max_visible_deg"] for r in rows),
        "per_scene_max_deg": {r["scene"]: round(r["max_visible_deg"], 2) for r in rows},
        "seconds_max": max(r["seconds"] for r in rows),
    }
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
