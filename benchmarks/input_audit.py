"""Bad-input audit: every command fed what a careless user or an attacker would give it.

Each case runs a real command in a subprocess inside a scratch folder and is classified:

* ``one-line``: the command failed with exit status 2 and printed one line ``error: ...``
  (or, for an interrupt, 130 and ``interrupted; ...``), no traceback;
* ``ok``: the input is fine after all (e.g. a spreadsheet's byte-order mark) and the command
  succeeded;
* ``traceback``, ``vague`` (a non-zero exit without one clear line) or ``silent`` (exit 0
  where an error was expected): defects.

A case also fails when a payload ran (a marker file appeared) or a path outside the scratch
folder's allowed places was written. The fixtures (a tiny generated dataset, an untrained
checkpoint, a footage folder) are made first (about a minute).

Usage: ``python -m benchmarks.input_audit [--only WORD] [--out outputs/input_audit]``. Writes
``audit.md`` and ``audit.json``; the last printed line is the JSON summary.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import os
import pickle
import subprocess
import sys
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

TINY_NET = {
    "_target_": "models.components.video_nets.CNNLSTMNet",
    "encoder": {
        "_target_": "models.components.frame_encoder.FrameEncoder",
        "name": "alexnet5",
        "feature_dim": 16,
        "width": 0.25,
    },
    "hidden_size": 8,
    "num_classes": 54,
}


class _Payload:
    """Pickles to ``os.makedirs(marker)``: a hostile checkpoint's code."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.makedirs, (self.marker,))


@dataclasses.dataclass(frozen=True)
class Case:
    """One bad input: the command, how to prepare the scratch folder, what is expected."""

    group: str
    name: str
    args: list[str]
    setup: Callable[[Path], None] | None = None
    expect: str = "one-line"


def _write_mp4(path: Path, frames: np.ndarray, fps: float = 15.0) -> None:
    import cv2

    height, width = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    for frame in frames:
        writer.write(frame)
    writer.release()


def make_fixtures(base: Path) -> None:
    """A tiny dataset, an untrained checkpoint of its classes and a footage folder."""
    import torch
    from hydra.utils import instantiate

    from models.material_classifier import MaterialClassifierModule

    data = base / "data"
    if not (data / "manifest.json").is_file():
        subprocess.run(
            [
                sys.executable,
                "-m",
                "datasets.generate",
                "preset=tiny",
                "render=tiny",
                "classes=[0,53]",
                "n_jobs=1",
                f"out_dir={data}",
                f"mesh_cache={base}/mesh",
                f"paths.log_dir={base}/logs",
            ],
            check=True,
            capture_output=True,
            cwd=ROOT,
        )
    ckpt = base / "run" / "checkpoints" / "best.ckpt"
    ckpt.parent.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(0)
    module = MaterialClassifierModule(instantiate(TINY_NET), net_config=TINY_NET, method="tiny")
    torch.save(
        {
            "hyper_parameters": {"net_config": TINY_NET, "method": "tiny"},
            "state_dict": module.state_dict(),
        },
        ckpt,
    )
    real = base / "real"
    real.mkdir(exist_ok=True)
    rows = ["video,stiffness,density,wind"]
    for i in range(6):
        rng = np.random.default_rng(i)
        frame = rng.integers(0, 255, size=(40, 48, 3), dtype=np.uint8)
        _write_mp4(real / f"f{i}.mp4", np.stack([np.roll(frame, 2 * t, 1) for t in range(24)]))
        rows.append(f"f{i}.mp4,{1 + i},{0.1 + 0.05 * i},W{1 + i % 3}")
    (real / "labels.csv").write_text("\n".join(rows) + "\n")
    _write_mp4(base / "outside.mp4", np.zeros((24, 40, 48, 3), dtype=np.uint8))
    (base / "afile").write_text("a file where a folder is expected")
    seq = base / "seq.npz"
    if not seq.is_file():
        subprocess.run(
            [
                sys.executable,
                "-m",
                "simulator.cloth.simulate",
                f"out_file={seq}",
                "record_time=0.2",
                f"paths.log_dir={base}/logs",
            ],
            check=True,
            capture_output=True,
            cwd=ROOT,
        )


