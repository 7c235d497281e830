"""Commands run as a stranger's files or a hurried user would have them (issue 61): names
stay inside their folders, outputs are checked before the work, Ctrl-C and ``kill -9`` end
cleanly with no process left behind, and the remaining bad inputs are one line."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

import sim2real.diagnose as diagnose_entry
import simulator.cloth.simulate as simulate_entry
from common.commands import INTERRUPTED
from common.errors import InputError
from tests.conftest import subprocess_env

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = str(ROOT / "configs")


def _compose(config, *overrides):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name=config, overrides=list(overrides))


def _run(args, cwd, timeout=120):
    return subprocess.run(
        [sys.executable, *args],
        cwd=cwd,
        env=subprocess_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.parametrize("name", ["../../escaped", "a/b", ".."])
def test_a_run_name_that_is_a_path_makes_no_folder(name, tmp_path):
    logs = tmp_path / "inside" / "logs"
    done = _run([str(ROOT / "train.py"), f"run_name={name}", f"paths.log_dir={logs}"], tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"error: run_name must be a single file or folder name (no '/' or '\\', not '.' or "
        f"'..'), got '{name}'"
    ]
    assert [p for p in tmp_path.rglob("*") if p.is_dir()] == []


def test_a_task_name_that_is_a_path_makes_no_folder(tmp_path):
    done = _run(
        ["-m", "simulator.cloth.simulate", "task_name=../x", f"paths.log_dir={tmp_path}/logs"],
        tmp_path,
    )
    assert done.returncode == 2 and "task_name must be a single" in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_diagnose_refuses_a_report_name_that_is_a_path(tmp_path):
    cfg = _compose(
        "diagnose",
        f"real_dir={tmp_path}/real",
        f"run={tmp_path}/run",
        "name=../../x",
        "paths.output_dir=/tmp/unused",
    )
    with pytest.raises(InputError, match=r"^name must be a single file or folder name"):
        diagnose_entry.run(cfg)
    assert list(tmp_path.iterdir()) == []


def _refuse_to_simulate(*args, **kwargs):
    raise AssertionError("the simulation ran although the destination was bad")


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("out_file={tmp}/file/seq.npz", r"^out_file: .*file exists and is not a folder$"),
        ("out_file={tmp}", r"^out_file: .* is a folder; give a file path$"),
        ("record_time=1e7", r"^record_time must be at most \d+ s here: 1e\+07 s at 30 frames/s"),
        ("export=obj", r"^export: .*frames_obj exists and is not a folder$"),
    ],
)
def test_simulate_checks_its_destination_before_simulating(
    override, message, tmp_path, monkeypatch
):
    monkeypatch.setattr(simulate_entry, "simulate", _refuse_to_simulate)
    (tmp_path / "file").write_text("x")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "frames_obj").write_text("a file where the frames go")
    cfg = _compose("simulate", f"paths.output_dir={tmp_path}/out", override.format(tmp=tmp_path))
    with pytest.raises(InputError, match=message):
        simulate_entry.run(cfg)


def _group(pgid: int) -> list[str]:
    out = subprocess.run(["ps", "-ww", "-eo", "pid=,pgid=,args="], capture_output=True, text=True)
    return [line for line in out.stdout.splitlines() if line.split()[1] == str(pgid)]


def _start(command, tmp_path):
    """``command`` in a process group of its own that takes Ctrl-C as a terminal's would."""
    return subprocess.Popen(
        [sys.executable, *command],
        cwd=tmp_path,
        env=subprocess_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def _start_generation(tmp_path):
    """A two-worker generation in a process group of its own, once its workers run."""
    proc = _start(
        [
            "-m",
            "datasets.generate",
            "preset=tiny",
            "classes=[0,53]",
            "render=tiny",
            "n_jobs=2",
            f"out_dir={tmp_path}/data",
            f"mesh_cache={tmp_path}/mesh",
            f"paths.log_dir={tmp_path}/logs",
        ],
        tmp_path,
    )
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and proc.poll() is None:
        if sum("LokyProcess" in line for line in _group(proc.pid)) >= 2:
            return proc
        time.sleep(0.2)
    proc.kill()
    pytest.fail(f"the generation's workers did not start: {proc.communicate()[1][-2000:]}")


def _gone(pgid: int, seconds: float) -> list[str]:
    deadline = time.monotonic() + seconds
    while (left := [ln for ln in _group(pgid) if "<defunct>" not in ln]) and (
        time.monotonic() < deadline
    ):
        time.sleep(0.2)
    return left


def test_ctrl_c_ends_a_parallel_generation_in_one_line_and_stops_its_workers(tmp_path):
    proc = _start_generation(tmp_path)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    lines = [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip()]
    assert lines[-1] == INTERRUPTED and "Traceback" not in err, err[-3000:]
    assert _gone(proc.pid, 10) == []


def test_killing_a_parallel_generation_leaves_no_process_behind(tmp_path):
    proc = _start_generation(tmp_path)
    proc.kill()
    proc.communicate(timeout=30)
    assert _gone(proc.pid, 10) == []


def test_power_preview_and_validate_refuse_bad_input_in_one_line(tmp_path, capsys):
    from datasets.preview import main as preview_main
    from sim2real.study.power import main as power_main
    from sim2real.study.validate import main as validate_main

    (tmp_path / "bad.json").write_text("{not json")
    (tmp_path / "other.json").write_text(json.dumps({"inputs": {"run": "x"}}))
    (tmp_path / "empty").mkdir()
    cases = [
        (power_main, [str(tmp_path / "bad.json")], "error: reports: ", "is not JSON"),
        (
            power_main,
            [str(tmp_path / "other.json")],
            "error: reports: ",
            "is not a diagnosis's report.json (report lacks 'name')",
        ),
        (
            power_main,
            [str(tmp_path / "bad.json"), "--draws", "0,2"],
            "error: --draws must be",
            "got '0,2'",
        ),
        (
            preview_main,
            [str(tmp_path / "empty"), "--out", str(tmp_path / "p")],
            "error: datasets: ",
            "manifest.json not found",
        ),
        (
            preview_main,
            [str(tmp_path / "none"), "--out", str(tmp_path / "p")],
            "error: datasets: ",
            "is not a folder",
        ),
        (validate_main, ["--sets", "0", "--run", str(tmp_path)], "error: --sets must be", "got 0"),
    ]
    for main, argv, start, words in cases:
        with pytest.raises(SystemExit) as info:
            main(argv)
        err = capsys.readouterr().err
        assert info.value.code == 2, err
        assert err.startswith(start) and words in err and err.count("\n") == 1, err
    assert not (tmp_path / "p").exists()


@pytest.mark.parametrize(
    ("config", "overrides", "field"),
    [
        ("generate", ["out_dir={file}"], "out_dir"),
        ("generate", ["out_dir={tmp}/d", "mesh_cache={file}/m"], "mesh_cache"),
        ("demo", ["out_dir={file}"], "out_dir"),
        ("tissue", ["tissue_job=ukf", "out_dir={file}"], "out_dir"),
        ("diagnose", ["real_dir={tmp}", "run={tmp}", "cache_dir={file}"], "cache_dir"),
        ("diagnose", ["real_dir={tmp}", "run={tmp}", "out_dir={file}/o"], "out_dir"),
    ],
)
def test_every_destination_is_checked_before_the_work(config, overrides, field, tmp_path):
    import apps.demo as demo_entry
    import benchmarks.thesis.tissue_jobs as tissue_entry
    import datasets.generate as generate_entry

    run = {
        "generate": generate_entry.run,
        "demo": demo_entry.run,
        "tissue": tissue_entry.run,
        "diagnose": diagnose_entry.run,
    }[config]
    (tmp_path / "file").write_text("x")
    given = [o.format(file=tmp_path / "file", tmp=tmp_path) for o in overrides]
    cfg = _compose(config, *given, "paths.output_dir=/tmp/unused")
    with pytest.raises(InputError, match=rf"^{field}: .*file (exists and )?is (not )?a"):
        run(cfg)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_demo_refuses_a_recording_longer_than_memory_allows(tmp_path):
    import apps.demo as demo_entry

    cfg = _compose("demo", "record_time=1e7", f"out_dir={tmp_path}/d", "paths.output_dir=/x")
    with pytest.raises(InputError, match=r"^record_time must be at most \d+ s here"):
        demo_entry.run(cfg)


def test_ctrl_c_inside_the_compiled_solver_ends_simulate_in_one_line(tmp_path):
    proc = _start(
        [
            "-m",
            "simulator.cloth.simulate",
            "record_time=60",
            f"out_file={tmp_path}/s.npz",
            f"paths.log_dir={tmp_path}/logs",
        ],
        tmp_path,
    )
    seen = ""
    while "step/s" not in seen and proc.poll() is None:  # simulating, past the compilation
        seen += os.read(proc.stderr.fileno(), 4096).decode(errors="replace")
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    lines = [ln for ln in (seen + err).replace("\r", "\n").splitlines() if ln.strip()]
    assert proc.returncode == 130 and lines[-1] == INTERRUPTED, (seen + err)[-2000:]
    assert "Traceback" not in seen + err and "SystemError" not in seen + err
    assert not (tmp_path / "s.npz").exists()
