"""The formation's ROS interface as plain data, without ROS: every topic's name, message type,
QoS and meaning, the QoS profiles, the per-robot names, and the readers of the messages.

The nodes attach rclpy's classes to these records (nodes/topics.py, nodes/qos.py); the
recorder, the bag reader and the analysis build from the same records without importing rclpy.
Per-robot topics have relative names, so a robot is placed by its namespace /robot_<i>.
"""

from dataclasses import dataclass
import re
from typing import Any

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.controller.estop import EstopReport, parse_report
from curve_formation.core.controller.plausibility import quaternion_problem
from curve_formation.core.formation.curve_codec import (
    CodecError,
    CurveClock,
    decode_agent_parameters,
    decode_curve,
    decode_curve_clock,
    decode_curve_rate,
    yaw_from_quaternion,
)
from curve_formation.core.formation.curves import Curve


CURVE = '/formation/curve'
OBSERVED_CURVE = '/formation/observed_curve'
ESTOP = '/formation/estop'
ESTOP_STATE = '/formation/estop_state'
READY = '/formation/ready'
CURVE_PATH = '/formation/curve_path'
CURVE_MARKERS = '/formation/markers'
ROBOT_POSES = '/formation/robot_poses'
FLEET = '/formation/fleet'
PREFLIGHT = '/formation/preflight'
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
TOP_SPEED = 'top_speed'

# Which bags record a topic (nodes/recorder.py).
EVERY_BAG = 'every bag'
WITH_IMAGES = 'with images'


@dataclass(frozen=True)
class QosSpec:
    """A QoS profile as data: reliable (else best effort), transient local (else volatile),
    and the history's depth (None: keep all).
    """

    reliable: bool
    transient_local: bool = False
    depth: int | None = 1


# Each profile, chosen for the data it carries.
QOS = {
    # Poses: latest wins, drops are fine (rclpy's qos_profile_sensor_data).
    'SENSOR': QosSpec(reliable=False, depth=5),
    # Velocity commands: reliable, only the newest matters.
    'COMMAND': QosSpec(reliable=True, depth=1),
    # A neighbour's state: reliable and shallow; stale values are rejected by stamp anyway.
    'STATE': QosSpec(reliable=True, depth=2),
    # The curve and its visualisation: latched, so a late joiner gets the current one.
    'LATCHED': QosSpec(reliable=True, transient_local=True, depth=1),
    # The start-up handshake (readiness.py): one message from each of many writers, all kept
    # (a reader's history is shared by every writer of a topic, so a shallow one would drop
    # some), and latched for a curve server that starts late.
    'ROLL_CALL': QosSpec(reliable=True, transient_local=True, depth=None),
    # Diagnostics and the e-stop: reliable, a few deep.
    'EVENTS': QosSpec(reliable=True, depth=5),
    # E-stop commands as read: best effort and volatile, which every writer matches (volatile
    # or transient-local, reliable or best-effort: `ros2 topic pub`, an RViz or Foxglove
    # button, a foot-pedal script). Nodes that act on the e-stop also read them with
    # ESTOP_RELIABLE, so a reliable sender's retransmissions reach them (nodes/estop.py).
    'ANY_PUBLISHER': QosSpec(reliable=False, depth=10),
    'ESTOP_RELIABLE': QosSpec(reliable=True, depth=10),
    # Camera frames: only the newest is worth processing; an older one would only add latency.
    'IMAGE': QosSpec(reliable=False, depth=1),
}


@dataclass(frozen=True)
class TopicSpec:
    """One topic: name (absolute, or relative for a per-robot topic), message type
    ('geometry_msgs/msg/PoseStamped', as bags and `ros2 topic` name it), QoS (a name in QOS:
    what our publishers offer and, unless reader_qos_name says otherwise, what our
    subscriptions ask), meaning, and which bags record it (or None).
    """

    name: str
    type_name: str
    qos_name: str
    meaning: str
    recorded: str | None = None
    reader_qos_name: str | None = None

    @property
    def qos(self) -> QosSpec:
        return QOS[self.qos_name]

    @property
    def reader_qos_key(self) -> str:
        """The QOS name our subscriptions ask for."""
        return self.reader_qos_name or self.qos_name

    @property
    def per_robot(self) -> bool:
        return not self.name.startswith('/')


