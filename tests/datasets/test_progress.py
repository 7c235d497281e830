"""Generation progress: the bar ticks per rendered clip and shows each unit's rollout."""

import multiprocessing

import pytest

from datasets.generation import _Progress, _queue_reports, _QueueReport, run_unit
from datasets.plan import plan_units

from .conftest import tiny_spec


@pytest.mark.render
def test_run_unit_reports_its_rollout_then_every_clip(tmp_path):
    spec = tiny_spec()
    unit = plan_units(spec)[0]
    reports = []
    run_unit(spec, unit, tmp_path, None, 1, report=lambda *message: reports.append(message))
    sims = [m for m in reports if m[0] == "sim"]
    clips = [m for m in reports if m[0] == "clip"]
    assert clips == [("clip", unit.index)] * (len(unit.sims) * spec.preset.clips_per_sim)
    steps, total = [m[2] for m in sims], sims[-1][3]
    assert len(sims) >= 10 and steps == sorted(steps) and steps[-1] == total
    assert reports.index(clips[0]) > reports.index(sims[-1])  # rendering follows the rollout


def test_bar_counts_clips_and_shows_rollouts_also_through_a_queue():
    spec = tiny_spec()
    units = plan_units(spec)
    progress = _Progress(spec, units, enabled=True)
    assert progress.bar.total == spec.clip_count == 6
    progress("sim", 0, 30, 60)
    progress("sim", 1, 15, 60)
    assert progress.bar.n == 0
    assert progress.bar.postfix == "unit 0 simulating 50%, unit 1 simulating 25%"
    progress("sim", 0, 60, 60)
    progress("clip", 0)
    assert progress.bar.n == 1 and progress.bar.postfix == "unit 1 simulating 25%"
    with multiprocessing.Manager() as manager:  # what worker processes report through
        queue = manager.Queue()
        report = _QueueReport(queue)
        report("clip", 0)
        report("clip", 1)
        queue.put(None)
        _queue_reports(queue, progress)
    assert progress.bar.n == 3
    progress.close()
