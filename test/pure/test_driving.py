"""Driving backwards (controller.reverse): which way a robot drives, and what it saves."""

import math
import sys

import numpy as np
import pytest

from conftest import ROOT
from curve_formation.core.config.agents import agent_configs
from curve_formation.core.config.loading import load_experiment
from curve_formation.core.controller.agent import AgentController
from curve_formation.core.controller.driving import drive_direction, steered_law
from curve_formation.core.controller.gains import Gains
from curve_formation.core.controller.law import agent_command
from curve_formation.core.controller.limits import WheelLimits
from curve_formation.core.controller.safety import AVOIDANCE_OFF
from curve_formation.core.formation.dynamics import arc_step
from curve_formation.paths import resolve_config


MONA = WheelLimits(0.08, 0.0225)   # wheel base (m), wheel speed limit (m/s)


def reversing_law(reverse=True, on_pc=False):
    """The arena files' law at 10 Hz (finite-time tail included)."""
    return Gains(2 / 3, 1 / 3, 0.01, law='observer', sampled_heading=True, tail_radius=0.05,
                 tail_gain=3.0, reverse=reverse).tick_law(10.0, on_pc)


def test_a_robot_drives_backwards_only_to_a_target_well_behind_it():
    law = reversing_law()
    assert drive_direction(1.0, 0, 0, 0, -0.3, 0.02, 0.0, 0.0, law, MONA) == -1.0     # behind
    assert drive_direction(1.0, 0, 0, 0, 0.3, 0.02, 0.0, 0.0, law, MONA) == 1.0       # ahead
    assert drive_direction(-1.0, 0, 0, 0, 0.3, 0.02, 0.0, 0.0, law, MONA) == 1.0
    # Beside it both ways take as long: the current way is kept (hysteresis).
    for front in (1.0, -1.0):
        assert drive_direction(front, 0, 0, 0, 0.01, 0.3, 0.0, 0.0, law, MONA) == front
    # Near the target the choice is kept, whatever the bearing.
    assert drive_direction(1.0, 0, 0, 0, -0.04, 0.0, 0.0, 0.0, law, MONA) == 1.0
    # Off: forwards, as the paper; without wheel limits there is nothing to time it by.
    assert drive_direction(1.0, 0, 0, 0, -0.3, 0.0, 0.0, 0.0, reversing_law(False), MONA) == 1.0
    assert drive_direction(1.0, 0, 0, 0, -0.3, 0.0, 0.0, 0.0, law, WheelLimits()) == 1.0
    # A drift pushing the robot forwards at 80 % of the wheel limit (k2 dhat_v) makes
    # backwards five times slower: it turns round instead; added on the PC the law cancels
    # it before the limits, so it does not count.
    push = 0.8 * MONA.max_wheel_speed / law.k2
    assert drive_direction(1.0, 0, 0, 0, -0.3, 0.0, push, 0.0, law, MONA) == 1.0
    assert drive_direction(1.0, 0, 0, 0, -0.3, 0.0, push, 0.0, reversing_law(on_pc=True),
                           MONA) == -1.0
    # A negative offset l leads backwards: +1 drives backwards, -1 forwards.
    behind = steered_law(law, -1.0)
    assert drive_direction(1.0, 0, 0, 0, -0.3, 0.02, 0.0, 0.0, behind, MONA) == 1.0
    assert drive_direction(1.0, 0, 0, 0, 0.3, 0.02, 0.0, 0.0, behind, MONA) == -1.0


def lone_trip(target, reverse):
    """Seconds a lone Mona (no disturbance) needs from the origin, facing +x, until its
    steered point is within 1 mm of target (m): the tick pipeline at 10 Hz.
    """
    law, period = reversing_law(reverse), 0.1
    x = y = theta = 0.0
    front, last = 1.0, (0.0, 0.0)
    for k in range(600):
        front = drive_direction(front, x, y, theta, *target, 0.0, 0.0, law, MONA)
        steered = steered_law(law, front)
        ex = x + steered.offset * math.cos(theta) - target[0]
        ey = y + steered.offset * math.sin(theta) - target[1]
        if math.hypot(ex, ey) < 1e-3:
            return k * period
        v, w, *_ = agent_command(ex, ey, 0, 0, ex, ey, x, y, theta, 0, 0, *last, 0, 0,
                                 steered, MONA, np.zeros((0, 3)), 0, AVOIDANCE_OFF)
        last = (v, w)
        for _ in range(100):
            x, y, theta = arc_step(x, y, theta, v, w, period / 100)
    raise AssertionError('not there in 60 s')


