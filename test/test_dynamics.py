"""The driven unicycle the fake robots and the fake arena move: commands at their due time and
the robot-side watchdog.
"""

import numpy as np
import pytest

from curve_formation.core.dynamics import arc_step, DrivenUnicycle


@pytest.mark.parametrize('step', [0.01, 1 / 30, 0.25, 3.0])
def test_the_watchdog_stops_the_motors_at_its_time_whatever_the_callers_step(step):
    """One command, then silence: the robot drives exactly `timeout` s (after its latency) and
    stands still from then on, however coarsely advance() is called.
    """
    robot = DrivenUnicycle((0.0, 0.0, 0.0), disturbance=(0.005, 0.1), latency=0.2, timeout=1.0)
    robot.drive(0.05, 0.3, now=0.0)
    stops = []
    for t in np.arange(step, 5.0 + step / 2, step):
        stops.append(robot.advance(t))
    assert sum(stops) == 1                        # turned off once, reported once
    expected = arc_step(0.0, 0.0, 0.0, 0.055, 0.4, 1.0)   # driven from 0.2 s to 1.2 s
    np.testing.assert_allclose(robot.pose, expected, atol=1e-12)
    assert robot.command == (0.0, 0.0)


def test_a_command_in_time_keeps_the_robot_driving():
    robot = DrivenUnicycle((0.0, 0.0, 0.0), timeout=1.0)
    for t in np.arange(0.0, 3.0, 0.5):
        robot.drive(0.05, 0.0, now=t)
    assert not robot.advance(3.4)
    np.testing.assert_allclose(robot.pose, (0.05 * 3.4, 0.0, 0.0), atol=1e-12)
