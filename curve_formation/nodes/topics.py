"""The formation's topics, each described once: name, message type, QoS and meaning.

Nodes create their publishers and subscriptions through `publisher` and `subscription`, the
recorder records the topics marked `recorded`, and the node tables of docs/nodes.md
(nodes/docs.py) are generated from the same records. Per-robot topics have relative names, so
a robot is placed by its namespace; `robot_topic` gives their absolute names.
"""

from dataclasses import dataclass
from typing import NamedTuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PolygonStamped, PoseArray, PoseStamped, Twist, Vector3Stamped
from nav_msgs.msg import Path
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Bool, Float64MultiArray, String
from visualization_msgs.msg import MarkerArray

from curve_formation.nodes import qos
from curve_formation.nodes.guard import Guarded


CURVE = '/formation/curve'
OBSERVED_CURVE = '/formation/observed_curve'
ESTOP = '/formation/estop'
ESTOP_STATE = '/formation/estop_state'
READY = '/formation/ready'
CURVE_PATH = '/formation/curve_path'
CURVE_MARKERS = '/formation/markers'
ROBOT_POSES = '/formation/robot_poses'
CAMERA_IMAGE = '/camera/image_raw'
CAMERA_POSES = '/camera/robot_poses'
CAMERA_DEBUG = '/camera/debug_image'
DIAGNOSTICS = '/diagnostics'
POSE = 'pose'
TRUE_POSE = 'true_pose'
CMD_VEL = 'cmd_vel'
STATE = 'formation_state'
ESTIMATE = 'disturbance_estimate'
TICK = 'control_tick'

# Which bags record a topic (nodes/recorder.py).
EVERY_BAG = 'every bag'
WITH_IMAGES = 'with images'


@dataclass(frozen=True)
class Topic:
    """One topic: name (absolute, or relative for a per-robot topic), message class, QoS
    (the name of a profile in nodes/qos.py: what our publishers offer and, unless
    reader_qos_name says otherwise, what our subscriptions ask), meaning, and which bags
    record it (or None).
    """

    name: str
    msg_class: type
    qos_name: str
    meaning: str
    recorded: str | None = None
    reader_qos_name: str | None = None

    @property
    def profile(self):
        return getattr(qos, self.qos_name)

    @property
    def reader_profile(self):
        return getattr(qos, self.reader_qos_name or self.qos_name)

    @property
    def per_robot(self):
        return not self.name.startswith('/')

    @property
    def type_name(self):
        """'geometry_msgs/msg/PoseStamped', as bags and `ros2 topic` name it."""
        return f'{self.msg_class.__module__.split(".")[0]}/msg/{self.msg_class.__name__}'


