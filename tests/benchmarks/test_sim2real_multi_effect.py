"""The multi-effect results writer: figures, targets and one-line errors."""

import json

import pytest

from benchmarks.sim2real_multi_effect import figures, loop_figures, main, table


def _row(seed, kind, **values):
    return {"seed": seed, "kind": kind, "budget": "quick", "minutes": 10.0 + seed % 7, **values}


ROWS = [
    _row(
        1,
        "multi",
        factor_f1=1.0,
        factor_f1_matter=1.0,
        factor_precision=1.0,
        factor_recall=1.0,
        stage_share_error_pts=4.0,
    ),
    _row(
        2,
        "multi",
        factor_f1=0.5,
        factor_f1_matter=0.5,
        factor_precision=1.0,
        factor_recall=1 / 3,
        stage_share_error_pts=20.0,
    ),
    _row(3, "twin", false_attribution=False),
    _row(4, "twin", false_attribution=True),
]


def _loop(before, after, control=None, density_score="material_score"):
    def corr(r):
        return {"pearson": r, "pearson_ci": [r - 0.1, r + 0.1]}

    pairs = {
        "bend_score": "stiffness",
        "stretch_score": "stretch_stiffness",
        density_score: "density",
    }
    every = {
        label: {"all": {s: {c: corr(v)} for s, c in pairs.items()}}
        for label, v in (("before", before), ("after", after), ("control", control))
        if v is not None
    }
    return {"shrink": {"score_correlations": every}}


def test_figures_and_targets_from_a_round_and_a_loop():
    result = figures(ROWS, loop_figures(_loop(0.25, 0.55)))
    assert result["sets"] == {"multi": 2, "twin": 2}
    assert result["factor_f1"] == pytest.approx(0.75)
    assert result["stage_share_error_pts"] == {"median": 12.0, "max": 20.0}
    assert result["twin_false_attribution"] == 0.5
    assert result["independent_engine_r_gain_min"] == pytest.approx(0.3)
    assert result["independent_engine_r_after_min"] == pytest.approx(0.55)
    met = {k: t["met"] for k, t in result["targets"].items()}
    assert met == {
        "multi_sets": False,
        "twin_sets": False,
        "factor_f1": False,
        "stage_share_error_pts_max": False,
        "twin_false_attribution": False,
        "independent_engine_r_gain_min": True,
        "independent_engine_r_after_min": True,
        "quick_minutes": True,
    }
    assert "| factor_f1 | >= 0.8 | 0.75 | no |" in table(result)
    assert result["independent_engine_r_gain_over_control_min"] is None  # no control run


def test_a_control_fine_tune_gives_the_gain_over_extra_training_alone():
    loop = loop_figures(_loop(0.25, 0.55, control=0.45))
    assert loop["bend_score vs stiffness"]["control"] == 0.45
    assert loop["bend_score vs stiffness"]["gain_over_control"] == pytest.approx(0.1)
    result = figures(ROWS, loop)
    assert result["independent_engine_r_gain_over_control_min"] == pytest.approx(0.1)


def test_a_model_with_a_density_axis_is_judged_on_its_density_score():
    thesis = loop_figures(_loop(0.25, 0.55))
    assert "material_score vs density" in thesis and "density_score vs density" not in thesis
    dense = loop_figures(_loop(0.1, 0.6, density_score="density_score"))
    assert dense["density_score vs density"]["gain"] == pytest.approx(0.5)
    assert "material_score vs density" not in dense
    # a density axis added by the loop: the model before is judged on its material score
    added = _loop(0.1, 0.6, control=0.2)
    added["shrink"]["score_correlations"]["after"] = _loop(0.0, 0.6, density_score="density_score")[
        "shrink"
    ]["score_correlations"]["after"]
    entry = loop_figures(added)["density_score vs density"]
    assert (entry["before"], entry["after"], entry["control"]) == (0.1, 0.6, 0.2)
    assert entry["before_score"] == entry["control_score"] == "material_score"


def test_without_a_loop_its_targets_are_not_measured():
    result = figures(ROWS, None)
    assert result["targets"]["independent_engine_r_gain_min"]["met"] is None
    assert "| independent_engine_r_after_min | >= 0.5 | – | – |" in table(result)


