"""Block-sparse (ELL) matrix products: today's per-instance layout against batch-innermost.

The compiled PCG (:mod:`simulator.kernels.pcg`) keeps one instance's matrix, (V, K, 3, 3)
float64 blocks, in its core's L2 for a whole solve. The batch-innermost layout that SIMD
across instances needs stores a group of 8 instances as (V, K, 3, 3, 8), 8x the bytes. This
probe times both on a 32 x 32 grid with a 13-slot stencil (the cloth's ELL width), 18
products in a row per instance or per group as in a solve, and reports microseconds per
instance-product. It also counts packed and scalar floating-point instructions in the group
kernel's assembly, which says whether numba vectorised the lane loop (docs/performance.md).

``python -m benchmarks.ell_layout_probe [--instances 56] [--repeats 7]``; the last line is JSON.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import time

import numpy as np
from numba import njit

from simulator.kernels.pcg import _matvec
from simulator.threads import use_process_threads

SIDE = 32
LANES = 8
PRODUCTS = 18
"""Products in a row per instance (a typical PCG solve at the production tolerance)."""
STENCIL = (
    (0, 0),
    (1, 0),
    (-1, 0),
    (0, 1),
    (0, -1),
    (1, 1),
    (-1, -1),
    (2, 1),
    (1, 2),
    (-1, -2),
    (-2, -1),
    (1, -1),
    (-1, 1),
)
"""Grid offsets of the 13 slots of a row (missing neighbours point at the row itself)."""


def stencil_columns(side: int = SIDE) -> np.ndarray:
    """ELL column of every slot, (side², 13)."""
    cols = np.zeros((side * side, len(STENCIL)), np.int64)
    for i in range(side):
        for j in range(side):
            for k, (a, b) in enumerate(STENCIL):
                ii, jj = i + a, j + b
                inside = 0 <= ii < side and 0 <= jj < side
                cols[i * side + j, k] = ii * side + jj if inside else i * side + j
    return cols


@njit(cache=True)
def _product_lanes(values, cols, p, out):
    """``out = A p`` for a group of 8 instances, lanes innermost: values (V, K, 3, 3, 8)."""
    acc = np.empty((3, 8), values.dtype)
    for i in range(values.shape[0]):
        acc[:] = 0.0
        for k in range(values.shape[1]):
            j = cols[i, k]
            for d in range(3):
                for e in range(3):
                    for lane in range(8):
                        acc[d, lane] += values[i, k, d, e, lane] * p[j, e, lane]
        for d in range(3):
            for lane in range(8):
                out[i, d, lane] = acc[d, lane]


@njit(cache=True)
def _solve_like(values, cols, free, p, out):
    """Today's kernel, the PCG's own product (every vertex free)."""
    for b in range(values.shape[0]):
        for _ in range(PRODUCTS):
            _matvec(values[b], cols, free, p[b], out[b])


@njit(cache=True)
def _solve_like_lanes(values, cols, p, out):
    for g in range(values.shape[0]):
        for _ in range(PRODUCTS):
            _product_lanes(values[g], cols, p[g], out[g])


def _to_lanes(a: np.ndarray) -> np.ndarray:
    """(B, ...) -> (B / 8, ..., 8): groups of 8 instances, the batch innermost."""
    groups = a.reshape(a.shape[0] // LANES, LANES, *a.shape[1:])
    return np.ascontiguousarray(np.moveaxis(groups, 1, -1))


def instruction_counts() -> dict:
    """Packed and scalar float64 multiply/FMA instructions in the group kernel's assembly."""
    asm = "\n".join(_product_lanes.inspect_asm().values())
    return {
        "packed": len(re.findall(r"\bv(?:mul|fmadd\d+)pd\b", asm)),
        "scalar": len(re.findall(r"\bv(?:mul|fmadd\d+)sd\b", asm)),
    }


def main(argv: list[str] | None = None) -> dict:
    """Time both layouts and print a table plus a JSON line."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--instances", type=int, default=56, help="a multiple of 8")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    if args.instances < LANES or args.instances % LANES:
        parser.error(f"--instances must be a positive multiple of {LANES}, got {args.instances}")
    use_process_threads(1)
    cols = stencil_columns()
    rng = np.random.default_rng(0)
    values = rng.normal(size=(args.instances, SIDE * SIDE, len(STENCIL), 3, 3))
    p = rng.normal(size=(args.instances, SIDE * SIDE, 3))
    out = np.zeros_like(p)
    lanes = (_to_lanes(values), cols, _to_lanes(p), _to_lanes(out))
    lanes32 = tuple(a if a is cols else a.astype(np.float32) for a in lanes)
    runs = {
        "per_instance_f64": (_solve_like, (values, cols, np.ones(SIDE * SIDE), p, out)),
        "lanes_f64": (_solve_like_lanes, lanes),
        "lanes_f32": (_solve_like_lanes, lanes32),
    }
    for fn, run_args in runs.values():
        fn(*run_args)  # compile (or load the cache) before timing
    lanes_out = np.moveaxis(runs["lanes_f64"][1][3], -1, 1).reshape(out.shape)
    if not np.allclose(lanes_out, out):
        raise RuntimeError("the two layouts disagree: the probe is wrong")
    times = {name: [] for name in runs}
    for _ in range(args.repeats):
        for name, (fn, run_args) in runs.items():
            start = time.perf_counter()
            fn(*run_args)
            times[name].append(time.perf_counter() - start)
    per = args.instances * PRODUCTS
    result = {
        "us_per_instance_product": {k: 1e6 * statistics.median(v) / per for k, v in times.items()},
        "instances": args.instances,
        "matrix_mb_per_instance": values[0].nbytes / 1e6,
        "lanes_kernel_instructions": instruction_counts(),
    }
    for name, us in result["us_per_instance_product"].items():
        print(f"{name:<18}{us:8.1f} us per instance-product")
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
