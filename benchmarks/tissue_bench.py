"""Tissue inverse problems: multi-region PSO recovery, UKF modulus estimation, monocular fps.

``python -m benchmarks.tissue_bench`` runs the three benchmarks of issue 5 with their default
sizes (PSO: ~3,500-tetrahedron organ, 40 particles; UKF: Table 4.1 moduli; monocular: 1,600
elements, one thread) and prints each result; the last line is JSON with ``pso_minutes``,
``pso_normal_rel_err``, ``ukf_rel_err``, ``mono_fps_1600``, ``mono_mean_err_mm``.
"""

from __future__ import annotations

import argparse
import json

from benchmarks.thesis.monocular_benchmark import run_mono_benchmark
from benchmarks.thesis.pso_benchmark import run_pso_benchmark
from benchmarks.thesis.ukf_experiments import run_ukf_benchmark
from simulator.threads import use_process_threads


def main(argv: list[str] | None = None) -> dict:
    """Run the three benchmarks and print the summary JSON line."""
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args(argv)
    use_process_threads(1)
    pso = run_pso_benchmark()
    print("PSO:", json.dumps(pso))
    ukf = run_ukf_benchmark()
    print("UKF:", json.dumps(ukf))
    mono = run_mono_benchmark(elements=1600)
    print("monocular:", json.dumps(mono))
    summary = {
        "pso_minutes": pso["pso_minutes"],
        "pso_normal_rel_err": pso["pso_normal_rel_err"],
        "ukf_rel_err": ukf["ukf_rel_err"],
        "mono_fps_1600": mono["mono_fps_1600"],
        "mono_mean_err_mm": mono["mono_mean_err_mm"],
    }
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
