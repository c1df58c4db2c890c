"""The MuJoCo world: a robot with mass, motors and casters moves as the unicycle it is
commanded as (no slip), its motors lag by their time constant, its imperfections are
physical, and contacts come from the engine's contact list.
"""

import math

import numpy as np
import pytest

from curve_formation.core.config.loading import build_experiment, load_experiment
from curve_formation.core.formation.dynamics import arc_step
from curve_formation.core.world.mujoco_world import MujocoWorld


def two_robots(poses=((0.5, 0.4, 0.3), (1.5, 0.4, 0.0)), physics=None, radius=0.04):
    """Two Mona robots in the 1.8 m x 0.8 m arena, no disturbance."""
    return build_experiment({
        'name': 'two', 'agents': {'count': 2, 'initial': {'poses': [list(p) for p in poses]}},
        'graph': {'leader': 1, 'edges': [{'from': 1, 'to': 2}]},
        'controller': {'law': 'observer', 'k1': 0.5, 'k2': 0.5, 'offset': 0.01,
                       'rate_hz': 10.0},
        'limits': {'wheel_base': 0.08, 'max_wheel_speed': 0.0225},
        'arena': {'size': [1.8, 0.8]}, 'robots': {'radius': radius},
        'physics': {'engine': 'mujoco', **(physics or {})},
        'curves': [{'basis': 'polynomial', 'order': 1, 'x': '0.5 + s', 'y': '0.4'}],
        'simulation': {'duration': 10.0}})


@pytest.mark.parametrize('v, w', [(0.02, 0.0), (0.02, 0.2), (0.0, 0.5), (0.01, -0.3),
                                  (-0.015, 0.1)])
def test_constant_wheel_speeds_trace_the_unicycle_arc_within_one_percent(v, w):
    """After the motors' start-up, 10 s at constant (v, w) end where the unicycle's exact
    arc ends: position within 1 % of the distance the wheels rolled, heading within 1 % of
    the turn.
    """
    world = MujocoWorld(two_robots())
    world.advance(0.0)
    world.command(0, v, w, 0.0)
    world.advance(1.0)
    start = world.poses()[0]
    world.advance(11.0)
    end = world.poses()[0]
    expected = arc_step(*start, v, w, 10.0)
    rolled = 10.0 * (abs(v) + 0.04 * abs(w))
    assert math.dist(end[:2], expected[:2]) < 0.01 * rolled
    assert abs(end[2] - expected[2]) <= max(0.01 * abs(w) * 10.0, 1e-3)
    assert world.contact_summary()['count'] == 0


@pytest.mark.parametrize('tau', [0.05, 0.12])
def test_a_wheel_step_response_shows_the_configured_motor_time_constant(tau):
    """A step of the wheel speed command: the wheel reaches 63 % of it at the motors' time
    constant (within 10 %), and all of it within 5 time constants.
    """
    world = MujocoWorld(two_robots(physics={'motor_time_constant': tau}))
    world.advance(0.0)
    world.command(0, 0.02, 0.0, 0.0)
    target = 0.02 / 0.015
    times, speeds = [], []
    t = 0.0
    while t < 6 * tau:
        t += world.dt
        world.advance(t)
        times.append(world.time)
        speeds.append(world.wheel_speeds()[0].mean())
    speeds = np.array(speeds)
    rise = times[int(np.argmax(speeds >= (1 - math.exp(-1)) * target))]
    assert rise == pytest.approx(tau, rel=0.10)
    assert speeds[-1] == pytest.approx(target, rel=0.01)


def test_robots_driven_into_each_other_and_a_wall_are_counted_by_the_engine():
    """Two robots head-on: one robot-robot contact, a push, a negative smallest gap; a third
    driven into the east wall: one robot-wall contact, and it stays at the wall.
    """
    world = MujocoWorld(two_robots(poses=((0.8, 0.4, 0.0), (1.0, 0.4, math.pi))))
    world.advance(0.0)
    world.command(0, 0.02, 0.0, 0.0)
    world.command(1, 0.02, 0.0, 0.0)
    world.advance(4.0)
    summary = world.contact_summary()
    assert summary['count'] == 1 and summary['walls'] == 0
    assert summary['largest_push'] > 0.01 and summary['smallest_gap'] < 0
    assert summary['time'] > 0.5   # they met after 3 s and pushed on
    world = MujocoWorld(two_robots(poses=((1.7, 0.4, 0.0), (0.5, 0.4, 0.0))))
    world.advance(0.0)
    world.command(0, 0.02, 0.0, 0.0)
    world.advance(10.0)
    summary = world.contact_summary()
    assert summary['walls'] == 1 and summary['count'] == 0
    assert world.poses()[0, 0] == pytest.approx(1.8 - 0.04, abs=0.001)