def _bad_checkpoints(base: Path) -> dict[str, Callable[[Path], None]]:
    """Writers of the files that are not checkpoints (each writes ``base/bad.ckpt``)."""
    import torch

    good = base / "run" / "checkpoints" / "best.ckpt"
    marker = base / "PAYLOAD-RAN"

    def pickled(path):
        raw = torch.load(good, weights_only=True)
        raw["extra"] = _Payload(marker)
        torch.save(raw, path)

    def nested_target(path):
        raw = torch.load(good, weights_only=True)
        raw["hyper_parameters"]["net_config"]["encoder"] = {
            "_target_": "os.makedirs",
            "name": str(marker),
        }
        torch.save(raw, path)

    def legacy_pickle(path):
        path.write_bytes(pickle.dumps({"state_dict": {}, "x": _Payload(marker)}))

    def zip_of_junk(path):
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w") as archive:
            archive.writestr("archive/data.pkl", b"\x80\x02junk")
        path.write_bytes(buffer.getvalue())

    return {
        "missing": lambda p: None,
        "a folder": lambda p: p.mkdir(),
        "empty": lambda p: p.write_bytes(b""),
        "text": lambda p: p.write_text("epoch: 3\n"),
        "truncated": lambda p: p.write_bytes(good.read_bytes()[:4000]),
        "bare tensor": lambda p: torch.save(torch.zeros(3), p),
        "pickled code": pickled,
        "nested _target_": nested_target,
        "legacy pickle with code": legacy_pickle,
        "zip of junk": zip_of_junk,
        "random bytes": lambda p: p.write_bytes(np.random.default_rng(0).bytes(2048)),
    }


def _labels(text: str | bytes) -> Callable[[Path], None]:
    def write(scratch: Path) -> None:
        folder = scratch / "real"
        path = folder / "labels.csv"
        (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)

    return write


def _copy_real(scratch: Path, base: Path) -> None:
    import shutil

    shutil.copytree(base / "real", scratch / "real")


