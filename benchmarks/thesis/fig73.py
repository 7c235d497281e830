"""Thesis Fig. 7.3: stretch and bend sensitivity curves of the basis material.

``python -m benchmarks.thesis.fig73 --out DIR`` writes ``sensitivity.csv``
and ``sensitivity.png`` (D vs 1/p and C vs 1/k, with a vertical line per Wang
fabric at its estimated ratio, as in the thesis figure).
"""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path

from common.files import atomic_write_bytes
from simulator.cloth.sensitivity import FabricStudy, fabric_study


def plot(study: FabricStudy, path: Path) -> None:
    """Two panels in the thesis's layout (x = reciprocal of the multiplier, log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    panels = (
        (axes[0], study.basis_stretch * 1000, study.stretch_ratio, "max stretch D [mm]", "1 / p"),
        (axes[1], study.basis_bend, study.bend_ratio, "max curvature C [1/m]", "1 / k"),
    )
    colors = plt.cm.tab10.colors
    for ax, values, ratios, ylabel, xlabel in panels:
        ax.plot(
            1 / study.multipliers, values, "o-", color="lightblue", label="camel-ponte-roma x m"
        )
        for i, (name, r) in enumerate(zip(study.fabrics, ratios, strict=True)):
            ax.axvline(1 / r, color=colors[i % 10], lw=1, label=name)
        ax.set_xscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=6, loc="best")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def main(argv: list[str] | None = None) -> FabricStudy:
    """Run the study and write CSV + PNG."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("outputs/sensitivity"))
    args = parser.parse_args(argv)
    study = fabric_study()
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["kind", "name", "multiplier", "stretch_D_m", "bend_C_per_m"])
    for m, d, c in zip(study.multipliers, study.basis_stretch, study.basis_bend, strict=True):
        writer.writerow(["basis", "camel-ponte-roma", m, d, c])
    for name, d, c, p, k in zip(
        study.fabrics,
        study.fabric_stretch,
        study.fabric_bend,
        study.stretch_ratio,
        study.bend_ratio,
        strict=True,
    ):
        writer.writerow(["fabric", name, f"p={p:.4g};k={k:.4g}", d, c])
    atomic_write_bytes(args.out / "sensitivity.csv", buf.getvalue().encode())
    plot(study, args.out / "sensitivity.png")
    print(f"wrote {args.out / 'sensitivity.csv'} and {args.out / 'sensitivity.png'}")
    return study


if __name__ == "__main__":
    main()
