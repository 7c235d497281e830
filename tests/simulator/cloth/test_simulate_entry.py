"""simulator.cloth.simulate end to end on a tiny scene, and its all-or-nothing frame export."""

from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import simulator.cloth.simulate as simulate_entry
from simulator.sequence import MeshSequence

CONFIGS = str(Path(__file__).resolve().parents[3] / "configs")
TINY = [
    "classes=[0,53.0]",
    "scenario.resolution_level=1",
    "scenario.settle_time=0.1",
    "record_time=0.1",
    "fps=30",
]


def test_tiny_run_writes_the_sequence_and_a_ply_series(tmp_path):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose(
            config_name="simulate", overrides=[f"paths.output_dir={tmp_path}", "export=ply", *TINY]
        )
    sequence = simulate_entry.run(cfg)
    assert sequence.labels == [0, 53]  # 53.0 is class 53
    saved = MeshSequence.load(tmp_path / "sequence.npz")
    np.testing.assert_array_equal(saved.pos, sequence.pos)
    frames = sorted((tmp_path / "frames_ply").iterdir())
    assert [p.name for p in frames] == [f"frame_{k:05d}.ply" for k in range(4)]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames_ply", "sequence.npz"]


class _Exporter:
    """Writes ``count`` frames, then fails if asked to."""

    def __init__(self, count: int, fail: bool):
        self.count, self.fail = count, fail

    def export(self, out_dir, *, fmt):
        paths = []
        for k in range(self.count):
            path = Path(out_dir) / f"frame_{k:05d}.{fmt}"
            path.write_text("mesh\n")
            paths.append(path)
        if self.fail:
            raise OSError("disk full")
        return paths


def test_export_is_all_or_nothing(tmp_path):
    out = tmp_path / "frames_obj"
    with pytest.raises(OSError, match="disk full"):
        simulate_entry._export(_Exporter(3, fail=True), out, "obj")
    assert list(tmp_path.iterdir()) == []  # neither the series nor its temporary folder
    out.mkdir()
    (out / "frame_00009.obj").write_text("stale\n")  # an older, longer series is replaced
    paths = simulate_entry._export(_Exporter(2, fail=False), out, "obj")
    assert paths == [out / "frame_00000.obj", out / "frame_00001.obj"]
    assert sorted(p.name for p in out.iterdir()) == ["frame_00000.obj", "frame_00001.obj"]
    assert list(tmp_path.iterdir()) == [out]
