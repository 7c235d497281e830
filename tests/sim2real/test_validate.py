"""Scoring of sealed sets: stage, top-1/top-3, strength interval, open set, Kendall tau."""

import dataclasses

import pytest

from sim2real.study.validate import (
    budget_names,
    load_budget,
    ranking_stability,
    score_set,
    stability_positions,
    stability_scores,
    summarise,
)
from tests.sim2real.reports import as_diagnosis


def _result(top, explained=True, ranking=None, interval=(1.0, 4.0), residual="none"):
    ranking = ranking or [top, "visual.white_balance", "physics.air_damping", "visual.shadows"]
    stages = {
        "visual.sensor_noise": "camera",
        "visual.white_balance": "camera",
        "physics.air_damping": "physics",
        "visual.shadows": "appearance",
        "physics.density_variation": "physics",
    }
    return as_diagnosis(
        {
            "ranking": {"ranking": ranking, "top": top, "explained": explained},
            "residual_stage": residual,
            "scored_rungs": ["pixel"],  # a diagnosis that found a gap
            "candidates": {
                n: {
                    "stage": stages[n],
                    "best_score": 0.8 if n == top else 0.1,
                    "strength_interval": list(interval),
                }
                for n in ranking
            },
        }
    )


def _answer(name, strength=2.0, kind="single", stage="camera", library=True):
    effect = {"name": name, "stage": stage, "strength": strength, "library": library}
    return {"seed": 1, "kind": kind, "effects": [effect]}


def test_a_correct_diagnosis_scores_everything():
    row = score_set(_result("visual.sensor_noise"), _answer("visual.sensor_noise"))
    assert row["stage_correct"] and row["top1"] and row["top3"]
    assert row["strength_in_interval"] and row["gap_closed"] == 0.8
    outside = score_set(
        _result("visual.sensor_noise", interval=(4.0, 8.0)), _answer("visual.sensor_noise")
    )
    assert outside["strength_in_interval"] is False


def test_without_a_significant_gap_nothing_counts_as_ranked():
    result = dataclasses.replace(_result("visual.sensor_noise", explained=False), scored_rungs=[])
    row = score_set(result, _answer("visual.sensor_noise"))
    assert not row["top1"] and not row["top3"]


def test_a_gap_whose_candidates_all_score_zero_ranks_nothing():
    # S's own classifier gap at its floor: every score 0, the order is the library's
    result = dataclasses.replace(
        _result("visual.sensor_noise", explained=False), scored_rungs=["pixel"]
    )
    for entry in result.candidates.values():
        entry["best_score"] = 0.0
    row = score_set(result, _answer("visual.sensor_noise"))
    assert not row["top3"] and row["detected"]
    tied = stability_scores([result, result, _result("visual.sensor_noise")])
    assert tied["no_gap_diagnoses"] == 2 and "kendall_tau" not in tied


def test_a_wrong_top_in_the_right_stage_counts_as_stage_and_top3_only():
    result = _result(
        "visual.white_balance",
        ranking=[
            "visual.white_balance",
            "visual.sensor_noise",
            "visual.shadows",
            "physics.air_damping",
        ],
    )
    row = score_set(result, _answer("visual.sensor_noise"))
    assert row["stage_correct"] and not row["top1"] and row["top3"]
    assert row["gap_closed"] == 0.1


def test_open_sets_score_false_attribution_and_residual_stage():
    answer = _answer("barrel_distortion", kind="open", library=False)
    named = score_set(_result("visual.sensor_noise"), answer)
    assert named["false_attribution"] and "top1" not in named
    residual = score_set(
        _result(
            "visual.sensor_noise",
            explained=False,
            residual="appearance or camera (the pixel statistics differ)",
        ),
        answer,
    )
    assert not residual["false_attribution"] and residual["stage_correct"]
    summary = summarise(
        [named, residual, score_set(_result("visual.sensor_noise"), _answer("visual.sensor_noise"))]
    )
    assert summary["open_false_attribution"] == 0.5 and summary["open_n"] == 2
    assert summary["top1"] == 1.0 and summary["top1_n"] == 1
    # the fabrics' density spread is in every set that has one: naming it alone is no error
    spread = {**answer, "density_range": [0.8, 1.25]}
    density = score_set(_result("physics.density_variation"), spread)
    assert not density["false_attribution"]
    assert score_set(_result("physics.density_variation"), answer)["false_attribution"]


