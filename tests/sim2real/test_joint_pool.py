"""Which candidates the joint fit may choose from (sim2real.pipeline._joint_pool)."""

from __future__ import annotations

from types import SimpleNamespace

from sim2real import pipeline


def _candidate(name: str, stage: str) -> SimpleNamespace:
    registry, field = name.split(".")
    return SimpleNamespace(
        name=name,
        stage=stage,
        registry=registry,
        field=field,
        needs_simulation=stage != "camera",
        log_scale=stage == "camera",
        integer=False,
    )


def _result(strengths, interval, neutral):
    low, high = interval
    return SimpleNamespace(
        strengths=strengths,
        holds_neutral=neutral is not None and low <= neutral <= high,
    )


def test_a_candidate_the_data_cannot_tell_from_its_neutral_strength_is_not_a_factor(monkeypatch):
    closures = {0: 0.1, 1: 0.6, 2: 0.3, 3: 0.2}
    monkeypatch.setattr(pipeline, "_set_closure", lambda oof, result, j, ref: closures[j])
    plan = [
        (_candidate("scene.wind_yaw_jitter_deg", "scene"), None),  # interval holds 15: out
        (_candidate("scene.size", "scene"), None),  # interval leaves out 0.5: in
        (_candidate("visual.motion_blur", "camera"), None),  # no neutral strength: in
    ]
    results = [
        _result((0.0, 17.5, 30.0, 45.0), (0.0, 45.0), 15.0),
        _result((0.3, 0.4, 0.6, 0.8), (0.6, 0.8), 0.5),
        _result((0.1, 0.4, 0.7, 1.0), (0.1, 1.0), None),
    ]
    budget = SimpleNamespace(joint_strengths=2)
    pool = pipeline._joint_pool(plan, results, None, budget, {})
    assert [f.name for f in pool] == ["scene.size", "visual.motion_blur"]
    size, blur = pool
    assert size.options == (0.3, 0.4, 0.8)  # the two ends and the best alone (0.4)
    assert size.simulated and not blur.simulated
    assert blur.log_scale and not size.log_scale  # the ends of its interval bisect like its grid
    assert size.setting == "scene.size"
