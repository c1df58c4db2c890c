"""The controller learns the robot it drives: its motors' lag fitted online with the link's
latency (core.controller.link_estimate, controller.estimate_motors), on MuJoCo robots with
drawn imperfections, 100 ms of link latency nobody told and a disturbance present.
"""

import functools
import math
from pathlib import Path

import numpy as np
import pytest
from test_link_estimate import driven_robot
import yaml

from curve_formation.core.config.loading import build_experiment, with_start
from curve_formation.core.config.starts import seeded_start
from curve_formation.core.controller.link_estimate import (
    estimate_latency,
    MOTOR_EXCITATION,
    TURN_SCALE,
)
from curve_formation.core.sim import pipeline
from curve_formation.core.world.mujoco_world import MujocoWorld, SERVO_LAG
from curve_formation.paths import resolve_config


# The MuJoCo robots' imperfections of docs/physics-results.md (benchmarks/physics.py)
IMPERFECTIONS = {'wheel_radius_mismatch': 0.03, 'motor_gain_spread': 0.1, 'dead_band': 0.05,
                 'command_bits': 8, 'battery_sag': 0.1}
# The MuJoCo motors (core.world.mujoco_world): physics.motor_time_constant (50 ms) is a
# first-order lag of 40 ms (FIRST_ORDER) followed by a wheel servo critically damped at
# SERVO_LAG (5 ms), whose double pole adds 10 ms of delay: its step response reaches 63 % at
# 52 ms. A fit of a latency and a first-order lag takes the servo's part as latency.
MOTOR_LAG = 0.05
FIRST_ORDER = MOTOR_LAG - 2 * SERVO_LAG


@pytest.mark.parametrize('latency, tau', [(0.0, 0.05), (0.1, 0.05), (0.1, 0.1), (0.3, 0.03)])
def test_the_motors_lag_and_the_latency_are_told_apart_from_a_robots_motion(latency, tau):
    """A robot under wandering commands through a link `latency` s late and motors with a
    first-order lag `tau` and a drift, its poses exact: the fit over (latency, lag) finds
    both within 5 ms, where a fit of the latency alone takes the lag for latency. (With a
    camera's noise, 0.2 mm and 3 mrad, these smooth commands split the two poorly:
    docs/link.md.)
    """
    robot = driven_robot(latency, motor_time_constant=tau, seconds=20.0, noise=(0.0, 0.0))
    found = estimate_latency(*robot, motor_time_constant=None)
    assert abs(found.latency - latency) <= 0.005, found
    assert abs(found.motor_time_constant - tau) <= 0.005, found
    alone = estimate_latency(*robot)
    assert alone.latency - latency > 0.5 * tau, alone


def imperfect_case(name, seed, swinging=False, told=None):
    """Experiment `name` from random start `seed` on MuJoCo robots with IMPERFECTIONS,
    nothing told about them, the controllers estimating latency and motors' lag online (a
    motor lag `told`, if given); swinging: the file's disturbance varies +-50 % in a 10 s
    sine.
    """
    path = resolve_config(name)
    data = yaml.safe_load(Path(path).read_text())
    data['physics'] = {'engine': 'mujoco', 'imperfections': {**IMPERFECTIONS, 'seed': seed}}
    data['controller'].update(estimate_latency=True, estimate_motors=True)
    if told is not None:
        data['limits']['motor_time_constant'] = told
    if swinging:
        data['disturbance']['varies'] = [{'kind': 'sine', 'amplitude': 0.5, 'period': 10.0}]
    case = build_experiment(data, str(path))
    return with_start(case, seeded_start(case, seed))


