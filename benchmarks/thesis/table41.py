"""UKF Young's-modulus recovery: thesis Table 4.1-style sweep and the dropped ball (§4.2-4.3).

``python -m benchmarks.thesis.table41 --out outputs/ukf [--body heart]`` writes ``ukf.csv``,
``ukf.md`` (ours beside the thesis's Table 4.1), ``ukf_ball.json`` and ``ukf.png`` (recovered
vs true modulus). ``--body heart`` runs the sweep on the gmsh biventricular heart (Newmark)
instead of the tet beam. Single-threaded. The last stdout line is JSON.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from benchmarks.thesis.outputs import save_png, write_csv
from benchmarks.thesis.ukf_experiments import (
    TABLE41_BODIES,
    THESIS_TABLE_4_1,
    ukf_dropped_ball,
    ukf_table41,
)
from common.files import atomic_write_bytes
from simulator.calibrate.ukf_body import INTEGRATORS
from simulator.threads import torch_threads


def markdown(rows: list[dict], ball: dict | None) -> str:
    """Table 4.1 layout, ours beside the thesis's, plus the dropped ball (if run)."""
    lines = [
        "| true E [kPa] | initial [kPa] | recovered [kPa] | avg rel. err [%] | surface err [mm] "
        "| thesis initial | thesis recovered | thesis rel. err [%] | thesis surface [mm] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        t = THESIS_TABLE_4_1.get(r["true_kpa"])
        thesis = (
            f"{t['init'][0]} ± {t['init'][1]} | {t['recovered'][0]} ± {t['recovered'][1]} "
            f"| {t['rel_err']} | {t['surface_mm'][0]} ± {t['surface_mm'][1]}"
            if t
            else "- | - | - | -"
        )
        lines.append(
            f"| {r['true_kpa']} | {r['init_mean_kpa']:.1f} ± {r['init_std_kpa']:.1f} "
            f"| {r['recovered_mean_kpa']:.2f} ± {r['recovered_std_kpa']:.2f} "
            f"| {r['avg_rel_err_pct']:.2f} | {r['surface_err_mm']:.3f} | {thesis} |"
        )
    if ball is None:
        return "\n".join(lines) + "\n"
    rec = ", ".join(f"{v:.2f}" for v in ball["recovered_kpa"])
    ini = ", ".join(f"{v:.1f}" for v in ball["init_kpa"])
    lines += [
        "",
        f"Dropped ball (gravity only): true {ball['true_kpa']} kPa, initial guesses {ini} kPa, "
        f"recovered {rec} kPa, average relative error {ball['avg_rel_err_pct']:.2f} %.",
    ]
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Recovered vs true modulus (ours and thesis)."""
    fig, ax = plt.subplots(figsize=(5, 4))
    true = [r["true_kpa"] for r in rows]
    ax.errorbar(
        true,
        [r["recovered_mean_kpa"] for r in rows],
        yerr=[r["recovered_std_kpa"] for r in rows],
        fmt="o",
        label=f"ours (UKF, {rows[0].get('body', 'beam')})",
    )
    thesis = [(k, v["recovered"]) for k, v in THESIS_TABLE_4_1.items() if k in true]
    ax.errorbar(
        [k for k, _ in thesis],
        [v[0] for _, v in thesis],
        yerr=[v[1] for _, v in thesis],
        fmt="s",
        label="thesis Table 4.1 (heart)",
    )
    ax.errorbar(
        true,
        [r["init_mean_kpa"] for r in rows],
        yerr=[r["init_std_kpa"] for r in rows],
        fmt="x",
        color="gray",
        label="initial guesses",
    )
    lim = [0, 1.1 * max(true)]
    ax.plot(lim, lim, "k:", lw=1)
    ax.set(xlabel="true E [kPa]", ylabel="E [kPa]", title="UKF Young's modulus recovery")
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_png(fig, path)


def run(
    out: Path,
    *,
    seed: int = 0,
    trials: int = 5,
    noise_mm: float = 0.01,
    body: str = "beam",
    integrator: str | None = None,
    moduli_kpa: tuple[int, ...] = (40, 80, 100, 140, 180),
    frames: int = 40,
    passes: int = 2,
    truth_mesh_refine: int = 1,
    ball: bool = True,
) -> tuple[list[dict], dict | None]:
    """Run the Table 4.1 sweep (and the dropped ball) single-threaded; write into ``out``."""
    with torch_threads(1):
        rows = ukf_table41(
            seed=seed,
            trials=trials,
            noise=1e-3 * noise_mm,
            body=body,
            integrator=integrator,
            moduli_kpa=tuple(moduli_kpa),
            frames=frames,
            passes=passes,
            truth_mesh_refine=truth_mesh_refine,
        )
        dropped = ukf_dropped_ball(seed=seed) if ball else None
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "ukf.csv", rows)
    if dropped is not None:
        atomic_write_bytes(out / "ukf_ball.json", json.dumps(dropped, indent=2).encode())
    text = markdown(rows, dropped)
    atomic_write_bytes(out / "ukf.md", text.encode())
    plot(rows, out / "ukf.png")
    print(text)
    summary = {
        "ukf_rel_err": max(r["avg_rel_err_pct"] for r in rows) / 100.0,
        "finite": all(math.isfinite(r["recovered_mean_kpa"]) for r in rows),
    }
    if dropped is not None:
        summary["ukf_ball_rel_err"] = dropped["avg_rel_err_pct"] / 100.0
    print(json.dumps(summary))
    return rows, dropped


def main(argv: list[str] | None = None) -> tuple[list[dict], dict | None]:
    """Parse the command line and :func:`run`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/ukf"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--noise-mm", type=float, default=0.01, help="tracking noise std [mm]")
    parser.add_argument("--body", choices=sorted(TABLE41_BODIES), default="beam")
    parser.add_argument(
        "--integrator", choices=sorted(INTEGRATORS), default=None, help="default: the body's"
    )
    parser.add_argument("--moduli", type=int, nargs="+", default=[40, 80, 100, 140, 180])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--passes", type=int, default=2)
    parser.add_argument(
        "--truth-mesh-refine", type=int, default=1, help="ground truth on an n times finer mesh"
    )
    parser.add_argument("--no-ball", action="store_true", help="skip the dropped ball")
    args = parser.parse_args(argv)
    return run(
        args.out,
        seed=args.seed,
        trials=args.trials,
        noise_mm=args.noise_mm,
        body=args.body,
        integrator=args.integrator,
        moduli_kpa=tuple(args.moduli),
        frames=args.frames,
        passes=args.passes,
        truth_mesh_refine=args.truth_mesh_refine,
        ball=not args.no_ball,
    )


if __name__ == "__main__":
    main()
