"""robot_bridge in the test's process: cmd_vel in over DDS, bytes out to an emulated robot's
end of the link (links.UdpEndpoint or PtyEndpoint, read here as the robot's firmware would).
"""

import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Bool

from conftest import no_history_qos
from curve_formation import links
from curve_formation.core.formation.dynamics import body_from_wheels
from curve_formation.nodes import qos, topics
from curve_formation.nodes.params import ParameterError
from curve_formation.nodes.robot_bridge import RobotBridge
from link_robot import BASE, Robot


class Operator(Node):
    """Publishes robot 1's cmd_vel and the e-stop, and keeps the bridge's link reports."""

    def __init__(self, context):
        super().__init__('operator', context=context)
        self.cmd = self.create_publisher(Twist, topics.robot_topic(1, topics.CMD_VEL),
                                         qos.COMMAND)
        self.estop = self.create_publisher(Bool, topics.ESTOP, qos.LATCHED)
        self.reports = []
        self.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diag,
                                 qos.EVENTS)

    def _on_diag(self, msg):
        for status in msg.status:
            self.reports.append((status.level[0], status.message,
                                 {kv.key: kv.value for kv in status.values}))

    def send(self, v, w):
        msg = Twist()
        msg.linear.x, msg.angular.z = float(v), float(w)
        self.cmd.publish(msg)


@pytest.fixture
def bench(ros):
    """(bridge factory, robot, operator, spin_until) over a UDP link on this machine."""
    context, add, spin_until = ros
    endpoint = links.UdpEndpoint(('127.0.0.1', 0))
    robot = Robot(endpoint)
    operator = add(Operator(context))
    bridges = []

    def make(link=None, namespace='/robot_1', **params):
        link = link or f'udp:127.0.0.1:{endpoint.socket.getsockname()[1]}'
        values = {'link': link, 'wheel_base': BASE, 'rate_hz': 10.0, **params}
        bridge = add(RobotBridge(context=context, namespace=namespace, parameter_overrides=[
            Parameter(k, value=v) for k, v in values.items()]))
        bridges.append(bridge)
        return bridge

    def spin(predicate=lambda: False, timeout=10.0, duration=None):
        """Spin (polling the robot) until predicate() or, with duration, for that long."""
        end = time.monotonic() + duration if duration else None

        def done():
            robot.poll()
            return time.monotonic() >= end if end else predicate()
        spin_until(done, timeout=max(timeout, duration or 0) + 1.0)

    yield make, robot, operator, spin
    for bridge in bridges:
        bridge.link.close()
    endpoint.close()


def connected(operator, spin):
    spin(lambda: operator.cmd.get_subscription_count() > 0)


def test_a_cmd_vel_goes_out_at_once_as_wheel_speeds_and_a_wheel_limit_keeps_the_curvature(
        bench):
    make, robot, operator, spin = bench
    make(max_wheel_speed=0.04)
    connected(operator, spin)
    operator.send(0.03, 0.5)           # wheels 0.01 and 0.05 m/s: 0.05 > 0.04

    def commands():   # (stop lines may come first: no cmd_vel has arrived yet)
        return [said for said in robot.said() if said[0] == 'command']

    spin(commands)
    kind, left, right, _ = commands()[0]
    assert max(abs(left), abs(right)) == pytest.approx(0.04, abs=2e-5)
    v, w = body_from_wheels(left, right, BASE)
    assert w / v == pytest.approx(0.5 / 0.03, rel=1e-3)
    spin(duration=0.3)
    operator.send(0.02, 0.0)
    spin(lambda: len(robot.said()) >= 2 and robot.said()[-1][1] == pytest.approx(0.02, 1e-3))


def test_a_stale_cmd_vel_sends_the_stop_line_at_the_robot_rate(bench):
    make, robot, operator, spin = bench
    make(command_timeout=0.3, rate_hz=10.0)
    connected(operator, spin)
    operator.send(0.02, 0.0)
    # (stop lines may come first, before the cmd_vel has arrived: CI once took one of those
    # for the stale command's)
    spin(lambda: any(said[0] == 'command' for said in robot.said()))
    sent = time.monotonic()
    driven = min(t for t, said in robot.lines if said[0] == 'command')
    spin(duration=1.5)
    stops = [(t, said) for t, said in robot.lines if said == ('stop', None) and t > driven]
    assert stops, robot.lines
    # first stop once the command is 0.3 s old (at the next 10 Hz tick), then at 10 Hz
    assert 0.3 <= stops[0][0] - sent < 0.3 + 0.25
    assert all(said[0] == 'stop' for t, said in robot.lines if t > stops[0][0])
    assert 8 <= len(stops) <= 13