def learnt(experiment, latency, seconds=20.0, noise=(0.0, 0.0)):
    """The pipeline's controllers after `seconds` of the experiment with a link `latency`
    s late (told nobody), its poses off by Gaussian `noise` (m, rad), and the result.
    """
    made = []

    class Recorded(pipeline.Pipeline):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)

    original = pipeline.Pipeline
    pipeline.Pipeline = Recorded
    try:
        result = pipeline.simulate_pipeline(experiment, 'mujoco', duration=seconds,
                                            link=pipeline.Link(command_latency=latency,
                                                              pose_noise=noise))
    finally:
        pipeline.Pipeline = original
    return made[0].controllers, result


@pytest.mark.parametrize('swinging', [False, True], ids=['constant', 'swinging'])
def test_each_controller_learns_its_motors_lag_and_latency_within_10_s(swinging):
    """arena_demo's robots with imperfections (unequal wheels, motor spread, dead band, 8-bit
    commands, battery sag), 50 ms motors and a link 100 ms late, neither told, the file's
    drift on the robots constant or swinging: every controller whose commands changed by
    MOTOR_EXCITATION in its first 10 s (most; a robot on one long straight trip tells
    nothing and keeps none) takes a motor lag within 10 s, and after 20 s holds one within
    15 ms of the motors' first-order lag (FIRST_ORDER), a latency within 20 ms of the
    link's, and the two together within 15 ms of the link's and the motors' whole delay (the
    servo's part in the latency), in the metrics as estimated_motor_time_constant.
    """
    controllers, result = learnt(imperfect_case('arena_demo', 1, swinging), 0.1)
    excited = []
    for i in range(result.commands.shape[1]):   # its commands from its first that drives
        sent = result.commands[:, i]
        driving = np.flatnonzero(np.abs(sent).max(axis=1) > 0)[0]
        early = sent[driving:][result.t[driving:] < result.t[driving] + 10.0]
        excited.append(max(np.ptp(early[:, 0]), np.ptp(early[:, 1]) * TURN_SCALE)
                       >= MOTOR_EXCITATION)
    excited = np.array(excited)
    assert excited.sum() >= 7, excited
    for c, told in zip(controllers, excited, strict=True):
        if not told:
            assert c.motor_time_constant == 0.0 and not c.robot.link.motor_taken
            continue
        first = c.robot.link.motor_taken[0][0] if c.robot.link.motor_taken else None
        assert first is not None and first <= 10.0, (c.config.index, c.robot.link.motor_taken)
        assert abs(c.motor_time_constant - FIRST_ORDER) <= 0.015, (c.config.index,
                                                                  c.robot.link.motor_taken)
        assert abs(c.latency - 0.1) <= 0.02, (c.config.index, c.robot.link.taken)
        whole = c.latency + c.motor_time_constant
        assert abs(whole - (0.1 + MOTOR_LAG)) <= 0.015, (c.config.index, whole)
    assert result.motor_lags == [c.motor_time_constant for c in controllers]


def test_a_cameras_noise_leaves_the_online_estimates_true_or_untold():
    """As above with a camera's noise on the poses (0.2 mm, 3 mrad at 30 Hz), 40 s: every
    controller that took a lag holds one within 15 ms of the motors' and a latency within
    20 ms of the link's; wheel gains and dead bands are told only where right (within 3 %,
    20 %). Measured: none is told at that noise (their standard errors 3 to 9 % over 60 s;
    docs/limitations.md), so the observer goes on taking the wheels' spread as drift.
    """
    from curve_formation.core.world.mujoco_world import draw_robots
    experiment = imperfect_case('arena_demo', 1)
    robots = draw_robots(experiment)
    true = robots.wheel_gains
    band = experiment.spec.physics.imperfections.dead_band * experiment.limits.max_wheel_speed
    controllers, _ = learnt(experiment, 0.1, seconds=40.0, noise=(0.0002, 0.003))
    took = [c for c in controllers if c.robot.link.motor_taken]
    assert len(took) >= 7, [c.config.index for c in took]
    for c in took:
        assert abs(c.motor_time_constant - FIRST_ORDER) <= 0.015, (c.config.index,
                                                                  c.robot.link.motor_taken)
        assert abs(c.latency - 0.1) <= 0.02, (c.config.index, c.robot.link.taken)
    for c in controllers:
        i = c.config.index
        if c.robot.wheel_gains is not None:
            np.testing.assert_allclose(c.robot.wheel_gains, true[i - 1], rtol=0.03)
        for _, value in c.robot.band.taken:
            assert abs(value - band) <= 0.2 * band, (i, c.robot.band.taken, band)


