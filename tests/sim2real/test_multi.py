"""Multi-effect and effect-free sealed sets: the draw, the factor and stage-share scores."""

import dataclasses

import pytest

from sim2real.candidates import candidate_library
from sim2real.diagnosis.joint import JointFit
from sim2real.study.multi import f1_ceiling, named_factors, predicted_stage_shares, score_multi
from sim2real.study.seal import MULTI_EFFECTS, _base_spec, draw_answer
from sim2real.study.validate import _table, score_set, summarise
from tests.sim2real.reports import as_diagnosis

LIBRARY = candidate_library(_base_spec(None, 1))


@pytest.mark.parametrize("seed", range(12))
def test_a_multi_set_withholds_several_effects_across_the_stages(seed):
    answer = draw_answer(seed, LIBRARY, "multi")
    effects = answer["effects"]
    low, high = MULTI_EFFECTS
    assert low <= len(effects) <= high
    assert len({e["stage"] for e in effects}) >= min(len(effects), 4) - 1 >= 2
    settings = [(LIBRARY[e["name"]].registry, LIBRARY[e["name"]].field) for e in effects]
    assert len(set(settings)) == len(settings)  # two effects never set one field
    for e in effects:
        LIBRARY[e["name"]].check_strength(e["strength"])
    assert draw_answer(seed, LIBRARY, "multi") == answer  # the seed decides everything


def test_stages_are_spread_over_many_sets_and_twins_withhold_nothing():
    stages = [{e["stage"] for e in draw_answer(s, LIBRARY, "multi")["effects"]} for s in range(40)]
    assert all(
        sum(stage in s for s in stages) >= 30
        for stage in ("physics", "scene", "appearance", "camera")
    )
    assert draw_answer(3, LIBRARY, "twin")["effects"] == []
    assert draw_answer(3, LIBRARY)["kind"] in ("single", "pair", "open")  # never drawn unasked


def test_multi_sets_draw_the_texture_family_and_the_backdrop_too():
    drawn = [e for s in range(40) for e in draw_answer(s, LIBRARY, "multi")["effects"]]
    for name in ("look.texture_mode", "look.backdrop"):
        strengths = {e["strength"] for e in drawn if e["name"] == name}
        assert strengths and strengths <= set(LIBRARY[name].choices) - {LIBRARY[name].default}
        assert all(e["stage"] == "appearance" for e in drawn if e["name"] == name)


def _joint(shapley: dict[str, float], stages: dict[str, str]) -> JointFit:
    return JointFit(
        factors=stages,
        strengths=dict.fromkeys(shapley, 1.0),
        strength_interval={},
        rung_closure={},
        closure=sum(shapley.values()),
        closure_interval=(0.0, 1.0),
        reset=dict(shapley),
        reset_interval=dict.fromkeys(shapley, (0.0, 1.0)),
        shapley=shapley,
        shapley_interval=dict.fromkeys(shapley, (0.0, 1.0)),
        path=[],
        sets=9,
    )


STAGES = {
    "physics.air_damping": "physics",
    "visual.sensor_noise": "camera",
    "visual.specular": "appearance",
    "scene.size": "scene",
}


def _diagnosis(joint=None, top="visual.sensor_noise", explained=False):
    result = as_diagnosis(
        {
            "ranking": {"ranking": [top], "top": top, "explained": explained},
            "scored_rungs": ["pixel"],
            "candidates": {
                top: {
                    "stage": STAGES[top],
                    "best_score": 0.3,
                    "best_strength": 4.0,
                    "strength_interval": [1.0, 2.0],
                }
            },
        }
    )
    return dataclasses.replace(result, joint=joint)


def _multi_answer(*names):
    effects = [{"name": n, "stage": STAGES[n], "strength": 1.0, "library": True} for n in names]
    return {"seed": 7, "kind": "multi", "effects": effects}


