"""Recorder: subscribes to the formation's topics raw and writes them to a ROS 2 bag.

Not a console script on its own: `curve-formation run ... --bag PATH` (and the demo) run it
beside the monitor. The bag is closed on Ctrl-C, SIGTERM and at the end of the run.
"""

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped, PoseStamped, Twist, Vector3Stamped
from nav_msgs.msg import Path
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray

from curve_formation import bag
from curve_formation.nodes import qos, topics


def formation_topics(n):
    """[(topic, message class, QoSProfile)] of an n-robot formation."""
    out = [(topics.CURVE, Float64MultiArray, qos.LATCHED),
           (topics.CURVE_PATH, Path, qos.LATCHED),
           (topics.DIAGNOSTICS, DiagnosticArray, qos.EVENTS)]
    for i in range(1, n + 1):
        out += [(topics.robot_topic(i, topics.POSE), PoseStamped, qos.SENSOR),
                (topics.robot_topic(i, topics.CMD_VEL), Twist, qos.COMMAND),
                (topics.robot_topic(i, topics.STATE), PointStamped, qos.STATE),
                (topics.robot_topic(i, topics.ESTIMATE), Vector3Stamped, qos.STATE)]
    return out


def type_name(msg_class):
    """'geometry_msgs/msg/PoseStamped' for geometry_msgs.msg.PoseStamped."""
    return f'{msg_class.__module__.split(".")[0]}/msg/{msg_class.__name__}'


def bag_qos(profile):
    """The rosbags Qos record of an rclpy QoSProfile."""
    return bag.qos(reliable=profile.reliability == ReliabilityPolicy.RELIABLE,
                   transient_local=profile.durability == DurabilityPolicy.TRANSIENT_LOCAL,
                   depth=profile.depth)


# The recorder's own queue: deep, so a busy executor does not overwrite unread messages.
RECORD_DEPTH = 500


class Recorder(Node):
    """Writes every message of the given topics, as received, to an open bag.BagWriter."""

    def __init__(self, writer, topic_list, **kwargs):
        super().__init__('formation_recorder', **kwargs)
        self.writer = writer
        self.received = {}
        for topic, msg_class, profile in topic_list:
            writer.add_topic(topic, type_name(msg_class), bag_qos(profile))
            self.received[topic] = 0
            deep = QoSProfile(depth=RECORD_DEPTH, reliability=profile.reliability,
                              durability=profile.durability)
            self.create_subscription(msg_class, topic,
                                     lambda data, topic=topic: self._on_message(topic, data),
                                     deep, raw=True)

    def _on_message(self, topic, data):
        self.received[topic] += 1
        self.writer.write(topic, self.get_clock().now().nanoseconds, data)