TOPICS = {t.name: t for t in (
    TopicSpec(CURVE, 'std_msgs/msg/Float64MultiArray', 'LATCHED',
              "the active curve: coefficients xi, for a moving curve their rate xi_dot, its "
              "clock (when it holds, s on the server's ROS clock; how long it has moved, s), "
              "then each agent's s_i; layout labels: basis kind and size, curve id, sizes of "
              'each part (core/formation/curve_codec.py)', EVERY_BAG),
    TopicSpec(ESTOP, 'std_msgs/msg/Bool', 'LATCHED', 'true stops every robot at once, false '
              'releases; read from any publisher (any reliability, any durability)', EVERY_BAG,
              reader_qos_name='ANY_PUBLISHER'),
    TopicSpec(ESTOP_STATE, 'diagnostic_msgs/msg/DiagnosticStatus', 'LATCHED',
              "each node's e-stop state, latched for nodes that start while stopped: name = "
              'the node, hardware_id = its robot, values engaged, by, since, robots, holders (the '
              'holders it hears, itself included)', EVERY_BAG,
              # read keeping all: a change reaches every holder at once, and a shallow
              # reader's history, shared by all writers, would drop some of their
              # announcements
              reader_qos_name='ROLL_CALL'),
    TopicSpec(CURVE_PATH, 'nav_msgs/msg/Path', 'LATCHED', 'the curve, sampled, for RViz',
              EVERY_BAG),
    TopicSpec(DIAGNOSTICS, 'diagnostic_msgs/msg/DiagnosticArray', 'EVENTS',
              "every node's status (1 Hz)", EVERY_BAG),
    TopicSpec(POSE, 'geometry_msgs/msg/PoseStamped', 'SENSOR', "a robot's pose, arena frame",
              EVERY_BAG),
    TopicSpec(CMD_VEL, 'geometry_msgs/msg/Twist', 'COMMAND',
              "a robot's velocity command (m/s, rad/s)", EVERY_BAG),
    TopicSpec(STATE, 'sensor_msgs/msg/JointState', 'STATE',
              "a controller's state for its out-neighbours: e_x, e_y, curve_id, leader_age",
              EVERY_BAG),
    TopicSpec(ESTIMATE, 'geometry_msgs/msg/Vector3Stamped', 'STATE',
              'disturbance estimate (x = d_v, y = d_w) every tick, stamped with the pose used',
              EVERY_BAG),
    TopicSpec(TICK, 'sensor_msgs/msg/JointState', 'STATE',
              'every tick: the command sent (v, w) and the stamps of the inputs it came from',
              EVERY_BAG),
    TopicSpec(TOP_SPEED, 'std_msgs/msg/Float64', 'LATCHED',
              "a robot's fastest straight drive (m/s) as its controller knows its wheels: "
              "the wheels' limit times the slower wheel's gain (its motor check's or "
              'learnt online; 1 where none); after its motor check, where it runs one. The '
              'curve server assigns targets by trip time with it', EVERY_BAG),
    TopicSpec(CAMERA_IMAGE, 'sensor_msgs/msg/Image', 'IMAGE', 'overhead camera frames',
              WITH_IMAGES),
    TopicSpec(CAMERA_POSES, 'geometry_msgs/msg/PoseArray', 'SENSOR',
              'every tracked robot in agent order, NaN when not seen', WITH_IMAGES),
    TopicSpec(CAMERA_DEBUG, 'sensor_msgs/msg/Image', 'IMAGE', 'annotated camera frame (bgr8)'),
    TopicSpec(TRUE_POSE, 'geometry_msgs/msg/PoseStamped', 'SENSOR',
              "a fake robot's ground-truth pose"),
    TopicSpec(ROBOT_POSES, 'sensor_msgs/msg/JointState', 'SENSOR',
              "every robot's pose in one message (x, y, theta per robot)", EVERY_BAG),
    TopicSpec(OBSERVED_CURVE, 'geometry_msgs/msg/PolygonStamped', 'EVENTS',
              'a newly observed curve as ordered points (arena frame, m)'),
    TopicSpec(CURVE_MARKERS, 'visualization_msgs/msg/MarkerArray', 'LATCHED',
              "curve line and each agent's target point", EVERY_BAG),
    TopicSpec(FLEET, 'diagnostic_msgs/msg/DiagnosticArray', 'LATCHED',
              "the fleet's status, 1 Hz: one status per robot (name robot_<i>, hardware_id its "
              'link), values seen, pose_age_s, link, reply_age_s, battery, estopped, motion, '
              'controller, top_speed_mps (as its controller measured the wheels), lost (when its '
              'marker or link was lost, s since t = 0)', EVERY_BAG),
    TopicSpec(PREFLIGHT, 'diagnostic_msgs/msg/DiagnosticArray', 'LATCHED',
              "the pre-flight's result: one status per robot (seen, link, reply age, stop "
              'confirmed, problems), and one for the whole fleet', EVERY_BAG),
    TopicSpec(READY, 'std_msgs/msg/String', 'ROLL_CALL',
              'names of the nodes that can receive /formation/curve (start-up handshake)'),
)}