def test_a_told_motor_lag_wins_over_the_estimate():
    """limits.motor_time_constant told (80 ms, wrong for these 50 ms motors) with
    estimate_motors: every controller keeps the told value; the latency is still estimated.
    """
    controllers, _ = learnt(imperfect_case('arena_demo', 1, told=0.08), 0.1, seconds=8.0)
    assert all(c.motor_time_constant == 0.08 and not c.robot.link.motor_taken for c in controllers)
    assert any(c.robot.link.taken for c in controllers)


def test_the_mujoco_world_leaves_the_experiments_disturbance_as_it_was():
    """A varying disturbance on the robots handed to the MuJoCo world each tick changes the
    world's, never the experiment's own (it once did: the sine compounded every tick and the
    robots spun).
    """
    experiment = imperfect_case('arena_demo', 1, swinging=True)
    before = np.array(experiment.disturbance, float)
    world = MujocoWorld(experiment)
    world.advance(0.0)
    for t in np.arange(0.1, 1.0, 0.1):
        for i, d in enumerate(experiment.disturbance_at(t)):
            world.disturb(i, d)
        world.advance(t)
    np.testing.assert_array_equal(experiment.disturbance, before)
    np.testing.assert_allclose(experiment.disturbance_at(2.5), before * 1.5)


def test_the_wheel_gains_told_online_are_within_3_percent():
    """arena_demo's imperfect robots (wheel radii within 3 %, motor gains within 10 %), the
    link 100 ms late, nothing told, starts 1-3: after 40 s about half the controllers tell
    their wheels' gains (speed per unit of command; a wheel whose commands hardly vary
    beyond the drift tells none; over starts 1-6: 4, 3, 7, 5, 4 and 3 of 9), each within
    3 % of the robot's drawn radius times motor gain, and the metrics carry them, each
    robot's in robot_estimates with its bound (3 standard errors, within which the drawn
    gains lie) and its source, with the latency's and the motors' lag's.
    """
    from curve_formation.core.record.metrics import result_metrics
    from curve_formation.core.world.mujoco_world import draw_robots
    counted = 0
    for seed in (1, 2, 3):
        experiment = imperfect_case('arena_demo', seed)
        robots = draw_robots(experiment)
        true = robots.wheel_gains
        controllers, result = learnt(experiment, 0.1, seconds=40.0)
        told = {c.config.index: c.robot.wheel_gains for c in controllers
                if c.robot.wheel_gains is not None}
        counted += len(told)
        for i, gains in told.items():
            np.testing.assert_allclose(gains, true[i - 1], rtol=0.03,
                                       err_msg=f'start {seed} robot {i}')
        metrics = result_metrics(result)
        assert [g is not None for g in metrics['estimated_wheel_gains']] == [
            c.robot.wheel_gains is not None for c in controllers]
        reported = metrics['robot_estimates']
        assert list(reported) == [f'robot_{c.config.index}' for c in controllers]
        for i, found in enumerate(reported.values()):
            if found['wheel_gains'] is None:
                assert found['wheel_gains_from'] is None and found['wheel_gains_bound'] is None
                continue
            assert found['wheel_gains_from'] == 'online', found
            off = np.abs(np.subtract(found['wheel_gains'], true[i]))
            assert (off <= found['wheel_gains_bound']).all(), (seed, i + 1, found, true[i])
            for name in ('command_latency', 'motor_time_constant'):
                assert found[f'{name}_from'] == 'online' and found[f'{name}_bound'] > 0.0, found
    assert counted >= 12, counted   # of 27


