"""What the gap test can see, sim against sim: inert, invisible and visible candidate strengths."""

import numpy as np
import pytest

from sim2real.candidates import Candidate
from sim2real.detectability import (
    candidate_detectability,
    detectable_at,
    detection_p,
    is_inert,
)
from sim2real.ladder import LadderFeatures
from sim2real.study.validate import score_set, summarise
from tests.sim2real.reports import as_diagnosis

GROUPS, CLIPS, DIM = 16, 3, 6


def _domain(seed: int, shift: float = 0.0) -> LadderFeatures:
    """Grouped Gaussian features on two rungs; ``shift`` moves the pixel rung's first 3 dims."""
    rng = np.random.default_rng(seed)
    groups = np.repeat([f"g{i}" for i in range(GROUPS)], CLIPS)
    rows = len(groups)
    pixel = np.repeat(rng.normal(0, 0.3, (GROUPS, DIM)), CLIPS, 0) + rng.normal(size=(rows, DIM))
    pixel[:, :3] += shift
    motion = rng.normal(size=(rows, DIM))
    return LadderFeatures(
        rungs={"pixel": pixel, "motion": motion},
        groups=groups,
        class_id=np.zeros(rows, dtype=int),
        stiffness=np.ones(rows),
        density=np.ones(rows),
    )


def _candidate(name: str, low=None, high=None) -> Candidate:
    return Candidate(name=name, stage="camera", registry="visual", field=name, low=low, high=high)


def test_a_set_equal_to_the_nominal_one_is_inert_and_any_change_is_not():
    nominal = _domain(0)
    assert is_inert(nominal, _domain(0))
    changed = _domain(0)
    changed.rungs["motion"] = changed.rungs["motion"].copy()
    changed.rungs["motion"][5, 2] += 1e-9
    assert not is_inert(nominal, changed)


def test_pooled_draws_keep_every_row_and_never_share_a_group():
    a, b = _domain(0), _domain(1)
    both = LadderFeatures.pooled(a, b)
    assert len(both) == len(a) + len(b)
    assert np.array_equal(both.rungs["pixel"], np.concatenate([a.rungs["pixel"], b.rungs["pixel"]]))
    assert len(set(both.groups)) == len(set(a.groups)) + len(set(b.groups))  # same ids in a, b
    assert np.array_equal(both.stiffness, np.concatenate([a.stiffness, b.stiffness]))


def test_a_seed_stream_reaches_the_generators_flat(monkeypatch):
    """numpy 2.5 refuses nested seeds ([[seed, 11, i, j], rung]); 2.4 flattened them."""
    seen, make = [], np.random.default_rng
    null, other = _domain(100), _domain(1)

    def flat_only(seed=None):
        seen.append(seed)
        assert np.ndim(seed) <= 1, f"nested seed {seed!r}"
        return make(seed)

    monkeypatch.setattr(np.random, "default_rng", flat_only)
    p = detection_p(null, other, n_perm=19, seed=[3, 11, 0, 1])
    streams = [list(np.ravel(s)) for s in seen]
    assert [3, 11, 0, 1, 0] in streams and [3, 11, 0, 1, 1] in streams  # one per rung
    monkeypatch.undo()
    assert detection_p(null, other, n_perm=19, seed=[3, 11, 0, 1]) == p


def test_the_detection_p_holds_its_level_and_picks_up_a_clear_shift():
    null = _domain(100)
    p_null = [detection_p(null, _domain(s), n_perm=99, seed=s) for s in range(12)]
    assert np.mean(np.array(p_null) < 0.05) <= 2 / 12  # about alpha under the null
    assert detection_p(null, _domain(1, shift=1.5), n_perm=99, seed=0) < 0.01


