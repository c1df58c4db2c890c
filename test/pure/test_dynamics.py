"""The driven unicycle the fake robots and the fake arena move: commands at their due time and
the robot-side watchdog.
"""

import numpy as np
import pytest

from curve_formation.core.formation.dynamics import arc_step, DrivenUnicycle


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


def test_the_kinematic_world_steps_at_once_only_where_no_contact_can_happen():
    """The kinematic world moves the robots over a pose period in one step while no two
    bodies nor a body and a wall can meet in it, and in physics_dt steps near a contact: two
    robots driven head-on meet and push each other exactly as with physics_dt steps
    throughout, in under half the steps.
    """
    from conftest import DATA_DIR
    from curve_formation.core.config.loading import load_experiment
    from curve_formation.core.world.kinematic import KinematicWorld
    experiment = load_experiment(DATA_DIR / 'arena_bodies.yaml')
    worlds = [KinematicWorld(experiment) for _ in range(2)]
    worlds[1]._apart_over = lambda span: False   # physics_dt steps throughout
    steps = []
    for world in worlds:
        count = []
        touch = world._touch
        world._touch = lambda step, touch=touch, count=count: (count.append(step), touch(step))
        t = 0.0
        world.advance(t)
        for _ in range(120):   # 4 s of 30 Hz pose periods, robots 1 and 4 head-on
            for i in (0, 3):
                world.command(i, 0.08, 0.0, t)
            t += 1 / 30
            world.advance(t)
        steps.append(len(count))
    at_once, fine = worlds
    np.testing.assert_allclose(at_once.poses(), fine.poses(), rtol=0, atol=1e-9)
    tallies = [world.contact_summary() for world in worlds]
    assert tallies[0]['count'] == tallies[1]['count'] == 1
    assert tallies[0]['time'] == pytest.approx(tallies[1]['time'])
    assert tallies[0]['smallest_gap'] == pytest.approx(tallies[1]['smallest_gap'], abs=1e-9)
    assert steps[0] < steps[1] / 2


def test_a_jittered_link_delays_each_command_its_own_way_but_never_reorders_them():
    """CommandQueue with latency 0.1 s and jitter +-0.03 s (as fake robots emulate Wi-Fi):
    every command acts 0.07-0.13 s after it came, or as soon as the one before it has, and
    the delays spread as a uniform draw does (std 0.017 s).
    """
    from curve_formation.core.formation.dynamics import CommandQueue
    queue = CommandQueue(latency=0.1, jitter=0.03, seed=4)
    sent = np.arange(0.0, 100.0, 0.1)
    for k, t in enumerate(sent):
        queue.push(float(k), 0.0, t)
    due = np.array([d for d, _, _ in queue.pending])
    assert (np.diff(due) >= 0).all()
    delays = due - sent
    assert delays.min() >= 0.07 - 1e-12 and delays.max() <= 0.13 + 1e-12
    assert np.std(delays) == pytest.approx(0.06 / np.sqrt(12), rel=0.1)
    steady = CommandQueue(latency=0.1)
    steady.push(1.0, 0.0, 5.0)
    assert [d for d, _, _ in steady.pending] == [5.1]