def turn_rate(physics, v=0.02, seconds=10.0):
    """(turn rate rad/s, forward speed m/s) of robot 1 commanded straight at v (m/s)."""
    world = MujocoWorld(two_robots(physics=physics))
    world.advance(0.0)
    world.command(0, v, 0.0, 0.0)
    world.advance(1.0)
    start = world.poses()[0]
    world.advance(1.0 + seconds)
    end = world.poses()[0]
    return (end[2] - start[2]) / seconds, math.dist(end[:2], start[:2]) / seconds, world


def test_unequal_wheels_and_motor_gains_turn_a_robot_commanded_straight_as_physics_says():
    """3 % wheel radius mismatch and 10 % motor gain spread: a straight command turns the
    robot at the rate its wheels' ground speeds give, (right - left) / wheel base.
    """
    imperfect = {'wheel_radius_mismatch': 0.03, 'motor_gain_spread': 0.1, 'seed': 3}
    w, speed, world = turn_rate({'imperfections': imperfect})
    (r_left, r_right), (g_left, g_right) = world.robots.wheel_radii[0], world.robots.gains[0]
    omega = 0.02 / 0.015
    left, right = omega * g_left * r_left, omega * g_right * r_right
    assert abs(w) > 0.002   # a physical disturbance
    assert w == pytest.approx((right - left) / 0.08, rel=0.03)
    assert speed == pytest.approx(0.5 * (left + right), rel=0.03)


def test_a_dead_band_and_eight_bit_commands_act_as_firmware_would():
    """Commands below the dead band leave the motors off; above it a wheel runs at the
    command rounded to the nearest of 127 steps of the wheel limit.
    """
    imperfect = {'dead_band': 0.05, 'command_bits': 8}
    _, speed, _ = turn_rate({'imperfections': imperfect}, v=0.04 * 0.0225)
    assert speed < 1e-5
    _, speed, _ = turn_rate({'imperfections': imperfect}, v=0.0123)
    step = 0.0225 / 127
    assert speed == pytest.approx(round(0.0123 / step) * step, rel=0.005)
    assert abs(speed - 0.0123) > 0.0005 * 0.0123   # rounded, not as commanded


def test_a_sagging_battery_slows_the_motors_as_configured():
    """10 % per 10 minutes: after 5 minutes a straight command drives 5 % slower (measured
    over 10 s: a robot on two wheels rocks a little on its casters).
    """
    world = MujocoWorld(two_robots(physics={'imperfections': {'battery_sag': 0.1}}))
    world.advance(300.0)
    world.command(0, 0.02, 0.0, 300.0)
    world.advance(301.0)
    start = world.poses()[0]
    world.advance(311.0)
    speed = math.dist(world.poses()[0][:2], start[:2]) / 10.0
    assert speed == pytest.approx(0.02 * (1 - 0.1 * 306 / 600), rel=0.002)


def test_the_watchdog_and_latency_reach_the_motors():
    """A command acts its latency after it was received and the motors stop `timeout` after
    the last one (as the kinematic robots do).
    """
    world = MujocoWorld(two_robots(), latency=0.5, timeout=1.0)
    world.advance(0.0)
    world.command(0, 0.02, 0.0, 0.0)
    world.advance(0.45)
    assert abs(world.wheel_speeds()[0]).max() < 1e-3
    world.advance(1.4)
    assert world.wheel_speeds()[0].mean() > 1.0
    assert world.advance(3.0) == [0]
    assert abs(world.wheel_speeds()[0]).max() < 1e-3


def test_the_shipped_arena_builds_with_walls_and_every_robot():
    experiment = load_experiment('config/mona_arena.yaml')
    world = MujocoWorld(experiment)
    np.testing.assert_allclose(world.poses(), experiment.initial_poses, atol=1e-9)
    names = {world.model.geom(g).name for g in range(world.model.ngeom)}
    assert {'wall_west', 'wall_east', 'wall_south', 'wall_north'} <= names
    assert world.model.nu == 2 * experiment.n


def test_a_robot_lighter_than_its_wheels_is_refused_when_the_file_loads():
    from curve_formation.core.config.errors import ConfigError
    with pytest.raises(ConfigError, match='physics.mass'):
        two_robots(physics={'mass': 0.008})