def test_the_command_writes_json_and_table_and_names_bad_inputs(tmp_path, capsys):
    round_ = tmp_path / "round"
    round_.mkdir()
    (round_ / "validation.json").write_text(json.dumps({"sets": ROWS}))
    out = tmp_path / "results"
    main(["--validation", str(round_), "--out", str(out)])
    written = json.loads((out / "sim2real_multi_effect.json").read_text())
    assert written["seeds"] == [1, 2, 3, 4]
    assert (out / "sim2real_multi_effect.md").read_text().startswith("| measure |")
    with pytest.raises(SystemExit) as stop:
        main(["--validation", str(tmp_path / "none"), "--out", str(out)])
    assert stop.value.code == 2
    assert capsys.readouterr().err.strip().startswith("error: --validation:")
    shrinkless = tmp_path / "diagnosis"
    shrinkless.mkdir()
    (shrinkless / "report.json").write_text(json.dumps({"shrink": None}))
    with pytest.raises(SystemExit):
        main(["--validation", str(round_), "--loop", str(shrinkless), "--out", str(out)])
    assert "run python -m sim2real.shrink" in capsys.readouterr().err


def test_a_cold_diagnosis_on_a_quiet_machine_is_judged_against_the_time_target(tmp_path, capsys):
    bench = tmp_path / "bench.txt"
    bench.write_text(
        "seal 3 min; diagnose 34 min\n"
        '{"diagnose_minutes": 34.0, "candidate_sets": 80, "kind": "multi"}\n'
    )
    round_ = tmp_path / "round"
    round_.mkdir()
    (round_ / "validation.json").write_text(json.dumps({"sets": ROWS}))
    out = tmp_path / "results"
    result = main(["--validation", str(round_), "--speed", str(bench), "--out", str(out)])
    assert result["quick_minutes"]["cold"] == 34.0 and result["quick_minutes"]["max"] == 14.0
    assert result["command"].startswith("python -m benchmarks.sim2real_multi_effect --validation")
    assert result["targets"]["quick_minutes"] == {
        "target": "<= 30",
        "measured": 34.0,
        "met": False,
    }
    assert "a cold diagnosis of a multi-effect set" in table(result)
    # A single-effect set's cold time is shown, not judged: it lacks the joint fit's sets.
    bench.write_text('{"diagnose_minutes": 28.0, "kind": "single"}\n')
    single = main(["--validation", str(round_), "--speed", str(bench), "--out", str(out)])
    assert single["targets"]["quick_minutes"]["measured"] == 28.0
    assert single["targets"]["quick_minutes"]["met"] is None
    assert "target is not judged" in table(single)
    assert figures(ROWS, None)["targets"]["quick_minutes"]["measured"] == 14.0  # the round's
    bench.write_text("diagnose 34 min\n")
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        main(["--validation", str(round_), "--speed", str(bench), "--out", str(out)])
    assert stop.value.code == 2
    assert capsys.readouterr().err.startswith("error: --speed:")


def test_a_rounds_committed_ledger_and_an_earlier_loop_give_the_same_figures(tmp_path, capsys):
    # The ledger: multi and twin rows in their own files, one seed met twice (the last wins).
    ledger = tmp_path / "round"
    ledger.mkdir()
    multi = [r for r in ROWS if r["kind"] == "multi"]
    stale = {**multi[0], "factor_f1": 0.0}
    (ledger / "rows_multi.jsonl").write_text("".join(json.dumps(r) + "\n" for r in [stale, *multi]))
    (ledger / "rows_twin.jsonl").write_text(
        "".join(json.dumps(r) + "\n" for r in ROWS if r["kind"] == "twin") + "\n"
    )
    loop_dir = tmp_path / "diagnosis"
    loop_dir.mkdir()
    (loop_dir / "report.json").write_text(json.dumps(_loop(0.25, 0.55)))
    first = main(
        ["--validation", str(ledger), "--loop", str(loop_dir), "--out", str(tmp_path / "a")]
    )
    assert first["seeds"] == [1, 2, 3, 4] and first["factor_f1"] == pytest.approx(0.75)
    earlier = tmp_path / "a" / "sim2real_multi_effect.json"
    again = main(
        ["--validation", str(ledger), "--loop", str(earlier), "--out", str(tmp_path / "b")]
    )
    assert again["independent_engine"] == first["independent_engine"]
    assert again["targets"] == first["targets"]
    (loop_dir / "validation.json").write_text(json.dumps({"sets": ROWS}))
    (ledger / "rows_twin.jsonl").write_text("not json\n")
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["--validation", str(ledger), "--out", str(tmp_path / "c")])
    assert "rows_twin.jsonl line 1 is not a scored set" in capsys.readouterr().err
    (tmp_path / "other.json").write_text("{}")
    with pytest.raises(SystemExit):
        main(["--validation", str(loop_dir), "--loop", str(tmp_path / "other.json")])
    assert "error: --loop:" in capsys.readouterr().err