def cases(base: Path) -> list[Case]:
    """Every case of the audit."""
    ckpt = base / "run" / "checkpoints" / "best.ckpt"
    data = base / "data"
    out = []
    for kind, write in _bad_checkpoints(base).items():
        setup = (lambda w: lambda s: w(s / "bad.ckpt"))(write)
        bad = "{scratch}/bad.ckpt"
        out += [
            Case(
                "checkpoint",
                f"evaluate: {kind}",
                ["-m", "models.evaluate", f"ckpt_path={bad}", f"data_dir={data}"],
                setup,
            ),
            Case(
                "checkpoint",
                f"clone: {kind}",
                ["-m", "apps.clone", f"run={bad}", f"data_dir={data}", f"video={base}/real/f0.mp4"],
                setup,
            ),
            Case(
                "checkpoint",
                f"diagnose: {kind}",
                [
                    "-m",
                    "sim2real.diagnose",
                    f"run={bad}",
                    f"data_dir={data}",
                    "real_dir={scratch}/real",
                    "out_dir={scratch}/o",
                    "cache_dir={scratch}/c",
                ],
                lambda s, w=write: (_copy_real(s, base), w(s / "bad.ckpt")),
            ),
            Case(
                "checkpoint",
                f"train init_from: {kind}",
                [
                    str(ROOT / "train.py"),
                    f"init_from={bad}",
                    f"dataset.dir={data}",
                    "paths.log_dir={scratch}/logs",
                    "trainer.max_epochs=1",
                    "dataset.preset=tiny",
                ],
                setup,
            ),
        ]
    real = lambda s: _copy_real(s, base)  # noqa: E731
    out += [
        Case(
            "paths",
            "train run_name=../../escaped",
            [str(ROOT / "train.py"), "run_name=../../escaped", "paths.log_dir={scratch}/logs"],
        ),
        Case(
            "paths",
            "train run_name=a/b",
            [str(ROOT / "train.py"), "run_name=a/b", "paths.log_dir={scratch}/logs"],
        ),
        Case(
            "paths",
            "simulate task_name=../x",
            ["-m", "simulator.cloth.simulate", "task_name=../x", "paths.log_dir={scratch}/logs"],
        ),
        Case(
            "paths",
            "diagnose name=../x",
            [
                "-m",
                "sim2real.diagnose",
                f"run={ckpt}",
                f"data_dir={data}",
                "real_dir={scratch}/real",
                "name=../x",
            ],
            real,
        ),
        Case(
            "paths",
            "generate preset.name=../x",
            ["-m", "datasets.generate", "preset=tiny", "preset.name=../x"],
        ),
        Case(
            "paths",
            "labels.csv ../outside.mp4",
            ["-m", "models.evaluate", f"ckpt_path={ckpt}", "real_dir={scratch}/real"],
            lambda s: (real(s), _labels("video,stiffness,density\n../outside.mp4,1,1\n")(s)),
        ),
        Case(
            "paths",
            "labels.csv absolute path",
            ["-m", "models.evaluate", f"ckpt_path={ckpt}", "real_dir={scratch}/real"],
            lambda s: (real(s), _labels(f"video,stiffness,density\n{base}/outside.mp4,1,1\n")(s)),
        ),
        Case(
            "paths",
            "labels.csv link outside",
            ["-m", "models.evaluate", f"ckpt_path={ckpt}", "real_dir={scratch}/real"],
            lambda s: (
                real(s),
                os.symlink(base / "outside.mp4", s / "real" / "l.mp4"),
                _labels("video,stiffness,density\nl.mp4,1,1\n")(s),
            ),
        ),
    ]
    afile = str(base / "afile")
    destinations = [
        (
            "simulate out_file below a file",
            ["-m", "simulator.cloth.simulate", f"out_file={afile}/x.npz"],
        ),
        ("simulate out_file is a folder", ["-m", "simulator.cloth.simulate", "out_file={scratch}"]),
        (
            "simulate log folder is a file",
            ["-m", "simulator.cloth.simulate", f"hydra.run.dir={afile}"],
        ),
        ("generate out_dir is a file", ["-m", "datasets.generate", f"out_dir={afile}"]),
        (
            "generate mesh_cache below a file",
            ["-m", "datasets.generate", "out_dir={scratch}/d", f"mesh_cache={afile}/m"],
        ),
        (
            "tissue out_dir is a file",
            ["-m", "benchmarks.thesis.tissue_jobs", "tissue_job=ukf", f"out_dir={afile}"],
        ),
        ("export out_dir is a file", ["-m", "simulator.export", str(base / "seq.npz"), afile]),
        ("demo out_dir is a file", ["-m", "apps.demo", f"out_dir={afile}"]),
        (
            "evaluate out_dir is a file",
            ["-m", "models.evaluate", f"ckpt_path={ckpt}", f"data_dir={data}", f"out_dir={afile}"],
        ),
        (
            "diagnose cache_dir is a file",
            [
                "-m",
                "sim2real.diagnose",
                f"run={ckpt}",
                f"data_dir={data}",
                f"real_dir={base}/real",
                f"cache_dir={afile}",
            ],
        ),
        ("preview --out is a file", ["-m", "datasets.preview", str(data), "--out", afile]),
        (
            "seal --out below a file",
            [
                "-m",
                "sim2real.study.seal",
                "--seed",
                "1",
                "--out",
                f"{afile}/s",
                "--data-dir",
                str(data),
            ],
        ),
        (
            "clone out_dir is a file",
            [
                "-m",
                "apps.clone",
                f"run={ckpt}",
                f"data_dir={data}",
                f"video={base}/real/f0.mp4",
                f"out_dir={afile}",
            ],
        ),
    ]
    out += [Case("destination", name, args) for name, args in destinations]
    for name, mount in (("read-only", "/tmp/audit-ro"), ("full", "/tmp/audit-full")):
        if Path(mount).is_mount():
            out += [
                Case(
                    "destination",
                    f"simulate on a {name} disk",
                    ["-m", "simulator.cloth.simulate", f"out_file={mount}/x.npz"],
                ),
                Case(
                    "destination",
                    f"generate on a {name} disk",
                    ["-m", "datasets.generate", f"out_dir={mount}/d"],
                ),
                Case(
                    "destination",
                    f"export on a {name} disk",
                    ["-m", "simulator.export", str(base / "seq.npz"), f"{mount}/e"],
                ),
                Case(
                    "destination",
                    f"tissue on a {name} disk",
                    ["-m", "benchmarks.thesis.tissue_jobs", "tissue_job=ukf", f"out_dir={mount}/t"],
                ),
            ]
    ev = ["-m", "models.evaluate", f"ckpt_path={ckpt}", "real_dir={scratch}/real"]
    out += [
        Case(
            "input",
            "export: missing sequence",
            ["-m", "simulator.export", "{scratch}/no.npz", "{scratch}/e"],
        ),
        Case(
            "input",
            "export: corrupt sequence",
            ["-m", "simulator.export", "{scratch}/c.npz", "{scratch}/e"],
            lambda s: (s / "c.npz").write_bytes((base / "seq.npz").read_bytes()[:3000]),
        ),
        Case(
            "input",
            "export: text file",
            ["-m", "simulator.export", "{scratch}/c.npz", "{scratch}/e"],
            lambda s: (s / "c.npz").write_text("hello"),
        ),
        Case(
            "input",
            "export: --instance 9",
            ["-m", "simulator.export", str(base / "seq.npz"), "{scratch}/e", "--instance", "9"],
        ),
        Case(
            "input",
            "power: bad JSON",
            ["-m", "sim2real.study.power", "{scratch}/r.json"],
            lambda s: (s / "r.json").write_text("{oops"),
        ),
        Case(
            "input",
            "power: JSON of something else",
            ["-m", "sim2real.study.power", "{scratch}/r.json"],
            lambda s: (s / "r.json").write_text("[1, 2]"),
        ),
        Case(
            "input",
            "preview: empty folder",
            ["-m", "datasets.preview", "{scratch}/e", "--out", "{scratch}/p"],
            lambda s: (s / "e").mkdir(),
        ),
        Case(
            "input",
            "validate --sets 0",
            [
                "-m",
                "sim2real.study.validate",
                "--sets",
                "0",
                "--run",
                str(ckpt),
                "--out",
                "{scratch}/v",
            ],
        ),
        Case("input", "shrink: no report", ["-m", "sim2real.shrink", "report={scratch}"]),
        Case(
            "input",
            "labels.csv with a BOM",
            ev,
            lambda s: (
                real(s),
                _labels(b"\xef\xbb\xbf" + (base / "real" / "labels.csv").read_bytes())(s),
            ),
            "ok",
        ),
        Case(
            "input",
            "labels.csv in latin-1",
            ev,
            lambda s: (
                real(s),
                _labels("video,stiffness,density,note\nf0.mp4,1,1,\xb5m\n".encode("latin-1"))(s),
            ),
        ),
        Case(
            "input",
            "negative stiffness",
            ev,
            lambda s: (
                real(s),
                _labels("video,stiffness,density\nf0.mp4,-1,1\nf1.mp4,2,1\nf2.mp4,3,1\n")(s),
            ),
        ),
        Case(
            "input",
            "constant measured columns",
            ev,
            lambda s: (
                real(s),
                _labels("video,stiffness,density\nf0.mp4,1,1\nf1.mp4,1,1\nf2.mp4,1,1\n")(s),
            ),
        ),
        Case(
            "input",
            "a single video",
            ev,
            lambda s: (real(s), _labels("video,stiffness,density\nf0.mp4,1,1\n")(s)),
        ),
        Case(
            "input",
            "a row with too many fields",
            ev,
            lambda s: (real(s), _labels("video,stiffness,density\nf0.mp4,1,1,7\n")(s)),
        ),
        Case(
            "input",
            "NUL in labels.csv",
            ev,
            lambda s: (real(s), _labels(b"video,stiffness,density\nf\x000.mp4,1,1\n")(s)),
        ),
        Case(
            "input",
            "simulate record_time=1e7",
            ["-m", "simulator.cloth.simulate", "record_time=1e7", "out_file={scratch}/s.npz"],
        ),
        Case(
            "input",
            "demo record_time=1e7",
            ["-m", "apps.demo", "record_time=1e7", "out_dir={scratch}/d"],
        ),
        Case(
            "input",
            "evaluate: bad checkpoint and missing data",
            ["-m", "models.evaluate", "ckpt_path={scratch}/none.ckpt", "data_dir={scratch}/none"],
        ),
        Case("input", "evaluate: no ckpt_path", ["-m", "models.evaluate", f"data_dir={data}"]),
        Case("input", "unknown override", ["-m", "simulator.cloth.simulate", "fps_typo=3"]),
        Case(
            "input",
            "override that does not parse",
            ["-m", "simulator.cloth.simulate", "classes=[0,"],
        ),
    ]
    return out


