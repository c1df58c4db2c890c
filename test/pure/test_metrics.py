import numpy as np
import pytest

from curve_formation.core.formation.curve_sources import expression_samples
from curve_formation.core.formation.curves import fit_curve, FourierBasis
from curve_formation.core.record import body_metrics, metrics


def test_settle_time_is_last_entry_below_tolerance():
    t = np.arange(10.0)
    norm = np.array([5, 3, 0.5, 2, 0.4, 0.3, 0.2, 0.1, 0.1, 0.1])
    assert metrics.settle_time(t, norm, 1.0, 0.0, np.inf) == 4.0
    assert metrics.settle_time(t, norm, 1.0, 2.0, np.inf) == 2.0   # relative to start
    assert metrics.settle_time(t, norm, 0.05, 0.0, np.inf) is None  # never below
    assert metrics.settle_time(t, norm, 10.0, 0.0, np.inf) == 0.0
    assert metrics.settle_time(t, norm, 1.0, 0.0, 4.0) is None      # window ends above


def test_a_dip_below_the_tolerance_just_before_the_end_is_not_settling():
    """An error rippling about the tolerance that happens to be below it in the last samples
    has not settled: the stretch below must last `hold` s before the window's end (run_metrics
    asks settle_hold: 5 s, or a tenth of a shorter phase).
    """
    t = np.arange(0.0, 60.0, 0.1)
    norm = 1.0 + 0.2 * np.cos(2 * np.pi * t / 10.0)   # above 1 for 5 s in every 10
    norm[t >= 59.3] = 0.9
    assert metrics.settle_time(t, norm, 1.0, 0.0, np.inf) == pytest.approx(59.3)
    assert metrics.settle_time(t, norm, 1.0, 0.0, np.inf, hold=5.0) is None
    norm[t >= 50.0] = 0.9   # below for the last 10 s: settled at 50 s
    assert metrics.settle_time(t, norm, 1.0, 0.0, np.inf, hold=5.0) == pytest.approx(50.0)
    assert metrics.settle_hold(0.0, 60.0) == 5.0 and metrics.settle_hold(0.0, 8.0) == 0.8


def circle():
    s, pts = expression_samples('cos(2*pi*s)', 'sin(2*pi*s)', 100, closed=True)
    return fit_curve(FourierBasis(1), s, pts).curve


def test_spacing_uniformity():
    curve = circle()
    even = curve.points(np.arange(6) / 6)
    assert metrics.spacing_uniformity(curve, even)['cv'] == pytest.approx(0, abs=1e-3)
    bunched = curve.points(np.array([0, 0.05, 0.1, 0.5]))
    result = metrics.spacing_uniformity(curve, bunched)
    assert result['cv'] > 0.5 and result['min_over_max'] == pytest.approx(0.1, abs=0.01)


def test_orientation_rates():
    t = np.linspace(0, 5, 501)
    poses = np.zeros((501, 2, 3))
    poses[:, 1, 2] = np.mod(0.7 * t, 2 * np.pi)   # wraps, still 0.7 rad/s
    np.testing.assert_allclose(metrics.orientation_rates(t, poses), [0, 0.7], atol=1e-9)


def test_peak_wheel_speed():
    commands = np.array([[[0.01, 0.2], [-0.02, 0.0]]])
    out = metrics.peak_speeds(commands, 0.1)
    assert out['peak_wheel_speed'] == pytest.approx(0.02)
    assert out['peak_w'] == pytest.approx(0.2)


def test_closest_approach_finds_the_nearest_pair_over_time():
    from curve_formation.core.record.body_metrics import closest_approach
    poses = np.zeros((3, 3, 3))
    poses[:, 1, 0] = [1.0, 0.3, 0.8]
    poses[:, 2, 1] = [2.0, 2.0, 0.5]
    assert closest_approach(poses) == (pytest.approx(0.3), 1)


def test_a_reversing_robot_is_measured_by_the_point_it_steers():
    """controller.reverse: a robot backing onto its target steers the point behind its axle;
    its error is that point's, not the 2 l of the point ahead (which it is without reverse).
    """
    from curve_formation.core.controller.gains import Gains
    offset = 0.01
    poses = np.array([[[0.5, 0.2, 0.0], [0.1, 0.1, np.pi / 2]]])   # (R=1, n=2, 3)
    targets = np.array([[[0.49, 0.2], [0.1, 0.11]]])   # behind robot 1, ahead of robot 2
    forwards = Gains(1.0, 0.0, offset)
    both = Gains(1.0, 0.0, offset, reverse=True)
    ahead = metrics.steered_points(poses, targets, forwards) - targets
    np.testing.assert_allclose(np.linalg.norm(ahead, axis=-1), [[2 * offset, 0.0]], atol=1e-12)
    steered = metrics.steered_points(poses, targets, both) - targets
    np.testing.assert_allclose(steered, 0.0, atol=1e-12)


def test_the_longest_standstill_away_from_the_target_is_found_with_its_robot_and_end():
    """Robot 1 stands 2 s far from its target, then 3 s more at it; robot 0 stands 1 s far
    from its target: the longest wait is robot 1's 2 s, ending at 3 s. Standing at the
    target, or driving, does not count.
    """
    t = np.arange(0.0, 8.01, 0.1)
    poses = np.zeros((len(t), 2, 3))
    poses[:, 0, 0] = 0.01 * t                                  # robot 0 drives...
    poses[(t >= 4.0) & (t <= 5.0), 0, 0] = 0.04                  # ...but stands 1 s
    poses[t > 5.0, 0, 0] = 0.04 + 0.01 * (t[t > 5.0] - 5.0)
    poses[:, 1, 1] = np.where(t < 1.0, 0.01 * t, 0.01)            # robot 1 stops at 1 s
    errors = np.full((len(t), 2), 0.5)
    errors[t > 3.0, 1] = 0.0                                      # its target comes to it
    seconds, robot, end = body_metrics.longest_standstill(t, poses, errors)
    assert robot == 1
    assert seconds == pytest.approx(2.0)
    assert end == pytest.approx(3.0)
    none = body_metrics.longest_standstill(t, poses, np.zeros_like(errors))
    assert none[0] == 0.0 and none[1] == -1
