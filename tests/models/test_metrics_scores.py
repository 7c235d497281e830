"""Grid metrics, material scores and bootstrap correlations against hand-computed values."""

import numpy as np
import pytest
import torch
from scipy import stats

from common.grid import ClassGrid
from models.correlation import correlate
from models.metrics import breakdown_metrics, classification_metrics, confusion_matrix
from models.scores import correlated_scores, material_scores
from simulator.cloth.material import BEND_MULTIPLIERS, STRETCH_MULTIPLIERS

GRID = ClassGrid(STRETCH_MULTIPLIERS, BEND_MULTIPLIERS)
"""The thesis's 6 x 9 grid, handed to the metrics as the data hands it."""


def _logits(predicted, runner_up=None):
    logits = torch.zeros(len(predicted), 54)
    logits[torch.arange(len(predicted)), torch.tensor(predicted)] = 5.0
    if runner_up is not None:
        logits[torch.arange(len(predicted)), torch.tensor(runner_up)] = 4.0
    return logits


def test_classification_metrics_by_hand():
    # true (s, b): 0 -> (0,0), 10 -> (1,1), 53 -> (5,8), 20 -> (2,2)
    labels = torch.tensor([0, 10, 53, 20])
    # predicted: exact; same stretch other bend (1,3); other stretch same bend (4,8); (0,0)
    logits = _logits([0, 12, 44, 0], runner_up=[1, 10, 53, 30])
    m = classification_metrics(logits, labels, GRID)
    assert m["acc"] == pytest.approx(0.25)
    assert m["top5"] == pytest.approx(0.75)  # the last's runner-up (30) is wrong
    assert m["stretch_acc"] == pytest.approx(0.5)
    assert m["bend_acc"] == pytest.approx(0.5)
    assert m["stretch_mae"] == pytest.approx((0 + 0 + 1 + 2) / 4)
    assert m["bend_mae"] == pytest.approx((0 + 2 + 0 + 2) / 4)
    assert m["grid_mae"] == pytest.approx(m["stretch_mae"] + m["bend_mae"])
    matrix = confusion_matrix(labels, logits.argmax(1), GRID.num_classes)
    assert matrix.sum() == 4 and matrix[20, 0] == 1 and matrix[10, 12] == 1
    with pytest.raises(ValueError, match="logits must be"):
        classification_metrics(torch.zeros(3, 10), torch.zeros(3), GRID)


def test_breakdown_gives_each_clip_position_its_own_metrics():
    # two arm simulations (wind_level -1) x clips 0, 1; only the clip-0 predictions are right
    labels = torch.tensor([0, 0, 53, 53])
    logits = _logits([0, 5, 53, 50])
    meta = [{"wind_level": -1, "clip_index": k} for k in (0, 1, 0, 1)]
    out = breakdown_metrics(logits, labels, meta, GRID)
    assert set(out) == {"by_clip_index"}  # one wind level: no wind breakdown
    first, second = out["by_clip_index"]["0"], out["by_clip_index"]["1"]
    assert first["clips"] == second["clips"] == 2
    assert first["acc"] == 1.0 and second["acc"] == 0.0
    assert second["stretch_acc"] == 1.0 and second["bend_mae"] == pytest.approx((5 + 3) / 2)
    wind = [{"wind_level": w, "clip_index": 0} for w in (2, 0, 2, 1)]
    assert list(breakdown_metrics(logits, labels, wind, GRID)) == ["by_wind_level"]
    assert list(breakdown_metrics(logits, labels, wind, GRID)["by_wind_level"]) == ["0", "1", "2"]


def test_material_scores_are_positions_in_the_stiffness_ordering():
    probs = torch.nn.functional.one_hot(torch.tensor([0, 13, 53]), 54).double()
    scores = material_scores(probs, GRID)
    assert scores["material_score"].tolist() == [0, 13, 53]
    assert scores["stretch_score"].tolist() == [0, 1, 5]
    assert scores["bend_score"].tolist() == [0, 4, 8]
    uniform = material_scores(torch.full((1, 54), 1 / 54, dtype=torch.float64), GRID)
    assert uniform["material_score"].item() == pytest.approx(26.5)
    assert uniform["bend_score"].item() == pytest.approx(4.0)


def test_correlation_matches_scipy_and_bootstrap_brackets_it():
    rng = np.random.default_rng(0)
    x = rng.normal(size=30)
    y = 0.7 * x + rng.normal(scale=0.6, size=30)
    c = correlate(x, y, rounds=500, seed=1)
    assert c.pearson == pytest.approx(stats.pearsonr(x, y)[0])
    assert c.spearman == pytest.approx(stats.spearmanr(x, y)[0])
    assert c.pearson_ci[0] < c.pearson < c.pearson_ci[1]
    assert c.spearman_ci[0] < c.spearman < c.spearman_ci[1]
    assert correlate(x, y, rounds=500, seed=1) == c  # seeded
    perfect = correlate(x, 3 * x + 1, rounds=100)
    assert perfect.pearson == pytest.approx(1.0) and perfect.pearson_ci[0] == pytest.approx(1.0)


def test_undefined_correlations_are_none_not_nan():
    assert correlate([1.0, 2.0], [3.0, 4.0]).pearson is None
    constant = correlate([1.0, 1.0, 1.0, 1.0], [1.0, 2.0, 3.0, 4.0])
    assert constant.pearson is None and constant.spearman_ci is None
    with pytest.raises(ValueError, match="finite"):
        correlate([1.0, np.nan, 2.0], [1.0, 2.0, 3.0])


