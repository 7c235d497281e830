"""Hydra entry of the tissue tools: every job config composes; a tiny job runs end to end."""

import functools
import inspect
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from benchmarks.thesis import paper_table1, table41, tissue_tables

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"
JOBS = {
    "tables": tissue_tables.run,
    "sensitivity": tissue_tables.run,
    "ukf": table41.run,
    "monocular": paper_table1.run,
}


def _compose(*overrides):
    with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
        return compose(config_name="tissue", overrides=list(overrides))


def test_every_job_config_is_listed():
    assert {p.stem for p in (CONFIGS / "tissue_job").glob("*.yaml")} == set(JOBS)


@pytest.mark.parametrize("name", sorted(JOBS))
def test_job_config_composes_to_its_tool_run(name, tmp_path):
    cfg = _compose(f"tissue_job={name}", f"out_dir={tmp_path}", "seed=3")
    job = instantiate(cfg.tissue_job, _convert_="all")
    assert isinstance(job, functools.partial) and job.func is JOBS[name]
    inspect.signature(job.func).bind(tmp_path, **job.keywords)  # every key is a parameter
    if "seed" in job.keywords:
        assert job.keywords["seed"] == 3


def test_tiny_ukf_job_runs_end_to_end_through_the_hydra_entry(tmp_path):
    out = tmp_path / "out"
    overrides = [
        "tissue_job=ukf",
        "tissue_job.moduli_kpa=[40]",
        "tissue_job.trials=1",
        "tissue_job.frames=6",
        "tissue_job.passes=1",
        "tissue_job.ball=false",
        f"out_dir={out}",
        f"hydra.run.dir={tmp_path / 'run'}",
    ]
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks.thesis.tissue_jobs", *overrides],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert {"ukf.csv", "ukf.md", "ukf.png", "tissue_job.yaml"} <= {p.name for p in out.iterdir()}
    assert "ukf_rel_err" in done.stdout.splitlines()[-1]
    assert (tmp_path / "run" / ".hydra" / "config.yaml").exists()


def test_argparse_mains_share_the_run_functions_and_name_bad_rows(tmp_path):
    with pytest.raises(ValueError, match="ratios"):
        tissue_tables.main(["--out", str(tmp_path), "--only", "t31", "--ratios", "0.5"])
    with pytest.raises(ValueError, match="only"):
        tissue_tables.run(tmp_path, only=("t33",))
