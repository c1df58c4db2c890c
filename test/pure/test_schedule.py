"""The curve schedule both the curve server and the nodes' pipeline step
(core.schedule.curve_schedule).
"""

import numpy as np
import pytest

from conftest import DATA_DIR
from curve_formation.core.config.experiment import ANNOUNCE_AHEAD
from curve_formation.core.config.loading import load_experiment
from curve_formation.core.formation.assignment import nearest_order, timed_order
from curve_formation.core.schedule.curve_schedule import CurveSchedule


@pytest.fixture
def begins_to_move(tmp_path):
    """moving_loop with a still first curve: the same curve begins to move at 1.5 s."""
    text = (DATA_DIR / 'moving_loop.yaml').read_text()
    moving = '    motion: {velocity: [0.01, 0.0]}\n'
    still = text.split('curves:\n')[1].split(moving)[0]
    path = tmp_path / 'begins_to_move.yaml'
    path.write_text(text.replace(moving, still.replace('  - basis', '  - start: 1.5\n    basis')
                                 + moving))
    return load_experiment(path)


def test_nothing_is_due_before_the_run_begins_then_each_curve_at_its_start():
    experiment = load_experiment(DATA_DIR / 'nearest_switch.yaml')
    schedule = CurveSchedule(experiment)
    assert schedule.due(100.0) == [] and schedule.next_due() is None
    schedule.begin(10.0)
    first, = schedule.due(10.0)
    assert first.curve_id == 0 and first.clock.run_time == 0.0 and first.rate is None
    np.testing.assert_array_equal(first.s, experiment.phases[0].s)
    switch_at = 10.0 + experiment.phases[1].start
    assert schedule.next_due() == switch_at and schedule.due(switch_at - 1e-6) == []
    second, = schedule.due(switch_at + 0.3)   # a timer called late publishes it then
    assert second.curve_id == 1 and second.clock.valid_at == switch_at + 0.3
    assert schedule.next_due() is None
    followed = schedule.close()
    assert [p.index for p in followed] == [0, 1]


def test_a_curve_that_only_begins_to_move_is_announced_ahead_dated_to_its_start(
        begins_to_move):
    schedule = CurveSchedule(begins_to_move)
    schedule.begin(0.0)
    still, = schedule.due(0.0)
    assert schedule.next_due() == pytest.approx(1.5 - ANNOUNCE_AHEAD)
    assert schedule.renewal(1.0) is None   # nothing moves yet
    moving, = schedule.due(1.5 - ANNOUNCE_AHEAD)
    assert moving.curve_id == 1 and moving.clock.valid_at == 1.5 and moving.rate is not None
    assert schedule.renewal(1.4) is None   # announced: still until it begins
    renewed = schedule.renewal(2.5)
    assert renewed.curve_id == 1 and renewed.clock.moving_for == pytest.approx(1.0)
    # moved 1 s at 0.01 m/s in x
    np.testing.assert_allclose(renewed.curve.points(renewed.s) - still.curve.points(still.s),
                               [[0.01, 0.0]] * begins_to_move.n, atol=1e-9)
    np.testing.assert_allclose(schedule.targets, renewed.curve.points(renewed.s))


def test_without_the_look_ahead_a_moving_curve_begins_when_published(begins_to_move):
    schedule = CurveSchedule(begins_to_move, announce_ahead=0.0)
    schedule.begin(0.0)
    schedule.due(0.0)
    assert schedule.due(1.4) == []
    moving, = schedule.due(1.6)
    assert moving.clock.valid_at == 1.6 and schedule.renewal(1.6).clock.moving_for == 0.0


def test_re_assigned_targets_keep_the_id_and_the_next_switch_assigns_from_them():
    experiment = load_experiment(DATA_DIR / 'nearest_switch.yaml')
    schedule = CurveSchedule(experiment)
    schedule.begin(0.0)
    first, = schedule.due(0.0)
    # every agent is where another's target is: a cyclic shift of the targets
    points = np.roll(first.curve.points(first.s), 1, axis=0)
    again = schedule.reassign(points, 2.0)
    assert again.curve_id == 0 and not np.array_equal(again.s, first.s)
    np.testing.assert_allclose(again.curve.points(again.s), points, atol=1e-9)
    assert schedule.reassign(points, 3.0) is None   # already so
    second, = schedule.due(experiment.phases[1].start)
    assert second.curve_id == 1
    expected = experiment.switched_to(experiment.phases[1], True, points)
    np.testing.assert_array_equal(second.s, expected.s)
    first_followed, _ = schedule.close()
    (when, s, _), = first_followed.changes
    assert when == 2.0 and np.array_equal(s, again.s)


def test_an_observed_curve_takes_over_with_the_next_id_and_stops_a_moving_one(begins_to_move):
    schedule = CurveSchedule(begins_to_move, scheduled=False)
    assert schedule.due(5.0) == []
    observed = schedule.observed(begins_to_move.phases[1].curve, begins_to_move.phases[1].s,
                                 3.0)
    assert observed.curve_id == 0 and observed.clock.run_time is None   # before the run began
    schedule = CurveSchedule(begins_to_move)
    schedule.begin(0.0)
    schedule.due(2.0)
    assert schedule.renewal(2.0) is not None
    observed = schedule.observed(begins_to_move.phases[0].curve, begins_to_move.phases[0].s,
                                 2.5)
    assert observed.curve_id == 2 and schedule.renewal(3.0) is None


def test_known_top_speeds_assign_each_curve_by_trip_time_from_where_the_robots_are():
    """Told the robots' control points and top speeds before the start, the first curve goes
    to them by trip time from there (timed_order: here much shorter than by distance; a
    robot not heard from at the wheels' limit); told points but no speeds, or speeds all
    alike, it is as loaded (from the file's start); the second curve is assigned from the
    first's targets through timed_order too.
    """
    experiment = load_experiment(DATA_DIR / 'nearest_switch.yaml')
    first, second = experiment.phases
    rng = np.random.default_rng(3)
    points = rng.uniform(-4.0, 4.0, (6, 2))
    speeds = np.array([2.0, 0.6, np.nan, 1.2, 2.0, 0.9])   # m/s; the limit is 2
    weighed = np.where(np.isnan(speeds), 2.0, speeds)
    for told, expected in ((None, first.s), (np.full(6, 1.5), first.s),
                           (speeds, first.s[timed_order(points, first.targets, weighed)])):
        schedule = CurveSchedule(experiment)
        schedule.robots_now(points, told)
        schedule.begin(0.0)
        published, = schedule.due(0.0)
        np.testing.assert_array_equal(published.s, expected)
    # the speeds decide here: by distance from the same points the order differs
    assert not np.array_equal(expected, first.s[nearest_order(points, first.targets)])
    schedule.robots_now(rng.uniform(-4.0, 4.0, (6, 2)), speeds)   # points unused: too late
    then, = schedule.due(second.start)
    there = first.curve.points(expected)
    np.testing.assert_array_equal(
        then.s, second.s[timed_order(there, second.targets, weighed)])
