"""Moving curves: the similarity motion, its coefficients' rate, and the feed-forward that keeps
a formation on a curve translating at 1 cm/s.
"""

import dataclasses

import numpy as np
import pytest

from conftest import DATA_DIR
from curve_formation.core.config.loading import load_experiment
from curve_formation.core.formation.curve_codec import CurveClock
from curve_formation.core.formation.motion import CurveMotion
from curve_formation.core.record.metrics import run_metrics
from curve_formation.core.record.received_phases import received_phases
from curve_formation.core.sim.batch import simulate
from curve_formation.paths import resolve_config


@pytest.fixture(scope='module')
def moving():
    return load_experiment(resolve_config('moving_curve'))


@pytest.mark.parametrize('phase', [0, 1])
def test_a_moved_curve_is_the_moved_points_and_its_rate_their_velocity(phase):
    curve = load_experiment(resolve_config('drawn_curve')).phases[phase].curve
    motion = CurveMotion((0.01, -0.02), 0.3, -0.05, (0.9, 0.4))
    s = np.linspace(0, 1, 50)
    for tau in (0.0, 1.7, 6.0):
        np.testing.assert_allclose(motion.curve(curve, tau).points(s),
                                   motion.points(curve.points(s), tau), atol=1e-12)
        h = 1e-6
        numeric = (motion.curve(curve, tau + h).points(s)
                   - motion.curve(curve, tau - h).points(s)) / (2 * h)
        np.testing.assert_allclose(motion.rate(curve, tau).points(s), numeric, atol=1e-8)
        np.testing.assert_allclose(motion.velocities(curve.points(s), tau), numeric, atol=1e-8)


def test_the_time_a_moved_curve_has_moved_for_is_found_from_the_curve_alone():
    curve = load_experiment(resolve_config('drawn_curve')).phases[0].curve
    motion = CurveMotion((0.01, -0.02), 0.3, -0.05, (0.9, 0.4))
    for tau in (0.05, 1.7, 6.0):
        assert motion.elapsed(curve, motion.curve(curve, tau), guess=tau + 0.4) == \
            pytest.approx(tau, abs=1e-6)
    assert motion.elapsed(curve, curve, guess=1.0) is None
    other = CurveMotion((0.0, 0.01)).curve(curve, 1.0)   # moved, but not by this motion
    assert motion.elapsed(curve, other, guess=1.0) is None
    assert CurveMotion().elapsed(curve, CurveMotion().curve(curve, 2.0), guess=2.0) is None


@pytest.mark.parametrize('late', [0.0, 0.3])
def test_a_moving_curve_received_late_is_judged_from_when_its_renewals_show_it_began(late):
    """A reader that gets a moving curve's first message `late` s after it was sent (seen:
    0.3 s, a late-joining monitor) and its 10 Hz renewals 1-20 ms after theirs: its phase
    starts `late` s before the first message, not at it (else every robot, on its moving
    target, reads `late` * 1 cm/s ahead of it).
    """
    experiment = load_experiment(DATA_DIR / 'moving_loop.yaml')
    phase = experiment.phases[0]
    lags = np.random.default_rng(0).uniform(0.001, 0.02, 40)
    sent = 0.1 * np.arange(40)
    got = sent - late + lags
    renewals = np.flatnonzero((sent > 0) & (got > 0))
    messages = [(0.0, 0, phase.curve, phase.s, None)]
    messages += [(got[k], 0, phase.motion.curve(phase.curve, sent[k]), phase.s, None)
                 for k in renewals]
    received, = received_phases(experiment, messages)
    assert received.start == pytest.approx(min(0.0, (got - sent)[renewals].min()), abs=1e-5)
    assert received.motion == phase.motion and not received.changes


@pytest.mark.parametrize('first', [0, 7])
def test_a_dated_moving_curve_starts_when_its_clock_says_whatever_the_arrivals(first):
    """Messages carrying their clock (CurveClock: valid at, moving for) date the motion's
    start exactly, whatever their delays, even for a reader whose first message is the 7th
    renewal (it is still known as the schedule's phase, with its motion).
    """
    experiment = load_experiment(DATA_DIR / 'moving_loop.yaml')
    phase = experiment.phases[0]
    began = 2.5   # s, on the reader's time scale
    sent = began + 0.1 * np.arange(first, 40)
    got = sent + np.random.default_rng(1).uniform(0.001, 0.05, len(sent))
    messages = [(got[k], 0, phase.motion.curve(phase.curve, sent[k] - began), phase.s,
                 CurveClock(sent[k], sent[k] - began)) for k in range(len(sent))]
    received, = received_phases(experiment, messages)
    assert received.start == pytest.approx(began, abs=1e-12)
    assert received.motion == phase.motion and not received.changes
    np.testing.assert_allclose(received.curve.xi, phase.curve.xi, atol=1e-15)
    assert received.fit == phase.fit   # the schedule's curve, residuals known


def test_the_next_phase_is_assigned_from_where_the_moving_curve_left_its_targets(moving):
    still, carried = moving.phases
    assert carried.motion is not None and carried.motion.velocity == (0.01, 0.0)
    np.testing.assert_allclose(carried.motion.about, still.curve.sample(400)[1].mean(axis=0))


def steady_errors(experiment, feed_forward, window=20.0):
    spec = experiment.spec.model_copy(update={'controller': experiment.spec.controller
                                              .model_copy(update={'feed_forward': feed_forward})})
    result = simulate(dataclasses.replace(experiment, spec=spec))
    late = result.t > result.t[-1] - window
    return np.linalg.norm(result.errors[late], axis=2).max(axis=0), result


def test_feed_forward_keeps_the_formation_on_a_curve_moving_at_1_cm_per_s(moving):
    """The loop translating at 1 cm/s from 60 s: with the feed-forward every robot ends on its
    moving target (under 2 mm; measured 1e-12), without it each one trails by v / k1 = 15 mm.
    """
    with_ff, result = steady_errors(moving, True)
    without, _ = steady_errors(moving, False)
    assert with_ff.max() < 0.002
    np.testing.assert_allclose(without, 0.01 / moving.gains.k1, rtol=0.05)
    assert result.contacts['count'] == 0
    # evenly spread along the curve where it is, not where it started (40 cm to the left)
    carried = run_metrics(result.experiment, result.t, result.poses, result.phase
                          )['phases'][1]
    assert carried['spacing']['cv'] == pytest.approx(carried['target_spacing']['cv'], abs=1e-6)


def test_a_curve_that_would_move_out_of_the_arena_is_refused():
    from curve_formation.core.config.errors import ConfigError
    from curve_formation.core.config.loading import build_experiment
    from curve_formation.core.config.safe_yaml import load
    text = resolve_config('moving_curve').read_text()
    assert 'velocity: [0.01, 0.0]' in text
    data = load(text.replace('velocity: [0.01, 0.0]', 'velocity: [0.02, 0.0]'))
    with pytest.raises(ConfigError, match=r'curves\[1\]: the curve leaves the arena by t = '
                       r'100 s, moving .* x 0\.27\.\.1\.91,'):
        build_experiment(data, 'fast.yaml')