def test_kendall_tau_of_identical_and_reversed_rankings():
    order = ["a", "b", "c", "d"]
    assert ranking_stability([order, order, order]) == pytest.approx(1.0)
    assert ranking_stability([order, order[::-1]]) == pytest.approx(-1.0)


def test_a_diagnosis_without_a_gap_ranks_nothing_and_is_left_out_of_the_tau():
    order, swapped = list("abcdef"), list("abcdfe")
    library = sorted(order, reverse=True)  # a no-gap diagnosis lists the library's order
    scored = {n: {"best_score": 0.1 * i} for i, n in enumerate(order)}
    found = [
        as_diagnosis({"ranking": {"ranking": r}, "scored_rungs": ["motion"], "candidates": scored})
        for r in (order, swapped)
    ]
    none = as_diagnosis({"ranking": {"ranking": library}, "scored_rungs": [], "candidates": scored})
    scores = stability_scores([found[0], none, found[1]])
    assert scores["no_gap_diagnoses"] == 1
    assert scores["kendall_tau"] == pytest.approx(ranking_stability([order, swapped]))
    assert scores["kendall_tau_all"] == pytest.approx(ranking_stability([order, library, swapped]))
    assert scores["kendall_tau_all"] < scores["kendall_tau"]
    alone = stability_scores([found[0], none, none])
    assert "kendall_tau" not in alone and alone["no_gap_diagnoses"] == 2
    rows = [{"kind": "single", **scores}, {"kind": "single", **alone}]
    summary = summarise(rows)
    assert summary["kendall_tau_n"] == 1 and summary["kendall_tau_all_n"] == 2


def test_weighted_tau_counts_swaps_at_the_top_more_than_at_the_bottom():
    order = list("abcdefgh")
    top_swap = ["b", "a", *order[2:]]
    bottom_swap = [*order[:-2], "h", "g"]
    assert ranking_stability([order, top_swap]) == pytest.approx(
        ranking_stability([order, bottom_swap])
    )
    assert ranking_stability([order, bottom_swap], weighted=True) > ranking_stability(
        [order, top_swap], weighted=True
    )
    assert ranking_stability([order, order], weighted=True) == pytest.approx(1.0)


def test_the_summary_counts_detection_and_top1_where_a_gap_was_found():
    gap = dataclasses.replace(_result("visual.sensor_noise"), scored_rungs=["pixel"])
    none = dataclasses.replace(_result("visual.sensor_noise", explained=False), scored_rungs=[])
    hit = score_set(gap, _answer("visual.sensor_noise"))
    missed = score_set(none, _answer("visual.sensor_noise"))
    open_set = score_set(gap, _answer("barrel_distortion", kind="open", library=False))
    summary = summarise([hit, missed, open_set])  # an open set has no effect to rank
    assert summary["detected"] == 0.5 and summary["detected_n"] == 2
    assert summary["top1_detected"] == 1.0 and summary["top1_detected_n"] == 1
    assert summary["top1"] == 0.5


def test_a_plan_cycles_singles_through_the_library_and_numbers_seeds_in_order():
    from sim2real.study.validate import set_plan

    names = ["a", "b", "c"]
    plan = set_plan("single:4,pair:2,open:1", names, 100)
    assert [p[0] for p in plan] == list(range(100, 107))
    assert [p[1:] for p in plan[:4]] == [
        ("single", "a"),
        ("single", "b"),
        ("single", "c"),
        ("single", "a"),
    ]
    assert plan[4:] == [(104, "pair", None), (105, "pair", None), (106, "open", None)]
    assert set_plan(None, names, 1) is None
    with pytest.raises(ValueError, match="kinds"):
        set_plan("double:2", names, 1)


