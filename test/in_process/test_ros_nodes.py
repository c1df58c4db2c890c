"""Nodes in-process with a private Context and executor, spin loops bounded by deadlines."""

import time

from geometry_msgs.msg import Twist
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
import yaml

from cases import circle_curve
from conftest import DATA_DIR, no_history_qos
from curve_formation.core.config.loading import load_experiment
from curve_formation.core.controller.inputs import State
from curve_formation.interface import QosSpec
from curve_formation.nodes import messages, qos, topics
from curve_formation.nodes.curve_server import CurveServer
from curve_formation.nodes.estop import EstopHolder
from curve_formation.nodes.formation_controller import FormationController
from curve_formation.nodes.params import ParameterError
from curve_formation.nodes.readiness import ReadyReport
from curve_formation.nodes.runtime import WithMessageInfo


def overrides(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


class Probe:
    """A helper node: publishes poses/states/curves and records cmd_vel of one robot; holds
    the e-stop, released, as the curve server would (a controller drives only once it has
    heard the e-stop state, or after nodes.estop.HEAR_WAIT s alone).
    """

    def __init__(self, context, robot, skew=0.0):
        self.node = rclpy.create_node('probe', context=context)
        self.estop = EstopHolder(self.node)
        self.skew = skew   # s, how far the probe's stamps lag the controller's clock
        self.pose_pub = self.node.create_publisher(
            messages.PoseStamped, topics.robot_topic(robot, topics.POSE), qos.SENSOR)
        self.curve_pub = self.node.create_publisher(Float64MultiArray, topics.CURVE,
                                                    qos.LATCHED)
        self.state_pubs = {}
        self.commands = []
        self.node.create_subscription(Twist, topics.robot_topic(robot, topics.CMD_VEL),
                                      lambda m: self.commands.append(
                                          (time.monotonic(), m.linear.x, m.angular.z)),
                                      qos.COMMAND)

    def now(self):
        return self.node.get_clock().now().nanoseconds * 1e-9

    def state(self, j, error, curve_id=0):
        if j not in self.state_pubs:
            self.state_pubs[j] = self.node.create_publisher(
                JointState, topics.robot_topic(j, topics.STATE), qos.STATE)
        stamp = self.now() - self.skew
        self.state_pubs[j].publish(messages.state_to_msg(State(error, curve_id, stamp, 0.0)))


def test_late_starting_controller_still_receives_the_current_curve(ros, tmp_path):
    context, add, spin_until = ros
    server = add(CurveServer(context=context, parameter_overrides=overrides(
        experiment='closed_curve')))
    spin_until(lambda: server.schedule.next_id == 1)
    published = time.monotonic()   # the curve is long published when the controller starts
    spin_until(lambda: time.monotonic() - published > 0.5)
    ctrl = add(FormationController(context=context, namespace='/robot_1', parameter_overrides=(
        overrides(index=1, agent_count=6, role='leader'))))
    spin_until(lambda: ctrl.controller.curve is not None)
    np.testing.assert_allclose(ctrl.controller.target, server.experiment.phases[0].targets[0])


def test_curve_server_starts_once_the_awaited_subscribers_say_they_receive(ros):
    """The schedule starts (curve 0 published) only once wait_for_ready nodes have reported,
    each once its own subscription counts the server's publisher (nodes/readiness.py).
    """
    context, add, spin_until = ros
    server = add(CurveServer(context=context, parameter_overrides=overrides(
        experiment='closed_curve', wait_for_ready=2)))
    received = []

    def reader(name):
        node = add(rclpy.create_node(name, context=context))
        sub = node.create_subscription(Float64MultiArray, topics.CURVE,
                                       lambda m: received.append(name), qos.LATCHED)
        report = ReadyReport(node, sub)
        spin_until(lambda: report.reported)

    reader('first')
    deadline = time.monotonic() + 1.0
    spin_until(lambda: time.monotonic() > deadline)
    assert server.ready.names == {'/first'}
    assert server.schedule.next_id == 0 and received == []   # one of two: not started
    reader('second')
    spin_until(lambda: sorted(received) == ['first', 'second'])
    assert server.ready.names == {'/first', '/second'} and server.schedule.next_id == 1


def test_curve_server_also_waits_until_its_publisher_reaches_that_many_readers(ros):
    """A ready report is the reader's side of a link; the schedule starts only once the
    server's own publisher has matched as many readers too: a curve published before would
    miss the readers it has not matched, and they would get a later message (a moving curve's
    renewal, mistaken for its start; seen in CI as a 3 mm offset of every robot).
    """
    context, add, spin_until = ros
    server = add(CurveServer(context=context, parameter_overrides=overrides(
        experiment='closed_curve', wait_for_ready=1)))
    reporter = add(rclpy.create_node('reporter', context=context))
    topics.publisher(reporter, topics.READY).publish(String(data='/reporter'))
    spin_until(lambda: server.ready.names == {'/reporter'})
    deadline = time.monotonic() + 1.0
    spin_until(lambda: time.monotonic() > deadline)
    assert server.schedule.next_id == 0   # reported, but no reader of the curve: not started
    node = add(rclpy.create_node('reader', context=context))
    received = []
    node.create_subscription(Float64MultiArray, topics.CURVE, received.append, qos.LATCHED)
    spin_until(lambda: received)
    assert server.schedule.next_id == 1


@pytest.mark.parametrize('period', [0.4, 0.0])
def test_curve_server_publishes_its_curve_again_for_a_reader_that_missed_it(ros, period):
    """A reader that never got the latched curve (here: a volatile subscription, which is
    given no history, as a restarted controller is not when Fast DDS fails to deliver it)
    receives the current curve, same id, within refresh_period; with 0, never.
    """
    context, add, spin_until = ros
    server = add(CurveServer(context=context, parameter_overrides=overrides(
        experiment='closed_curve', refresh_period=period)))
    spin_until(lambda: server.schedule.next_id == 1)
    node = add(rclpy.create_node('late', context=context))
    received = []
    node.create_subscription(Float64MultiArray, topics.CURVE,
                             lambda m: received.append(messages.curve_from_msg(m)[1]),
                             no_history_qos())
    deadline = time.monotonic() + 3.0
    spin_until(lambda: len(received) >= 2 or time.monotonic() > deadline)
    if period:
        assert received[:2] == [0, 0] and server.schedule.next_id == 1
    else:
        assert received == []


def test_follower_drives_only_while_its_inputs_are_fresh(ros):
    context, add, spin_until = ros
    ctrl = add(FormationController(context=context, namespace='/robot_2', parameter_overrides=(
        overrides(index=2, agent_count=3, in_neighbours=[1], weights=[1.0],
                  neighbour_timeout=0.3, pose_timeout=0.3, k2=0.0,
                  leader_timeout=5.0))))   # the neighbour is the leader: its own timeout
    probe = Probe(context, 2)
    add(probe.node)
    probe.curve_pub.publish(messages.curve_to_msg(circle_curve(), 0, [0.0, 1 / 3, 2 / 3]))
    spin_until(lambda: ctrl.controller.curve is not None)

    def feed(seconds, neighbour=True):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            probe.pose_pub.publish(messages.pose_to_msg(0.0, 0.0, 0.0, probe.now()))
            if neighbour:
                probe.state(1, (0.1, 0.0))
            spin_until(lambda: True)
            for _ in range(5):
                ctrl.executor.spin_once(timeout_sec=0.01)

    feed(1.0)
    assert probe.commands and probe.commands[-1][1:] != (0.0, 0.0)
    assert ctrl.controller.tick(probe.now()).stopped is None
    silent_from = time.monotonic()
    feed(1.0, neighbour=False)
    zero_since = next(t for t, v, w in probe.commands if t > silent_from and (v, w) == (0, 0))
    assert zero_since - silent_from < 0.3 + 0.1 + 0.1
    assert all((v, w) == (0, 0) for t, v, w in probe.commands if t > zero_since)
    assert 'neighbour 1 stale' in ctrl._last_reason


def test_stamps_from_a_clock_far_behind_do_not_stop_a_follower(ros):
    """Poses and states stamped by hosts whose clocks lag this one by 20 s (no time sync):
    inputs are judged by when they arrive, so the robot drives; when they stop, it stops.
    """
    context, add, spin_until = ros
    ctrl = add(FormationController(context=context, namespace='/robot_2', parameter_overrides=(
        overrides(index=2, agent_count=3, in_neighbours=[1], weights=[1.0], k2=0.0))))
    probe = Probe(context, 2, skew=20.0)
    add(probe.node)
    probe.curve_pub.publish(messages.curve_to_msg(circle_curve(), 0, [0.0, 1 / 3, 2 / 3]))
    spin_until(lambda: ctrl.controller.curve is not None)
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        probe.pose_pub.publish(messages.pose_to_msg(0.0, 0.0, 0.0, probe.now() - probe.skew))
        probe.state(1, (0.1, 0.0))
        for _ in range(5):
            ctrl.executor.spin_once(timeout_sec=0.01)
    assert ctrl._last_reason is None and probe.commands[-1][1:] != (0.0, 0.0)
    deadline = time.monotonic() + 1.0
    spin_until(lambda: time.monotonic() > deadline)          # inputs stop
    assert 'stale' in ctrl._last_reason and probe.commands[-1][1:] == (0.0, 0.0)


def test_nan_inputs_are_rejected_not_forwarded(ros):
    context, add, spin_until = ros
    ctrl = add(FormationController(context=context, namespace='/robot_1', parameter_overrides=(
        overrides(index=1, agent_count=3, role='leader'))))
    assert not ctrl.controller.on_pose(float('nan'), 0.0, 0.0, 1.0)
    assert ctrl.controller.pose is None and ctrl.controller.rejected == 1


@pytest.mark.parametrize('params, name', [
    ({'index': 1, 'agent_count': 3, 'role': 'leader', 'k1': -1.0}, 'k1'),
    ({'agent_count': 3}, 'index'),
    ({'index': 2, 'agent_count': 3, 'in_neighbours': [1], 'weights': [1.0, 2.0]}, 'weights'),
    ({'index': 2, 'agent_count': 3, 'in_neighbours': [7]}, 'in_neighbours'),
    ({'index': 1, 'agent_count': 3, 'role': 'leader', 'law': 'random'}, 'law'),
    ({'index': 1, 'agent_count': 3, 'role': 'follower'}, 'role'),
    ({'index': 1, 'agent_count': 3, 'role': 'leader', 'offset': 0.0}, 'offset'),
    ({'index': 1, 'agent_count': 3, 'role': 'leader', 'k2': 'fast'}, 'k2'),
    ({'index': 1, 'agent_count': 3, 'role': 'leader', 'reverse': True}, 'reverse'),
    ({'index': 1, 'agent_count': 3, 'role': 'leader', 'observer_growth': 4.0},
     'observer_growth'),
    ({'index': 1, 'agent_count': 3, 'role': 'leader', 'observer_growth': 0.5},
     'observer_growth'),
])
def test_bad_parameters_are_refused_naming_the_parameter(ros, params, name):
    context, _, _ = ros
    with pytest.raises(ParameterError, match=f"'{name}'"):
        FormationController(context=context, namespace='/robot_1',
                            parameter_overrides=overrides(**params))


def test_a_curve_that_begins_to_move_is_announced_ahead_and_dated_to_its_start(ros, tmp_path):
    """The loop, still, then the same loop moving from 1.5 s: the server plans the moving
    phase's first message announce_ahead (0.2 s) before its start and it comes then (to
    within its timer's lateness on a loaded machine: twice 0.2 s late beside the other test
    streams), its clock saying it begins to move at the start; renewals follow from then,
    each dated where its curve is.
    """
    text = (DATA_DIR / 'moving_loop.yaml').read_text()
    moving = '    motion: {velocity: [0.01, 0.0]}\n'
    still = text.split('curves:\n')[1].split(moving)[0]
    assert still.startswith('  - basis') and moving in text
    path = tmp_path / 'begins_to_move.yaml'
    path.write_text(text.replace(moving, still.replace('  - basis', '  - start: 1.5\n    basis')
                                 + moving))
    context, add, spin_until = ros
    server = add(CurveServer(context=context, parameter_overrides=overrides(
        experiment=str(path))))
    probe = add(rclpy.create_node('observer', context=context))
    got = []
    # each message with when the server published it (its DDS source time: the system
    # clock, as the server's ROS clock), not when this test's executor got round to it; every
    # message kept (the curve's own depth of 1 lets a renewal replace the announcement in a
    # reader that took neither yet, as one did under load)
    probe.create_subscription(
        Float64MultiArray, topics.CURVE, WithMessageInfo(lambda m, info: got.append(
            (info['source_timestamp'] * 1e-9, messages.curve_from_msg(m),
             messages.curve_clock_from_msg(m)))),
        qos.profile(QosSpec(reliable=True, transient_local=True, depth=None)))
    spin_until(lambda: server.start is not None)
    began = server.start + 1.5
    # the still curve is out and the server's timer wakes for the next: the announcement
    assert server.schedule.next_due() == pytest.approx(began - 0.2, abs=1e-9)
    spin_until(lambda: sum(c[1] == 1 for _, c, _ in got) >= 4)
    (first_at, (first, _), first_clock), *renewals = [g for g in got if g[1][1] == 1]
    assert first_clock.motion_began == pytest.approx(began, abs=1e-9)
    assert -0.3 <= began - first_at <= 0.25   # published at its plan, or late by the load
    phase = load_experiment(str(path)).phases[1]
    np.testing.assert_allclose(first.xi, phase.curve.xi, atol=1e-12)
    assert first_clock.run_time == pytest.approx(1.5, abs=1e-9)
    for _, (curve, _), clock in renewals:
        assert clock.motion_began == pytest.approx(began, abs=1e-9)
        assert clock.run_start == pytest.approx(server.start, abs=1e-9)
        np.testing.assert_allclose(curve.xi, phase.motion.curve(phase.curve,
                                                                clock.moving_for).xi,
                                   atol=1e-12)
        assert clock.moving_for >= 0.0


def test_curve_server_fits_and_publishes_an_observed_curve(ros):
    from geometry_msgs.msg import Point32, PolygonStamped
    context, add, spin_until = ros
    server = add(CurveServer(context=context, parameter_overrides=overrides(
        experiment='closed_curve', observed_basis='fourier', observed_size=6)))
    spin_until(lambda: server.schedule.next_id == 1)
    probe = add(rclpy.create_node('observer', context=context))
    received = []
    probe.create_subscription(Float64MultiArray, topics.CURVE,
                              lambda m: received.append(messages.curve_from_msg(m)), qos.LATCHED)
    pub = probe.create_publisher(PolygonStamped, topics.OBSERVED_CURVE, qos.EVENTS)
    s = np.linspace(0, 1, 90, endpoint=False)
    msg = PolygonStamped()
    msg.polygon.points = [Point32(x=float(3 + 2 * np.cos(2 * np.pi * v)),
                                  y=float(1 + np.sin(2 * np.pi * v))) for v in s]
    spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(msg)
    spin_until(lambda: any(cid == 1 for _, cid in received))
    curve = next(c for c, cid in received if cid == 1)
    pts = curve.points(np.linspace(0, 1, 7))
    # Observed points are parameterised by chord length; an ellipse in that parameter is not a
    # finite Fourier series, so K = 6 leaves a small residual (measured 0.012, 0.3 % of size).
    assert np.abs((pts[:, 0] - 3) ** 2 / 4 + (pts[:, 1] - 1) ** 2 - 1).max() < 0.02
    # The same message again (the tracker resends one it has not seen answered: a busy
    # tracker may not have read the answer yet) is not a new curve.
    pub.publish(msg)
    # Refused, the current curve staying: too few points for the basis, two points, a NaN,
    # more points than MAX_OBSERVED_POINTS.
    from curve_formation.nodes.curve_server import MAX_OBSERVED_POINTS
    good = list(msg.polygon.points)
    nan = good[:40] + [Point32(x=float('nan'), y=1.0)] + good[41:]
    many = [Point32(x=float(np.cos(a)), y=float(np.sin(a)))
            for a in np.linspace(0, 6.28, MAX_OBSERVED_POINTS + 1)]
    for points in (good[:5], good[:2], nan, many):
        msg.polygon.points = points
        pub.publish(msg)
    deadline = time.monotonic() + 2.0
    spin_until(lambda: time.monotonic() > deadline)
    assert server.schedule.next_id == 2
    msg.polygon.points = good   # the same line seen again later (another stamp) is taken
    msg.header.stamp.sec = 5
    pub.publish(msg)
    spin_until(lambda: server.schedule.next_id == 3)


def test_curve_server_sends_each_agents_assigned_parameter(ros, tmp_path, arena_dict):
    arena_dict['agents']['assignment'] = 'nearest'
    path = tmp_path / 'arena.yaml'
    path.write_text(yaml.safe_dump(arena_dict))
    experiment = load_experiment(path)
    context, add, spin_until = ros
    probe = add(rclpy.create_node('observer', context=context))
    received = []
    probe.create_subscription(Float64MultiArray, topics.CURVE, lambda m: received.append(
        messages.agent_parameters_from_msg(m)), qos.LATCHED)
    add(CurveServer(context=context, parameter_overrides=overrides(experiment=str(path))))
    spin_until(lambda: received)
    np.testing.assert_allclose(received[0], experiment.phases[0].s)
    assert not np.all(np.diff(received[0]) > 0)   # re-ordered, not the paper's s_i = (i-1)/n


def test_a_switch_after_a_re_assignment_assigns_from_the_re_assigned_targets(ros, tmp_path,
                                                                          arena_dict):
    """Robots sit on the first curve's targets, two pairs of them swapped: the server
    re-assigns (at 1 s) and at the switch (3 s) assigns the second curve from the targets as
    re-assigned (Phase.assigned_from), as the simulator does, not as at load time.
    """
    arena_dict['curves'][1]['start'] = 3.0
    path = tmp_path / 'arena.yaml'
    path.write_text(yaml.safe_dump(arena_dict))
    experiment = load_experiment(path)
    first, second = experiment.phases
    swap = np.array([1, 0, 3, 2, 4, 5, 6, 7, 8])
    there = first.targets[swap]
    expected = second.assigned_from(there).s
    assert not np.array_equal(expected, second.s)
    offset = experiment.gains.offset
    poses = np.column_stack([there[:, 0] - offset, there[:, 1], np.zeros(9)])
    context, add, spin_until = ros
    probe = add(rclpy.create_node('observer', context=context))
    received = []
    probe.create_subscription(Float64MultiArray, topics.CURVE, lambda m: received.append(
        messages.curve_from_msg(m)[1:] + (messages.agent_parameters_from_msg(m),)),
        qos.LATCHED)
    pub = topics.publisher(probe, topics.ROBOT_POSES)
    probe.create_timer(0.1, lambda: pub.publish(messages.robot_poses_to_msg(
        poses, probe.get_clock().now().nanoseconds * 1e-9)))
    add(CurveServer(context=context, parameter_overrides=overrides(experiment=str(path))))
    spin_until(lambda: any(cid == 1 for cid, _ in received), timeout=10.0)
    ids = [cid for cid, _ in received]
    assert ids[0] == 0 and ids.count(0) >= 2, ids   # the first curve, then re-assigned
    np.testing.assert_allclose(received[ids.index(0) + 1][1], first.s[swap])
    np.testing.assert_allclose(next(s for cid, s in received if cid == 1), expected)


def test_the_server_waits_for_the_checked_robots_top_speeds_and_assigns_by_trip_time(
        ros, tmp_path, arena_dict):
    """With controller.motor_check the server starts the schedule only once every robot's
    top_speed has come (sent when its check is done), then assigns the first curve by trip
    time from where the robots are (timed_order over their poses' control points, each trip
    over its robot's top speed), which here differs from the order by distance; a speed
    that is no speed is refused (that robot taken at the wheels' limit).
    """
    from std_msgs.msg import Float64
    arena_dict['controller']['motor_check'] = True
    path = tmp_path / 'arena.yaml'
    path.write_text(yaml.safe_dump(arena_dict))
    experiment = load_experiment(path)
    first = experiment.phases[0]
    limit = experiment.limits.max_wheel_speed
    rng = np.random.default_rng(1)
    poses = np.column_stack([rng.uniform(0.3, 1.5, 9), rng.uniform(0.2, 0.8, 9),
                             rng.uniform(-np.pi, np.pi, 9)])
    speeds = limit * rng.uniform(0.6, 1.0, 9)
    told = speeds.copy()
    told[4] = -1.0   # refused: robot 5 taken at the limit
    speeds[4] = limit
    from curve_formation.core.formation.assignment import nearest_order, timed_order
    from curve_formation.core.formation.dynamics import offset_points
    points = offset_points(poses, experiment.gains.offset)
    expected = first.s[timed_order(points, first.targets, speeds)]
    assert not np.array_equal(expected, first.s[nearest_order(points, first.targets)])
    context, add, spin_until = ros
    probe = add(rclpy.create_node('observer', context=context))
    received = []
    probe.create_subscription(Float64MultiArray, topics.CURVE, lambda m: received.append(
        messages.agent_parameters_from_msg(m)), qos.LATCHED)
    pub = topics.publisher(probe, topics.ROBOT_POSES)
    probe.create_timer(0.05, lambda: pub.publish(messages.robot_poses_to_msg(
        poses, probe.get_clock().now().nanoseconds * 1e-9)))
    speed_pubs = [topics.publisher(probe, topics.TOP_SPEED, i) for i in range(1, 10)]
    server = add(CurveServer(context=context,
                             parameter_overrides=overrides(experiment=str(path))))
    for i in range(8):   # all but robot 9's
        speed_pubs[i].publish(Float64(data=float(told[i])))
    deadline = time.monotonic() + 1.5
    spin_until(lambda: time.monotonic() > deadline)
    assert received == [] and server.start is None
    speed_pubs[8].publish(Float64(data=float(told[8])))
    spin_until(lambda: received)
    np.testing.assert_allclose(server.speeds[[0, 1, 2, 3, 5, 6, 7, 8]],
                               speeds[[0, 1, 2, 3, 5, 6, 7, 8]])
    assert np.isnan(server.speeds[4])
    np.testing.assert_allclose(received[0], expected)


# The kinematic world's pushes are tested without ROS (test_dynamics.py); over DDS in -m slow.
@pytest.mark.parametrize('physics', [pytest.param('kinematic', marks=pytest.mark.slow),
                                     'mujoco'])
def test_fake_arena_bodies_push_each_other_and_count_the_contact(ros, physics):
    """Two robots driven head-on at each other: they meet, push, and never overlap by more
    than a physics step's travel (MuJoCo's soft contacts: measured 1.2 mm at 8 cm/s); the
    contact is counted once and reported.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Twist

    from curve_formation.nodes import topics
    from curve_formation.nodes.fake_arena import FakeArena
    context, add, spin_until = ros
    arena = add(FakeArena(context=context, parameter_overrides=[
        Parameter('experiment', value=str(DATA_DIR / 'arena_bodies.yaml')),
        Parameter('physics', value=physics)]))
    probe = add(rclpy.create_node('driver', context=context))
    reports = []
    probe.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, reports.append, 10)
    # Robots 1 (1.1, 0.4) and 4 (0.7, 0.4) face each other across the middle.
    pubs = {i: probe.create_publisher(Twist, topics.robot_topic(i, topics.CMD_VEL), 1)
            for i in (1, 4)}
    spin_until(lambda: all(p.get_subscription_count() for p in pubs.values()))
    start = time.monotonic()
    closest = np.inf
    while time.monotonic() - start < 4.0:
        for pub in pubs.values():
            pub.publish(messages.twist_to_msg(0.08, 0.0))
        pause = time.monotonic() + 0.05
        spin_until(lambda pause=pause: time.monotonic() > pause)
        poses = arena.world.poses()
        closest = min(closest, np.hypot(*(poses[0, :2] - poses[3, :2])))
    # 0.4 m apart at 8 cm/s each (drifting with the file's disturbance), they met after about
    # 2 s and pushed each other from then on, the bodies never overlapping.
    assert closest >= 2 * arena.radius - (1e-9 if physics == 'kinematic' else 2e-3)
    summary = arena.contact_summary()
    assert summary['count'] == 1 and summary['time'] > 0.25
    spin_until(lambda: any(s.hardware_id == 'fake_arena' and s.message == '1 contacts'
                           for r in reports for s in r.status), timeout=3.0)


def test_a_double_parameter_takes_an_integer_and_a_wrong_type_is_named(ros):
    """ROS users type `-p k1:=2`: an integer for a double is taken; a string is refused."""
    context, add, _ = ros
    ctrl = add(FormationController(context=context, namespace='/robot_1', parameter_overrides=(
        overrides(index=1, agent_count=3, role='leader', k1=2, rate_hz=10, weights=[]))))
    assert ctrl.config.gains.k1 == 2.0 and isinstance(ctrl.config.gains.k1, float)
    with pytest.raises(ParameterError, match="'k1' has the wrong type"):
        FormationController(context=context, namespace='/robot_2', parameter_overrides=(
            overrides(index=1, agent_count=3, role='leader', k1='fast')))
    with pytest.raises(ParameterError, match="'k2' must be in"):
        FormationController(context=context, namespace='/robot_3', parameter_overrides=(
            overrides(index=1, agent_count=3, role='leader', k2=-1)))


def test_malformed_curve_messages_are_refused_and_the_curve_kept(ros):
    context, add, spin_until = ros
    ctrl = add(FormationController(context=context, namespace='/robot_2', parameter_overrides=(
        overrides(index=2, agent_count=3, in_neighbours=[1]))))
    probe = Probe(context, 2)
    add(probe.node)
    good = messages.curve_to_msg(circle_curve(), 0, [0.0, 1 / 3, 2 / 3])
    probe.curve_pub.publish(good)
    spin_until(lambda: ctrl.controller.curve_id == 0)
    wrong_layout = Float64MultiArray(data=list(good.data))     # no layout at all
    nan = messages.curve_to_msg(circle_curve(), 1, [0.0, 1 / 3, 2 / 3])
    nan.data[0] = float('nan')
    short = messages.curve_to_msg(circle_curve(), 2, [0.0, 1 / 3, 2 / 3])
    short.data = short.data[:3]
    no_s = messages.curve_to_msg(circle_curve(), 3)
    for msg in (wrong_layout, nan, short, no_s):
        probe.curve_pub.publish(msg)
        deadline = time.monotonic() + 0.3
        spin_until(lambda deadline=deadline: time.monotonic() > deadline)
        assert ctrl.controller.curve_id == 0


@pytest.mark.parametrize('name', ['closed_curve', 'mona_arena', 'arena_demo',
                                  str(DATA_DIR / 'fast_disturbed.yaml')])
def test_agent_settings_survive_the_trip_through_node_parameters(ros, name):
    """Experiment -> AgentConfig (core.controller.agent_config.agent_configs) -> node parameters
    (what
    the runner writes) -> the node's AgentConfig: the same settings, for every agent.
    """
    from rclpy.parameter import Parameter

    from curve_formation.core.config.agents import agent_configs
    from curve_formation.core.config.parameters import node_parameters
    from curve_formation.nodes.formation_controller import agent_config
    from curve_formation.paths import resolve_config
    context, add, _ = ros
    import dataclasses
    experiment = load_experiment(resolve_config(name))
    configs = agent_configs(experiment, 10.0)
    # and a setting no shipped file uses
    configs[0] = dataclasses.replace(
        configs[0], gains=dataclasses.replace(configs[0].gains, observer_order=2),
        estimate_latency=True)
    for config in configs:
        params = [Parameter(k, value=v) for k, v in node_parameters(config).items()]
        node = add(FormationController(context=context, namespace=f'/robot_{config.index}',
                                       parameter_overrides=params))
        assert node.config == config
        assert agent_config(node.params) == config


def test_after_a_late_call_the_monitor_waits_for_a_fresh_pose_but_not_forever(ros, monkeypatch):
    """The sampling clock is driven by hand at 20 Hz. A call 0.4 s late is skipped, and so is
    every call after it until a pose arrives (a publisher held up with the machine resumes
    when the scheduler lets it: seen 0.37 s late in CI); then sampling goes on. A robot that
    fell silent is recorded again WAKE_LIMIT after the late call.
    """
    from types import SimpleNamespace

    from curve_formation.nodes import monitor as monitor_module
    context, add, _ = ros
    clock = SimpleNamespace(now=0.0)
    monkeypatch.setattr(monitor_module, 'time', SimpleNamespace(monotonic=lambda: clock.now))
    monitor = add(monitor_module.Monitor(1, record_hz=20.0, context=context))
    monitor._on_curve(messages.curve_to_msg(circle_curve(), 0, [0.0]),
                      {'source_timestamp': 0, 'received_timestamp': 0})

    def tick(at, pose_before=False):
        clock.now = at - 0.01
        if pose_before:
            monitor._on_pose(1, messages.pose_to_msg(at, 0.0, 0.0, at))
        clock.now = at
        rows = len(monitor.recording)
        monitor._sample()
        return len(monitor.recording) > rows
    recorded = [tick(0.05 * k, pose_before=True) for k in range(1, 5)]      # 0.05 .. 0.2 s
    recorded += [tick(0.6), tick(0.65), tick(0.7, pose_before=True), tick(0.75)]
    assert recorded == [True] * 4 + [False, False, True, True]
    assert monitor.late_samples == 2
    # silent from here: late at 1.2 s, then nothing arrives
    late = 1.2
    after = [tick(late + 0.05 * k) for k in range(0, 25)]
    first = after.index(True)
    assert not any(after[:first]) and all(after[first:])
    assert 0.05 * first == pytest.approx(monitor_module.WAKE_LIMIT, abs=0.051)


def test_only_a_monitor_that_times_curve_switches_reads_every_controllers_state(ros):
    """States come at the pose rate from every robot; a run without a curve switch
    (adoption=False) does not take them in.
    """
    from curve_formation.nodes.monitor import Monitor
    context, add, spin_until = ros
    timing = add(Monitor(2, context=context))
    other = add(Monitor(2, context=context, adoption=False))
    probe = add(rclpy.create_node('probe', context=context))
    state_pub = topics.publisher(probe, topics.STATE, 2)
    state = messages.state_to_msg(State((0.01, 0.0), 3, 1.0, 0.0))

    def adopted():
        state_pub.publish(state)
        return (2, 3) in timing.adopted
    spin_until(adopted)
    assert other.adopted == {}

    def state_readers(node):
        return sum(sub.topic_name.endswith(topics.STATE) for sub in node.subscriptions)
    assert (state_readers(timing), state_readers(other)) == (2, 0)


def test_a_controller_with_pose_from_all_takes_its_row_of_a_message_of_its_team(ros):
    """pose_from_all: robot 2 of 3 reads its pose from its row of /formation/robot_poses (no
    subscription to its own pose topic); a NaN row, or a message of another team's size,
    gives it no pose.
    """
    context, add, spin_until = ros
    ctrl = add(FormationController(context=context, namespace='/robot_2', parameter_overrides=(
        overrides(index=2, agent_count=3, in_neighbours=[1], pose_from_all=True))))
    probe = add(rclpy.create_node('probe', context=context))
    poses_pub = topics.publisher(probe, topics.ROBOT_POSES)
    spin_until(lambda: poses_pub.get_subscription_count() == 1)
    assert probe.count_subscribers('/robot_2/pose') == 0
    for every in ([[0.1, 0.2, 0.3], [np.nan] * 3, [0.4, 0.5, 0.6]],
                  [[0.1, 0.2, 0.3], [0.7, 0.8, 0.9]]):   # not seen; another team's
        poses_pub.publish(messages.robot_poses_to_msg(np.array(every), 5.0))
        deadline = time.monotonic() + 0.5
        spin_until(lambda deadline=deadline: time.monotonic() > deadline)
        assert ctrl.controller.pose is None
    poses_pub.publish(messages.robot_poses_to_msg(
        np.array([[0.1, 0.2, 0.3], [0.7, 0.8, 0.9], [0.4, 0.5, 0.6]]), 5.0))
    spin_until(lambda: ctrl.controller.pose is not None)
    assert ctrl.controller.pose == (0.7, 0.8, 0.9) and ctrl.controller.pose_stamp == 5.0


def test_a_monitor_that_reads_every_pose_in_one_message_takes_each_seen_row(ros):
    """With poses_from_all (a run whose poses all come on /formation/robot_poses) the monitor
    reads no robot's own pose topic; a seen row is that robot's pose, a NaN row one not seen,
    named as such while the run waits.
    """
    from curve_formation.nodes.monitor import Monitor
    context, add, spin_until = ros
    monitor = add(Monitor(3, context=context, poses_from_all=True))
    probe = add(rclpy.create_node('probe', context=context))
    poses_pub = topics.publisher(probe, topics.ROBOT_POSES)
    every = np.array([[0.1, 0.2, 0.3], [np.nan] * 3, [0.4, 0.5, 0.6]])

    def seen():
        poses_pub.publish(messages.robot_poses_to_msg(every, 12.5))
        return not np.isnan(monitor.latest.pose_stamps[[0, 2]]).any()
    spin_until(seen)
    assert monitor.count_subscribers('/robot_1/pose') == 0
    assert np.allclose(monitor.latest.poses[[0, 2]], every[[0, 2]])
    assert list(monitor.latest.pose_stamps[[0, 2]]) == [12.5, 12.5]
    assert list(monitor.unseen) == [False, True, False]
    assert monitor.missing()[0] == f'robot 2 on {topics.ROBOT_POSES}'


def test_what_the_monitor_keeps_does_not_grow_with_the_run(ros):
    """A run of hours: curve messages (refreshed every second, renewed faster when moving),
    e-stop announcements (every second from every holder), link reports and samples do not
    pile up in the monitor's memory. Messages are handed to its callbacks directly.
    """
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    from curve_formation.nodes.monitor import Monitor, TIMING_WINDOW
    context, add, _ = ros
    experiment = load_experiment(DATA_DIR / 'fast_closed.yaml')
    n = experiment.n
    monitor = add(Monitor(n, context=context, experiment=experiment))
    phase = experiment.phases[0]
    curve_msg = messages.curve_to_msg(phase.curve, 0, phase.s)
    info = {'source_timestamp': 0, 'received_timestamp': 0}
    states = [messages.estop_state_to_msg(f'/robot_{i}/formation_controller', 'controller',
                                          i, False, '', 0.0) for i in range(1, n + 1)]

    def link_report(level):
        status = DiagnosticStatus(level=bytes([level]), name='/robot_3/robot_bridge',
                                  message='ok' if level == 0 else 'no reply from the robot',
                                  values=[KeyValue(key='sent', value='1')])
        return DiagnosticArray(status=[status])
    for second in range(4000):
        monitor._on_curve(curve_msg, info)
        for state in states:
            monitor._on_estop_state(state)
        monitor._on_diagnostics(link_report(2 if 500 <= second < 510 or second > 3990 else 0))
        monitor._on_cmd(1, Twist(), info)
        monitor.last_call = None
        monitor._sample()
    assert len(monitor.followed_phases()) == 1 and not monitor.followed_phases()[0].changes
    assert len(monitor.estop_events) == n          # one per holder: nothing changed
    levels = [level for _, level, _, _ in monitor.links['/robot_3/robot_bridge']]
    assert levels == [2, 2, 2]                     # two onsets and the newest
    assert len(monitor.command_arrivals[0]) == TIMING_WINDOW
    assert len(monitor.recording) == 4000 and monitor.recording._held < 4000
    assert monitor.recording.arrays()['poses'].shape == (4000, n, 3)
