"""Simulator speed under a concurrent CPU load, by torch thread count (oversubscription check).

``python -m benchmarks.thread_load_bench [--steps 100] [--repeats 3] [--backend kernels|torch]
[--batch 1]``

Workload: ``--batch`` 32 x 32 wind cloths (W3, 5 ms steps) from rest, ``--steps`` steps, one
Newton step per time step, on the compiled kernels (the CPU default; their parallel loops
take the process's torch thread count) or the torch path. For each thread setting (``1`` =
one torch thread per process, this project's default for simulating processes; ``default`` =
torch's own, one per core) it times the workload on a quiet machine and then beside a second
process that runs the same workload with the same thread setting in a loop (two simulations
sharing the CPU, as two dataset workers or a benchmark beside a test run do). Both processes
start with this process's environment, which ``import simulator`` gives
``OMP_WAIT_POLICY=PASSIVE`` unless it was set (:mod:`simulator.threads`); run it with
``OMP_WAIT_POLICY=ACTIVE`` to see OpenMP's spinning threads.

The fair slowdown is what the lost CPU share explains: two processes of ``t`` threads each
on ``c`` cores may each slow by ``max(1, 2 t / c)``. The table prints the measured slowdown
beside it; the last line is JSON. Take it on an otherwise quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import torch

from simulator.cloth.material import ClothMaterial
from simulator.cloth.scenes import ScenarioWind
from simulator.integrators import IntegratorBackwardEuler, solve_static
from simulator.solvers import NewtonSettings
from simulator.threads import use_process_threads

DT = 0.005
CLASS_ID = 13
WIND_LEVEL = 2


def workload(steps: int, backend: str = "kernels", batch: int = 1) -> float:
    """Wall seconds of ``steps`` backward-Euler steps of ``batch`` 32 x 32 wind cloths."""
    scene = ScenarioWind(resolution_level=3, settle_time=0.0, ramp_time=0.25)
    model, state, driver = scene.build(
        ClothMaterial.from_classes([CLASS_ID] * batch),
        seeds=list(range(batch)),
        wind_levels=[WIND_LEVEL] * batch,
    )
    static = NewtonSettings(
        max_iters=50, tol_dx=1e-9, cg_rtol=1e-6, cg_max_iters=1000, backend=backend
    )
    state, _ = solve_static(model, state, driver.control(0.0, state.pos), settings=static)
    integrator = IntegratorBackwardEuler(NewtonSettings(max_iters=1, cg_rtol=1e-2, backend=backend))
    start = time.perf_counter()
    for k in range(1, steps + 1):
        state, _ = integrator.step(model, state, driver.control(k * DT, state.pos), DT)
    return time.perf_counter() - start


def _threads_arg(text: str) -> int | None:
    return None if text == "default" else int(text)


def _worker_args(args: argparse.Namespace, threads: str) -> list[str]:
    return [
        "--threads",
        threads,
        "--steps",
        str(args.steps),
        "--repeats",
        str(args.repeats),
        "--backend",
        args.backend,
        "--batch",
        str(args.batch),
    ]


def _child_env() -> dict:
    return {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")}


def _start_load(args: argparse.Namespace) -> subprocess.Popen:
    cmd = [
        sys.executable,
        "-m",
        "benchmarks.thread_load_bench",
        "--load-worker",
        *_worker_args(args, args.threads),
    ]
    return subprocess.Popen(
        cmd, env=_child_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )


def measure(args: argparse.Namespace, threads: str) -> dict:
    """Quiet and loaded medians for one thread setting (run in a fresh child process)."""
    cmd = [
        sys.executable,
        "-m",
        "benchmarks.thread_load_bench",
        "--measure-worker",
        *_worker_args(args, threads),
    ]
    out = subprocess.run(cmd, env=_child_env(), check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _use_threads(threads: str) -> None:
    count = _threads_arg(threads)
    if count is not None:
        use_process_threads(count)


def _measure_worker(args: argparse.Namespace) -> None:
    _use_threads(args.threads)
    run = (args.steps, args.backend, args.batch)
    workload(10, args.backend, args.batch)  # warm-up (allocator, compiled kernels)
    quiet = [workload(*run) for _ in range(args.repeats)]
    load = _start_load(args)
    try:
        time.sleep(2.0)  # let the load start simulating
        loaded = [workload(*run) for _ in range(args.repeats)]
    finally:
        load.kill()
        load.wait()
    print(
        json.dumps(
            {
                "threads": torch.get_num_threads(),
                "quiet_s": quiet,
                "loaded_s": loaded,
            }
        )
    )


def main(argv: list[str] | None = None) -> dict:
    """Run both thread settings, print a table and a JSON line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--backend", default="kernels", choices=["kernels", "torch"])
    parser.add_argument("--batch", type=int, default=1, help="cloths simulated at once")
    parser.add_argument("--threads", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--load-worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--measure-worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.load_worker:
        _use_threads(args.threads)
        while True:
            workload(args.steps, args.backend, args.batch)
    if args.measure_worker:
        _measure_worker(args)
        return {}
    cores = os.cpu_count() or 1
    rows = {}
    for setting in ("1", "default"):
        r = measure(args, setting)
        quiet, loaded = statistics.median(r["quiet_s"]), statistics.median(r["loaded_s"])
        rows[setting] = {
            **r,
            "quiet_median_s": quiet,
            "loaded_median_s": loaded,
            "slowdown": loaded / quiet,
            "fair_slowdown": max(1.0, 2 * r["threads"] / cores),
        }
    print(
        f"{cores} cores, {args.steps} steps of {args.batch} 32 x 32 wind cloth(s) on "
        f"{args.backend}, medians of {args.repeats}"
    )
    print(f"{'threads':<10}{'quiet s':>10}{'loaded s':>10}{'slowdown':>10}{'fair':>8}")
    for setting, r in rows.items():
        label = f"{setting} ({r['threads']})"
        print(
            f"{label:<10}{r['quiet_median_s']:>10.2f}{r['loaded_median_s']:>10.2f}"
            f"{r['slowdown']:>10.2f}{r['fair_slowdown']:>8.2f}"
        )
    result = {
        "cores": cores,
        "steps": args.steps,
        "backend": args.backend,
        "batch": args.batch,
        "settings": rows,
    }
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
