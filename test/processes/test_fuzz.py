"""One bad message never stops the formation: malformed and absurd messages of every input
family, published into a running formation (one process per node), kill no node, and the
formation goes on, with a complete output folder.
"""

import itertools
import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point32, PolygonStamped, PoseStamped, Twist
import numpy as np
import pytest
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from conftest import DATA_DIR
from curve_formation.core.formation.curves import Curve, make_basis
from curve_formation.core.record import metrics
from curve_formation.nodes import messages, qos, topics
from curve_formation.run.run_options import RunOptions
from curve_formation.run.runner import Run


def curve_msg(label_id='curve_id=0', size=1, data=None, extra=()):
    curve = Curve(make_basis('fourier', 1), [4.0, 8.0, 0.0, 4.0, 0.0, 8.0])
    msg = messages.curve_to_msg(curve, 0, [0.0, 1 / 6, 2 / 6, 3 / 6, 4 / 6, 5 / 6])
    msg.layout.dim[2].label = label_id
    msg.layout.dim[1].size = size
    if data is not None:
        msg.data = data
    msg.layout.dim.extend(MultiArrayDimension(label=a, size=b, stride=c) for a, b, c in extra)
    return msg


def pose_msg(x, y, q=(0.0, 0.0, 0.0, 1.0)):
    msg = PoseStamped()
    msg.pose.position.x, msg.pose.position.y = x, y
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = q
    return msg


def state_msg(values, names=messages.STATE_FIELDS):
    return JointState(name=list(names), position=[float(v) for v in values])


def polygon(points):
    return PolygonStamped(polygon=type(PolygonStamped().polygon)(
        points=[Point32(x=float(x), y=float(y)) for x, y in points]))


def junk_estop_state():
    return DiagnosticStatus(name='/x' * 300, values=[KeyValue(key='engaged', value='maybe')])


def junk_contacts():
    return DiagnosticArray(status=[DiagnosticStatus(
        name='/fuzz', hardware_id='fake_arena',
        values=[KeyValue(key='count', value='many'), KeyValue(key='time', value='[')])])


# (topic, message class, QoS, message) for every family of bad input
FAMILIES = [
    (topics.CURVE, Float64MultiArray, qos.LATCHED, curve_msg('curve_id=' + '9' * 400)),
    (topics.CURVE, Float64MultiArray, qos.LATCHED, Float64MultiArray()),
    (topics.CURVE, Float64MultiArray, qos.LATCHED, curve_msg(size=10 ** 9)),
    (topics.CURVE, Float64MultiArray, qos.LATCHED, curve_msg(data=[math.nan] * 12)),
    (topics.CURVE, Float64MultiArray, qos.LATCHED,
     curve_msg(extra=[('s', 10 ** 6, 10 ** 6)])),
    ('/robot_2/formation_state', JointState, qos.STATE, state_msg([0.1, 0.0, math.nan, 0.0])),
    ('/robot_2/formation_state', JointState, qos.STATE, state_msg([0.1, 0.0, math.inf, 0.0])),
    ('/robot_2/formation_state', JointState, qos.STATE, state_msg([1e300, 0.0, 0.0, 0.0])),
    ('/robot_2/formation_state', JointState, qos.STATE, state_msg([0.1], names=['e_x'])),
    ('/robot_3/pose', PoseStamped, qos.SENSOR, pose_msg(1e300, 0.0)),
    ('/robot_3/pose', PoseStamped, qos.SENSOR, pose_msg(4.0, 4.0, (0.0, 0.0, 0.0, 0.0))),
    ('/robot_3/pose', PoseStamped, qos.SENSOR, pose_msg(4.0, 4.0, (0.0, 0.0, 1.2, 1.6))),
    ('/robot_3/pose', PoseStamped, qos.SENSOR, pose_msg(math.nan, 4.0)),
    (topics.ROBOT_POSES, JointState, qos.SENSOR, JointState(position=[1.0, 2.0])),
    (topics.ESTOP_STATE, DiagnosticStatus, qos.LATCHED, junk_estop_state()),
    (topics.DIAGNOSTICS, DiagnosticArray, qos.EVENTS, junk_contacts()),
    (topics.OBSERVED_CURVE, PolygonStamped, qos.EVENTS,   # a loop 1e30 m away
     polygon([(1e30 + 1e28 * math.cos(a), 1e30 + 1e28 * math.sin(a))
              for a in np.linspace(0.0, 2 * math.pi, 50, endpoint=False)])),
    (topics.OBSERVED_CURVE, PolygonStamped, qos.EVENTS, polygon([(0.0, 0.0), (1.0, 1.0)])),
    ('/robot_4/cmd_vel', Twist, qos.COMMAND, messages.twist_to_msg(math.nan, 0.0)),
]


