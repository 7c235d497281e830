"""*thesis* Tables 3.1 and 3.2 (multi-region recovery sweeps) and Fig. 3.7 (sensitivity).

Writes CSV and PNG files to ``--out``:

* ``table31.csv/.png``: tumour-to-region volume ratio sweep, tumour 70 kPa, rest 30 kPa;
  recovered mean ``mu`` of the tumour-side and normal regions, ours beside the thesis's.
* ``table32.csv/.png``: tumour stiffness sweep at a fixed ratio (thesis: about 0.64).
* ``sensitivity.csv/.png``: sphere in cube (*thesis* §3.2.3), sphere stretched by balanced
  surface forces; axis ratio of the deformed sphere against its relative ``mu`` for the
  Mooney-Rivlin model and for linear elasticity calibrated to the same deformation at 1.

Synthetic targets: the scene (organ + tissue, see :mod:`simulator.tissue.scenes`) is solved with
the known per-tet moduli; the recovery sees only the target surface and the contact forces
of the tissue. The organ model is ``--material linear`` (the small-strain linearisation of
eq. 3.8, the default: one sparse LU per candidate) or ``--material mooney_rivlin`` (eq. 3.8
in full, in target and recovery; ~10x slower). ``--ratios`` / ``--tumour-kpa`` pick rows.
Run: ``python -m benchmarks.thesis.tissue_tables --out outputs/tissue`` or through Hydra,
``python -m benchmarks.thesis.tissue_jobs job=tables`` (:mod:`benchmarks.thesis.tissue_jobs`).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.thesis.outputs import save_png, write_csv
from simulator.calibrate.multiregion import MultiRegionObjective, recover_regions
from simulator.energies.loads import EnergyNodalForce
from simulator.integrators.backward_euler import solve_static
from simulator.model import SimControl, SimModel, SimState
from simulator.solvers.newton import NewtonSettings
from simulator.threads import torch_threads
from simulator.tissue.meshing import REGION_TISSUE, organ_scene, sphere_in_cube
from simulator.tissue.scenes import (
    MATERIALS,
    OrganForwardModel,
    organ_energy,
    organ_load_case,
    solve_organ_scene,
)

THESIS_T31 = {
    "ratio": [0.022, 0.14, 0.30, 0.49, 0.65, 0.76, 0.85],
    "tumour_region": [30.63, 31.54, 39.18, 43.93, 51.23, 61.16, 71.01],
    "normal_region": [29.15, 28.89, 31.22, 30.17, 31.49, 29.31, 30.46],
}
THESIS_T32 = {
    "tumour_kpa": [70, 140, 210, 280, 350, 420, 490],
    "tumour_region": [51.23, 112.92, 157.44, 186.78, 202.22, 254.20, 272.58],
    "normal_region": [31.49, 28.28, 30.04, 28.56, 27.62, 29.61, 25.18],
}
NORMAL_KPA = 30.0


def recover_case(
    ratio: float,
    tumour_kpa: float,
    *,
    tet_target: int,
    material: str = "linear",
    compression: float = 0.1,
    swarm: int = 40,
    seed: int = 0,
    max_iters: int = 60,
    upper_kpa: float = 600.0,
) -> dict:
    """Generate a synthetic target and recover the two region moduli with the PSO."""
    scene = organ_scene(ratio, tet_target=tet_target)
    organ = scene.mesh.tet_region != REGION_TISSUE
    mu = torch.where(scene.tet_tumour[organ], tumour_kpa * 1e3, NORMAL_KPA * 1e3)[None].double()
    pos, _ = solve_organ_scene(scene, mu, material=material, compression=compression)
    case = organ_load_case(scene, pos[0])
    objective = MultiRegionObjective(OrganForwardModel(case, material=material), case.target_pos)
    res = recover_regions(
        objective,
        [5e3, 5e3],
        [upper_kpa * 1e3] * 2,
        swarm_size=swarm,
        seed=seed,
        max_iters=max_iters,
    )
    best = res["best_mu"] / 1e3
    return {
        "ratio": scene.tumour_ratio,
        "tumour_kpa": tumour_kpa,
        "organ_tets": int(organ.sum()),
        "tumour_region_kpa": float(best[0]),
        "normal_region_kpa": float(best[1]),
        "normal_rel_err": float(abs(best[1] - NORMAL_KPA) / NORMAL_KPA),
        "iterations": res["iterations"],
        "evaluations": res["evaluations"],
        "seconds": res["seconds"],
        "best_f": res["best_f"],
    }


def _plot(path: Path, x, ours, thesis, xlabel: str, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    for key, style in (("tumour_region", "o-"), ("normal_region", "s-")):
        ax.plot(x, ours[key], style, label=f"ours: {key.replace('_', ' ')}")
        ax.plot(
            x,
            thesis[key],
            style.replace("-", "--"),
            alpha=0.6,
            label=f"thesis: {key.replace('_', ' ')}",
        )
    ax.set_xlabel(xlabel)
    ax.set_ylabel("recovered mean mu [kPa]")
    ax.set_title(title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_png(fig, path)


def sensitivity_study(
    rel_values=(0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0),
    *,
    mu_ref: float = 30e3,
    force_total: float = 600.0,
    mesh_size: float = 0.015,
) -> list[dict]:
    """Axis ratio of the stretched sphere against its relative ``mu`` (*thesis* Fig. 3.7).

    Balanced forces pull the sphere's surface caps at ``|x| > 0.8 R`` outwards along x; the
    cube's surface is fixed. Mooney-Rivlin and linear models; the linear reference modulus
    is calibrated (bisection) to give the same axis ratio at relative ``mu`` = 1.
    """
    mesh = sphere_in_cube(0.1, 0.025, mesh_size)
    pos0 = mesh.vert_pos
    radius = 0.025
    sphere_tris = mesh.surface_tri_indices  # outer cube surface
    cube_verts = torch.unique(sphere_tris)
    inner = torch.unique(mesh.tet_indices[mesh.tet_region == 0])
    on_sphere = inner[(pos0[inner].norm(dim=1) > 0.98 * radius)]
    caps = on_sphere[pos0[on_sphere, 0].abs() > 0.8 * radius]
    force = torch.zeros(1, mesh.vert_count, 3, dtype=pos0.dtype)
    force[0, caps, 0] = torch.sign(pos0[caps, 0]) * force_total / (0.5 * len(caps))
    rel = torch.tensor(rel_values, dtype=pos0.dtype)
    settings = NewtonSettings(max_iters=30, tol_dx=1e-8, linear_solver="direct")

    def axis_ratio(material: str, scale: torch.Tensor) -> torch.Tensor:
        mu = torch.stack([scale * mu_ref, torch.full_like(scale, mu_ref)], -1)
        tet_mu = mu[:, mesh.tet_region]
        energies = (organ_energy(tet_mu, material=material), EnergyNodalForce(force))
        batch = tet_mu.shape[0]
        model = SimModel(
            mesh, energies, (), pos0.new_ones(batch, mesh.vert_count), cube_verts
        ).with_pattern()
        rest = pos0[None].repeat(batch, 1, 1)
        state = SimState(rest, torch.zeros_like(rest), rest.new_zeros(batch))
        state, _ = solve_static(model, state, SimControl(rest[:, cube_verts]), settings=settings)
        x = state.pos[:, on_sphere]
        major = x[..., 0].amax(-1) - x[..., 0].amin(-1)
        minor = 0.5 * (
            x[..., 1].amax(-1) - x[..., 1].amin(-1) + x[..., 2].amax(-1) - x[..., 2].amin(-1)
        )
        return major / minor

    nonlinear = axis_ratio("mooney_rivlin", rel)
    target = float(nonlinear[rel_values.index(1.0)])
    lo, hi = 0.2, 5.0  # scale of the linear reference modulus
    for _ in range(30):
        mid = (lo * hi) ** 0.5
        ratio = float(axis_ratio("linear", torch.tensor([mid], dtype=pos0.dtype))[0])
        lo, hi = (lo, mid) if ratio < target else (mid, hi)
        if hi / lo < 1.001:
            break
    lin_scale = (lo * hi) ** 0.5
    linear = axis_ratio("linear", rel * lin_scale)
    return [
        {
            "relative_mu": float(r),
            "axis_ratio_mooney_rivlin": float(n),
            "axis_ratio_linear": float(li),
            "linear_reference_scale": lin_scale,
        }
        for r, n, li in zip(rel, nonlinear, linear, strict=True)
    ]


def _plot_sensitivity(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rel = np.array([r["relative_mu"] for r in rows])
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.5))
    for key, label in (
        ("axis_ratio_mooney_rivlin", "Mooney-Rivlin"),
        ("axis_ratio_linear", "linear"),
    ):
        y = np.array([r[key] for r in rows])
        axes[0].plot(rel, y, "o-", label=label)
        axes[1].plot(rel, np.abs(np.gradient(y, rel)), "o-", label=label)
    axes[0].set_xlabel("relative mu")
    axes[0].set_ylabel("axis ratio (major / minor)")
    axes[1].set_xlabel("relative mu")
    axes[1].set_ylabel("|d axis ratio / d relative mu|")
    axes[0].legend()
    fig.tight_layout()
    save_png(fig, path)


TABLES = {
    "t31": {
        "thesis": THESIS_T31,
        "stem": "table31",
        "x": "ratio",
        "case": lambda ratio: (ratio, 70.0),
        "xlabel": "tumour-to-region volume ratio",
        "title": "Table 3.1 (tumour 70 kPa",
    },
    "t32": {
        "thesis": THESIS_T32,
        "stem": "table32",
        "x": "tumour_kpa",
        "case": lambda kpa: (0.64, float(kpa)),
        "xlabel": "tumour mu [kPa]",
        "title": "Table 3.2 (ratio 0.64",
    },
}
"""How each table sweeps: the thesis column, its (ratio, tumour kPa) case, plot labels."""


def _table(out: Path, name: str, selected: list, kw: dict) -> list[dict]:
    """Recover the selected rows of one table; write its CSV and PNG."""
    spec = TABLES[name]
    thesis = spec["thesis"]
    keep = [i for i, x in enumerate(thesis[spec["x"]]) if x in selected]
    rows = []
    for i in keep:
        row = recover_case(*spec["case"](thesis[spec["x"]][i]), **kw)
        for key, values in thesis.items():
            row[f"thesis_{key}_kpa" if key.endswith("region") else f"thesis_{key}"] = values[i]
        row["material"] = kw["material"]
        rows.append(row)
        print(json.dumps(row), flush=True)
    write_csv(out / f"{spec['stem']}.csv", rows)
    _plot(
        out / f"{spec['stem']}.png",
        [r[spec["x"]] for r in rows],
        {k: [r[f"{k}_kpa"] for r in rows] for k in ("tumour_region", "normal_region")},
        {k: [v[i] for i in keep] for k, v in thesis.items()},
        spec["xlabel"],
        f"{spec['title']}, {kw['material']})",
    )
    return rows


def _select(values: list, wanted, field: str) -> list:
    """The thesis rows to run: all, or those whose value is in ``wanted``."""
    if wanted is None:
        return list(values)
    missing = [w for w in wanted if not any(abs(w - v) < 1e-9 for v in values)]
    if missing:
        raise ValueError(f"{field} must be among the thesis rows {values}, got {missing}")
    return [v for v in values if any(abs(w - v) < 1e-9 for w in wanted)]


def run(
    out: Path,
    *,
    tet_target: int = 1500,
    material: str = "linear",
    max_iters: int = 40,
    seed: int = 0,
    only: tuple[str, ...] = ("t31", "t32", "sens"),
    ratios: tuple[float, ...] | None = None,
    tumour_kpa: tuple[float, ...] | None = None,
    threads: int = 1,
) -> dict[str, list[dict]]:
    """Run the selected tables and write their CSV and PNG files into ``out``.

    Args:
        out: output folder.
        tet_target: organ tets of the scene meshes.
        material: organ model in target and recovery, one of ``MATERIALS``: ``linear`` (the
            small-strain linearisation of eq. 3.8) or ``mooney_rivlin`` (eq. 3.8 in full).
        max_iters: PSO iterations per recovery.
        seed: PSO seed.
        only: which of ``t31``, ``t32``, ``sens`` to run.
        ratios: Table 3.1 rows to run (thesis ratios), all if ``None``.
        tumour_kpa: Table 3.2 rows to run (thesis tumour moduli [kPa]), all if ``None``.
        threads: torch threads.

    Returns:
        The rows of each table that ran, by name.
    """
    unknown = set(only) - {"t31", "t32", "sens"}
    if unknown:
        raise ValueError(f"only must name t31, t32 or sens, got {sorted(unknown)}")
    if material not in MATERIALS:
        raise ValueError(f"material must be one of {MATERIALS}, got {material!r}")
    t31 = _select(THESIS_T31["ratio"], ratios, "ratios")
    t32 = _select(THESIS_T32["tumour_kpa"], tumour_kpa, "tumour_kpa")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    kw = {"tet_target": tet_target, "material": material, "max_iters": max_iters, "seed": seed}
    tables: dict[str, list[dict]] = {}
    with torch_threads(threads):
        for name, selected in (("t31", t31), ("t32", t32)):
            if name in only:
                tables[name] = _table(out, name, selected, kw)
        if "sens" in only:
            start = time.perf_counter()
            rows = sensitivity_study()
            write_csv(out / "sensitivity.csv", rows)
            _plot_sensitivity(out / "sensitivity.png", rows)
            print(json.dumps({"sensitivity_seconds": time.perf_counter() - start}), flush=True)
            tables["sens"] = rows
    return tables


def main(argv: list[str] | None = None) -> dict[str, list[dict]]:
    """Parse the command line and :func:`run`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/tissue"))
    parser.add_argument("--tet-target", type=int, default=1500)
    parser.add_argument(
        "--material",
        default="linear",
        choices=MATERIALS,
        help="linear: small-strain linearisation of eq. 3.8 (fast); mooney_rivlin: full eq. 3.8",
    )
    parser.add_argument("--max-iters", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", default="t31,t32,sens")
    parser.add_argument("--ratios", type=float, nargs="+", help="Table 3.1 rows (default all)")
    parser.add_argument("--tumour-kpa", type=float, nargs="+", help="Table 3.2 rows (default all)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    return run(
        args.out,
        tet_target=args.tet_target,
        material=args.material,
        max_iters=args.max_iters,
        seed=args.seed,
        only=tuple(args.only.split(",")),
        ratios=args.ratios,
        tumour_kpa=args.tumour_kpa,
        threads=args.threads,
    )


if __name__ == "__main__":
    main()
