"""The Table 7.2 regeneration command: collects run reports and patches the README block."""

import json

import pytest

from benchmarks.thesis.table72 import END, START, main


def _report(log_dir, name, acc, **extra):
    path = log_dir / "train" / name / "eval" / "sim_test.json"
    path.parent.mkdir(parents=True)
    result = {"acc": acc, "top5": 0.5, "clips": 432, "device": "CPU, 2 threads", **extra}
    path.write_text(json.dumps(result))


def test_table_collects_runs_and_patches_readme(tmp_path):
    logs = tmp_path / "logs"
    _report(logs, "wind-L1-random-full-s0-cnn_lstm", 0.25)
    _report(logs, "wind-L1-random-full-s0-base1", 0.125)
    _report(logs, "wind-L1-random-full-s0-seq-cnn_lstm", 0.75)
    _report(logs, "wind-L1-random-full-s0-cnn_lstm_diff", 0.5)
    _report(logs, "wind-L1-random-full-s0-bgswap-cnn_lstm", 0.375)
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{START}\nold table\n{END}\noutro\n")
    out = tmp_path / "table72.md"
    table = main(
        [
            "--log-dir",
            str(logs),
            "--ledger",
            str(tmp_path / "runs"),
            "--out",
            str(out),
            "--readme",
            str(readme),
        ]
    )
    wind, wind_swap, wind_seq = [
        [c.strip() for c in line.split("|")[1:-1]]
        for line in table.splitlines()
        if line.startswith("| wind")
    ]
    assert wind[3:12] == [
        "full",
        "held-out sims",
        "as rendered",
        "432",
        "12.5 (50)",
        "-",
        "25.0 (50)",
        "-",
        "50.0 (50)",
    ]
    assert wind[12] == "-"  # no two-stream run
    assert wind[13:] == ["53.6", "53.3", "64.7"]  # thesis, wind Unif-1 Rand1
    assert wind_swap[4:12] == [
        "held-out sims",
        "background swap",
        "432",
        "-",
        "-",
        "37.5 (50)",
        "-",
        "-",
    ]
    assert wind_seq[4:12] == [
        "thesis sub-seq.",
        "as rendered",
        "432",
        "-",
        "-",
        "75.0 (50)",
        "-",
        "-",
    ]
    text = readme.read_text()
    assert "old table" not in text and text.startswith("intro\n") and text.endswith("outro\n")
    assert table in text and out.read_text().endswith(table)
    assert "CPU, 2 threads" in table


def test_several_presets_and_textures_give_a_row_each_run_setting(tmp_path):
    logs = tmp_path / "logs"
    _report(logs, "arm-L1-random-small-s0-base1", 0.25)
    _report(logs, "arm-L1-random-small-s0-seq-base1", 0.75)
    _report(logs, "arm-L1-random-full-s0-cnn_lstm_diff", 0.5)
    _report(logs, "arm-L1-grid-full-s0-cnn_lstm_diff", 0.625)
    table = main(
        [
            "--log-dir",
            str(logs),
            "--ledger",
            str(tmp_path / "runs"),
            "--out",
            str(tmp_path / "t.md"),
            "--wind-preset",
            "full",
            "--arm-preset",
            "small,full",
            "--texture",
            "random,grid",
        ]
    )
    arm = [
        [c.strip() for c in line.split("|")[1:-1]]
        for line in table.splitlines()
        if line.startswith("| arm")
    ]
    assert [(row[2], row[3], row[4]) for row in arm] == [
        ("random", "small", "held-out sims"),
        ("random", "small", "thesis sub-seq."),
        ("random", "full", "held-out sims"),
        ("grid", "full", "held-out sims"),
    ]
    assert arm[0][7] == "25.0 (50)" and arm[2][11] == "50.0 (50)" and arm[3][11] == "62.5 (50)"
    assert arm[2][13:] == arm[3][13:] == ["54.0", "56.8", "62.9"]  # thesis beside every texture
    assert "bgswap" not in table.split("No runs yet:")[1]  # variants are not listed as missing
    assert "arm random full thesis sub-seq." in table.split("No runs yet:")[1]
    assert "| wind" not in table and "wind grid full held-out sims" in table
    assert "arm full cnn_lstm_diff" not in table  # no epochs recorded: no budget note