class Fuzzer(Node):
    """Publishes FAMILIES one after the other, every `period` s, from `start` s on."""

    def __init__(self, context, period=0.05):
        super().__init__('fuzzer', context=context, start_parameter_services=False)
        self.pubs = {}
        for topic, cls, profile, _ in FAMILIES:
            self.pubs.setdefault(topic, self.create_publisher(cls, topic, profile))
        self.cycle = itertools.cycle(FAMILIES)
        self.sent = 0
        self.timer = self.create_timer(period, self._send)

    def _send(self):
        topic, _, _, msg = next(self.cycle)
        if hasattr(msg, 'header'):
            msg.header.stamp = self.get_clock().now().to_msg()
        self.pubs[topic].publish(msg)
        self.sent += 1


def logs_of(folder):
    return {path.stem: path.read_text() for path in (folder / 'logs').glob('*.log')}


@pytest.mark.filterwarnings('error::RuntimeWarning')   # no overflow in the run's metrics
def test_bad_messages_of_every_family_kill_no_node_and_the_formation_goes_on(ros_domain,
                                                                           tmp_path):
    """6 s of every family at 20 Hz: no node dies, every robot drives again once the second
    cmd_vel publisher is gone, the formation's error keeps coming down, and the output folder
    is complete. The monitor refuses the poses the controllers refuse (1e300 m), so the run's
    metrics are not made of them (they overflowed the error norm before).
    """
    with Run(DATA_DIR / 'fast_closed.yaml', tmp_path, RunOptions(
            bag_path=tmp_path / 'bag', controllers_per_process=1), log=lambda *_: None) as run:
        run.spin_for(1.0)
        fuzzer = Fuzzer(run.observers.context)
        run.observers.add_node(fuzzer)
        run.spin_for(6.0)
        fuzzer.destroy_timer(fuzzer.timer)
        # its cmd_vel publisher made robot 4's command two-sourced: held until it goes
        fuzzer.destroy_publisher(fuzzer.pubs['/robot_4/cmd_vel'])
        run.spin_for(3.0)
        commands = run.monitor.latest.commands.copy()
        refused = run.monitor.latest.refused
        result = run.write_results()
        deaths = run.graph.deaths
        data = run.recording()
    assert fuzzer.sent > 5 * len(FAMILIES)
    assert deaths == [], deaths
    assert refused > 0
    assert (abs(commands).sum(axis=1) > 0).all(), commands          # every robot driving
    followed, phase = run.followed(data['t'])
    norm = metrics.error_norm(metrics.target_errors(data['poses'], phase, followed,
                                                    t=data['t']))
    quiet = np.searchsorted(data['t'], data['t'][-1] - 3.0)   # the fuzzing's end
    assert norm[-1] < 0.8 * norm[quiet] < 0.8 * norm[0], (norm[0], norm[quiet], norm[-1])
    for name in ('metrics.json', 'paths.png', 'trajectory.npz'):
        assert (tmp_path / name).exists(), name
    logs = logs_of(tmp_path)
    assert 'curve refused' in logs['robot_2.formation_controller']
    assert 'rejected' in logs['robot_3.formation_controller']   # poses, states of 2
    assert 'leaves the arena beyond +-10000 m' in logs['curve_server']
    # a second publisher on robot 4's cmd_vel: reported, the robot held meanwhile
    (episode,) = result['command_sources']['robot_4']
    assert episode[2] == ['/fuzzer', '/robot_4/formation_controller'] and episode[1] is not None
    assert 'nodes publish /robot_4/cmd_vel' in logs['robot_4.fake_robot']