@pytest.mark.parametrize('target', [(-0.3, 0.0), (-0.3, 0.05), (-0.2, -0.15)])
def test_driving_backwards_saves_the_half_turn_to_a_target_behind(target):
    """Forwards the robot first turns round (up to pi at both wheels' limit: 5.6 s for a
    Mona); backwards it turns only by what the target lies off straight behind, and arrives
    within 15 % of the fastest way there (that turn in place, then straight at the limit).
    """
    turn_rate = 2 * MONA.max_wheel_speed / MONA.wheel_base
    off_behind = math.pi - abs(math.atan2(target[1], target[0]))
    fastest = math.hypot(*target) / MONA.max_wheel_speed + off_behind / turn_rate
    backwards, forwards = lone_trip(target, True), lone_trip(target, False)
    assert backwards < 1.15 * fastest
    assert forwards > backwards + 0.6 * (math.pi - 2 * off_behind) / turn_rate
    assert lone_trip((0.3, 0.05), True) == lone_trip((0.3, 0.05), False)   # ahead: unchanged


def test_a_curves_first_pose_takes_the_sooner_way_outright():
    """Until the robot has turned for either way there is nothing for the hysteresis to
    keep: a target 98 degrees to its right (82 behind) is reached backwards, 0.5 s sooner,
    from a curve's first pose; on the way the choice holds until the other way is
    REVERSE_HYSTERESIS sooner; a new curve decides afresh.
    """
    law = reversing_law(on_pc=True)
    right = math.radians(-98.0)
    tx, ty = 0.3 * math.cos(right), 0.3 * math.sin(right)
    assert drive_direction(1.0, 0, 0, 0, tx, ty, 0.0, 0.0, law, MONA) == 1.0
    assert drive_direction(1.0, 0, 0, 0, tx, ty, 0.0, 0.0, law, MONA, 0.0) == -1.0
    experiment = load_experiment(resolve_config('mona_arena'))
    controller = AgentController(agent_configs(experiment, 10.0)[0])
    phase = experiment.phases[0]
    heading = 0.3

    def pose_with_target_at(bearing):
        """The robot's pose 30 cm from its target, which lies `bearing` (rad) off its heading."""
        tx, ty = controller.target
        way = heading + bearing
        return tx - 0.3 * math.cos(way), ty - 0.3 * math.sin(way), heading

    # Poses 10 s apart: a robot could drive from one to the next (a jump a robot cannot
    # make is rejected as a measurement, core.controller.plausibility).
    controller.set_curve(phase.curve, 0, phase.s)
    assert controller.on_pose(*pose_with_target_at(right), 0.0)
    assert controller.front == -1.0
    ahead = math.radians(82.0)   # forwards now 0.5 s sooner
    assert controller.on_pose(*pose_with_target_at(ahead), 10.0)
    assert controller.front == -1.0
    controller.set_curve(phase.curve, 0, phase.s)   # re-assigned: the same curve
    assert controller.on_pose(*pose_with_target_at(ahead), 20.0)
    assert controller.front == -1.0
    controller.set_curve(phase.curve, 1, phase.s)   # a new curve
    assert controller.on_pose(*pose_with_target_at(ahead), 30.0)
    assert controller.front == 1.0


def test_the_benchmarks_fastest_time_with_drift_turns_the_quicker_way_round():
    """benchmarks/collision_avoidance.fastest_with_drift, the estimate its table reports:
    without drift the turn-and-straight time; a turn drift to the left makes a right turn
    slower than the limit allows, and a long right turn quicker the other way round; a
    forward drift makes backwards slower than turning round.
    """
    sys.path.insert(0, str(ROOT / 'benchmarks'))
    from collision_avoidance import fastest_with_drift
    u, base = MONA.max_wheel_speed, MONA.wheel_base
    rate = 2 * u / base
    right = (0.0, -0.3)   # 30 cm to the right of a robot facing +x
    assert fastest_with_drift(right, 0.0, (0.0, 0.0), MONA, False) == pytest.approx(
        0.5 * math.pi / rate + 0.3 / u)
    straight = u - 0.5 * base * 0.1
    assert fastest_with_drift(right, 0.0, (0.0, 0.1), MONA, False) == pytest.approx(
        0.5 * math.pi / (rate - 0.1) + 0.3 / straight)
    # 170 degrees to its right: the left way round (190 degrees) is quicker with the drift.
    behind = (0.3 * math.cos(math.radians(-170)), 0.3 * math.sin(math.radians(-170)))
    assert fastest_with_drift(behind, 0.0, (0.0, 0.5), MONA, False) == pytest.approx(
        math.radians(190) / (rate + 0.5) + 0.3 / (u - 0.5 * base * 0.5))
    # Straight behind with a forward drift of half the limit: turning round is quicker
    # than backing at half the limit; without the drift, backing is.
    back = (-0.3, 0.0)
    assert fastest_with_drift(back, 0.0, (0.5 * u, 0.0), MONA, True) == pytest.approx(
        math.pi / rate + 0.3 / (1.5 * u))
    assert fastest_with_drift(back, 0.0, (0.0, 0.0), MONA, True) == pytest.approx(0.3 / u)
