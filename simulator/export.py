"""Export a saved mesh sequence as a per-frame ``.obj`` or ``.ply`` series.

``python -m simulator.export sequence.npz out_dir [--format ply] [--instance 0]``

The sequence and the destination are checked before anything is written; the frames are
written into a stage beside ``out_dir`` that replaces it only when every frame is there, so a
full disk or Ctrl-C leaves no half series behind.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from common.commands import report_user_errors
from common.errors import InputError
from common.files import staged_folder
from common.paths import check_output_dir
from simulator.sequence import MeshSequence


def export_sequence(sequence: MeshSequence, out_dir: Path, fmt: str, instance: int) -> list[Path]:
    """Write every frame of ``instance`` into ``out_dir`` whole, or nothing."""
    with staged_folder(out_dir) as stage:
        written = sequence.export(stage, instance=instance, fmt=fmt)
    return [out_dir / p.name for p in written]


@report_user_errors
def main(argv: list[str] | None = None) -> list[Path]:
    """Parse arguments and write the frames."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("sequence", type=Path, help="a sequence.npz written by the simulator")
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--format", choices=["obj", "ply"], default="obj")
    parser.add_argument("--instance", type=int, default=0, help="which instance of the batch")
    args = parser.parse_args(argv)
    sequence = MeshSequence.load(args.sequence)
    count = sequence.pos.shape[0]
    if not 0 <= args.instance < count:
        raise InputError(
            f"--instance must be in [0, {count - 1}] ({args.sequence} holds {count} instances), "
            f"got {args.instance}"
        )
    out_dir = check_output_dir(args.out_dir, "out_dir")
    paths = export_sequence(sequence, out_dir, args.format, args.instance)
    print(f"wrote {len(paths)} {args.format} frames to {out_dir}")
    return paths


if __name__ == "__main__":
    main()
