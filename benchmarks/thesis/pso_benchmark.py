"""Multi-region PSO recovery benchmark (issue 5 performance target, *thesis* §3.3.3).

``run_pso_benchmark()`` builds the organ scene at about ``tet_target`` organ tets with a
tumour (ratio 0.3, 70 kPa in a 30 kPa organ), generates the synthetic target, and runs the
40-particle PSO, timing everything after the target is made. Importable (for
``benchmarks/tissue_bench.py``) and runnable: ``python -m benchmarks.thesis.pso_benchmark``.
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from simulator.calibrate.multiregion import MultiRegionObjective, recover_regions
from simulator.tissue.meshing import REGION_TISSUE, organ_scene
from simulator.tissue.scenes import OrganForwardModel, organ_load_case, solve_organ_scene

__all__ = ["run_pso_benchmark"]


def run_pso_benchmark(
    tet_target: int = 4000,
    swarm: int = 40,
    seed: int = 0,
    *,
    tumour_ratio: float = 0.3,
    tumour_kpa: float = 70.0,
    normal_kpa: float = 30.0,
    material: str = "linear",
    homogeneous_side: bool = False,
    max_iters: int = 60,
    threads: int | None = 1,
) -> dict:
    """Time a multi-region PSO recovery; returns minutes, errors and counts.

    With ``homogeneous_side`` the whole tumour-side region gets ``tumour_kpa`` (no embedded
    tumour): the truth is then representable by two region moduli and the errors measure the
    solver and the PSO alone; otherwise they include the bias of fitting one modulus to a
    region with an embedded tumour (*thesis* Table 3.1 setting).

    Returns:
        ``pso_minutes`` (wall time of the PSO), ``pso_normal_rel_err`` (normal region),
        ``pso_tumour_region_kpa`` and ``pso_tumour_rel_err`` (against the tumour side's
        volume-weighted mean modulus, the best a homogeneous region can do), iterations,
        evaluations, organ tet count, ``setup_seconds``.
    """
    if threads is not None:
        torch.set_num_threads(threads)
    start = time.perf_counter()
    scene = organ_scene(tumour_ratio, tet_target=tet_target)
    organ = scene.mesh.tet_region != REGION_TISSUE
    tumour = scene.tet_tumour[organ]
    if homogeneous_side:
        tumour = scene.mesh.tet_region[organ] == 0
    mu = torch.where(tumour, tumour_kpa * 1e3, normal_kpa * 1e3)[None].double()
    pos, _ = solve_organ_scene(scene, mu, material=material, compression=0.1)
    case = organ_load_case(scene, pos[0])
    objective = MultiRegionObjective(OrganForwardModel(case, material=material), case.target_pos)
    setup = time.perf_counter() - start
    res = recover_regions(
        objective, [5e3, 5e3], [600e3, 600e3], swarm_size=swarm, seed=seed, max_iters=max_iters
    )
    mesh = case.mesh
    side = mesh.tet_region == 0
    vol = mesh.tet_rest_volume
    side_mean = float((vol[side] * mu[0, side]).sum() / vol[side].sum()) / 1e3
    best = res["best_mu"] / 1e3
    return {
        "pso_minutes": res["seconds"] / 60.0,
        "pso_normal_rel_err": float(abs(best[1] - normal_kpa) / normal_kpa),
        "pso_normal_region_kpa": float(best[1]),
        "pso_tumour_region_kpa": float(best[0]),
        "pso_tumour_side_mean_kpa": side_mean,
        "pso_tumour_rel_err": float(abs(best[0] - side_mean) / side_mean),
        "iterations": res["iterations"],
        "evaluations": res["evaluations"],
        "organ_tets": int(mesh.tet_count),
        "tumour_ratio": scene.tumour_ratio,
        "material": material,
        "homogeneous_side": homogeneous_side,
        "setup_seconds": setup,
    }


def main(argv: list[str] | None = None) -> dict:
    """``python -m benchmarks.thesis.pso_benchmark``: run the benchmark, print one JSON line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tet-target", type=int, default=4000, help="organ tetrahedra")
    parser.add_argument("--swarm", type=int, default=40, help="PSO particles")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.tet_target < 1 or args.swarm < 1:
        parser.error("--tet-target and --swarm must be >= 1")
    result = run_pso_benchmark(args.tet_target, args.swarm, args.seed)
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