def test_the_bridge_never_sends_faster_than_the_robot_takes(bench):
    make, robot, operator, spin = bench
    make(rate_hz=10.0)
    connected(operator, spin)
    start = time.monotonic()
    while time.monotonic() - start < 2.0:        # cmd_vel at about 100 Hz for 2 s
        operator.send(0.02, 0.1)
        spin(duration=0.01)
    spin(duration=0.2)
    elapsed = time.monotonic() - start     # 2.2 s, longer on a busy machine
    commands = [said for said in robot.said(start) if said[0] == 'command']
    # never the 100 Hz it was given: at most 12 lines in any second (10 Hz and two more, so
    # that a 10 Hz controller's late ticks are never held back)
    assert 15 <= len(commands) <= 12 * elapsed + 1, (len(commands), elapsed)
    times = np.array([t for t, said in robot.lines if t >= start and said[0] == 'command'])
    in_a_second = [np.sum((times >= t) & (times < t + 0.99)) for t in times]
    assert max(in_a_second) <= 12, in_a_second


def test_e_stop_stops_the_robot_until_released(bench):
    """Sent as `ros2 topic pub` sends it (reliable, volatile): the robot gets stop lines only,
    whatever cmd_vel says, until the release.
    """
    make, robot, operator, spin = bench
    make()
    connected(operator, spin)
    estop = operator.create_publisher(Bool, topics.ESTOP, no_history_qos())
    spin(lambda: estop.get_subscription_count() > 0)
    operator.send(0.02, 0.0)
    spin(lambda: robot.said())
    estop.publish(Bool(data=True))
    spin(lambda: robot.said()[-1][0] == 'stop')
    engaged = time.monotonic()
    for _ in range(10):
        operator.send(0.02, 0.0)
        spin(duration=0.1)
    assert all(said[0] == 'stop' for said in robot.said(engaged))
    estop.publish(Bool(data=False))
    spin(lambda: robot.said()[-1][0] == 'command', timeout=2.0)


def test_a_second_command_publisher_holds_the_robot_stopped_until_it_is_gone(bench, ros):
    """One command source per robot: while a second node publishes its cmd_vel, the robot
    gets only stop lines, and the bridge says who publishes.
    """
    make, robot, operator, spin = bench
    context, add, _ = ros
    bridge = make()
    connected(operator, spin)
    operator.send(0.02, 0.0)
    spin(lambda: robot.said() and robot.said()[-1][0] == 'command')
    intruder = add(Node('teleop', context=context))
    twin = intruder.create_publisher(Twist, topics.robot_topic(1, topics.CMD_VEL), qos.COMMAND)
    spin(lambda: bridge.source.extra, timeout=5.0)
    held = time.monotonic()
    for _ in range(10):
        operator.send(0.02, 0.0)
        spin(duration=0.1)
    assert all(said[0] == 'stop' for said in robot.said(held))
    assert bridge.source.names == ['/operator', '/teleop']
    intruder.destroy_publisher(twin)
    spin(lambda: not bridge.source.extra, timeout=5.0)
    operator.send(0.02, 0.0)
    spin(lambda: robot.said()[-1][0] == 'command', timeout=2.0)


def test_a_bridge_that_starts_while_stopped_sends_only_stop_lines(bench):
    """The stop was sent once, before this bridge existed, and its sender is gone: the bridge
    learns it from the nodes that hold it (here another bridge) and its robot gets only zero
    wheel speeds, whatever cmd_vel says.
    """
    make, robot, operator, spin = bench
    other = links.UdpEndpoint(('127.0.0.1', 0))
    try:
        make(link=f'udp:127.0.0.1:{other.socket.getsockname()[1]}', namespace='/robot_2')
        estop = operator.create_publisher(Bool, topics.ESTOP, no_history_qos())
        spin(lambda: estop.get_subscription_count() > 0)
        estop.publish(Bool(data=True))
        operator.destroy_publisher(estop)
        spin(duration=0.5)
        bridge = make()
        connected(operator, spin)
        spin(lambda: bridge.estop.engaged, timeout=5.0)
        started = time.monotonic()
        for _ in range(10):
            operator.send(0.02, 0.0)
            spin(duration=0.1)
        said = robot.said()
        assert said and all(line[0] == 'stop' for line in said), said
        assert len(robot.said(started)) >= 5
    finally:
        other.close()