def test_factor_scores_and_stage_shares_against_the_truth():
    joint = _joint(
        {"physics.air_damping": 0.5, "visual.sensor_noise": 0.2, "visual.specular": 0.1}, STAGES
    )
    result = _diagnosis(joint)
    answer = _multi_answer("physics.air_damping", "visual.sensor_noise", "scene.size")
    truth = {
        "closure": 0.9,
        "matter": ["physics.air_damping", "visual.sensor_noise"],
        "stage_shares": {"physics": 0.6, "camera": 0.3},
    }
    row = score_set(result, answer, truth)
    assert row["model"] is None  # a report without the model's digest (older reports)
    digest = dataclasses.replace(
        result, inputs=dataclasses.replace(result.inputs, checkpoint_digest="0123abcd")
    )
    assert score_set(digest, answer, truth)["model"] == "0123abcd"
    assert row["factor_precision"] == pytest.approx(2 / 3)
    assert row["factor_recall"] == pytest.approx(2 / 3)
    assert row["factor_f1"] == pytest.approx(2 / 3)
    assert row["factor_f1_matter"] == pytest.approx(0.8)  # 2 of 3 named, both that matter found
    # physics 50 vs 60, camera 20 vs 30, appearance 10 vs 0: the worst is 10 points
    assert row["stage_share_error_pts"] == pytest.approx(10.0)
    summary = summarise([row, {**row, "seed": 8, "stage_share_error_pts": 30.0}])
    assert summary["factor_f1"] == pytest.approx(2 / 3) and summary["factor_f1_n"] == 2
    assert summary["stage_share_error_pts_max"] == 30.0
    # naming nothing: no precision (no named factor was wrong), recall and F1 0
    empty = score_set(_diagnosis(_joint({"scene.size": 0.2}, STAGES)), answer, truth)
    assert empty["factor_precision"] is None
    assert empty["factor_recall"] == 0.0 and empty["factor_f1"] == 0.0
    both = summarise([row, {**empty, "seed": 8}])
    assert both["factor_precision"] == pytest.approx(2 / 3) and both["factor_precision_n"] == 1
    assert both["factor_f1"] == pytest.approx(1 / 3) and both["factor_f1_n"] == 2
    assert summary["factor_f1_ceiling"] is None  # the truth's strengths were not recorded


def test_the_f1_ceiling_names_exactly_the_effects_that_matter():
    withheld = {"physics.air_damping": 0.5, "visual.sensor_noise": 2.0, "scene.size": 0.9}
    row = {"kind": "multi", "truth_strengths": withheld, "truth_matter": ["scene.size"]}
    assert f1_ceiling(row) == pytest.approx(0.5)  # precision 1, recall 1/3
    every = {**row, "truth_matter": sorted(withheld)}
    assert f1_ceiling(every) == 1.0
    assert f1_ceiling({**row, "truth_matter": []}) == 0.0  # nothing leaves a trace
    assert f1_ceiling({"kind": "multi"}) is None
    summary = summarise([row, every, {"kind": "twin"}])
    assert summary["factor_f1_ceiling"] == pytest.approx(0.75)


def test_a_named_true_factor_is_checked_against_its_strength_interval():
    shapley = {"physics.air_damping": 0.5, "visual.sensor_noise": 0.3, "visual.specular": 0.1}
    joint = dataclasses.replace(
        _joint(shapley, STAGES),
        strength_interval={"physics.air_damping": (0.5, 2.0), "visual.sensor_noise": (3.0, 4.0)},
    )
    answer = {
        **_multi_answer("physics.air_damping", "visual.sensor_noise"),
        "image_effects": "twins",
    }
    answer["effects"][1]["strength"] = 9.0  # on the second implementation's own scale
    refit = {"closure": 0.8, "matter": [], "stage_shares": {}, "strengths": {}}
    # the damping's sealed 1.0 is inside; the noise has no refit to compare with
    row = score_set(_diagnosis(joint), answer, refit)
    assert (row["strengths_checked"], row["strengths_in_interval"]) == (1, 1)
    refit["strengths"] = {"visual.sensor_noise": 4.5}  # the library strength that matches best
    row = score_set(_diagnosis(joint), answer, refit)
    assert (row["strengths_checked"], row["strengths_in_interval"]) == (2, 1)
    assert row["strength_intervals"]["visual.sensor_noise"] == [3.0, 4.0]  # shown beside
    assert row["truth_strengths"] == {"visual.sensor_noise": 4.5}
    rendered = {**answer, "image_effects": "library"}  # the sealed 9.0 is on the library's scale
    assert score_set(_diagnosis(joint), rendered, refit)["strengths_in_interval"] == 1
    summary = summarise([row, {**row, "seed": 8, "strengths_in_interval": 2}])
    assert summary["factor_strength_in_interval"] == pytest.approx(3 / 4)
    assert summary["factor_strength_in_interval_n"] == 4


def test_without_a_joint_fit_the_named_effect_counts_and_twins_score_false_attribution():
    named = _diagnosis(None, explained=True)
    assert named_factors(named) == {"visual.sensor_noise"}
    assert predicted_stage_shares(named) == {"camera": 0.3}
    assert named_factors(_diagnosis(None)) == set()
    twin = {"seed": 9, "kind": "twin", "effects": []}
    clean = score_set(_diagnosis(None), twin)
    assert clean["false_attribution"] is False
    assert clean["stage_correct"] is None  # nothing withheld: no stage to get right
    table = _table(summarise([clean]), [clean])
    assert "| 9 | twin |  | nothing named | – | – | – |" in table
    assert score_set(named, twin)["false_attribution"] is True
    flagged = score_multi(_diagnosis(_joint({"scene.size": 0.7}, STAGES)), twin, None)
    assert flagged["false_attribution"] is True
    # a calibrated simulator that closes 20 % of the gap names no factor (reported, not named)
    partial = _diagnosis(_joint({"scene.size": 0.2}, STAGES))
    assert partial.joint.strengths and named_factors(partial) == set()
    assert score_multi(partial, twin, None)["false_attribution"] is False
    assert predicted_stage_shares(partial) == {}
    summary = summarise([score_set(named, twin), score_set(_diagnosis(None), twin)])
    assert summary["twin_false_attribution"] == 0.5 and summary["twin_n"] == 2
    assert summary["open_n"] == 0


