"""Offscreen render throughput: frames per second of one 32 x 32-vertex cloth clip on EGL.

Scene: an analytic waving cloth (0.5 m square hanging in the x-z plane like the wind scene,
travelling waves out of plane, no simulator needed), the wind camera preset at the default
resolution (112 x 112) or ``--size``, a random procedural texture and background. One
:class:`render.renderer.ClothRenderer` is created once and warmed up (shader compilation,
first texture upload); each run then renders one clip of ``--frames`` frames through
``render_clip`` (normals, upload, rasterisation, read-back, compositing, effects), and the
figure is frames / wall time, median over ``--repeats`` runs. ``--effects`` turns on every
visual effect but shadows, motion blur (which multiply the rasterisation cost by ~2.3 and
``motion_blur_samples``) and frame_rate (which changes the frame count); the rolling shutter
is among them. ``--shadows``, ``--rolling-shutter`` (8 band renders a frame) and
``--motion-blur`` (4 sub-frame renders) add one effect each. Each repeat also renders the
same clip on the reference path (whole frames for every rolling-shutter band, a new mesh a
frame: ``band_scissor`` and ``update_in_place`` off), checks that the bytes are equal and
reports the speed-up of the fast paths.

Usage: ``python -m benchmarks.render_bench [--frames 200] [--repeats 3] [--size 112]
[--supersample 1] [--effects] [--shadows] [--rolling-shutter] [--motion-blur]``. The last line
is JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import numpy as np

from render.backgrounds import make_background
from render.camera import DEFAULT_RESOLUTION, CameraSpec
from render.effects import EFFECT_NAMES, VisualEffects
from render.lights import LightSpec
from render.renderer import ClothRenderer
from render.textures import make_texture

VERTS_PER_SIDE = 32
SIZE_M = 0.5
FPS = 30.0


def waving_cloth(frame_count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Analytic waving cloth: pos (K, V, 3) [m], tri_indices (F, 3), uv (V, 2) [m]."""
    n = VERTS_PER_SIDE
    u, v = np.meshgrid(np.linspace(0, SIZE_M, n), np.linspace(0, SIZE_M, n))
    u, v = u.ravel(), v.ravel()
    t = np.arange(frame_count)[:, None] / FPS
    # Out-of-plane travelling waves growing with the distance from the pinned top edge,
    # plus a slow lift towards +y, so every frame has new normals and silhouettes.
    amplitude = 0.04 * (v / SIZE_M)
    wave = amplitude * np.sin(2 * np.pi * (1.3 * t - 2.0 * v - 0.7 * u))
    lift = 0.35 * (0.5 - 0.5 * np.cos(2 * np.pi * t / 4.0))
    pos = np.empty((frame_count, n * n, 3))
    pos[..., 0] = u - SIZE_M / 2 + 0.01 * np.sin(2 * np.pi * (0.9 * t - 3.0 * v))
    pos[..., 1] = v * np.sin(lift) + wave * np.cos(lift)
    pos[..., 2] = 1.0 - v * np.cos(lift) + wave * np.sin(lift)
    tris = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            tris += [[a, a + n, a + 1], [a + 1, a + n, a + n + 1]]
    return pos.astype(np.float32), np.asarray(tris, np.int64), np.stack([u, v], -1)


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmark and print a summary plus a JSON line."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--size", type=int, default=DEFAULT_RESOLUTION)
    parser.add_argument("--supersample", type=int, default=1)
    parser.add_argument("--effects", action="store_true")
    parser.add_argument("--shadows", action="store_true")
    parser.add_argument("--rolling-shutter", action="store_true")
    parser.add_argument("--motion-blur", action="store_true")
    args = parser.parse_args(argv)

    switches = {}
    if args.effects:
        excluded = ("shadows", "motion_blur", "frame_rate")
        switches = {n: True for n in EFFECT_NAMES if n not in excluded}
    for name in ("shadows", "rolling_shutter", "motion_blur"):
        if getattr(args, name):
            switches[name] = True
    effects = VisualEffects(**switches)
    camera = CameraSpec.wind(args.size, args.size)
    pos, tri, uv = waving_cloth(args.frames)
    rng = np.random.default_rng(0)
    texture = make_texture("random", rng)
    background = make_background(rng, camera.width, camera.height)

    walls: dict[bool, list[float]] = {True: [], False: []}
    with ClothRenderer(camera, LightSpec(), effects, supersample=args.supersample) as renderer:
        renderer.render_clip(pos[:2], tri, uv, texture, background, rng=rng)  # warm-up
        for repeat in range(args.repeats):
            frames = {}
            for fast in (True, False):  # side by side, so that both see the same machine
                renderer.band_scissor = renderer.update_in_place = fast
                start = time.perf_counter()
                frames[fast] = renderer.render_clip(
                    pos, tri, uv, texture, background, rng=np.random.default_rng(repeat)
                )
                walls[fast].append(time.perf_counter() - start)
            if not np.array_equal(frames[True], frames[False]):
                raise SystemExit("render_bench: the fast paths changed the frames")
    fps_all = [args.frames / w for w in walls[True]]
    reference_fps = statistics.median(args.frames / w for w in walls[False])
    result = {
        "render_fps": statistics.median(fps_all),
        "render_fps_all": fps_all,
        "ms_per_frame": 1e3 / statistics.median(fps_all),
        "reference_fps": reference_fps,
        "speedup": statistics.median(fps_all) / reference_fps,
        "frames": args.frames,
        "size": [camera.width, camera.height],
        "supersample": args.supersample,
        "verts": VERTS_PER_SIDE**2,
        "effects": sorted(switches),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cpus",
    }
    print(
        f"{args.frames} frames at {camera.width}x{camera.height} (supersample "
        f"{args.supersample}, effects {sorted(switches) or 'none'}): "
        f"{result['render_fps']:.1f} frames/s median "
        f"({', '.join(f'{f:.1f}' for f in fps_all)}), {result['ms_per_frame']:.2f} ms/frame; "
        f"reference path {reference_fps:.1f} frames/s, same bytes, {result['speedup']:.2f}x"
    )
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