def test_grouped_bootstrap_counts_fabrics_not_videos():
    """Three identical videos per fabric carry the information of one: with the fabric as
    group, r, intervals and p-values equal those of the 10 fabrics alone; treating the 30
    videos as independent would give narrower intervals and smaller p-values."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=10)
    y = 0.6 * x + rng.normal(scale=0.8, size=10)
    fabrics = correlate(x, y, rounds=400, seed=2)
    videos = np.repeat(x, 3), np.repeat(y, 3)
    grouped = correlate(
        *videos, groups=np.repeat([f"fabric{i}" for i in range(10)], 3), rounds=400, seed=2
    )
    assert (grouped.count, grouped.group_count) == (30, 10)
    for field in ("pearson", "pearson_p", "spearman", "spearman_p"):
        assert getattr(grouped, field) == pytest.approx(getattr(fabrics, field)), field
    for field in ("pearson_ci", "spearman_ci"):
        assert getattr(grouped, field) == pytest.approx(getattr(fabrics, field)), field
    naive = correlate(*videos, rounds=400, seed=2)
    assert naive.group_count == 30 and naive.pearson_p < grouped.pearson_p
    assert np.ptp(naive.pearson_ci) < 0.8 * np.ptp(grouped.pearson_ci)
    # ungrouped p-values are scipy's
    assert fabrics.pearson_p == pytest.approx(stats.pearsonr(x, y)[1])
    assert fabrics.spearman_p == pytest.approx(stats.spearmanr(x, y)[1])
    # fewer than 3 groups: r is defined, intervals and p-values are not
    few = correlate(videos[0][:6], videos[1][:6], groups=[0, 0, 0, 1, 1, 1], rounds=50)
    assert few.pearson is not None and few.pearson_ci is None and few.pearson_p is None


def test_metrics_and_scores_follow_the_grid_they_are_given():
    grid = ClassGrid.from_json(
        {"stretch_multipliers": [1, 2], "bend_multipliers": [1, 2, 4], "num_classes": 6}
    )
    assert (grid.num_classes, grid.stretch_count, grid.bend_count) == (6, 2, 3)
    scores = material_scores(torch.nn.functional.one_hot(torch.tensor([0, 4, 5]), 6).double(), grid)
    assert scores["stretch_score"].tolist() == [0, 1, 1]
    assert scores["bend_score"].tolist() == [0, 1, 2]
    logits = torch.zeros(2, 6)
    logits[0, 5], logits[1, 1] = 1.0, 1.0  # true 2 = (0, 2) -> 5 = (1, 2); true 1 -> 1
    m = classification_metrics(logits, torch.tensor([2, 1]), grid)
    assert (m["acc"], m["bend_acc"], m["stretch_mae"]) == (0.5, 1.0, 0.5)
    with pytest.raises(ValueError, match=r"probs must have shape \(N, 6\)"):
        material_scores(torch.zeros(1, 54), grid)
    with pytest.raises(ValueError, match="counts"):
        ClassGrid.from_json({**grid.to_json(), "num_classes": 54})
    with pytest.raises(ValueError, match="class_grid must have stretch_multipliers"):
        ClassGrid.from_json({"num_classes": 6})
    assert ClassGrid.from_json(GRID.to_json()) == GRID and GRID.num_classes == 54


def test_a_density_axis_adds_density_metrics_and_a_density_score():
    grid = ClassGrid((1.0, 2.0), (1.0, 3.0), (0.5, 1.0, 2.0))  # ids (s * 2 + b) * 3 + d
    assert grid.position(7) == (1, 0, 1) and grid.class_id(1, 1, 2) == 11
    assert ClassGrid.from_json(grid.to_json()) == grid
    assert "density_count" not in GRID.to_json() and ClassGrid.from_json(GRID.to_json()) == GRID
    with pytest.raises(ValueError, match="counts"):
        ClassGrid.from_json({**grid.to_json(), "density_count": 1})
    # true (s, b, d): 7 -> (1,0,1), 2 -> (0,0,2); predicted 8 -> (1,0,2), 2 exact
    labels = torch.tensor([7, 2])
    logits = torch.zeros(2, 12)
    logits[0, 8] = logits[1, 2] = 1.0
    m = classification_metrics(logits, labels, grid)
    assert (m["acc"], m["stretch_acc"], m["bend_acc"], m["density_acc"]) == (0.5, 1.0, 1.0, 0.5)
    assert m["density_mae"] == pytest.approx(0.5) and m["grid_mae"] == pytest.approx(0.5)
    assert "density_acc" not in classification_metrics(_logits([0]), torch.tensor([0]), GRID)
    probs = torch.nn.functional.one_hot(torch.tensor([7, 2, 11]), 12).double()
    scores = material_scores(probs, grid)
    assert scores["density_score"].tolist() == [1, 2, 2]
    assert scores["stretch_score"].tolist() == [1, 0, 1]
    assert scores["bend_score"].tolist() == [0, 0, 1]
    assert correlated_scores(grid)[-1] == "density_score"
    assert "density_score" not in material_scores(torch.full((1, 54), 1 / 54), GRID)
    assert "density_score" not in correlated_scores(GRID)