def test_gains_fitted_through_a_lag_in_doubt_are_not_kept():
    """mona_arena seed 3's imperfect robots, a link 100 ms late, nothing told, 40 s: two
    robots first take a lag 20 ms long (its latency as short: the fits trade them) and fitted
    through it their wheels' gains came out 4 to 6 % high, told with errors under 1 %. Gains
    are fitted again with the lag and latency traded by the lag's bound either way and told
    only within GAIN_ERROR of that too; not before the lag has a bound; and those found are
    dropped once a fit doubts them so or the lag moves by LAG_MOVED: every gain held at the
    end lies within its reported bound of the drawn one.
    """
    from curve_formation.core.controller.wheel_estimate import LAG_MOVED, NO_GAINS, WheelGains
    from curve_formation.core.record.metrics import result_metrics
    from curve_formation.core.world.mujoco_world import draw_robots
    experiment = imperfect_case('mona_arena', 3)
    robots = draw_robots(experiment)
    true = robots.wheel_gains
    controllers, result = learnt(experiment, 0.1, seconds=40.0)
    reported = result_metrics(result)['robot_estimates']
    held = 0
    for i, found in enumerate(reported.values()):
        if found['wheel_gains'] is None:
            continue
        held += 1
        off = np.abs(np.subtract(found['wheel_gains'], true[i]))
        assert (off <= found['wheel_gains_bound']).all(), (i + 1, found, true[i])
    assert held >= 5, reported
    # the lag moved from the one the gains were fitted through: dropped
    wheels = controllers[0].robot.wheels
    wheels.found = WheelGains((1.0, 1.0), (0.001, 0.001), 0.0, 50, through=(0.1, 0.06))
    wheels.moved(0.1, 0.06 - 0.5 * LAG_MOVED)
    assert wheels.found.gains == (1.0, 1.0)
    wheels.moved(0.1, 0.04)
    assert wheels.found == NO_GAINS


