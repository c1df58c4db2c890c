"""The one sampler of a run's record (core.record.sampling) and the one phase index
(core.config.experiment.phase_index), shared by the live monitor, the bag analysis and the
simulators.
"""

import numpy as np
import pytest

from curve_formation.core.config.experiment import phase_index
from curve_formation.core.record.sampling import GridSampler, LatestValues


def latest_before(events, at, width):
    """Reference: the value of the last event at or before `at`, NaN before any."""
    value = np.full(width, np.nan)
    for t, v in events:
        if t <= at:
            value = np.asarray(v, float)
    return value


def test_grid_rows_hold_each_robots_latest_value_at_or_before_the_row_time():
    rng = np.random.default_rng(4)
    n, hz, t0, end = 3, 20.0, 10.0, 12.0
    # some of them exactly at row times
    times = np.sort(np.r_[rng.uniform(9.0, 12.5, 300), 10.0, 10.05, 10.1, 11.0])
    events = [(t, int(rng.integers(1, n + 1)), str(rng.choice(['pose', 'cmd'])),
               tuple(rng.normal(size=3))) for t in times]
    latest = LatestValues(n)
    sampler = GridSampler(latest, hz)
    sampler.start(t0)
    for t, i, kind, v in events:
        sampler.until(t)
        if kind == 'pose':
            latest.pose(i, *v, t - 0.01)
        else:
            latest.command(i, *v[:2])
    record = sampler.finish(end)
    grid = t0 + np.arange(0.0, end - t0, 1.0 / hz)
    np.testing.assert_allclose(record['t'], grid - t0)
    for r, at in enumerate(grid):
        for i in range(1, n + 1):
            poses = [(t, v) for t, j, kind, v in events if j == i and kind == 'pose']
            cmds = [(t, v[:2]) for t, j, kind, v in events if j == i and kind == 'cmd']
            np.testing.assert_array_equal(record['poses'][r, i - 1], latest_before(poses, at, 3))
            np.testing.assert_array_equal(record['commands'][r, i - 1],
                                          latest_before(cmds, at, 2))
            stamps = [(t, (t - 0.01 - t0,)) for t, _ in poses]
            np.testing.assert_allclose(record['pose_stamps'][r, i - 1],
                                       latest_before(stamps, at, 1)[0])
    assert np.isnan(record['dhat']).all()


def test_values_before_t0_carry_into_the_first_row_and_rows_stop_before_the_end():
    latest = LatestValues(1)
    sampler = GridSampler(latest, 10.0)
    sampler.until(0.5)               # before start(): no row
    latest.command(1, 0.01, 0.2)
    sampler.start(1.0)
    sampler.until(1.35)
    record = sampler.finish(1.2)     # rows at 1.0 and 1.1; the one at 1.2 and after dropped
    np.testing.assert_allclose(record['t'], [0.0, 0.1])
    np.testing.assert_allclose(record['commands'][:, 0], [[0.01, 0.2], [0.01, 0.2]])


@pytest.mark.parametrize('pose', [(5.0, 0.0, 0.0), (0.0, 0.0, np.nan), (np.inf, 0.0, 0.0)])
def test_a_pose_the_controllers_would_refuse_is_not_taken_and_is_counted(pose):
    latest = LatestValues(2, fence=(-1.0, -1.0, 1.0, 1.0))
    assert latest.pose(1, 0.5, 0.5, 0.1, 3.0)
    assert not latest.pose(1, *pose, 4.0)
    assert latest.refused == 1
    np.testing.assert_array_equal(latest.poses[0], [0.5, 0.5, 0.1])
    assert latest.pose_stamps[0] == 3.0 and np.isnan(latest.poses[1]).all()


def test_a_row_is_a_copy_that_later_values_do_not_change():
    latest = LatestValues(1)
    latest.estimate(1, 0.1, 0.2)
    row = latest.row(5.0, 2.0)
    latest.estimate(1, 0.3, 0.4)
    assert row['t'] == 3.0 and tuple(row['dhat'][0]) == (0.1, 0.2)


def test_the_phase_followed_is_the_last_begun_by_then():
    starts = [0.0, 2.0, 5.0]
    t = np.array([-1.0, 0.0, 1.99, 2.0, 4.0, 5.0, 9.0])
    np.testing.assert_array_equal(phase_index(starts, t), [0, 0, 0, 1, 1, 2, 2])
    np.testing.assert_array_equal(phase_index([3.0], t), np.zeros(len(t)))
