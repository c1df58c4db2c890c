"""The e-stop's rules (core.controller.estop) and what a run's metrics say of it
(core.record.metrics).
"""

import math

import numpy as np
import pytest

from conftest import CONFIG_DIR
from curve_formation.core.config.loading import load_experiment
from curve_formation.core.controller.estop import (
    estop_fields,
    EstopLatch,
    parse_report,
    stopped_intervals,
    stopped_time,
)
from curve_formation.core.record import metrics
from curve_formation.core.sim.batch import simulate


def test_a_stop_holds_until_a_release_and_a_release_older_than_the_stop_is_ignored():
    latch = EstopLatch()
    assert latch.command(True, 10.0, '/pedal', now=10.01)
    assert latch.engaged and latch.by == '/pedal' and latch.since == 10.0
    assert not latch.command(True, 10.1, '/pedal', now=10.11)      # repeats change nothing
    # A release sent before the newest stop (a retransmission overtaken by a later stop).
    assert not latch.command(False, 10.05, '/cli', now=10.2)
    assert latch.engaged
    assert latch.command(False, 11.0, '/cli', now=11.0)
    assert not latch.engaged and latch.by == '/cli'


def test_a_peer_passes_on_a_newer_stop_but_never_undoes_a_newer_release():
    latch = EstopLatch()
    # a node that starts while the formation is stopped takes the stop up
    assert latch.peer(True, 5.0, '/cli', now=20.0)
    assert latch.engaged and latch.by == '/cli'
    assert latch.command(False, 21.0, '/cli', now=21.0)
    # a peer still announcing the stop of 5.0 s (it missed the release) changes nothing
    assert not latch.peer(True, 5.0, '/cli', now=21.5)
    assert not latch.engaged
    # a peer that got a newer stop first passes it on
    assert latch.peer(True, 22.0, '/pedal', now=22.01)
    assert latch.engaged
    # a peer's release never releases
    other = EstopLatch()
    other.command(True, 1.0, '/cli', now=1.0)
    assert not other.peer(False, 2.0, '/cli', now=2.0) and other.engaged


def test_stopped_intervals_join_every_holder_and_stay_open_until_the_last_release():
    events = [(1.0, 'a', False), (2.0, 'a', True), (2.01, 'b', True), (2.5, 'a', True),
              (5.0, 'a', False), (5.2, 'b', False), (7.0, 'b', True)]
    intervals = stopped_intervals(events, end=9.0)
    assert intervals == [(2.0, 5.2), (7.0, None)]
    assert stopped_time(intervals, 9.0) == pytest.approx(3.2 + 2.0)
    assert stopped_intervals([(1.0, 'a', False)], 9.0) == []


def test_an_e_stop_report_survives_its_text_fields_and_junk_is_refused():
    fields = estop_fields(True, 'formation_controller', '/cli', 12.5, 9, holders=11)
    report = parse_report('/robot_3/formation_controller', 'robot_3', fields)
    assert (report.engaged, report.robot, report.robots, report.since) == (True, 'robot_3', 9,
                                                                           12.5)
    assert report.holders == 11
    assert parse_report('/x', '', estop_fields(False, 'curve_server', '', -math.inf, 0)).since \
        == -math.inf
    for bad in ({'engaged': 'yes'}, {**fields, 'since': 'nan'}, {**fields, 'robots': '-1'},
                {**fields, 'robots': '9' * 400}, {**fields, 'since': 'inf'},
                {**fields, 'holders': 'many'}):
        with pytest.raises(ValueError, match='not an e-stop state'):
            parse_report('/x', '', bad)


@pytest.fixture(scope='module')
def settled_run():
    experiment = load_experiment(CONFIG_DIR / 'closed_curve.yaml')
    return simulate(experiment, duration=40.0)


def test_a_phase_interrupted_by_the_e_stop_settles_only_after_the_release(settled_run):
    r = settled_run
    plain = metrics.result_metrics(r)['phases'][0]
    assert plain['settled'] and plain['settle_time'] < 20.0
    held = metrics.run_metrics(r.experiment, r.t, r.poses, r.phase, estops=[(2.0, 25.0)])
    phase = held['phases'][0]
    assert phase['settled'] and phase['interrupted_by_estop']
    assert phase['settle_time'] >= 25.0
    assert held['estop'] == {'intervals': [[2.0, 25.0]], 'stopped_for': 23.0}
    still = metrics.run_metrics(r.experiment, r.t, r.poses, r.phase, estops=[(30.0, None)])
    assert not still['phases'][0]['settled'] and not still['all_settled']
    assert still['phases'][0]['not_settled_because'] == ('the e-stop was engaged at the end '
                                                         'of the phase')
    assert np.isclose(still['estop']['stopped_for'], r.t[-1] - 30.0)
    before = metrics.run_metrics(r.experiment, r.t, r.poses, r.phase, estops=[])
    assert before['phases'][0]['settle_time'] == plain['settle_time']
    assert not before['phases'][0]['interrupted_by_estop']