def test_the_wheels_are_sent_their_commands_divided_by_their_gains_within_the_limits():
    """Gains estimated (left 1.05, right 0.95): each wheel is asked its speed over its gain,
    so the motion is the one wanted; where that would pass the wheel or turn limits both
    wheels are scaled down together; without gains, or standing, the command is as it was;
    wheels faster than nominal are used to the full where the law asks for its fastest.
    """
    from curve_formation.core.controller.agent_config import AgentConfig
    from curve_formation.core.controller.gains import Gains
    from curve_formation.core.controller.limits import WheelLimits
    from curve_formation.core.controller.robot_model import RobotModel
    from curve_formation.core.controller.wheel_estimate import WheelGains
    from curve_formation.core.formation.dynamics import body_from_wheels, wheel_speeds

    limits = WheelLimits(wheel_base=0.08, max_wheel_speed=0.05, max_angular_rate=1.0)
    model = RobotModel(AgentConfig(index=1, agent_count=1, neighbours=(),
                                   gains=Gains(1.0, 0.5, 0.1), limits=limits,
                                   estimate_motors=True))
    assert model.compensated(0.02, 0.1) == (0.02, 0.1)   # no gains yet
    model.wheels.found = WheelGains((1.05, 0.95), (0.001, 0.001), 0.001, 100)
    v, w = model.compensated(0.02, 0.1)
    left, right = wheel_speeds(v, w, limits.wheel_base)
    done = body_from_wheels(1.05 * left, 0.95 * right, limits.wheel_base)
    np.testing.assert_allclose(done, (0.02, 0.1))
    v, w = model.compensated(0.05, 0.0)   # the right wheel would be asked 0.0526 m/s
    left, right = wheel_speeds(v, w, limits.wheel_base)
    assert max(abs(left), abs(right)) == pytest.approx(0.05)
    assert right / left == pytest.approx(1.05 / 0.95)   # the same motion's direction
    _, w = model.compensated(0.0, 1.0)
    assert abs(w) <= 1.0 + 1e-12
    assert model.compensated(0.0, 0.0) == (0.0, 0.0)
    # both wheels fast (1.05, 1.04): asked for its fastest the robot gets what its wheels
    # give, 4 % over nominal, straight, no command past the limit; at 90 % of it and below
    # (FULL_FROM), the motion asked, and between the two no jump
    model.wheels.found = WheelGains((1.05, 1.04), (0.001, 0.001), 0.001, 100)

    def made(v, w):   # as AgentController: the law's motion realised, then compensated
        promised = model.realised(v, w, (v, w), (0.0, 0.0))[:2]
        left, right = wheel_speeds(*model.compensated(*promised), limits.wheel_base)
        assert max(abs(left), abs(right)) <= limits.max_wheel_speed + 1e-12
        given = np.array(body_from_wheels(1.05 * left, 1.04 * right, limits.wheel_base))
        # the wheels give what realised promised the observer, across the ramp too
        np.testing.assert_allclose(given, promised, atol=1e-12)
        return given

    np.testing.assert_allclose(made(0.05, 0.0), (0.052, 0.0), atol=1e-12)
    np.testing.assert_allclose(made(0.045, 0.0), (0.045, 0.0), atol=1e-12)
    np.testing.assert_allclose(made(0.02, 0.1), (0.02, 0.1), atol=1e-12)
    speeds = [made(v, 0.0)[0] for v in np.linspace(0.04, 0.05, 101)]
    # steps of 0.1 mm/s asked: at most 0.3 mm/s made (a jump to the full speed: 2 mm/s)
    assert (np.diff(speeds) > 0.0).all() and np.diff(speeds).max() < 0.0003
    v, w, reference, shift = model.realised(0.05, 0.0, (0.05, 0.0), (0.0, 0.0))
    np.testing.assert_allclose([v, w, *reference, *shift], [0.052, 0.0, 0.052, 0.0, 0.002, 0.0],
                               atol=1e-12)


@pytest.mark.parametrize('gains', [(1.0, 0.9), (0.9, 1.0)])
def test_the_observer_takes_a_slow_wheels_missing_speed_for_no_disturbance(gains):
    """Gains known (one wheel 10 % slow) and a saturated approach: each command divided by
    the gains is scaled down into the wheel limits, and the observer expects the motion the
    wheels then give, so it learns no disturbance (it would take the slow wheel's missing
    10 % for one and carry it, a push on, to the target); the robot closes in meanwhile.
    """
    from test_agent import circle, config, THIRDS

    from curve_formation.core.controller.agent import AgentController
    from curve_formation.core.controller.gains import Gains
    from curve_formation.core.controller.limits import WheelLimits
    from curve_formation.core.controller.wheel_estimate import WheelGains
    from curve_formation.core.formation.dynamics import body_from_wheels, wheel_speeds

    limits = WheelLimits(0.08, 0.0225)
    ctrl = AgentController(config(index=1, agent_count=3, neighbours=(), limits=limits,
                                  gains=Gains(1.0, 0.5, 0.1, law='observer', observer_rate=5.0),
                                  estimate_motors=True))
    ctrl.set_curve(circle(), 0, THIRDS)
    ctrl.robot.wheels.found = WheelGains(gains, (0.001, 0.001), 0.001, 100)
    ctrl.robot.wheels.update = lambda *_: None   # the gains held as found
    x, y, theta = 0.75, 0.0, 0.0   # 0.25 m inside its target, heading to it
    wheels_real, learnt = [], []
    for k in range(60):   # 6 s at 10 Hz, poses at 30 Hz
        t = 10.0 + 0.1 * k
        ctrl.on_pose(x, y, theta, t)
        if k == 0:
            start = np.hypot(*ctrl.own_error())   # m
        tick = ctrl.tick(t + 0.001)
        assert tick.stopped is None
        left, right = wheel_speeds(tick.v, tick.w, limits.wheel_base)
        assert max(abs(left), abs(right)) <= limits.max_wheel_speed + 1e-12
        wheels_real.append(max(abs(left), abs(right)))
        learnt.append(np.hypot(*ctrl.dhat))
        v, w = body_from_wheels(gains[0] * left, gains[1] * right, limits.wheel_base)
        for step in range(3):
            for _ in range(10):
                x, y = x + v * math.cos(theta) / 300, y + v * math.sin(theta) / 300
                theta += w / 300
            if step < 2:
                ctrl.on_pose(x, y, theta, t + (step + 1) / 30)
    assert max(wheels_real) == pytest.approx(limits.max_wheel_speed)   # saturated
    # m/s: nothing learnt (expecting the motion wanted, it learnt the 2.25 mm/s missing
    # over k2: 4.5e-3)
    assert max(learnt) < 1e-4, max(learnt)
    assert np.hypot(*ctrl.own_error()) < start - 0.1   # m: it drove on


