"""Hydra entry point: recover a garment's pattern, material and the body's pose from one image.

``python -m apps.garment.recover image=photo.png garment=skirt`` (``configs/garment.yaml``)
runs :func:`apps.garment.recovery.recover_garment` and writes into the run folder
(``logs/garment/runs/<time>/``), all at the end (staged in a hidden folder and moved into
place, so a failure or Ctrl-C leaves none of them):

* ``pattern.svg`` (cuttable, millimetres) and ``pattern.json`` (G with units, the material C,
  the panels' outlines and the seams);
* ``garment.obj`` and ``body.obj`` (or ``.ply``): the draped garment and the posed mannequin;
* ``overlay.png``: the recovered garment drawn over the input; ``side_by_side.png``: the input
  beside the re-render of body and garment under the estimated light;
* ``objective.png``: the best objective after every swarm iteration, per stage;
* ``result.json``: G, C, pose, body, curvatures, wrinkle densities and the map of Eq. 6.6;
  ``timings.json``: the seconds spent per part (the only file that changes between runs of
  the same config and seed).

A progress bar with ETA counts the swarm iterations. Every field is checked before any work:
a bad value (an unreadable image, a garment not in the library, a mask of another size, a
person too small to fit, a parameter outside its range) ends the command with one line
``error: <field> ...`` and nothing is written.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from common.checks import check_choice, check_float, check_int, check_threads
from common.commands import hydra_command
from common.configs import config_errors
from common.errors import InputError
from simulator.garment.patterns import GARMENT_TYPES, GarmentType, param_specs
from simulator.threads import use_process_threads

from .recovery import RecoveryResult, RecoverySettings, check_under, recover_garment

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
EXPORT_FORMATS = ("obj", "ply")
MIN_IMAGE_SIDE = 64
"""Smallest accepted image side [px]."""
MIN_PERSON_HEIGHT = 100
"""Smallest person height in the image [px] the body fit can work with."""
OUTPUTS = (
    "pattern.svg",
    "pattern.json",
    "overlay.png",
    "side_by_side.png",
    "objective.png",
    "result.json",
    "timings.json",
)


def read_image(path_text, field: str) -> np.ndarray:
    """An RGB image file as uint8 (H, W, 3); one-line errors naming ``field``."""
    import cv2

    path = Path(str(path_text))
    if path.suffix.lower() not in IMAGE_SUFFIXES:
        raise InputError(
            f"{field}: {path} is not an image file; allowed: {', '.join(IMAGE_SUFFIXES)}"
        )
    if not path.is_file():
        raise InputError(f"{field}: no such file {path}")
    data = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if data is None or data.size == 0:
        raise InputError(f"{field}: cannot read {path} as an image (empty or corrupt)")
    h, w = data.shape[:2]
    if min(h, w) < MIN_IMAGE_SIDE:
        raise InputError(f"{field}: {path} is {w} x {h} px; at least {MIN_IMAGE_SIDE} px a side")
    return cv2.cvtColor(data, cv2.COLOR_BGR2RGB)


def read_mask(path_text, field: str, shape: tuple[int, int]) -> np.ndarray:
    """A mask image (non-zero = inside) of the given (H, W), bool."""
    import cv2

    path = Path(str(path_text))
    if path.suffix.lower() not in IMAGE_SUFFIXES or not path.is_file():
        raise InputError(
            f"{field}: {path} is not an existing image file ({', '.join(IMAGE_SUFFIXES)})"
        )
    data = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if data is None or data.size == 0:
        raise InputError(f"{field}: cannot read {path} as an image (empty or corrupt)")
    if data.shape != tuple(shape):
        raise InputError(
            f"{field}: {path} is {data.shape[1]} x {data.shape[0]} px, the image is "
            f"{shape[1]} x {shape[0]} px; the mask must have the image's size"
        )
    mask = data > 0
    if not mask.any():
        raise InputError(f"{field}: {path} is empty (no non-zero pixel)")
    return mask


def _checked(cfg: DictConfig) -> dict:
    """Every field, validated; raises :class:`InputError` naming the first bad one."""
    with config_errors():
        threads = check_threads(cfg.get("threads", 1), "threads")
        garment = check_choice(cfg.garment, "garment", GARMENT_TYPES)
        under = cfg.get("under") or []
        if isinstance(under, str) or not all(isinstance(g, str) for g in under):
            raise InputError(f"under must be a list of garment names, got {under!r}")
        under = check_under(garment, list(under))
        seed = check_int(cfg.seed, "seed", 0)
        export = check_choice(cfg.export, "export", EXPORT_FORMATS)
        cam = cfg.camera
        distance = check_float(cam.distance, "camera.distance", 0.5, 50.0)
        height = check_float(cam.height, "camera.height", -5.0, 10.0)
        look = check_float(cam.look_at_height, "camera.look_at_height", -5.0, 10.0)
        yfov = check_float(cam.yfov_deg, "camera.yfov_deg", 1.0, 120.0)
        values = OmegaConf.to_container(cfg.recovery, resolve=True)
        if not isinstance(values, dict):
            raise InputError("recovery must be a mapping of RecoverySettings fields")
        allowed = set(RecoverySettings.__dataclass_fields__)
        unknown = sorted(set(values) - allowed)
        if unknown:
            raise InputError(f"recovery: unknown {unknown}; allowed: {sorted(allowed)}")
        settings = RecoverySettings(**{**values, "seed": seed})
    image = read_image(cfg.image, "image")
    mask = read_mask(cfg.mask, "mask", image.shape[:2]) if cfg.mask is not None else None
    person = None
    if cfg.person_mask is not None:
        person = read_mask(cfg.person_mask, "person_mask", image.shape[:2])
    from render.camera import CameraSpec

    camera = CameraSpec(
        position=(0.0, -distance, height),
        look_at=(0.0, 0.0, look),
        up=(0.0, 0.0, 1.0),
        yfov_deg=yfov,
        width=image.shape[1],
        height=image.shape[0],
    )
    out_dir = Path(str(cfg.out_dir))
    return {
        "threads": threads,
        "garment": garment,
        "under": under,
        "settings": settings,
        "image": image,
        "mask": mask,
        "person": person,
        "camera": camera,
        "export": export,
        "out_dir": out_dir,
    }


def check_person(person: np.ndarray) -> None:
    """Refuse a person mask too small for the body fit (one line naming ``image``)."""
    rows = np.nonzero(person.any(axis=1))[0]
    tall = int(rows[-1] - rows[0] + 1) if len(rows) else 0
    if tall < MIN_PERSON_HEIGHT:
        raise InputError(
            f"image: the person found is {tall} px tall; at least {MIN_PERSON_HEIGHT} px are "
            "needed to fit the body (a larger or closer view, or person_mask=...)"
        )


def run(cfg: DictConfig) -> RecoveryResult:
    """Recover the garment and write the outputs (see the module docstring)."""
    fields = _checked(cfg)
    use_process_threads(fields["threads"], name="threads")
    from .image import parse_person

    image = fields["image"]
    person = fields["person"] if fields["person"] is not None else parse_person(image)
    check_person(person)
    settings: RecoverySettings = fields["settings"]

    from tqdm import tqdm

    bar = tqdm(
        total=settings.body_iters + settings.planned_iterations(),
        unit="it",
        desc="body",
        smoothing=0.05,
    )

    def progress(stage: str) -> None:
        bar.set_description(stage, refresh=False)
        bar.update(1)

    try:
        result = recover_garment(
            image,
            fields["garment"],
            fields["camera"],
            settings,
            mask=fields["mask"],
            person=person,
            under=fields["under"],
            progress=progress,
        )
    finally:
        bar.close()
    paths = write_outputs(result, image, fields["camera"], fields["out_dir"], fields["export"])
    log.info("wrote %s", ", ".join(p.name for p in paths))
    return result


def result_json(result: RecoveryResult) -> dict:
    """``result.json``: what was recovered (deterministic for a config and seed)."""
    from .scenes import REGIONS

    specs = {p.name: p for p in param_specs(result.garment)}
    return {
        "garment": result.garment.value,
        "params": {
            k: {"value": v, "unit": specs[k].unit} for k, v in result.pattern.params.items()
        },
        "material": {"basis": "gray-interlock", **result.material},
        "pose_deg": result.pose.to_dict(),
        "body": {
            "height": result.body.shape.height,
            "offset": result.body.offset.tolist(),
            "fit_loss": result.body.loss,
        },
        "regions": list(REGIONS[result.garment.value]),
        "curvature": result.curvature.tolist(),
        "curvature_target": result.curvature_target.tolist(),
        "wrinkle_density": result.density.tolist(),
        "wrinkle_map": {
            "a": result.wrinkle_map[0],
            "b": result.wrinkle_map[1],
            "form": "K = a + b P (K [1/m], P [1/m])",
        },
        "light": {
            "direction": result.light.direction.tolist(),
            "ambient_ratio": result.light.ambient_ratio,
        },
        "history": result.history,
    }


def _render_result(result: RecoveryResult, camera, *, garment_only: bool = False):
    from .scenes import GARMENT_COLORS, render_scene

    caps = result.body.mannequin().capsules(result.pose.angles[None])[0]
    if garment_only:
        caps = caps[:0]
    color = GARMENT_COLORS[result.garment.value]
    return render_scene(
        camera,
        result.light.light_spec(),
        caps,
        [(result.pos, result.pattern.topology.tri_indices, color)],
        masks=False,
    )


def overlay_image(result: RecoveryResult, image: np.ndarray, camera) -> np.ndarray:
    """The recovered garment drawn over the input at 70 % opacity, uint8 (H, W, 3)."""
    from .image import mesh_mask

    render, _, _ = _render_result(result, camera)
    px, _ = camera.project(result.pos)
    mask = mesh_mask(px, result.pattern.topology.tri_indices, image.shape[:2])
    out = image.astype(np.float64)
    out[mask] = 0.3 * out[mask] + 0.7 * render[mask]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def objective_figure(history: list[dict], path: Path) -> None:
    """Plot the best objective per swarm iteration, one line per stage and round."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    groups = {"material": 0, "joint_material": 0, "sizing": 1, "pose": 2}
    titles = ("material (Eq. 6.5 + silhouette)", "sizing (Eq. 6.10) [px]", "pose (Eq. 6.14)")
    step = 0
    for entry in history:
        entry.setdefault("step", step)
        step += 1
    for key in sorted({(h["stage"], h["round"]) for h in history}):
        pts = [h for h in history if (h["stage"], h["round"]) == key]
        ax = axes[groups[key[0]]]
        ax.plot(
            [p["step"] for p in pts],
            [p["objective"] for p in pts],
            "o-",
            ms=3,
            label=f"{key[0]} round {key[1]}",
        )
    for ax, title in zip(axes, titles, strict=True):
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("swarm iteration")
        if ax.lines:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100, metadata={"Software": None})
    plt.close(fig)
    for entry in history:
        entry.pop("step", None)


