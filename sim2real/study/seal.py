"""Sealed pseudo-real sets: footage from our own generator with a withheld effect.

``python -m sim2real.study.seal --seed N --out DIR [--data-dir TRAINING_DATA] [--kind ...]``
draws, from the seed alone, one or two effects of the candidate library (``--kind multi``:
3-6 across the stages) at strengths inside their plausible ranges (or an effect outside the
library, made as a camera or the scene makes it, :mod:`.open_set`: barrel lens distortion,
exposure flicker, a tone curve, a stronger wind), plus nuisance differences (fresh textures
and backgrounds, a slightly moved camera, the wind direction's jitter off nominal) and
continuous materials (stretch and bend multipliers log-uniform over the subspace's span,
areal density x [0.8, 1.25]). It writes only what a real set has: one folder of PNG frames
per video and ``labels.csv`` (video, stiffness, density, wind, fps), with neutral names. The
answer goes to a separate JSON file (default ``DIR.answer.json``) whose sha256 is printed;
the diagnosis never reads it.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import shutil
from pathlib import Path

import numpy as np

from common.commands import report_user_errors
from common.errors import InputError
from common.paths import check_output_dir
from datasets.plan import SimulationPlan
from datasets.spec import PRESETS, DatasetSpec, check_int
from simulator.cloth.material import (
    BASIS_MATERIAL,
    BEND_MULTIPLIERS,
    STRETCH_MULTIPLIERS,
    ClothMaterial,
    load_wang_material,
)

from ..candidates import Candidate, candidate_library
from .open_set import OPEN_SET_EFFECTS, render_sealed_video

__all__ = ["OPEN_SET_EFFECTS", "SEAL_KINDS", "draw_answer", "seal_set"]

SEAL_KINDS = ("single", "pair", "open", "multi", "twin")
_DRAWN_KINDS = ("single", "pair", "open")
"""Kinds a seed draws when none is given (``multi`` and ``twin`` are asked for by name)."""
_KIND_WEIGHTS = (0.5, 0.25, 0.25)
IMAGE_EFFECT_SOURCES = ("library", "twins")
"""Who applies a sealed set's library image effects (:func:`seal_set`'s ``image_effects``)."""
MULTI_EFFECTS = (3, 6)
"""A ``multi`` set's count of simultaneous library effects, drawn uniformly (inclusive)."""
_SEAL_STREAM = 7


def _draw_strength(candidate: Candidate, rng: np.random.Generator):
    """A strength in the half of the plausible range away from the effect's neutral value.

    Effects whose off state lies below the range are drawn in its upper half, those whose
    neutral value lies above it (a JPEG quality of 100) in its lower half; where the neutral
    value lies inside the range (a scene field's nominal value, a frame-rate ratio of 1), a
    side is picked and the strength is drawn in that side's outer half. Log-uniform on
    ranges over a factor 4, else uniform. The weaker halves are left out on purpose: there an
    effect is often too weak to leave a significant gap in 90 videos at all (measured in
    the smoke validation), so a set would test the detection limit, not the attribution.
    """
    if candidate.choices:
        options = [c for c in candidate.choices if c != candidate.default]
        return options[int(rng.integers(len(options)))]
    if candidate.low is None:
        return None
    scale = np.log if candidate.log_scale else (lambda v: v)
    back = math.exp if candidate.log_scale else (lambda v: v)
    low, high = float(scale(candidate.low)), float(scale(candidate.high))
    neutral = candidate.neutral
    if neutral is None or neutral <= candidate.low:
        low = 0.5 * (low + high)
    elif neutral >= candidate.high:
        high = 0.5 * (low + high)
    else:
        middle = float(scale(neutral))
        if rng.uniform() < 0.5:
            high = 0.5 * (low + middle)
        else:
            low = 0.5 * (middle + high)
    value = back(rng.uniform(low, high))
    return round(value) if candidate.integer else float(f"{value:.4g}")


