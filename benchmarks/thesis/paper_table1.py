"""Monocular reconstruction benchmark table (the paper's Table 1 and §7.2.2 baselines).

``python -m benchmarks.thesis.paper_table1 --out outputs/monocular`` reconstructs the
synthetic stretching sequence with 256/576/1024/1600 elements, the StVK model and the
linear-FEM and mass-spring baselines, under clean and noisy/occluded tracks, and writes
``monocular.csv``, ``monocular.md`` (ours beside the paper's Table 1) and ``monocular.png``.
Single-threaded; frame rates are medians of ``--repeats`` runs. The last stdout line is JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from benchmarks.thesis.monocular_benchmark import PAPER_TABLE1, mono_table
from benchmarks.thesis.outputs import save_png, write_csv
from common.files import atomic_write_bytes


def markdown(rows: list[dict]) -> str:
    """Table 1 layout (ours vs paper) plus the full per-condition table."""
    main = {
        r["elements"]: r
        for r in rows
        if r["model"] == "stvk"
        and r["condition"] == "clean"
        and r["newton_iters"] == 1
        and r["solver"] == "direct"
    }
    noisy = {r["elements"]: r for r in rows if r["model"] == "stvk" and r["condition"] == "noisy"}
    lines = [
        "| elements | ours fps | ours mean / RMS 3D err, clean [mm] "
        "| ours mean / RMS, noisy + occl. [mm] | paper fps (C++) | paper avg 2D err [%] |",
        "|---|---|---|---|---|---|",
    ]
    for n, (err2d, fps) in PAPER_TABLE1.items():
        if n not in main:
            continue
        c, z = main[n], noisy.get(n)
        nz = f"{z['mean_err_mm']:.2f} / {z['rms_err_mm']:.2f}" if z else "-"
        lines.append(
            f"| {n} | {c['fps']:.0f} | {c['mean_err_mm']:.2f} / {c['rms_err_mm']:.2f} | {nz} "
            f"| {fps:.0f} | {err2d} |"
        )
    lines += [
        "",
        "| elements | model | condition | features | Newton its | solver | mean [mm] | RMS [mm] "
        "| max [mm] | fps |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['elements']} | {r['model']} | {r['condition']} | {r['features']} "
            f"| {r['newton_iters']} | {r['solver']} | {r['mean_err_mm']:.2f} "
            f"| {r['rms_err_mm']:.2f} | {r['max_err_mm']:.2f} | {r['fps']:.1f} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Mean 3D error and frame rate against the element count, per model and condition."""
    fig, (ax_err, ax_fps) = plt.subplots(1, 2, figsize=(10, 4))
    base = [r for r in rows if r["newton_iters"] == 1 and r["solver"] == "direct"]
    colours = {"stvk": "tab:green", "linear": "tab:blue", "mass_spring": "tab:orange"}
    for model in sorted({r["model"] for r in base}):
        colour = colours.get(model)
        for cond, style in (("clean", "-o"), ("noisy", "--s"), ("noisy_all", ":^")):
            sel = sorted(
                (r for r in base if r["model"] == model and r["condition"] == cond),
                key=lambda r: r["elements"],
            )
            if sel:
                ax_err.plot(
                    [r["elements"] for r in sel],
                    [r["mean_err_mm"] for r in sel],
                    style,
                    color=colour,
                    label=f"{model} {cond}",
                )
        sel = sorted(
            (r for r in base if r["model"] == model and r["condition"] == "clean"),
            key=lambda r: r["elements"],
        )
        ax_fps.plot(
            [r["elements"] for r in sel],
            [r["fps"] for r in sel],
            "-o",
            color=colour,
            label=f"ours {model}",
        )
    ax_fps.set_yscale("log")
    ax_fps.plot(
        list(PAPER_TABLE1), [v[1] for v in PAPER_TABLE1.values()], "k--x", label="paper (C++)"
    )
    ax_err.set(xlabel="elements", ylabel="mean 3D error [mm]", title="reconstruction error")
    ax_fps.set(xlabel="elements", ylabel="frames / s (1 thread)", title="frame rate")
    ax_err.legend(fontsize=6)
    ax_fps.legend(fontsize=7)
    fig.tight_layout()
    save_png(fig, path)


def run(
    out: Path,
    *,
    seed: int = 0,
    repeats: int = 3,
    elements: tuple[int, ...] = (256, 576, 1024, 1600),
) -> list[dict]:
    """Run the table and write CSV, Markdown and PNG into ``out``."""
    rows = mono_table(seed=seed, elements=tuple(elements), repeats=repeats)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "monocular.csv", rows)
    text = markdown(rows)
    atomic_write_bytes(out / "monocular.md", text.encode())
    plot(rows, out / "monocular.png")
    print(text)
    head = next(
        r
        for r in rows
        if r["model"] == "stvk" and r["condition"] == "clean" and r["elements"] == elements[-1]
    )
    print(
        json.dumps(
            {f"mono_fps_{head['elements']}": head["fps"], "mono_mean_err_mm": head["mean_err_mm"]}
        )
    )
    return rows


def main(argv: list[str] | None = None) -> list[dict]:
    """Parse the command line and :func:`run`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/monocular"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--elements", type=int, nargs="+", default=[256, 576, 1024, 1600])
    args = parser.parse_args(argv)
    return run(args.out, seed=args.seed, repeats=args.repeats, elements=tuple(args.elements))


if __name__ == "__main__":
    main()