def classify(done: subprocess.CompletedProcess, expect: str) -> tuple[str, str]:
    """The outcome of one run and the line a user saw."""
    lines = [
        ln for ln in done.stderr.replace("\r", "\n").splitlines() if ln.strip() and "%|" not in ln
    ]
    last = lines[-1].strip() if lines else ""
    if "Traceback" in done.stderr:
        return "traceback", last
    if done.returncode == 0:
        return ("ok" if expect == "ok" else "silent"), last
    errors = [ln for ln in lines if ln.startswith("error: ")]
    if done.returncode == 2 and len(errors) == 1 and last == errors[0]:
        return "one-line", last
    return "vague", last


def run_case(case: Case, base: Path, scratch: Path) -> dict:
    """Run one case in a fresh scratch folder; its row."""
    scratch.mkdir(parents=True)
    if case.setup is not None:
        case.setup(scratch)
    args = [a.replace("{scratch}", str(scratch)) for a in case.args]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, *args], cwd=scratch, env=env, capture_output=True, text=True, timeout=600
    )
    outcome, line = classify(done, case.expect)
    marker = base / "PAYLOAD-RAN"
    if marker.exists():
        outcome, line = "payload ran", str(marker)
        marker.rmdir()
    escaped = [
        p
        for p in (scratch / "escaped", scratch.parent / "escaped", scratch.parent / "x")
        if p.exists()
    ]
    if escaped:
        outcome, line = "wrote outside", str(escaped)
    good = outcome == case.expect
    return {
        "group": case.group,
        "case": case.name,
        "outcome": outcome,
        "pass": good,
        "line": line,
        "seconds": round(time.perf_counter() - start, 1),
    }


