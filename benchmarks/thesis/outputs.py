"""Atomic CSV and PNG outputs of the table tools (a crash never leaves half a file)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from common.files import atomic_write_bytes

__all__ = ["save_png", "write_csv"]


def write_csv(path: Path, rows: list[dict]) -> None:
    """Rows (same keys) as a CSV file with a header line."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(path, buf.getvalue().encode())


def save_png(fig, path: Path, *, dpi: int = 120) -> None:
    """Save a matplotlib figure as PNG and close it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
