"""Every argparse command prints its help and exits on ``--help``, before doing any work.

The Hydra entry points (simulator.cloth.simulate, datasets.generate, apps.demo,
apps.clone, train.py, benchmarks.thesis.tissue_jobs, sim2real.diagnose, models.evaluate) get
``--help`` from Hydra itself.
"""

import importlib
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HYDRA = {
    "simulator.cloth.simulate",
    "datasets.generate",
    "apps.demo",
    "apps.clone",
    "benchmarks.thesis.tissue_jobs",
    "sim2real.diagnose",
    "models.evaluate",
    "sim2real.shrink",
    "sim2real.candidates",
    "apps.garment.recover",
    "apps.garment.tryon",
}

COMMANDS = [
    "benchmarks.datagen_bench",
    "benchmarks.detection_limits",
    "benchmarks.diagnose_bench",
    "benchmarks.ell_layout_probe",
    "benchmarks.footage_ceiling",
    "benchmarks.gap_resolution",
    "benchmarks.input_audit",
    "benchmarks.sim2real_accuracy",
    "benchmarks.sim2real_multi_effect",
    "benchmarks.sim2real_rung_invariance",
    "benchmarks.mujoco_cloth",
    "benchmarks.precond_bench",
    "benchmarks.drape_bench",
    "benchmarks.render_bench",
    "benchmarks.sim_bench",
    "benchmarks.thread_load_bench",
    "benchmarks.tissue_bench",
    "benchmarks.train_bench",
    "benchmarks.thesis.feature_probe",
    "benchmarks.thesis.geometry_oracle",
    "datasets.preview",
    "benchmarks.thesis.table72",
    "sim2real.study.power",
    "sim2real.study.seal",
    "sim2real.study.validate",
    "sim2real.study.independent",
    "benchmarks.thesis.pso_benchmark",
    "simulator.export",
    "benchmarks.thesis.paper_table1",
    "benchmarks.thesis.fig73",
    "benchmarks.thesis.table71",
    "benchmarks.thesis.tissue_tables",
    "benchmarks.thesis.garment_tables",
    "benchmarks.thesis.garment_pose",
    "benchmarks.thesis.table41",
]


@pytest.mark.parametrize("name", COMMANDS)
def test_help_prints_usage_and_exits(name, monkeypatch, capsys, tmp_path):
    module = importlib.import_module(name)
    monkeypatch.chdir(tmp_path)  # anything written by mistake lands here, and is caught
    monkeypatch.setattr(sys, "argv", [f"python -m {name}", "--help"])
    with pytest.raises(SystemExit) as info:
        module.main()
    assert info.value.code == 0
    assert capsys.readouterr().out.startswith("usage:")
    assert list(tmp_path.iterdir()) == []


def test_every_runnable_module_is_listed():
    runnable = {
        ".".join(path.relative_to(ROOT).with_suffix("").parts)
        for package in (
            "apps",
            "benchmarks",
            "datasets",
            "models",
            "render",
            "sim2real",
            "simulator",
        )
        for path in (ROOT / package).rglob("*.py")
        if 'if __name__ == "__main__"' in path.read_text()
    }
    assert runnable == set(COMMANDS) | HYDRA