def test_extra_scene_gets_rows_with_its_motions_thesis_numbers(tmp_path):
    logs = tmp_path / "logs"
    _report(logs, "armstrokes-L1-grid-full-s0-cnn_lstm_diff", 0.5)
    table = main(
        [
            "--log-dir",
            str(logs),
            "--ledger",
            str(tmp_path / "runs"),
            "--out",
            str(tmp_path / "t.md"),
            "--scenes",
            "arm,armstrokes",
            "--texture",
            "grid",
        ]
    )
    (row,) = [
        [c.strip() for c in line.split("|")[1:-1]]
        for line in table.splitlines()
        if line.startswith("| armstrokes")
    ]
    assert (
        row[0] == "armstrokes" and row[11] == "50.0 (50)" and row[13:] == ["54.0", "56.8", "62.9"]
    )
    assert "armstrokes grid full thesis sub-seq." not in table  # extra scenes: no gap list
    assert "arm grid full held-out sims" in table.split("No runs yet:")[1]
    with pytest.raises(SystemExit):
        main(
            [
                "--log-dir",
                str(logs),
                "--ledger",
                str(tmp_path / "runs"),
                "--out",
                str(tmp_path / "t.md"),
                "--scenes",
                "flag",
            ]
        )


def test_default_writes_docs_results_and_leaves_the_readme_alone(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _report(tmp_path / "logs", "wind-L1-random-full-s0-base1", 0.125)
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{START}\nold table\n{END}\noutro\n")
    table = main(["--ledger", str(tmp_path / "runs")])
    assert readme.read_text() == f"intro\n{START}\nold table\n{END}\noutro\n"
    assert (tmp_path / "docs" / "results" / "table72.md").read_text().endswith(table)
    assert "12.5 (50)" in table


def test_readme_without_markers_is_refused(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("no block\n")
    with pytest.raises(ValueError, match="table72:start"):
        main(
            [
                "--log-dir",
                str(tmp_path),
                "--ledger",
                str(tmp_path / "runs"),
                "--out",
                str(tmp_path / "t.md"),
                "--readme",
                str(readme),
            ]
        )


def test_ledger_keeps_the_table_when_run_folders_are_gone(tmp_path):
    logs, ledger = tmp_path / "logs", tmp_path / "runs"
    _report(
        logs,
        "wind-L1-random-full-s0-base1",
        0.125,
        epochs=3,
        train_minutes=4.0,
        confusion=[[1, 0], [0, 1]],
    )
    _report(logs, "wind-L1-random-full-s0-seq-cnn_lstm", 0.75)
    args = ["--ledger", str(ledger), "--out", str(tmp_path / "t.md")]
    first = main(["--log-dir", str(logs), *args])
    entry = json.loads((ledger / "wind-L1-random-full-s0-base1.json").read_text())
    assert entry["acc"] == 0.125 and entry["run"] == "wind-L1-random-full-s0-base1"
    assert "confusion" not in entry
    assert sorted(p.name for p in ledger.iterdir()) == [
        "wind-L1-random-full-s0-base1.json",
        "wind-L1-random-full-s0-seq-cnn_lstm.json",
    ]
    assert main(["--log-dir", str(tmp_path / "gone"), *args]) == first  # fresh checkout
    _report(logs, "wind-L1-random-full-s0-cnn_lstm", 0.5)
    _report(logs / "new", "wind-L1-random-full-s0-base1", 0.25)
    refreshed = main(["--log-dir", str(logs / "new"), *args])  # a re-run replaces its entry
    assert "25.0 (50)" in refreshed and "12.5 (50)" not in refreshed
    assert json.loads((ledger / "wind-L1-random-full-s0-base1.json").read_text())["acc"] == 0.25


def test_mesh_levels_get_rows_beside_the_thesis_row_of_their_level(tmp_path):
    logs = tmp_path / "logs"
    _report(logs, "wind-L1-random-full-s0-base1", 0.25, epochs=5, train_minutes=8.0)
    _report(logs, "wind-L3-random-full-s0-base1", 0.5, epochs=5, train_minutes=9.0)
    table = main(
        [
            "--log-dir",
            str(logs),
            "--ledger",
            str(tmp_path / "runs"),
            "--out",
            str(tmp_path / "t.md"),
            "--scenes",
            "wind",
            "--level",
            "1,3",
        ]
    )
    rows = [
        [c.strip() for c in line.split("|")[1:-1]]
        for line in table.splitlines()
        if line.startswith("| wind")
    ]
    assert [(row[1], row[7], row[13:]) for row in rows] == [
        ("Unif-1", "25.0 (50)", ["53.6", "53.3", "64.7"]),
        ("Unif-3", "50.0 (50)", ["56.9", "53.0", "66.7"]),
    ]
    assert "L3 wind random full base1 5 epochs / 9 min" in table
    missing = table.split("No runs yet:")[1].split("Trained on:")[0]
    assert "L1 wind random full thesis sub-seq." in missing and "L3" not in missing
    with pytest.raises(SystemExit):
        main(
            [
                "--log-dir",
                str(logs),
                "--ledger",
                str(tmp_path / "runs"),
                "--out",
                str(tmp_path / "t.md"),
                "--level",
                "1,4",
            ]
        )