@functools.cache
@functools.cache
def banded_run(swinging, seed=1):
    """(experiment, controllers, result, logs) of 70 s of arena_demo start `seed` on
    imperfect MuJoCo robots, a link 100 ms late, nothing told (shared by the dead band's
    tests, which only read it); logs: {robot model: ([(t, v, w) sent], [(t, x, y, theta)
    seen])} over the whole run.
    """
    return logged_run(imperfect_case('arena_demo', seed, swinging), 70.0)


def logged_run(experiment, seconds):
    """(experiment, controllers, result, logs) of `seconds` of the experiment, a link 100 ms
    late; logs: {robot model: ([(t, v, w) sent], [(t, x, y, theta) seen])}.
    """
    from curve_formation.core.controller.robot_model import RobotModel
    logs = {}
    sent, seen = RobotModel.sent, RobotModel.seen

    def log_sent(model, now, v, w):
        logs.setdefault(model, ([], []))[0].append((now, v, w))
        sent(model, now, v, w)

    def log_seen(model, taken, x, y, theta):
        logs.setdefault(model, ([], []))[1].append((taken, x, y, theta))
        seen(model, taken, x, y, theta)

    RobotModel.sent, RobotModel.seen = log_sent, log_seen
    try:
        controllers, result = learnt(experiment, 0.1, seconds=seconds)
    finally:
        RobotModel.sent, RobotModel.seen = sent, seen
    return experiment, controllers, result, logs


@pytest.mark.xdist_group('banded_run')   # one worker: banded_run's cache shared
@pytest.mark.parametrize('swinging', [False, True], ids=['constant', 'swinging'])
def test_the_motors_dead_band_is_found_online_within_20_percent(swinging):
    """arena_demo's imperfect robots (a dead band of 5 % of the fastest wheel speed among
    the rest), a link 100 ms late, nothing told, 70 s: with the file's drift constant, about
    half the controllers take a dead band (two fits in a row agreeing), each within 20 % of
    the drawn one but for one robot at most, within 2x (over 20 starts of each arena file 6
    and 12 of the bands taken were outside 20 %, up to 1.9x: docs/link.md; on this start,
    as the other robots' use of their gains changed, robot 5 once took 1.5x at 55 s, its
    fit's least squares there clearly at 1.4-1.5x); under a drift
    swinging +-50 % while the robots stand (which the fit cannot follow) none that is off by
    more; the metrics carry each.
    """
    from curve_formation.core.record.metrics import result_metrics
    experiment, controllers, result, _ = banded_run(swinging)
    band = experiment.spec.physics.imperfections.dead_band * experiment.limits.max_wheel_speed
    taken = {c.config.index: c.robot.band.taken for c in controllers if c.robot.band.taken}
    if not swinging:   # 4 to 6 of 9 on this start as the runs changed (7 on seed 3)
        assert len(taken) >= 4, taken
    off = {i: found for i, found in taken.items()
           if any(abs(value - band) > 0.2 * band + 1e-12 for _, value in found)}
    assert len(off) <= (0 if swinging else 1), (off, band)
    assert all(value <= 2.0 * band for found in off.values() for _, value in found), (off, band)
    metrics = result_metrics(result)
    assert metrics['estimated_dead_band'] == [c.robot.band.band for c in controllers]


