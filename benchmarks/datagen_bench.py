"""Dataset generation throughput: render frames/s, end-to-end clips/min, full-preset projection.

``python -m benchmarks.datagen_bench [--level 1] [--jobs 2] [--rounds 1]``

1. Render: one process renders 10-frame clips of a simulated wind sequence at the dataset's
   image size (texture, background and compositing included, PNG encoding excluded).
2. End to end: runs the first ``rounds x jobs`` work units of the ``full`` wind preset
   (each unit = one simulation of all 54 classes = 216 clips) exactly as
   ``python -m datasets.generate preset=full`` does (simulate + render + write shards, joblib
   workers), into a temporary directory, and projects the whole preset's 12 units from it.

The last line is JSON with ``render_fps``, ``clips_per_min`` and ``full_wind_minutes``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from datasets.generate import spec_from_config
from datasets.generation import generate_dataset, simulate_unit
from datasets.plan import plan_units
from render.backgrounds import make_background
from render.textures import make_texture
from simulator.threads import use_process_threads

CONFIGS = str(Path(__file__).resolve().parents[1] / "configs")


def _spec(level: int, preset: str):
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose(
            config_name="generate",
            overrides=[f"preset={preset}", f"level={level}", "motion=wind", "texture=random"],
        )
    return spec_from_config(cfg)


def render_fps(spec, clips: int = 20) -> float:
    """Frames/s of one renderer on a short simulated sequence (median over clips)."""
    from render.renderer import ClothRenderer

    unit = plan_units(spec)[0]
    small = type(unit)(index=0, sims=unit.sims[:2])
    seq = simulate_unit(spec, small, None)
    rng = np.random.default_rng(0)
    texture = make_texture("random", rng, spec.texture_size)
    background = make_background(rng, spec.camera.width, spec.camera.height)
    times = []
    with ClothRenderer(spec.camera, spec.lights, spec.visual) as renderer:
        frames = spec.preset.frames_per_clip
        for i in range(clips + 2):
            start = time.perf_counter()
            renderer.render_clip(
                seq.pos[i % 2, :frames],
                seq.tri_indices,
                seq.uv,
                texture,
                background,
                rng=np.random.default_rng(i),
            )
            if i >= 2:  # the first clips warm up the GL pipeline
                times.append(time.perf_counter() - start)
    return frames / statistics.median(times)


def main(argv: list[str] | None = None) -> dict:
    """Run both measurements, print a table and the JSON line."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", type=int, default=1, help="mesh resolution level (1-3)")
    parser.add_argument("--jobs", type=int, default=2, help="parallel workers")
    parser.add_argument("--rounds", type=int, default=1, help="units per worker to time")
    args = parser.parse_args(argv)
    use_process_threads(1)  # as every simulating process (the workers set their own)
    spec = _spec(args.level, "full")
    fps = render_fps(spec)
    print(f"render: {fps:.0f} frames/s at {spec.camera.width}x{spec.camera.height} (1 process)")

    units = plan_units(spec)
    count = min(len(units), args.jobs * args.rounds)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        generate_dataset(
            spec,
            Path(tmp) / "data",
            n_jobs=args.jobs,
            max_units=count,
            mesh_cache=Path(tmp) / "cache",
        )
        seconds = time.perf_counter() - start
    clips = count * spec.unit_size * spec.preset.clips_per_sim
    clips_per_min = clips / seconds * 60
    full_minutes = spec.clip_count / clips_per_min
    print(
        f"end to end: {count} units ({clips} clips, level {args.level}, {args.jobs} jobs) in "
        f"{seconds:.0f} s = {clips_per_min:.1f} clips/min\n"
        f"projected full wind preset ({spec.clip_count} clips x "
        f"{spec.preset.frames_per_clip} frames): {full_minutes:.1f} min"
    )
    result = {
        "render_fps": round(fps, 1),
        "clips_per_min": round(clips_per_min, 1),
        "full_wind_minutes": round(full_minutes, 1),
        "level": args.level,
        "jobs": args.jobs,
        "units_timed": count,
    }
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