REGISTRY = {t.name: t for t in (
    Topic(CURVE, Float64MultiArray, 'LATCHED',
          "the active curve: coefficients xi, for a moving curve their rate xi_dot, its "
          "clock (when it holds, s on the server's ROS clock; how long it has moved, s), then "
          "each agent's s_i; layout labels: basis kind and size, curve id, sizes of each part "
          '(core/curve_codec.py)', EVERY_BAG),
    Topic(ESTOP, Bool, 'LATCHED', 'true stops every robot at once, false releases; read '
          'from any publisher (any reliability, any durability)', EVERY_BAG,
          reader_qos_name='ANY_PUBLISHER'),
    Topic(ESTOP_STATE, DiagnosticStatus, 'LATCHED',
          "each node's e-stop state, latched for nodes that start while stopped: name = the "
          "node, hardware_id = its robot, values engaged, by, robots", EVERY_BAG,
          # read keeping all: a change reaches every holder at once, and a shallow reader's
          # history, shared by all writers, would drop some of their announcements
          reader_qos_name='ROLL_CALL'),
    Topic(CURVE_PATH, Path, 'LATCHED', 'the curve, sampled, for RViz', EVERY_BAG),
    Topic(DIAGNOSTICS, DiagnosticArray, 'EVENTS', "every node's status (1 Hz)", EVERY_BAG),
    Topic(POSE, PoseStamped, 'SENSOR', "a robot's pose, arena frame", EVERY_BAG),
    Topic(CMD_VEL, Twist, 'COMMAND', "a robot's velocity command (m/s, rad/s)", EVERY_BAG),
    Topic(STATE, JointState, 'STATE',
          "a controller's state for its out-neighbours: e_x, e_y, curve_id, leader_age",
          EVERY_BAG),
    Topic(ESTIMATE, Vector3Stamped, 'STATE',
          'disturbance estimate (x = d_v, y = d_w) every tick, stamped with the pose used',
          EVERY_BAG),
    Topic(TICK, JointState, 'STATE',
          'every tick: the command sent (v, w) and the stamps of the inputs it came from',
          EVERY_BAG),
    Topic(CAMERA_IMAGE, Image, 'IMAGE', 'overhead camera frames', WITH_IMAGES),
    Topic(CAMERA_POSES, PoseArray, 'SENSOR',
          'every tracked robot in agent order, NaN when not seen', WITH_IMAGES),
    Topic(CAMERA_DEBUG, Image, 'IMAGE', 'annotated camera frame (bgr8)'),
    Topic(TRUE_POSE, PoseStamped, 'SENSOR', "a fake robot's ground-truth pose"),
    Topic(ROBOT_POSES, JointState, 'SENSOR',
          "every robot's pose in one message (x, y, theta per robot)", EVERY_BAG),
    Topic(OBSERVED_CURVE, PolygonStamped, 'EVENTS',
          'a newly observed curve as ordered points (arena frame, m)'),
    Topic(CURVE_MARKERS, MarkerArray, 'LATCHED', "curve line and each agent's target point",
          EVERY_BAG),
    Topic(READY, String, 'ROLL_CALL',
          'names of the nodes that can receive /formation/curve (start-up handshake)'),
)}


def robot_namespace(index):
    """Namespace of robot `index` (1-based): /robot_<i>."""
    return f'/robot_{index}'


def robot_topic(index, name):
    """Absolute name of a per-robot topic, e.g. /robot_3/pose."""
    return f'{robot_namespace(index)}/{name}'


def _placed(name, robot):
    return name if robot is None else robot_topic(robot, name)


def publisher(node, name, robot=None):
    """node's publisher of the registered topic `name` (of robot `robot`, if given)."""
    topic = REGISTRY[name]
    return node.create_publisher(topic.msg_class, _placed(name, robot), topic.profile)


def subscription(node, name, callback, robot=None, **kwargs):
    """node's subscription to the registered topic `name` (of robot `robot`, if given), its
    callback guarded (nodes/guard.py: a message it cannot take is rejected, never fatal);
    kwargs go to create_subscription (raw, event_callbacks).
    """
    topic = REGISTRY[name]
    placed = _placed(name, robot)
    return node.create_subscription(topic.msg_class, placed, Guarded(node, placed, callback),
                                    topic.reader_profile, **kwargs)


def recorded(n, images=False):
    """[Topic] a run of n robots records, per-robot topics by their absolute names."""
    kinds = (EVERY_BAG, WITH_IMAGES) if images else (EVERY_BAG,)
    chosen = [t for t in REGISTRY.values() if t.recorded in kinds]
    out = [t for t in chosen if not t.per_robot]
    for i in range(1, n + 1):
        out += [Topic(robot_topic(i, t.name), t.msg_class, t.qos_name, t.meaning, t.recorded,
                      t.reader_qos_name) for t in chosen if t.per_robot]
    return out


class Use(NamedTuple):
    """A line of a node's TOPICS table: 'pub' or 'sub', a registered name, what the node
    does with it (default: the registry's meaning), and for a per-robot topic the robot's
    placeholder shown in its name ('<i>': every robot; None: the node's own namespace).
    """

    direction: str
    name: str
    meaning: str | None = None
    robot: str | None = None

    @property
    def shown_name(self):
        return _placed(self.name, self.robot)
