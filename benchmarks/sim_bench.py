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

Usage: ``python -m benchmarks.sim_bench [--repeats 3] [--batch-repeats 1] [--dtype float64]
[--threads 1]`` (one torch thread by default, as every simulating process; see
:mod:`simulator.threads`).
The last line is JSON.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import torch

from simulator.integrators import IntegratorBackwardEuler, solve_static
from simulator.material import ClothMaterial, class_summary
from simulator.scenario import ScenarioWind
from simulator.solvers import NewtonSettings
from simulator.threads import use_process_threads

DT = 0.005
DURATION = 2.0
SINGLE_CLASS = 13  # p = 1, k = 5: membrane ~ camel-ponte-roma
WIND_LEVEL = 2


def run_ours(classes: list[int], dtype: torch.dtype, settings: NewtonSettings) -> dict:
    """Time ``DURATION / DT`` steps of the wind scene for a batch of classes."""
    scene = ScenarioWind(resolution_level=3, pose="corners", settle_time=0.0, ramp_time=0.25)
    material = ClothMaterial.from_classes(classes)
    device = "cuda" if torch.cuda.is_available() else "cpu"
    model, state, driver = scene.build(
        material,
        seeds=list(range(len(classes))),
        wind_levels=[WIND_LEVEL] * len(classes),
        dtype=dtype,
        device=device,
    )
    state, _ = solve_static(model, state, driver.control(0.0, state.pos))
    integrator = IntegratorBackwardEuler(settings)
    steps = round(DURATION / DT)
    cg_total = 0
    if device == "cuda":
        torch.cuda.synchronize()
    start = time.perf_counter()
    for k in range(1, steps + 1):
        state, stats = integrator.step(model, state, driver.control(k * DT, state.pos), DT)
        cg_total += int(stats.cg_iters.max())
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
    }


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
    args = parser.parse_args(argv)
    use_process_threads(args.threads or None)
    dtype = getattr(torch, args.dtype)
    settings = NewtonSettings(max_iters=1, cg_rtol=1e-2, cg_max_iters=200)
    verts = 32 * 32
    single = [run_ours([SINGLE_CLASS], dtype, settings) for _ in range(args.repeats)]
    result = {
        "machine": f"{platform.processor() or platform.machine()}, torch threads "
        f"{torch.get_num_threads()}, device {single[0]['device']}",
        "dtype": args.dtype,
        "dt_s": DT,
        "single": summarise([r["wall_s"] for r in single], verts, 1),
    }
    result["single"]["cg_iters_per_step"] = single[0]["cg_iters_per_step_max"]
    if not args.skip_batch:
        batch = [run_ours(list(range(54)), dtype, settings) for _ in range(args.batch_repeats)]
        result["batch54"] = summarise([r["wall_s"] for r in batch], verts, 54)
        result["batch54"]["cg_iters_per_step_max"] = batch[0]["cg_iters_per_step_max"]
        result["batch54"]["finite"] = all(r["finite"] for r in batch)

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
    if mj.get("available"):
        ours_single = result["single"]["sim_vertex_seconds_per_wall_s"]
        result["ratio_single_vs_mujoco"] = ours_single / mj["sim_vertex_seconds_per_wall_s"]
        if "batch54" in result:
            result["ratio_batch54_vs_mujoco"] = (
                result["batch54"]["sim_vertex_seconds_per_wall_s"]
                / mj["sim_vertex_seconds_per_wall_s"]
            )

    print(f"{'run':<14}{'wall s':>10}{'wall s/sim s':>14}{'vert-s/s':>12}{'vert-steps/s':>14}")
    rows = [("ours x1", result["single"])]
    if "batch54" in result:
        rows.append(("ours x54", result["batch54"]))
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
            )
        )
    for name, r in rows:
        print(
            f"{name:<14}{r['wall_s_median']:>10.2f}{r['wall_s_per_sim_s']:>14.2f}"
            f"{r['sim_vertex_seconds_per_wall_s']:>12.0f}{r['vertex_steps_per_s']:>14.0f}"
        )
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