def write_outputs(
    result: RecoveryResult, image: np.ndarray, camera, out_dir: Path, export: str = "obj"
) -> list[Path]:
    """Write every output through a hidden staging folder; returns the final paths."""
    import cv2
    import trimesh

    from simulator.sequence import atomic_write_bytes

    out_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".garment-", dir=out_dir))
    names = [*OUTPUTS, f"garment.{export}", f"body.{export}"]
    try:
        pattern = result.pattern
        (staging / "pattern.svg").write_text(pattern.to_svg())
        (staging / "pattern.json").write_text(
            json.dumps(pattern.to_json({"basis": "gray-interlock", **result.material}), indent=2)
            + "\n"
        )
        render, _, _ = _render_result(result, camera)
        side = np.concatenate([image, np.full((image.shape[0], 8, 3), 255, np.uint8), render], 1)
        for name, picture in (
            ("overlay.png", overlay_image(result, image, camera)),
            ("side_by_side.png", side),
        ):
            _, data = cv2.imencode(".png", cv2.cvtColor(picture, cv2.COLOR_RGB2BGR))
            atomic_write_bytes(staging / name, data.tobytes())
        objective_figure(result.history, staging / "objective.png")
        (staging / "result.json").write_text(json.dumps(result_json(result), indent=2) + "\n")
        (staging / "timings.json").write_text(json.dumps(result.timings, indent=2) + "\n")
        garment = trimesh.Trimesh(result.pos, pattern.topology.tri_indices, process=False)
        garment.export(staging / f"garment.{export}")
        body = result.body.mannequin().trimesh(result.pose)
        body.export(staging / f"body.{export}")
        for name in names:
            os.replace(staging / name, out_dir / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [out_dir / n for n in names]


main = hydra_command(run, config_name="garment", config_path="../../configs")
"""The command line: ``python -m apps.garment.recover image=... garment=skirt``."""


if __name__ == "__main__":
    main()


__all__ = ["GarmentType", "main", "overlay_image", "read_image", "read_mask", "run"]