def test_the_estimate_of_a_robot_commanded_within_its_dead_band_does_not_wind_up():
    """A robot that never moves (its pose the same each tick) while the law asks for motion:
    the paper's law integrates its error into the estimate without bound, unless the
    commands leave its motors idle in a dead band (told, or estimated: limits.min_wheel_speed
    or controller.estimate_motors), where the estimate holds; the observer law learns
    nothing inside a band, and outside one its estimate stops where the wheel limits cut
    the command.
    """
    from test_agent import circle, config, THIRDS

    from curve_formation.core.controller.agent import AgentController
    from curve_formation.core.controller.gains import Gains
    from curve_formation.core.controller.limits import WheelLimits

    def estimate_after(law, band, seconds):
        cfg = config(index=1, agent_count=3, neighbours=(), limits=WheelLimits(0.08, 0.0225),
                     min_wheel_speed=band, gains=Gains(1.0, 0.5, 0.1, law=law))
        ctrl = AgentController(cfg)
        ctrl.set_curve(circle(), 0, THIRDS)
        for k in range(int(seconds * 30)):
            t = 10.0 + k / 30
            ctrl.on_pose(0.9, 0.1, 0.3, t)   # 0.2 m from its target, never moving
            if k % 3 == 0:
                assert ctrl.tick(t + 0.001).stopped is None
        return np.hypot(*ctrl.dhat)

    # above the fastest wheel speed: every command leaves the motors idle
    assert estimate_after('paper', 0.03, 60.0) == 0.0
    assert estimate_after('paper', 0.0, 60.0) > 2.0 * estimate_after('paper', 0.0, 30.0) - 1e-3
    assert estimate_after('observer', 0.03, 60.0) == 0.0
    held = estimate_after('observer', 0.0, 30.0)
    assert held > 0.0 and estimate_after('observer', 0.0, 60.0) == pytest.approx(held)


@pytest.mark.xdist_group('banded_run')   # one worker: banded_run's cache shared
def test_measure_link_finds_the_dead_band_in_a_bag_and_prints_the_line(tmp_path, capsys):
    """The commands and poses of the dead band test's robots (constant drift, 70 s, starts 1
    and 2) written to a bag with arena_demo's experiment: measure-link finds a band for
    about half the robots (over starts 1-5: 3, 5, 8, 6 and 5 of 9), each within 20 % of the
    drawn one but for one robot a start at most, within 2x (as online: the test above),
    each with its bound, and prints the limits line to tell it.
    """
    import json

    from curve_formation.cli import main
    counted = 0
    for seed in (1, 2):
        experiment, controllers, _, logs = banded_run(False, seed)
        band = (experiment.spec.physics.imperfections.dead_band
                * experiment.limits.max_wheel_speed)
        bag = logged_bag(tmp_path / f'bag{seed}', experiment, controllers, logs)
        capsys.readouterr()
        assert main(['measure-link', str(bag), '--json', str(tmp_path / 'link.json')]) == 0
        found = json.loads((tmp_path / 'link.json').read_text())
        bands = {i: r['dead_band'] for i, r in found['robots'].items() if r['dead_band']}
        counted += len(bands)
        off = {i: value for i, value in bands.items()
               if abs(value - band) > 0.2 * band + 1e-12}
        assert len(off) <= 1 and all(v <= 2.0 * band for v in off.values()), (off, band)
        # each with its bound, in the JSON and the table
        assert all(0.0 < found['robots'][i]['dead_band_bound'] < 0.5 * v
                   for i, v in bands.items())
        out = capsys.readouterr().out
        if bands:
            assert 'limits: {min_wheel_speed: 0.00' in out
        rows = [line.split() for line in out.splitlines() if line[:5].strip() in bands]
        assert len(rows) == len(bands) and all(row[-2] == '+-' for row in rows), out
    assert counted >= 7, counted   # of 18


