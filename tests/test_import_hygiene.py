"""`import simulator` stays light, and the layers hold: the solver core imports no wing."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("package", ["simulator", "simulator.cloth", "simulator.calibrate"])
def test_simulator_import_keeps_heavy_frameworks_out(package):
    code = (
        f"import sys, {package}\n"
        "bad = [m for m in ('pyrender', 'lightning', 'hydra', 'cv2') if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120)
    assert done.returncode == 0, done.stderr.decode()


def test_core_imports_no_wing():
    """The import-linter contracts of pyproject.toml (CI also runs ``lint-imports``)."""
    pytest.importorskip("importlinter")
    code = (
        "import sys; from importlinter.cli import lint_imports; "
        "sys.exit(lint_imports(no_cache=True))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, timeout=300, cwd=ROOT, text=True
    )
    assert done.returncode == 0, done.stdout[-3000:]
    assert "0 broken" in done.stdout


def test_core_contract_lists_every_core_module():
    """A new module of the core is under the contract too: every top-level module or
    subpackage of ``simulator`` that is not a wing is a source of the core contract."""
    import pkgutil
    import tomllib

    import simulator

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    core = next(c for c in contracts["contracts"] if c["name"].startswith("The solver core"))
    wings = {"cloth", "tissue", "calibrate", "monocular", "garment"}
    modules = {m.name for m in pkgutil.iter_modules(simulator.__path__)} - wings
    assert {s.removeprefix("simulator.") for s in core["source_modules"]} == modules
    assert {f"simulator.{w}" for w in wings} <= set(core["forbidden_modules"])


def test_only_entry_points_under_simulator_import_hydra_and_none_matplotlib():
    import re

    entry_points = {"simulator/cloth/simulate.py"}
    pattern = re.compile(r"^\s*(?:import|from)\s+(hydra|omegaconf|matplotlib)\b", re.M)
    found = {
        str(path.relative_to(ROOT)): sorted(set(pattern.findall(path.read_text())))
        for path in (ROOT / "simulator").rglob("*.py")
    }
    hydra = {f for f, mods in found.items() if {"hydra", "omegaconf"} & set(mods)}
    plots = {f for f, mods in found.items() if "matplotlib" in mods}
    assert hydra <= entry_points, hydra - entry_points
    assert not plots, plots


def test_no_package_imports_the_train_script():
    """``train.py`` is a command line only: what it runs lives in :mod:`models.training`."""
    import re

    pattern = re.compile(r"^\s*(?:import train\b|from train import)", re.M)
    packages = (
        "common",
        "simulator",
        "render",
        "datasets",
        "models",
        "apps",
        "sim2real",
        "benchmarks",
    )
    offenders = [
        str(path.relative_to(ROOT))
        for package in packages
        for path in (ROOT / package).rglob("*.py")
        if pattern.search(path.read_text())
    ]
    assert offenders == []


def test_study_contract_lists_every_module_of_the_diagnosis():
    """A new module of the diagnosis is under the contract that keeps the study out of it."""
    import pkgutil
    import tomllib

    import sim2real

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    study = next(c for c in contracts["contracts"] if "validation study" in c["name"])
    modules = {m.name for m in pkgutil.iter_modules(sim2real.__path__)} - {"study"}
    assert {s.removeprefix("sim2real.") for s in study["source_modules"]} == modules
