"""The stacked fit: a partner fitted on top of the leader (pure logic, made-up closures)."""

import pytest

from datasets.spec import DatasetSpec, SizePreset
from sim2real.candidates import candidate_library
from sim2real.diagnosis import OPEN_SET_MARGIN, CandidateResult
from sim2real.pipeline import _stack_on_leader
from sim2real.stacking import STACK_MIN_LEADER, stack_label, stacked_fit
from simulator.cloth.scenes import ScenarioWind
from tests.sim2real.reports import ranking_of

SPEC = DatasetSpec(motion="wind", scenario=ScenarioWind(), preset=SizePreset("t", 2, 1, 0, 0))
LIBRARY = candidate_library(SPEC)
SHAKE, BLUR = LIBRARY["visual.camera_shake"], LIBRARY["visual.motion_blur"]
NOISE, LIFT = LIBRARY["visual.sensor_noise"], LIBRARY["physics.aero_lift"]
THRESHOLD = 0.5


def _result(name, strengths, score):
    """Made-up closures, the kernel distance's on "pixel" equal to the classifier's."""
    score = list(score)
    return CandidateResult(name, "camera", tuple(strengths), {}, {"pixel": score}, score)


class World:
    """Closures of stacked sets by (first, its value, second, its value); records builds."""

    def __init__(self, closes, kernel=1.0):
        self.closes, self.kernel, self.built = closes, kernel, []

    def build(self, specs):
        assert all(isinstance(spec, DatasetSpec) for spec in specs.values())
        self.built += list(specs)

    def score(self, name, stage, values, labels):
        assert all(label in self.built for label in labels)
        return _result(name, values, [self.closes(label) for label in labels])


def _pair_closure(label):
    """Shake 0.01 + blur 1.0 is the truth: closure falls with the distance from it."""
    parts = dict(p.split("@") for p in label.split(":", 1)[1].split("+"))
    shake = float(parts["visual.camera_shake"])
    blur = float(parts.get("visual.motion_blur", 0.0))
    return 1.0 - 40 * abs(shake - 0.01) - 0.5 * abs(blur - 1.0)


def test_a_partner_that_alone_widens_the_gap_explains_it_on_top_of_the_leader():
    leader = _result(SHAKE.name, (0.001, 0.003, 0.012), (0.1, 0.42, 0.3))
    world = World(lambda label: _pair_closure(label) if "motion_blur" in label else 0.2)
    partners = [(BLUR, (0.1, 0.316, 1.0), -0.05), (NOISE, (0.5, 2.0, 8.0), 0.06)]
    fit = stacked_fit(
        SPEC,
        SHAKE,
        leader,
        (0.001, 0.003, 0.012),
        partners,
        world.build,
        world.score,
        kernel=lambda r: world.kernel,
        threshold=THRESHOLD,
    )
    assert fit["best"] == BLUR.name and fit["best_strength"] == 1.0
    # The refit moved the leader from its own best (0.003) towards the truth (0.012).
    assert fit["refit"]["best_strength"] == 0.012 and fit["leader_strength"] == 0.012
    assert fit["score"] == pytest.approx(1.0 - 40 * 0.002)
    assert fit["explained"]
    assert stack_label(SHAKE, 0.003, BLUR, 1.0) in world.built  # held at its own best first


@pytest.mark.parametrize(
    ("case", "pair", "kernel", "alone"),
    [
        ("under threshold + margin", THRESHOLD + OPEN_SET_MARGIN - 0.01, 1.0, 0.0),
        ("kernel disagrees", 0.9, 0.2, 0.0),
        ("partner alone closes as much", 0.9, 1.0, 0.9),
    ],
)
def test_a_pair_explains_only_under_the_coalition_rules(case, pair, kernel, alone):
    leader = _result(SHAKE.name, (0.003,), (0.42,))
    world = World(lambda label: pair, kernel=kernel)
    fit = stacked_fit(
        SPEC,
        SHAKE,
        leader,
        (0.003,),
        [(BLUR, (1.0,), alone)],
        world.build,
        world.score,
        kernel=lambda r: world.kernel,
        threshold=THRESHOLD,
    )
    assert not fit["explained"], case
    assert fit["refit"] is None  # one leader strength: nothing to refit


def test_a_leader_that_simulates_is_held_and_only_re_rendering_candidates_are_partners():
    ranking = ranking_of(
        explained=False, top=LIFT.name, threshold=THRESHOLD, kernel_rungs=["pixel"]
    )
    plan = [(LIFT, (0.1, 0.35, 1.2)), (BLUR, (0.1, 1.0)), (SHAKE, (0.001, 0.012))]
    results = [
        _result(LIFT.name, plan[0][1], (0.1, 0.45, 0.2)),
        _result(BLUR.name, plan[1][1], (0.0, 0.1)),
        _result(SHAKE.name, plan[2][1], (0.0, 0.05)),
    ]
    world = World(lambda label: 0.9 if "camera_shake" in label else 0.3)

    class Budget:
        strengths = 3

    ranked, fit = _stack_on_leader(
        ranking, plan, results, SPEC, Budget, build=world.build, score=world.score
    )
    assert set(fit["partners"]) == {BLUR.name, SHAKE.name}
    assert all(label.startswith(f"stack:{LIFT.name}@0.35+") for label in world.built)
    assert fit["refit"] is None and fit["best"] == SHAKE.name
    assert ranked.explained and ranked.explained_by == [LIFT.name, SHAKE.name]
    assert ranked.explained_by_score == 0.9


def test_no_stacked_fit_when_explained_or_the_leader_closes_too_little():
    plan = [(SHAKE, (0.001, 0.012)), (BLUR, (0.1, 1.0))]
    weak = [
        _result(SHAKE.name, plan[0][1], (0.0, STACK_MIN_LEADER - 0.01)),
        _result(BLUR.name, plan[1][1], (0.0, 0.1)),
    ]

    def never(*args):
        raise AssertionError("no set may be built")

    for ranking, results in [
        (ranking_of(explained=True, top=SHAKE.name), weak),
        (ranking_of(explained=False, top=None), weak),
        (ranking_of(explained=False, top=SHAKE.name, threshold=THRESHOLD), weak),
    ]:
        assert _stack_on_leader(ranking, plan, results, None, None, build=never, score=never) == (
            ranking,
            None,
        )


def test_the_report_lists_the_partners_best_first():
    from sim2real.report import _stacked_lines

    leader = _result(SHAKE.name, (0.003,), (0.42,))
    world = World(lambda label: 0.9 if "motion_blur" in label else 0.3)
    fit = stacked_fit(
        SPEC,
        SHAKE,
        leader,
        (0.003,),
        [(NOISE, (0.5, 2.0), 0.0), (BLUR, (0.1, 1.0), 0.0)],
        world.build,
        world.score,
        kernel=lambda r: 0.8,
        threshold=THRESHOLD,
    )
    text = "\n".join(_stacked_lines(fit))
    assert "closes 90 % (kernel 80 %) and explains the gap" in text
    assert text.index(BLUR.name) < text.index(NOISE.name)
    assert _stacked_lines(None) == []