@pytest.mark.xdist_group('banded_run')   # one worker: banded_run's cache shared
def test_measure_link_prints_each_robots_own_band_into_its_fleet(tmp_path, capsys):
    """The dead band test's bag (arena_demo start 1, 70 s) with a robots.fleet in its
    experiment: measure-link prints that fleet, each entry as written with its robot's own
    dead band (as in its table and JSON) put in where it found one, ready to paste; where
    the experiment lists no fleet, one line per robot that has a band instead.
    """
    import json

    from curve_formation.cli import main
    experiment, controllers, _, logs = banded_run(False)
    data = yaml.safe_load(Path(experiment.source).read_text())
    links = [{'marker': i, 'link': f'udp:127.0.0.1:{9000 + i}', 'replies': False}
             for i in range(1, 10)]
    data['robots']['fleet'] = links
    bag = logged_bag(tmp_path / 'bag', experiment, controllers, logs, yaml.safe_dump(data))
    capsys.readouterr()
    assert main(['measure-link', str(bag), '--json', str(tmp_path / 'link.json')]) == 0
    out = capsys.readouterr().out
    robots = json.loads((tmp_path / 'link.json').read_text())['robots']
    printed = yaml.safe_load(out[out.index('robots:\n  fleet:'):])['robots']['fleet']
    assert len(printed) == 9
    banded = 0
    for i, (entry, written) in enumerate(zip(printed, links, strict=True), start=1):
        assert {k: entry[k] for k in written} == written   # the entry as written
        band = robots[str(i)]['dead_band']
        if band is None:
            assert entry == written
            continue
        banded += 1   # rounded to 0.01 mm/s
        assert entry['min_wheel_speed'] == pytest.approx(band, abs=1e-5)
    assert banded >= 1
    # no fleet in the experiment: a line per robot with a band
    plain = logged_bag(tmp_path / 'plain', experiment, controllers, logs)
    assert main(['measure-link', str(plain)]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines()
             if line.startswith('robot ') and 'min_wheel_speed' in line]
    assert len(lines) == banded, lines


def logged_bag(path, experiment, controllers, logs, text=None):
    """A bag at `path` of logged_run's commands and poses with the experiment (its file's
    text, or `text`): path.
    """
    from geometry_msgs.msg import Twist
    from rclpy.serialization import serialize_message

    from curve_formation.bags.analysis import EXPERIMENT_KEY
    from curve_formation.bags.bag import BagWriter, qos
    from curve_formation.nodes.messages import pose_to_msg
    start = 1_000_000_000.0
    with BagWriter(path) as writer:
        for c in controllers:
            i = c.config.index
            writer.add_topic(f'/robot_{i}/cmd_vel', 'geometry_msgs/msg/Twist', qos())
            writer.add_topic(f'/robot_{i}/pose', 'geometry_msgs/msg/PoseStamped', qos())
            commands, poses = logs[c.robot]
            for t, v, w in commands:
                msg = Twist()
                msg.linear.x, msg.angular.z = float(v), float(w)
                writer.write(f'/robot_{i}/cmd_vel', (start + t) * 1e9, serialize_message(msg))
            for t, x, y, theta in poses:
                writer.write(f'/robot_{i}/pose', (start + t + 0.01) * 1e9,
                             serialize_message(pose_to_msg(x, y, theta, start + t)))
        writer.set_custom(EXPERIMENT_KEY, text or Path(experiment.source).read_text())
    return path