def test_the_closed_loop_retrains_with_every_factor_of_the_calibrated_simulator():
    from sim2real.shrink import chosen_effects

    joint = _joint({"physics.air_damping": 0.5, "visual.sensor_noise": 0.2}, STAGES)
    assert chosen_effects(_diagnosis(joint)) == [
        ("physics.air_damping", 1.0),
        ("visual.sensor_noise", 1.0),
    ]
    assert chosen_effects(_diagnosis(None, explained=True)) == [("visual.sensor_noise", 4.0)]
    with pytest.raises(ValueError, match="named no effect"):
        chosen_effects(_diagnosis(None))
    assert chosen_effects(_diagnosis(joint), "scene.size=0.5") == [("scene.size", 0.5)]
    # a calibrated simulator that closes too little to name its factors, used on request
    partial = _diagnosis(_joint({"scene.size": 0.2}, STAGES))
    with pytest.raises(ValueError, match="use_effects=calibrated"):
        chosen_effects(partial)
    assert chosen_effects(partial, "calibrated") == [("scene.size", 1.0)]
    with pytest.raises(ValueError, match="no calibrated simulator"):
        chosen_effects(_diagnosis(None), "calibrated")


def test_the_truth_is_refitted_from_its_sealed_strengths_over_the_scored_grid():
    from sim2real.study.multi import _truth_factors

    result = as_diagnosis(
        {
            "candidates": {
                "visual.defocus_blur": {"stage": "camera", "strengths": [0.75, 1.5, 2.25, 3.0]},
                "scene.pose": {"stage": "scene", "strengths": ["edge"]},
            }
        }
    )
    answer = {
        "kind": "multi",
        "effects": [
            {"name": "visual.defocus_blur", "stage": "camera", "strength": 2.018, "library": True},
            {"name": "scene.pose", "stage": "scene", "strength": "edge", "library": True},
            {"name": "visual.shadows", "stage": "appearance", "strength": None, "library": True},
            {"name": "a new effect", "stage": "physics", "strength": 1.0, "library": False},
        ],
    }
    defocus, pose, shadows = _truth_factors(result, answer, spread=3)
    assert defocus.start == 2.018 and defocus.options == (0.75, 2.018, 2.25, 3.0)
    assert pose.options == ("edge",) and pose.start == "edge"
    assert shadows.options == (None,) and shadows.start is None  # a switch: on


def test_the_fabrics_density_spread_is_a_true_difference_of_every_set_that_has_one():
    from sim2real.study.multi import FABRIC_SPREAD, _truth_factors, answer_effects

    spread = {"density_range": [0.8, 1.25]}
    twin = {"seed": 9, "kind": "twin", "effects": []}
    (entry,) = answer_effects({**twin, **spread})
    assert entry["name"] == FABRIC_SPREAD and entry["strength"] == pytest.approx(0.4463, abs=1e-4)
    assert answer_effects(twin) == [] and answer_effects({**twin, "density_range": [1, 1]}) == []
    names_density = _diagnosis(_joint({FABRIC_SPREAD: 0.7}, {FABRIC_SPREAD: "physics"}))
    row = score_set(names_density, {**twin, **spread})
    assert row["false_attribution"] is False and row["named_fabric_spread"] is True
    assert score_set(names_density, twin)["false_attribution"] is True  # no spread in that set
    both = _joint({FABRIC_SPREAD: 0.4, "scene.size": 0.2}, {**STAGES, FABRIC_SPREAD: "physics"})
    assert score_set(_diagnosis(both), {**twin, **spread})["false_attribution"] is True
    assert summarise([row])["twin_named_fabric_spread"] == 1.0
    # in a multi set it is one more withheld effect, refitted and attributed with the others
    multi = {**_multi_answer("scene.size"), **spread}
    assert score_set(_diagnosis(both), multi)["factor_f1"] == 1.0
    result = as_diagnosis({"candidates": {FABRIC_SPREAD: {"stage": "physics", "strengths": []}}})
    (_, density) = _truth_factors(result, multi, spread=3)
    assert density.name == FABRIC_SPREAD and density.start == entry["strength"]