def test_verdicts_separate_inert_invisible_partly_and_visible_candidates():
    # S' as S itself: sampling noise out of the way, only the planted shifts differ
    nominal, null = _domain(0), _domain(0)
    sets = {
        "inert@1.0": _domain(0),
        "inert@4.0": _domain(0),
        "weak@0.01": _domain(0, shift=0.01),
        "weak@0.02": _domain(0, shift=0.02),
        "ramp@0.01": _domain(0, shift=0.01),
        "ramp@2.0": _domain(0, shift=2.0),
        "switch@None": _domain(0, shift=2.0),
    }
    plan = [
        (_candidate("inert", 1.0, 4.0), (1.0, 4.0)),
        (_candidate("weak", 0.01, 0.02), (0.01, 0.02)),
        (_candidate("ramp", 0.01, 2.0), (0.01, 2.0)),
        (_candidate("switch"), (None,)),
    ]
    found = candidate_detectability(
        plan, sets, nominal, null, lambda c, v: f"{c.name}@{v!r}", alpha=0.05, n_perm=99, seed=0
    )
    assert {n: e["verdict"] for n, e in found.items()} == {
        "inert": "inert",
        "weak": "undetected",
        "ramp": "partly",
        "switch": "detected",
    }
    assert found["inert"]["p"] == [1.0, 1.0] and all(found["inert"]["inert"])
    assert found["ramp"]["detected"] == [False, True] and found["ramp"]["log_scale"]
    # the nearest strength tried decides, in log scale for a log-spaced candidate: 0.1 is
    # nearer 0.01 than 2.0 in log scale, though not in linear scale
    assert not detectable_at(found["ramp"], 0.1)
    assert detectable_at(found["ramp"], 0.5)
    assert detectable_at(found["switch"], None)
    assert not detectable_at(found["switch"], "edge")  # a value never tried


@pytest.mark.parametrize(("gap", "visible"), [(False, False), (False, True), (True, True)])
def test_validation_splits_misses_of_power_from_misses_of_identification(gap, visible):
    result = {
        "ranking": {
            "ranking": ["visual.a", "visual.b"],
            "top": "visual.a" if gap else None,
            "explained": gap,
        },
        "candidates": {
            "visual.a": {
                "stage": "camera",
                "best_score": 0.9 if gap else 0.0,
                "strength_interval": [1.0, 2.0],
            }
        },
        "scored_rungs": ["pixel"] if gap else [],
        "residual_stage": "camera",
        "detectability": {
            "visual.a": {
                "strengths": [1.0, 2.0],
                "log_scale": False,
                "detected": [visible, visible],
            }
        },
    }
    answer = {
        "seed": 1,
        "kind": "single",
        "effects": [{"name": "visual.a", "stage": "camera", "strength": 1.2, "library": True}],
    }
    row = score_set(as_diagnosis(result), answer)
    assert row["truth_detectable"] is visible
    summary = summarise([row])
    assert summary["truth_detectable_n"] == 1
    if visible:
        assert summary["top1_detectable"] == float(gap)
        assert summary["gap_missed_when_detectable"] == float(not gap)
        assert summary["gap_found_when_undetectable_n"] == 0
    else:
        assert summary["top1_detectable"] is None and summary["top1_detectable_n"] == 0
        assert summary["gap_found_when_undetectable"] == 0.0


def test_a_no_gap_verdict_names_the_candidates_it_could_not_rule_out():
    from sim2real.report import verdict

    entry = {"strengths": [1.0], "p": [0.5], "inert": [False], "detected": [False]}
    result = {
        "location": {"significant": [], "gap_p": 0.4, "alpha": 0.05},
        "ranking": {},
        "rungs": {},
        "inputs": {"sim_groups": 27},
        "detectability": {
            "visual.specular": {**entry, "verdict": "undetected"},
            "physics.self_collision": {**entry, "inert": [True], "p": [1.0], "verdict": "inert"},
            "visual.sensor_noise": {**entry, "detected": [True], "verdict": "detected"},
        },
    }
    text = verdict(as_diagnosis(result))
    assert text.startswith("No gap beyond the within-domain noise floor")
    assert "27 simulations against 27" in text and "pools 54" in text
    assert "hardest to rule out: visual.specular." in text
    assert (
        "Inert in this scene (they change no feature at any strength tried): "
        "physics.self_collision." in text
    )
    assert "sensor_noise" not in text