def test_a_fixed_single_effect_keeps_a_drawn_strength():
    from datasets.spec import PRESETS, DatasetSpec
    from sim2real.candidates import candidate_library
    from sim2real.study.seal import draw_answer
    from simulator.cloth.scenes import ScenarioWind

    library = candidate_library(
        DatasetSpec(motion="wind", scenario=ScenarioWind(), preset=PRESETS["small"])
    )
    answer = draw_answer(7, library, "single", "visual.sensor_noise")
    (effect,) = answer["effects"]
    # strengths are drawn in the half of the range away from neutral (upper half in log)
    assert effect["name"] == "visual.sensor_noise" and 2.0 <= effect["strength"] <= 8.0
    with pytest.raises(ValueError, match="effect"):
        draw_answer(7, library, "pair", "visual.sensor_noise")


def test_validation_reads_the_budget_configs_that_the_diagnosis_reads():
    assert {"quick", "full"} <= set(budget_names())
    quick, full = load_budget("quick"), load_budget("full")
    assert (quick.name, quick.sims_per_class, tuple(quick.class_grid)) == ("quick", 6, (3, 3))
    assert (full.name, full.strengths) == ("full", 5)
    with pytest.raises(ValueError, match=r"--budget must be one of .*quick.*got 'fast'"):
        load_budget("fast")


def test_budget_settings_on_top_of_a_config_change_only_those_and_are_named():
    quick = load_budget("quick")
    changed = load_budget("quick", ["refine=visual", "shapley_top=2", "class_grid=[2,2]"])
    assert (changed.refine, changed.shapley_top, changed.class_grid) == ("visual", 2, (2, 2))
    assert changed.name == "quick+refine=visual,shapley_top=2,class_grid=[2,2]"
    untouched = {"name", "refine", "shapley_top", "class_grid"}
    for field in dataclasses.fields(quick):
        if field.name not in untouched:
            assert getattr(changed, field.name) == getattr(quick, field.name), field.name
    assert load_budget("quick", []) == quick
    with pytest.raises(ValueError, match=r"--budget-set must be KEY=VALUE with KEY one of .*refi"):
        load_budget("quick", ["speed=11"])
    with pytest.raises(ValueError, match="--budget-set"):
        load_budget("quick", ["refine"])
    with pytest.raises(ValueError, match=r"budget\.refine must be none, visual or all"):
        load_budget("quick", ["refine=some"])


def test_stability_sets_are_spread_over_the_plan_so_every_kind_is_measured():
    from sim2real.study.validate import set_plan

    assert stability_positions(32, 6) == {0, 5, 11, 16, 21, 27}
    assert stability_positions(32, 3) == {0, 11, 21}
    assert stability_positions(5, 10) == set(range(5)) and stability_positions(32, 0) == set()
    plan = set_plan("open:4,single:22,pair:6", [f"e{i}" for i in range(22)], 0)
    kinds = [plan[i][1] for i in sorted(stability_positions(len(plan), 6))]
    assert kinds == ["open", "single", "single", "single", "single", "pair"]  # as the plan's mix


def test_the_summary_gives_the_ranking_stability_per_kind_of_set():
    rows = [
        {"kind": "open", "kendall_tau": 0.7},
        {"kind": "open", "kendall_tau": 0.8},
        {"kind": "single", "kendall_tau": 0.9},
        {"kind": "single"},
    ]
    summary = summarise(rows)
    assert summary["kendall_tau"] == pytest.approx(0.8) and summary["kendall_tau_n"] == 3
    by_kind = summary["kendall_tau_by_kind"]
    assert by_kind["open"] == (pytest.approx(0.75), 2) and by_kind["single"] == (0.9, 1)