def test_shutdown_sends_the_stop_line_several_times(bench):
    make, robot, operator, spin = bench
    bridge = make(stop_repeats=3)
    connected(operator, spin)
    operator.send(0.02, 0.0)
    spin(lambda: robot.said())
    before = len(robot.lines)
    bridge.on_shutdown()
    spin(lambda: len(robot.lines) >= before + 3, timeout=2.0)
    assert [said for _, said in robot.lines[before:]] == [('stop', None)] * 3


def test_non_finite_cmd_vel_is_never_sent(bench):
    make, robot, operator, spin = bench
    make()
    connected(operator, spin)
    operator.send(float('nan'), 0.0)
    operator.send(0.01, float('inf'))
    spin(duration=0.3)
    assert all(said[0] == 'stop' for said in robot.said())   # nothing but stale stops


def test_garbage_from_the_robot_is_counted_and_never_stops_the_bridge(bench):
    make, robot, operator, spin = bench
    robot.answer = False
    make()
    connected(operator, spin)
    operator.send(0.02, 0.0)
    spin(lambda: robot.said())
    junk = [bytes(range(256)), b'\xff' * 70000, b'x' * (links.MAX_LINE + 10) + b'\n',
            b'ok\n', b'\x00\n', b'err\n', b'okay\n']
    for data in junk:
        robot.endpoint.send(data[:65000])
    for _ in range(5):
        operator.send(0.02, 0.0)
        spin(duration=0.15)
    spin(lambda: operator.reports and int(operator.reports[-1][2]['replies']) == 2)
    counts = operator.reports[-1][2]
    assert int(counts['malformed']) >= 3 and int(counts['dropped_lines']) >= 1, counts
    assert robot.said()[-1][0] == 'command'     # still forwarding


def test_a_silent_robot_is_reported_as_a_lost_link_and_recovers(bench):
    make, robot, operator, spin = bench
    robot.answer = False
    make(reply_timeout=0.5)
    connected(operator, spin)
    for _ in range(15):
        operator.send(0.02, 0.0)
        spin(duration=0.1)
    spin(lambda: operator.reports and operator.reports[-1][0] == 2)
    assert operator.reports[-1][1] == 'no reply from the robot'
    robot.answer = True
    for _ in range(25):
        operator.send(0.02, 0.0)
        spin(duration=0.1)
    level, message, values = operator.reports[-1]
    assert (level, message) == (0, 'ok'), operator.reports[-1]
    assert float(values['reply_age_s']) < 0.5
    assert float(values['latency_ms_p99']) > 0


def test_a_serial_robot_that_appears_later_is_reached(bench, tmp_path):
    """The bridge starts before the robot's serial port exists (robot off): link errors are
    reported, and commands go through once the port is there.
    """
    make, robot, operator, spin = bench
    path = tmp_path / 'robot_1'
    make(link=f'serial:{path}', command_timeout=5.0)
    connected(operator, spin)
    operator.send(0.02, 0.0)
    spin(lambda: operator.reports and operator.reports[-1][0] == 1, timeout=3.0)
    level, message, values = operator.reports[-1]
    assert 'No such file' in message and int(values['failed']) >= 1
    robot.endpoint.close()
    robot.endpoint = links.PtyEndpoint(path)
    for _ in range(30):
        operator.send(0.02, 0.0)
        spin(duration=0.1)
        if robot.said():
            break
    assert robot.said() and robot.said()[-1][0] == 'command'
    # once it sends again the link is reported ok, the past error still named
    count = len(operator.reports)
    spin(lambda: len(operator.reports) > count and operator.reports[-1][0] == 0, timeout=3.0)
    level, message, values = operator.reports[-1]
    assert message == 'ok' and 'No such file' in values['last_error']
    robot.endpoint.close()


@pytest.mark.parametrize(('params', 'says'), [
    ({'link': 'tcp:robot:1'}, "parameter 'link': expected udp:HOST:PORT"),
    ({'wire_format': '', 'command_template': 'go {left}\n', 'stop_template': 'x\n'},
     "parameter 'wire_format': the command template 'go {left}\\n' lacks ['right']"),
])
def test_bad_bridge_parameters_are_refused_naming_the_parameter(bench, params, says):
    make, *_ = bench
    with pytest.raises(ParameterError) as error:
        make(**params)
    assert says in str(error.value)
