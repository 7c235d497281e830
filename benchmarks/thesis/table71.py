"""Print thesis Table 7.1: each Wang fabric's estimated multipliers and nearest class.

``python -m benchmarks.thesis.table71 [--out DIR]`` also writes ``table71.md`` and
``table71.csv`` (ours beside the thesis's numbers).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from common.files import atomic_write_bytes
from simulator.cloth.material import nearest_class
from simulator.cloth.sensitivity import THESIS_TABLE_7_1, FabricStudy, fabric_study


def table_rows(study: FabricStudy) -> list[dict]:
    """One row per fabric, ours and the thesis's."""
    rows = []
    for name, p, k in zip(study.fabrics, study.stretch_ratio, study.bend_ratio, strict=True):
        cls, pq, kq = nearest_class(p, k)
        tp, tpq, tk, tkq = THESIS_TABLE_7_1[name]
        rows.append(
            {
                "material": name,
                "stretch_ratio": p,
                "stretch_class": pq,
                "bend_ratio": k,
                "bend_class": kq,
                "class_id": cls,
                "thesis_stretch": tp,
                "thesis_stretch_class": tpq,
                "thesis_bend": tk,
                "thesis_bend_class": tkq,
            }
        )
    return rows


def markdown(rows: list[dict]) -> str:
    """Table 7.1 as Markdown."""
    lines = [
        "| material | stretch p~ (p) | bend k~ (k) | class | thesis p~ (p) | thesis k~ (k) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['material']} | {r['stretch_ratio']:.3g} ({r['stretch_class']:g}) | "
            f"{r['bend_ratio']:.3g} ({r['bend_class']:g}) | {r['class_id']} | "
            f"{r['thesis_stretch']:g} ({r['thesis_stretch_class']:g}) | "
            f"{r['thesis_bend']:g} ({r['thesis_bend_class']:g}) |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> list[dict]:
    """Compute, print and optionally save the table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=None, help="directory for table71.md/.csv")
    args = parser.parse_args(argv)
    rows = table_rows(fabric_study())
    text = markdown(rows)
    print(text)
    if args.out is not None:
        atomic_write_bytes(args.out / "table71.md", text.encode())
        import io

        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
        atomic_write_bytes(args.out / "table71.csv", buf.getvalue().encode())
    return rows


if __name__ == "__main__":
    main()