_ROBOT_TOPIC = re.compile(r'^/robot_(\d+)/([A-Za-z0-9_]+)$')


ROBOT_PREFIX = 'robot_'   # of every robot's name: robot_<i>


def robot_name(index: int) -> str:
    """Name of robot `index` (1-based): robot_<i>, as its namespace, e-stop and diagnostics
    know it.
    """
    return f'{ROBOT_PREFIX}{index}'


def robot_index(name: str) -> int | None:
    """The robot (1-based) a name belongs to: 3 for robot_3, /robot_3, /robot_3/robot_bridge
    or robot_3.formation_controller (its first part); None for any other name.
    """
    first = name.strip('/').split('/')[0].split('.')[0]
    number = first.removeprefix(ROBOT_PREFIX) if first.startswith(ROBOT_PREFIX) else ''
    return int(number) if number.isdigit() else None


def robot_namespace(index: int) -> str:
    """Namespace of robot `index` (1-based): /robot_<i>."""
    return f'/{robot_name(index)}'


def robot_topic(index: int, name: str) -> str:
    """Absolute name of a per-robot topic, e.g. /robot_3/pose."""
    return f'{robot_namespace(index)}/{name}'


def robot_of(topic: str, among: tuple[str, ...] | None = None) -> tuple[int, str] | None:
    """(robot index, per-robot name) of an absolute per-robot topic, e.g. (3, 'pose') of
    /robot_3/pose; None for any other name, or for a name not `among` those given.
    """
    match = _ROBOT_TOPIC.match(topic)
    if match is None or (among is not None and match.group(2) not in among):
        return None
    return int(match.group(1)), match.group(2)


def type_name(topic: str) -> str | None:
    """The message type of a topic by its absolute name (a per-robot one of any robot), or
    None if it is not one of the formation's.
    """
    placed = robot_of(topic)
    spec = TOPICS.get(placed[1] if placed is not None else topic)
    return None if spec is None or (placed is None and spec.per_robot) else spec.type_name


# Readers of the formation's messages into core values. They use attribute access only, so
# they read rclpy's message objects (nodes/messages.py) and those rosbags deserialises from a
# bag (bags/analysis.py) alike; a malformed message raises CodecError.

def stamp_to_seconds(stamp: Any) -> float:
    """A builtin_interfaces/Time as s."""
    return stamp.sec + stamp.nanosec * 1e-9


def pose_from_msg(msg: Any) -> tuple[float, float, float, float]:
    """(x, y, theta, stamp s) from a PoseStamped (m, m, rad; planar: heading from the
    quaternion); CodecError if the quaternion is not unit (core.controller.plausibility).
    """
    q = msg.pose.orientation
    problem = quaternion_problem(q.x, q.y, q.z, q.w)
    if problem is not None:
        raise CodecError(f'pose with a {problem}')
    return (msg.pose.position.x, msg.pose.position.y, yaw_from_quaternion(q.x, q.y, q.z, q.w),
            stamp_to_seconds(msg.header.stamp))


def twist_from_msg(msg: Any) -> tuple[float, float]:
    """(v m/s, omega rad/s) of a Twist."""
    return msg.linear.x, msg.angular.z


def _curve_dims(msg: Any) -> list[tuple[str, int]]:
    return [(d.label, d.size) for d in msg.layout.dim]


def curve_from_msg(msg: Any) -> tuple[Curve, int]:
    """(Curve, curve id) from a curve message (core.formation.curve_codec's layout)."""
    return decode_curve(_curve_dims(msg), msg.data)


def curve_rate_from_msg(msg: Any) -> Curve | None:
    """A moving curve's coefficient rate (Curve; points(s) in m/s), or None."""
    return decode_curve_rate(_curve_dims(msg), msg.data)


def curve_clock_from_msg(msg: Any) -> CurveClock | None:
    """When a curve message's coefficients hold (CurveClock), or None."""
    return decode_curve_clock(_curve_dims(msg), msg.data)


def agent_parameters_from_msg(msg: Any) -> FloatArray | None:
    """The agents' parameters s (n,) a curve message carries, or None."""
    return decode_agent_parameters(_curve_dims(msg), msg.data)


def estop_state_from_msg(msg: Any) -> EstopReport:
    """core.controller.estop.EstopReport of a node's e-stop state (DiagnosticStatus)."""
    try:
        return parse_report(msg.name, msg.hardware_id, {kv.key: kv.value for kv in msg.values})
    except ValueError as exc:
        raise CodecError(str(exc)) from None
