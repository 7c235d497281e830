"""The power study: pooling more nominal draws finds a weak shift that one draw misses."""

import numpy as np
import pytest

from sim2real.ladder import LadderFeatures
from sim2real.study.power import pooled_detection

CLIPS, DIM = 3, 4


def _domain(seed: int, groups: int, shift: float = 0.0) -> LadderFeatures:
    """Grouped Gaussian features on two rungs; ``shift`` moves the motion rung's first dim."""
    rng = np.random.default_rng(seed)
    ids = np.repeat([f"g{i}" for i in range(groups)], CLIPS)
    rows = len(ids)
    motion = np.repeat(rng.normal(0, 0.3, (groups, DIM)), CLIPS, 0) + rng.normal(size=(rows, DIM))
    motion[:, 0] += shift
    return LadderFeatures(
        rungs={"pixel": rng.normal(size=(rows, DIM)), "motion": motion},
        groups=ids,
        class_id=np.zeros(rows, dtype=int),
        stiffness=np.ones(rows),
        density=np.ones(rows),
    )


def test_more_draws_find_a_weak_shift_that_one_draw_mostly_misses_and_name_its_rung():
    found = []
    for s in range(8):
        real = _domain(100 + s, groups=60, shift=0.5)
        draws = [_domain(10 * s + d, groups=10) for d in range(6)]
        found.append(pooled_detection(draws, real, [1, 6], n_perm=99, seed=s))
    assert [(f["sims"], m["sims"]) for f, m in found] == [(10, 60)] * 8
    assert sum(f["detected"] for f, _ in found) <= 3
    assert sum(m["detected"] for _, m in found) >= 7
    assert sum("motion" in m["pixel_or_motion"] for _, m in found) >= 7
    assert sum("pixel" in m["rungs"] for _, m in found) <= 2  # the unshifted rung: about alpha


def test_nominal_draws_against_a_nominal_real_set_stay_below_the_level_mostly():
    draws = [_domain(s, groups=10) for s in range(4)]
    found = [
        pooled_detection(draws, _domain(50 + s, groups=30), [4], n_perm=99, seed=s)[0]
        for s in range(10)
    ]
    assert sum(f["detected"] for f in found) <= 2


def test_counts_beyond_the_draws_given_are_refused():
    with pytest.raises(ValueError, match=r"counts: 3 is not in 1\.\.2"):
        pooled_detection([_domain(0, 5), _domain(1, 5)], _domain(2, 5), [3])