def _multi_effects(library: dict[str, Candidate], rng: np.random.Generator) -> list[Candidate]:
    """3-6 library effects (:data:`MULTI_EFFECTS`), one from each stage first, then any.

    At most one effect per setting (two effects that set one field cannot both hold); in the
    order of the library's names.
    """
    low, high = MULTI_EFFECTS
    count = int(rng.integers(low, high + 1))
    names = sorted(library)
    stages = sorted({library[n].stage for n in names})
    stages = [stages[int(i)] for i in rng.permutation(len(stages))]  # 3 effects: 3 of 4 stages
    order = [names[int(i)] for i in rng.permutation(len(names))]
    first = [next(n for n in order if library[n].stage == stage) for stage in stages]
    picked, settings = [], set()
    for name in [*first, *order]:
        setting = (library[name].registry, library[name].field)
        if len(picked) == count or setting in settings:
            continue
        picked.append(name)
        settings.add(setting)
    return [library[n] for n in sorted(picked)]


def draw_answer(
    seed: int, library: dict[str, Candidate], kind: str | None = None, effect: str | None = None
) -> dict:
    """The withheld effect(s) of sealed set ``seed`` (and its kind) drawn from the seed.

    ``multi``: several library effects at once, across the stages (:func:`_multi_effects`);
    ``twin``: none (only the nuisances and materials every set has).

    ``effect`` fixes the library effect of a ``single`` set (its strength is still drawn), so
    that a validation can cover every switch.
    """
    rng = np.random.default_rng([seed, _SEAL_STREAM])
    drawn_kind = _DRAWN_KINDS[int(rng.choice(len(_DRAWN_KINDS), p=_KIND_WEIGHTS))]
    kind = kind or drawn_kind
    if kind not in SEAL_KINDS:
        raise ValueError(f"kind must be one of {SEAL_KINDS}, got {kind!r}")
    names = sorted(library)
    effects = []
    if kind == "open":
        open_names = sorted(OPEN_SET_EFFECTS)
        name = open_names[int(rng.integers(len(open_names)))]
        stage, (low, high) = OPEN_SET_EFFECTS[name]
        strength = float(f"{rng.uniform(low, high):.4g}")
        effects.append({"name": name, "stage": stage, "strength": strength, "library": False})
    elif kind == "twin":
        pass
    elif kind == "multi":
        for candidate in _multi_effects(library, rng):
            effects.append(
                {
                    "name": candidate.name,
                    "stage": candidate.stage,
                    "strength": _draw_strength(candidate, rng),
                    "library": True,
                }
            )
    else:
        count = 1 if kind == "single" else 2
        picked = rng.choice(len(names), size=count, replace=False)
        if effect is not None:
            if kind != "single" or effect not in library:
                raise ValueError(
                    f"effect: {effect!r} must be a library effect of a single set; allowed: {names}"
                )
            picked = [names.index(effect)]
        for i in sorted(int(p) for p in picked):
            candidate = library[names[i]]
            effects.append(
                {
                    "name": candidate.name,
                    "stage": candidate.stage,
                    "strength": _draw_strength(candidate, rng),
                    "library": True,
                }
            )
    return {"seed": seed, "kind": kind, "effects": effects}


def _sealed_spec(base: DatasetSpec, answer: dict, rng: np.random.Generator) -> tuple:
    """The pseudo-real set's spec (library effects on, nuisances applied) and the nuisances."""
    library = candidate_library(base)
    spec = base
    for effect in answer["effects"]:
        if effect["library"]:
            spec = library[effect["name"]].apply(spec, effect["strength"])
    shift = rng.uniform(-0.01, 0.01, size=3)
    position = tuple(float(p + s) for p, s in zip(spec.camera.position, shift, strict=True))
    scenario = spec.scenario
    nuisance = {"camera_shift_m": shift.round(4).tolist()}
    if hasattr(scenario, "wind_yaw_jitter_deg"):
        jitter = float(max(0.0, scenario.wind_yaw_jitter_deg + rng.uniform(-3, 3)))
        scenario = dataclasses.replace(scenario, wind_yaw_jitter_deg=jitter)
        nuisance["wind_yaw_jitter_deg"] = round(jitter, 3)
    for effect in answer["effects"]:
        if effect["name"] == "wind_speed":
            speeds = tuple(s * effect["strength"] for s in scenario.wind_speeds)
            scenario = dataclasses.replace(scenario, wind_speeds=speeds)
    spec = dataclasses.replace(
        spec, camera=dataclasses.replace(spec.camera, position=position), scenario=scenario
    )
    return spec, nuisance


