"""Atomic writers for evaluation artefacts: JSON (no NaN allowed), Markdown and PNG figures.

Wind levels are written W1, W2, W3 (weakest first) in every report, as in the README and in
Bouman et al.'s real sets; the datasets store them as indices 0, 1, 2 (:func:`wind_label`).
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from common.files import atomic_write_bytes
from common.grid import ClassGrid

__all__ = [
    "MarkdownTable",
    "confusion_png",
    "markdown_table",
    "scatter_png",
    "wind_label",
    "write_json",
    "write_text",
]


def write_json(path: str | Path, payload) -> None:
    """Write ``payload`` as indented JSON; NaN or infinity raises instead of being written."""
    text = json.dumps(payload, indent=2, sort_keys=True, allow_nan=False)
    atomic_write_bytes(path, (text + "\n").encode())


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) atomically."""
    atomic_write_bytes(path, text.encode())


class MarkdownTable(str):
    """A GitHub Markdown table as text that keeps its header and rows (for an HTML page)."""

    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]


def markdown_table(header: list[str], rows: list[list]) -> MarkdownTable:
    """A GitHub Markdown table; floats keep what the caller formatted."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    table = MarkdownTable("\n".join(lines) + "\n")
    table.header = tuple(str(h) for h in header)
    table.rows = tuple(tuple(str(c) for c in row) for row in rows)
    return table


def wind_label(level: int | str) -> str:
    """Report name of a simulated wind level index: 0 -> "W1"; -1 (no wind) -> "none"."""
    level = int(level)
    return "none" if level < 0 else f"W{level + 1}"


def _png_bytes(fig) -> bytes:
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    plt.close(fig)
    return buffer.getvalue()


def scatter_png(
    path: str | Path,
    measured,
    predicted,
    winds,
    *,
    xlabel: str,
    ylabel: str,
    title: str,
) -> None:
    """Write a scatter plot of ``predicted`` against ``measured``, one colour per wind label.

    Videos without a wind label are drawn in grey as "no wind label".
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.asarray(measured, dtype=np.float64)
    y = np.asarray(predicted, dtype=np.float64)
    labels = [str(w) for w in winds]
    fig, ax = plt.subplots(figsize=(5.0, 4.0), dpi=100)
    colours = plt.get_cmap("tab10").colors
    for k, wind in enumerate(sorted(set(labels))):
        pick = np.array([label == wind for label in labels])
        colour = colours[k % len(colours)] if wind else "0.5"
        ax.scatter(x[pick], y[pick], s=22, color=colour, label=wind or "no wind label")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.legend(title="wind", fontsize=8, title_fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    atomic_write_bytes(path, _png_bytes(fig))


def confusion_png(path: str | Path, matrix: np.ndarray, title: str, grid: ClassGrid) -> None:
    """Write the confusion matrix over ``grid``'s classes (54 x 54 for the thesis's) as a PNG.

    Rows are true classes, columns predicted, row-normalised; the stretch blocks of bend (and
    density) classes (6 blocks of 9 for the thesis's grid) are outlined.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = np.asarray(matrix, dtype=np.float64)
    rows = counts.sum(axis=1, keepdims=True)
    share = np.divide(counts, rows, out=np.zeros_like(counts), where=rows > 0)
    bends = grid.bend_count * grid.density_count  # classes per stretch block
    fig, ax = plt.subplots(figsize=(7.5, 6.5), dpi=110)
    image = ax.imshow(share, cmap="viridis", vmin=0.0, vmax=1.0, interpolation="nearest")
    for edge in range(bends, counts.shape[0], bends):
        ax.axhline(edge - 0.5, color="white", linewidth=0.6)
        ax.axvline(edge - 0.5, color="white", linewidth=0.6)
    centres = [s * bends + (bends - 1) / 2 for s in range(grid.stretch_count)]
    names = [f"p{m:g}" for m in grid.stretch_multipliers]
    ax.set_xticks(centres, names)
    ax.set_yticks(centres, names)
    low, high = grid.bend_multipliers[0], grid.bend_multipliers[-1]
    ax.set_xlabel(f"predicted class (stretch block; bend {low:g}..{high:g} inside)")
    ax.set_ylabel("true class")
    ax.set_title(title, fontsize=10)
    fig.colorbar(image, ax=ax, fraction=0.046, pad=0.04, label="fraction of the true class")
    fig.tight_layout()
    atomic_write_bytes(path, _png_bytes(fig))
