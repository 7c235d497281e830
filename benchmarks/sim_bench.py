"""Simulator throughput on the wind scene, beside MuJoCo's flex cloth in the same run.

Scene: 32 x 32-vertex cloth (0.5 m square, top corners pinned), wind W3, 2 s
of simulated time at a 5 ms step, starting from the settled rest state.
(a) one instance, (b) 54 instances (one per class) in one batch. Primary
figure: simulated vertex-seconds per wall second (vertices x simulated
seconds x instances / wall time); also vertex-steps per second and wall
seconds per simulated second. MuJoCo 4 simulates the same cloth (1024
vertices, same pins, membrane stiffness and bending of the single instance's
class, wind, duration, 5 ms step, ``integrator="discrete"``, Newton) and the
script prints the ratio. Medians over ``--repeats``.

Backends (``--backends kernels,torch``, the first is the headline): the compiled CPU kernels
(:mod:`simulator.kernels`; ``kernels`` runs each step's whole Newton solve in one compiled call,
``kernels_loop`` keeps the Newton loop in Python as before that kernel existed) and the torch
path, run side by side. Accuracy: the single
instance's trajectory (every 10th step) against a reference run of the same scene, the torch
path or the kernels (``--reference-backend``) converged tightly (10 Newton iterations, CG to
1e-10) at the same dt; mean and max
vertex position difference per backend.

Usage: ``python -m benchmarks.sim_bench [--repeats 3] [--batch-repeats 1] [--dtype float64]
[--threads 1] [--backends kernels,torch] [--skip-batch] [--batch-sizes 54]
[--reference-backend kernels|torch|none]`` (one thread by default, as every simulating process;
see :mod:`simulator.threads`). ``--batch-sizes 54,540`` adds larger batches (the classes
cycled), which is what a GPU needs to fill; ``--reference-backend none`` skips the accuracy
reference (on CUDA the torch path's tight reference solve is launch-bound and slow; its
agreement with the CPU is a test, ``test_cuda_matches_cpu_when_available``).
Runs on CUDA when present (the torch path; the kernels, a kernels reference too, run on the
CPU beside it).
The last line is JSON; its top level holds the headline backend's ``backend``,
``pos_err_mean_m``, ``pos_err_max_m``, ``single_speedup_vs_mujoco`` and
``ratio_batch54_vs_mujoco``, and ``runs`` every backend's figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import statistics
import time

import torch

from simulator.cloth.material import ClothMaterial, class_summary
from simulator.cloth.scenes import ScenarioWind
from simulator.integrators import IntegratorBackwardEuler, solve_static
from simulator.kernels import resolve_backend
from simulator.solvers import NewtonSettings
from simulator.threads import use_process_threads

DT = 0.005
DURATION = 2.0
SINGLE_CLASS = 13  # p = 1, k = 5: membrane ~ camel-ponte-roma
WIND_LEVEL = 2


BENCH_BACKENDS = {
    "kernels": ("kernels", True),
    "kernels_loop": ("kernels", False),
    "torch": ("torch", False),
}
"""``--backends`` names: (``sim.backend``, whole-step kernel)."""

RECORD_EVERY = 10
"""Steps between the positions kept for the accuracy comparison."""
REFERENCE = NewtonSettings(max_iters=10, tol_dx=1e-9, cg_rtol=1e-10, cg_max_iters=2000)
"""Tight solve of the accuracy reference; either backend gives the same trajectory to 1e-9 m
(``tests/simulator/core/test_kernels.py``), the kernels in minutes instead of about 20."""


def bench_device(backend: str) -> str:
    """Where ``sim.backend`` runs: the kernels on the CPU, the torch path on CUDA when present."""
    return "cuda" if backend != "kernels" and torch.cuda.is_available() else "cpu"


def run_ours(classes: list[int], dtype: torch.dtype, settings: NewtonSettings) -> dict:
    """Time ``DURATION / DT`` steps of the wind scene for a batch of classes."""
    scene = ScenarioWind(resolution_level=3, pose="corners", settle_time=0.0, ramp_time=0.25)
    material = ClothMaterial.from_classes(classes)
    device = bench_device(settings.backend)
    model, state, driver = scene.build(
        material,
        seeds=list(range(len(classes))),
        wind_levels=[WIND_LEVEL] * len(classes),
        dtype=dtype,
        device=device,
    )
    # the untimed start-up equilibrium on the run's own backend (on the torch path alone it took
    # longer than the timed run for 54 instances)
    static = NewtonSettings(
        max_iters=50, tol_dx=1e-9, cg_rtol=1e-6, cg_max_iters=1000, backend=settings.backend
    )
    state, _ = solve_static(model, state, driver.control(0.0, state.pos), settings=static)
    integrator = IntegratorBackwardEuler(settings)
    steps = round(DURATION / DT)
    cg_total = 0
    if device == "cuda":
        torch.cuda.synchronize()
    track = []
    start = time.perf_counter()
    for k in range(1, steps + 1):
        state, stats = integrator.step(model, state, driver.control(k * DT, state.pos), DT)
        cg_total += int(stats.cg_iters.max())
        if k % RECORD_EVERY == 0:
            track.append(state.pos[0].clone())
    if device == "cuda":
        torch.cuda.synchronize()
    wall = time.perf_counter() - start
    finite = bool(torch.isfinite(state.pos).all())
    return {
        "wall_s": wall,
        "steps": steps,
        "cg_iters_per_step_max": cg_total / steps,
        "finite": finite,
        "device": device,
        "track": torch.stack(track).double().cpu(),
    }


def position_error(track: torch.Tensor, reference: torch.Tensor) -> dict:
    """Mean and max vertex position difference [m] of two (T, V, 3) trajectories."""
    dist = torch.linalg.vector_norm(track - reference, dim=-1)
    return {"pos_err_mean_m": float(dist.mean()), "pos_err_max_m": float(dist.max())}


def summarise(walls: list[float], verts: int, instances: int) -> dict:
    """Median-based throughput figures."""
    wall = statistics.median(walls)
    steps = round(DURATION / DT)
    return {
        "wall_s_median": wall,
        "wall_s_all": walls,
        "wall_s_per_sim_s": wall / DURATION,
        "sim_vertex_seconds_per_wall_s": verts * DURATION * instances / wall,
        "vertex_steps_per_s": verts * steps * instances / wall,
    }


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmark and print a table plus a JSON line."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--batch-repeats", type=int, default=1)
    parser.add_argument("--dtype", choices=["float32", "float64"], default="float64")
    parser.add_argument("--skip-batch", action="store_true")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (0: one per core)")
    parser.add_argument(
        "--backends",
        default="kernels,torch",
        help="comma-separated: kernels, kernels_loop, torch (first = headline)",
    )
    parser.add_argument(
        "--reference-backend",
        default="kernels",
        choices=["kernels", "torch", "none"],
        help="backend of the tightly converged accuracy reference (none: skip it)",
    )
    parser.add_argument(
        "--batch-sizes",
        default="54",
        help="comma-separated instance counts of the batched runs (classes cycled)",
    )
    args = parser.parse_args(argv)
    try:
        batch_sizes = [int(b) for b in args.batch_sizes.split(",") if b.strip()]
    except ValueError:
        batch_sizes = []
    if not batch_sizes or min(batch_sizes) < 1:
        parser.error(f"--batch-sizes: comma-separated positive integers, got {args.batch_sizes!r}")
    use_process_threads(args.threads or None)
    backends = [b.strip() for b in args.backends.split(",") if b.strip()]
    for backend in backends:
        if backend not in BENCH_BACKENDS:
            parser.error(f"--backends: each must be one of {list(BENCH_BACKENDS)}, got {backend!r}")
        resolve_backend(BENCH_BACKENDS[backend][0], bench_device(BENCH_BACKENDS[backend][0]))
    dtype = getattr(torch, args.dtype)
    verts = 32 * 32
    reference = None
    if args.reference_backend != "none":
        reference_settings = dataclasses.replace(REFERENCE, backend=args.reference_backend)
        reference = run_ours([SINGLE_CLASS], torch.float64, reference_settings)["track"]
    result = {
        "machine": f"{platform.processor() or platform.machine()}, threads "
        f"{torch.get_num_threads()}"
        + (f", {torch.cuda.get_device_name()}" if torch.cuda.is_available() else ""),
        "dtype": args.dtype,
        "dt_s": DT,
        "backend": backends[0],
        "reference_backend": args.reference_backend,
        "runs": {},
    }
    for backend in backends:
        name, whole_step = BENCH_BACKENDS[backend]
        settings = NewtonSettings(
            max_iters=1, cg_rtol=1e-2, cg_max_iters=200, backend=name, whole_step=whole_step
        )
        single = [run_ours([SINGLE_CLASS], dtype, settings) for _ in range(args.repeats)]
        run = {
            "device": single[0]["device"],
            "single": summarise([r["wall_s"] for r in single], verts, 1),
            **(
                position_error(single[0]["track"], reference)
                if reference is not None
                else {"pos_err_mean_m": None, "pos_err_max_m": None}
            ),
        }
        run["single"]["cg_iters_per_step"] = single[0]["cg_iters_per_step_max"]
        for size in [] if args.skip_batch else batch_sizes:
            classes = [c % 54 for c in range(size)]
            batch = [run_ours(classes, dtype, settings) for _ in range(args.batch_repeats)]
            key = f"batch{size}"
            run[key] = summarise([r["wall_s"] for r in batch], verts, size)
            run[key]["cg_iters_per_step_max"] = batch[0]["cg_iters_per_step_max"]
            run[key]["finite"] = all(r["finite"] for r in batch)
        result["runs"][backend] = run

    from benchmarks.mujoco_cloth import run_mujoco_cloth

    summary = class_summary(SINGLE_CLASS)
    mj = run_mujoco_cloth(
        duration_s=DURATION,
        repeats=args.repeats,
        vert_per_side=32,
        size_m=0.5,
        density_kg_m2=summary["density"],
        stretch_stiffness_n_per_m=summary["stretch_stiffness"],
        bend_stiffness_nm=summary["bend_stiffness"],
        wind_speed_m_s=ScenarioWind().wind_speeds[WIND_LEVEL],
        dt_s=DT,
    )
    result["mujoco"] = {
        k: mj.get(k)
        for k in (
            "available",
            "reason",
            "mujoco_version",
            "integrator",
            "solver",
            "wall_s_median",
            "sim_vertex_seconds_per_wall_s",
            "vertex_steps_per_wall_s",
            "wall_s_per_sim_s",
        )
    }
    mj_rate = mj["sim_vertex_seconds_per_wall_s"] if mj.get("available") else None
    for run in result["runs"].values():
        if mj_rate:
            run["single_speedup_vs_mujoco"] = (
                run["single"]["sim_vertex_seconds_per_wall_s"] / mj_rate
            )
            for key in [k for k in run if k.startswith("batch")]:
                run[f"ratio_{key}_vs_mujoco"] = run[key]["sim_vertex_seconds_per_wall_s"] / mj_rate
    headline = result["runs"][backends[0]]
    for key in (
        "pos_err_mean_m",
        "pos_err_max_m",
        "single_speedup_vs_mujoco",
        "ratio_batch54_vs_mujoco",
    ):
        result[key] = headline.get(key)

    print(
        f"{'run':<22}{'wall s':>10}{'wall s/sim s':>14}{'vert-s/s':>12}{'vert-steps/s':>14}"
        f"{'err mean/max mm':>18}"
    )
    rows = []
    for backend, run in result["runs"].items():
        err = (
            f"{1e3 * run['pos_err_mean_m']:.3f}/{1e3 * run['pos_err_max_m']:.3f}"
            if run["pos_err_mean_m"] is not None
            else "-"
        )
        rows.append((f"ours {backend} x1", run["single"], err))
        for key in [k for k in run if k.startswith("batch")]:
            rows.append((f"ours {backend} x{key[5:]}", run[key], ""))
    if mj.get("available"):
        rows.append(
            (
                "mujoco x1",
                {
                    "wall_s_median": mj["wall_s_median"],
                    "wall_s_per_sim_s": mj["wall_s_per_sim_s"],
                    "sim_vertex_seconds_per_wall_s": mj["sim_vertex_seconds_per_wall_s"],
                    "vertex_steps_per_s": mj["vertex_steps_per_wall_s"],
                },
                "",
            )
        )
    for name, r, err in rows:
        print(
            f"{name:<22}{r['wall_s_median']:>10.2f}{r['wall_s_per_sim_s']:>14.2f}"
            f"{r['sim_vertex_seconds_per_wall_s']:>12.0f}{r['vertex_steps_per_s']:>14.0f}"
            f"{err:>18}"
        )
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
