"""UKF Young's-modulus recovery: thesis Table 4.1-style sweep and the dropped ball (§4.2-4.3).

``python -m simulator.tools.ukf_table --out outputs/ukf`` writes ``ukf.csv``, ``ukf.md``
(ours beside the thesis's Table 4.1), ``ukf_ball.json`` and ``ukf.png`` (recovered vs true
modulus and the filter's convergence). Single-threaded. The last stdout line is JSON.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch

from simulator.inverse.ukf_experiments import (
    THESIS_TABLE_4_1,
    ukf_dropped_ball,
    ukf_table41,
)
from simulator.sequence import atomic_write_bytes


def markdown(rows: list[dict], ball: dict) -> str:
    """Table 4.1 layout, ours beside the thesis's, plus the dropped ball."""
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
        label="ours (UKF, tet beam)",
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
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def main(argv: list[str] | None = None) -> tuple[list[dict], dict]:
    """Run both experiments and write the outputs into ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/ukf"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--noise-mm", type=float, default=0.01, help="tracking noise std [mm]")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    rows = ukf_table41(seed=args.seed, trials=args.trials, noise=1e-3 * args.noise_mm)
    ball = ukf_dropped_ball(seed=args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(args.out / "ukf.csv", buf.getvalue().encode())
    atomic_write_bytes(args.out / "ukf_ball.json", json.dumps(ball, indent=2).encode())
    text = markdown(rows, ball)
    atomic_write_bytes(args.out / "ukf.md", text.encode())
    plot(rows, args.out / "ukf.png")
    print(text)
    worst = max(r["avg_rel_err_pct"] for r in rows) / 100.0
    print(
        json.dumps(
            {
                "ukf_rel_err": worst,
                "ukf_ball_rel_err": ball["avg_rel_err_pct"] / 100.0,
                "finite": all(math.isfinite(r["recovered_mean_kpa"]) for r in rows),
            }
        )
    )
    return rows, ball


if __name__ == "__main__":
    main()
