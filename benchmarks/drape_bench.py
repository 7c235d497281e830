"""Drape time of a garment with the direct solver's SuperLU options against SuperLU's default.

Drapes the t-shirt of the scenes of pose a (over what the pants cover) at an edge length for a
fixed number of quasi-static steps (the stopping test off, so both paths do the same work),
``--batch`` instances at once, alternating the project's :data:`SPLU_OPTIONS` with ``{}``
(SuperLU's default) ``--repeats`` times. Prints the median wall time of each, their ratio, the
largest position difference between the two drapes, and JSON as the last line.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
import torch

import simulator.solvers.newton as newton
from apps.garment.scenes import SCENES
from benchmarks.thesis.garment_tables import probe_garment
from simulator.garment.drape import DrapeSettings, GarmentBatch, drape, garment_material
from simulator.threads import use_process_threads


def tshirt_batch(edge_length: float, batch: int, steps: int):
    """The t-shirt of pose a as a drape batch, its start positions and drape settings."""
    garment = probe_garment(edge_length, "tshirt")
    spec = next(g for g in SCENES[0].garments if g.garment == "tshirt")
    coords = np.repeat(garment.pattern.coords[None], batch, 0)
    x0 = np.repeat(garment.start, batch, 0)
    settings = DrapeSettings(max_steps=steps, speed_tol=0.0)
    caps = np.repeat(garment.obstacle, batch, 0)
    material = garment_material([spec.material["bend"]] * batch, [garment.stretch] * batch)
    topology = garment.pattern.topology
    built = GarmentBatch.build(topology, coords, material, caps, settings, pos_hint=x0)
    return built, x0, settings, len(garment.pattern.coords)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--edge-length", type=float, default=0.05, help="m (default 0.05)")
    parser.add_argument("--batch", type=int, default=4, help="instances draped at once (4)")
    parser.add_argument("--steps", type=int, default=20, help="quasi-static steps (20)")
    parser.add_argument("--repeats", type=int, default=3, help="timings per path (3)")
    args = parser.parse_args(argv)
    for name in ("batch", "steps", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be >= 1, got {getattr(args, name)}")
    if not args.edge_length > 0:
        parser.error(f"--edge-length must be > 0 m, got {args.edge_length}")
    use_process_threads(1, name="threads")
    built, x0, settings, verts = tshirt_batch(args.edge_length, args.batch, args.steps)
    project = dict(newton.SPLU_OPTIONS)
    paths = {"project": project, "superlu_default": {}}
    seconds: dict[str, list[float]] = {k: [] for k in paths}
    pos: dict[str, torch.Tensor] = {}
    try:
        for _ in range(args.repeats):
            for name, options in paths.items():
                newton.SPLU_OPTIONS = options
                tick = time.perf_counter()
                pos[name] = drape(built, x0, settings).pos
                seconds[name].append(time.perf_counter() - tick)
    finally:
        newton.SPLU_OPTIONS = project
    med = {k: statistics.median(v) for k, v in seconds.items()}
    out = {
        "edge_length": args.edge_length,
        "vertices": verts,
        "batch": args.batch,
        "steps": args.steps,
        "options": project,
        "seconds_median": med,
        "speedup": med["superlu_default"] / med["project"],
        "max_position_difference_m": float((pos["project"] - pos["superlu_default"]).abs().max()),
    }
    for name, value in med.items():
        print(f"{name:16s} {value:8.2f} s (median of {args.repeats})")
    print(
        f"speed-up {out['speedup']:.2f}x; largest position difference "
        f"{out['max_position_difference_m']:.1e} m"
    )
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
