"""Export a saved mesh sequence as a per-frame ``.obj`` or ``.ply`` series.

``python -m simulator.export sequence.npz out_dir [--format ply] [--instance 0]``
"""

from __future__ import annotations

import argparse
from pathlib import Path

from simulator.sequence import MeshSequence


def main(argv: list[str] | None = None) -> list[Path]:
    """Parse arguments and write the frames."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("sequence", type=Path, help="a sequence.npz written by the simulator")
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--format", choices=["obj", "ply"], default="obj")
    parser.add_argument("--instance", type=int, default=0, help="which instance of the batch")
    args = parser.parse_args(argv)
    paths = MeshSequence.load(args.sequence).export(
        args.out_dir, instance=args.instance, fmt=args.format
    )
    print(f"wrote {len(paths)} {args.format} frames to {args.out_dir}")
    return paths


if __name__ == "__main__":
    main()