def _markdown(rows: list[dict]) -> str:
    lines = ["| group | case | outcome | what the user sees |", "|---|---|---|---|"]
    for r in rows:
        mark = "" if r["pass"] else " **(defect)**"
        text = r["line"].replace("|", "\\|")
        lines.append(f"| {r['group']} | {r['case']} | {r['outcome']}{mark} | `{text}` |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/input_audit"))
    parser.add_argument("--only", help="run the cases whose name contains this text")
    args = parser.parse_args(argv)
    base = args.out.resolve() / "fixtures"
    base.mkdir(parents=True, exist_ok=True)
    print("fixtures ...", flush=True)
    make_fixtures(base)
    todo = [c for c in cases(base) if not args.only or args.only in c.name]
    runs = args.out.resolve() / "runs"
    if runs.exists():
        import shutil

        shutil.rmtree(runs)
    rows = []
    for index, case in enumerate(todo):
        row = run_case(case, base, runs / f"{index:03d}")
        rows.append(row)
        print(
            f"[{index + 1}/{len(todo)}] {row['outcome']:12s} {case.group}: {case.name}: "
            f"{row['line'][:150]}",
            flush=True,
        )
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
    summary = {"cases": len(rows), "passed": sum(r["pass"] for r in rows), "outcomes": counts}
    (args.out / "audit.md").write_text(_markdown(rows))
    (args.out / "audit.json").write_text(json.dumps({"summary": summary, "rows": rows}, indent=1))
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