def seal_set(
    out: str | Path,
    *,
    base: DatasetSpec,
    seed: int,
    videos: int = 90,
    clips_per_video: int = 4,
    clip_len: int = 10,
    kind: str | None = None,
    answer: dict | None = None,
    answer_path: str | Path | None = None,
    overwrite: bool = False,
    density_range: tuple[float, float] = (0.8, 1.25),
    image_effects: str | None = None,
) -> tuple[Path, str]:
    """Write sealed set ``seed`` into ``out``; returns (answer file, its sha256).

    Args:
        out: The real-style folder to write (must not exist unless ``overwrite``).
        base: The training data's spec (scene, level, texture mode, camera, settings).
        seed: Decides everything withheld and every random draw.
        videos: Videos; wind levels cycle W1, W2, W3 (Bouman et al.: 30 fabrics x 3 winds).
        clips_per_video: Clips of ``clip_len`` frames each video is long enough for.
        clip_len: Frames per clip.
        kind: ``single``, ``pair``, ``open``, ``multi`` or ``twin`` (default: drawn from the
            seed among the first three).
        answer: A given answer instead of a drawn one (tests plant a known effect).
        answer_path: Where the answer goes (default: ``<out>.answer.json``).
        overwrite: Replace an existing ``out``.
        density_range: Areal density factors on the basis fabric's, drawn uniformly
            (``(1, 1)``: every video at the training data's density).
        image_effects: Who applies the library's image effects: ``library`` (the renderer,
            as a candidate set does) or ``twins`` (second implementations written apart,
            :mod:`.image_twins`); default ``twins`` for ``multi`` and ``twin`` sets, else
            ``library``.
    """
    from simulator.cloth.rollout import simulate

    check_int("seed", seed, low=0)
    check_int("videos", videos, low=4)
    check_int("clips_per_video", clips_per_video)
    out = Path(out)
    answer_path = Path(answer_path) if answer_path else out.with_name(out.name + ".answer.json")
    if out.exists() and not overwrite:
        raise ValueError(f"out: {out} exists; choose another folder or pass --overwrite")
    answer_path.parent.mkdir(parents=True, exist_ok=True)
    library = candidate_library(base)
    answer = answer or draw_answer(seed, library, kind)
    if image_effects is None:
        image_effects = "twins" if answer["kind"] in ("multi", "twin") else "library"
    if image_effects not in IMAGE_EFFECT_SOURCES:
        raise ValueError(
            f"image_effects must be one of {IMAGE_EFFECT_SOURCES}, got {image_effects!r}"
        )
    rng = np.random.default_rng([seed, _SEAL_STREAM, 1])
    spec, nuisance = _sealed_spec(base, answer, rng)
    p = np.exp(rng.uniform(*np.log([min(STRETCH_MULTIPLIERS), max(STRETCH_MULTIPLIERS)]), videos))
    k = np.exp(rng.uniform(*np.log([min(BEND_MULTIPLIERS), max(BEND_MULTIPLIERS)]), videos))
    low, high = density_range
    if not 0 < low <= high:
        raise ValueError(f"density_range must be 0 < low <= high, got {density_range}")
    density_factor = rng.uniform(low, high, videos)
    basis = load_wang_material(BASIS_MATERIAL)
    sim_seeds = [int(s) for s in rng.integers(1, 2**31 - 1, size=videos)]
    winds = [
        i % len(spec.scenario.wind_speeds) if hasattr(spec.scenario, "wind_speeds") else 0
        for i in range(videos)
    ]
    # A slower camera (frame_rate) records longer, as a real one filming the same clips does.
    frame_count = dataclasses.replace(
        spec,
        preset=dataclasses.replace(
            spec.preset, clips_per_sim=clips_per_video, frames_per_clip=clip_len
        ),
    ).frames_per_sim
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    rows = ["video,stiffness,density,wind,fps"]
    batch = 30
    for first in range(0, videos, batch):
        idx = list(range(first, min(videos, first + batch)))
        material = ClothMaterial.from_wang(
            basis,
            stretch_mult=p[idx].tolist(),
            bend_mult=k[idx].tolist(),
            dtype=spec.sim.torch_dtype(),
        )
        material = dataclasses.replace(
            material, density=material.density * material.density.new_tensor(density_factor[idx])
        )
        seq = simulate(
            spec.scenario,
            material,
            seeds=[sim_seeds[i] for i in idx],
            wind_levels=[winds[i] for i in idx],
            fps=spec.preset.fps,
            record_time=(frame_count - 1) / spec.preset.fps,
            effects=spec.physics,
            settings=spec.sim,
        )
        weighed = spec.physics.density_factors([sim_seeds[i] for i in idx])
        for b, i in enumerate(idx):
            plan = SimulationPlan(-1, i, sim_seeds[i], winds[i], "test")
            # as the spec renders it, plus any out-of-library image effect (open_set)
            frames = render_sealed_video(
                spec,
                seq,
                b,
                plan,
                spec.lead_in_frames,
                frame_count,
                rng_seed=[sim_seeds[i], _SEAL_STREAM, 2],
                effects=answer["effects"],
                image_twins=image_effects == "twins",
            )
            _write_frames(partial / f"v{i:03d}", frames)
            # a withheld density_variation re-weighs the cloth on top of the fabric's own draw
            density = basis.density * density_factor[i] * weighed[b]
            rows.append(f"v{i:03d},{k[i]:.6g},{density:.6g},W{winds[i] + 1},{spec.preset.fps:g}")
    (partial / "labels.csv").write_text("\n".join(rows) + "\n")
    if out.exists():
        shutil.rmtree(out)
    partial.rename(out)
    answer = {
        **answer,
        "nuisance": nuisance,
        "videos": videos,
        "base_spec_key": base.key(),
        "sealed_spec_key": spec.key(),
        "image_effects": image_effects,
        "density_range": [float(low), float(high)],
    }
    text = json.dumps(answer, indent=2, sort_keys=True) + "\n"
    answer_path.write_text(text)
    return answer_path, hashlib.sha256(text.encode()).hexdigest()


def _write_frames(folder: Path, frames: np.ndarray) -> None:
    import cv2

    folder.mkdir(parents=True)
    for t, frame in enumerate(frames):
        if not cv2.imwrite(str(folder / f"frame_{t:04d}.png"), frame[..., ::-1]):
            raise OSError(f"could not write {folder / f'frame_{t:04d}.png'}")


def _base_spec(data_dir: str | None, level: int) -> DatasetSpec:
    if data_dir:
        from datasets.manifest import read_json

        return DatasetSpec.from_json(read_json(Path(data_dir) / "spec.json")["spec"])
    from simulator.cloth.rollout import SimSettings
    from simulator.cloth.scenes import ScenarioWind

    settings = SimSettings(max_dt=0.00834, settle_max_dt=0.0167, dtype="float32")
    return DatasetSpec(
        motion="wind",
        scenario=ScenarioWind(resolution_level=level),
        preset=PRESETS["full"],
        lead_in=0.4,
        sim=settings,
    )


@report_user_errors
def main(argv: list[str] | None = None) -> None:
    """Command line: write one sealed set and print its answer file's sha256."""
    parser = argparse.ArgumentParser(
        prog="python -m sim2real.study.seal", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--out", required=True, help="folder to write (videos + labels.csv)")
    parser.add_argument("--data-dir", help="training dataset folder (its spec.json is the base)")
    parser.add_argument("--level", type=int, default=1, help="mesh level without --data-dir")
    parser.add_argument("--videos", type=int, default=90)
    parser.add_argument("--clips-per-video", type=int, default=4)
    parser.add_argument("--kind", choices=SEAL_KINDS, help="default: drawn from the seed")
    parser.add_argument("--answer", help="answer file (default: <out>.answer.json)")
    parser.add_argument("--overwrite", action="store_true")
    parser.add_argument(
        "--image-effects",
        choices=IMAGE_EFFECT_SOURCES,
        help="who applies the library's image effects (default: twins for "
        "multi and twin sets, else library)",
    )
    parser.add_argument(
        "--density-range",
        type=float,
        nargs=2,
        default=(0.8, 1.25),
        metavar=("LOW", "HIGH"),
        help="areal density factors drawn per video",
    )
    args = parser.parse_args(argv)
    check_output_dir(args.out, "--out")
    try:
        path, digest = seal_set(
            args.out,
            base=_base_spec(args.data_dir, args.level),
            seed=args.seed,
            videos=args.videos,
            clips_per_video=args.clips_per_video,
            kind=args.kind,
            answer_path=args.answer,
            overwrite=args.overwrite,
            density_range=tuple(args.density_range),
            image_effects=args.image_effects,
        )
    except ValueError as err:  # the sealing's own checks name the field
        raise InputError(str(err)) from None
    print(f"sealed set: {args.out}")
    print(f"answer: {path} sha256 {digest}")


if __name__ == "__main__":
    main()
