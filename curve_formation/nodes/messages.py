"""Conversions between ROS messages and core values, at the nodes' edges.

Curve message (std_msgs/Float64MultiArray on /formation/curve): data = xi (2H values, the
paper's layout); layout.dim[0] = ('xi', 2H, 2H), dim[1] = ('basis=<fourier|polynomial>', H, 0),
dim[2] = ('curve_id=<k>', 0, 0).
Every robot's pose (sensor_msgs/JointState on /formation/robot_poses): header.stamp = when
the poses were taken, position = x_1, y_1, theta_1, x_2, ... in agent order (m, rad, arena
frame; NaN for a robot not seen), no names (a compact vector: 50 robots decode in 30 us, a
PoseArray of 50 in 630 us).
Neighbour state (sensor_msgs/JointState on /robot_<i>/formation_state, used as a labelled
vector with a header): names STATE_FIELDS, positions their values: e_x, e_y (m, arena frame),
the curve id, and the age of the newest news of the leader the robot has when its pose was
taken (s, NO_NEWS before any; slightly negative for news that came after the pose; an age,
not a stamp, so that hosts' clocks need not agree); header.stamp = stamp of the pose the error
was computed from.
"""

from collections.abc import Sequence
import math

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import (
    Point32,
    PolygonStamped,
    Pose,
    PoseArray,
    PoseStamped,
    Twist,
    Vector3Stamped,
)
import numpy as np
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from curve_formation.core.controller.estop import estop_fields
from curve_formation.core.controller.inputs import State, Tick
from curve_formation.core.formation.curve_codec import (
    CodecError,
    curve_id_from_float,
    CurveClock,
    encode_curve,
    quaternion_from_yaw,
)
from curve_formation.core.formation.curves import Curve
from curve_formation.interface import (  # noqa: F401 (the readers, for the nodes)
    agent_parameters_from_msg,
    curve_clock_from_msg,
    curve_from_msg,
    curve_rate_from_msg,
    estop_state_from_msg,
    pose_from_msg,
    stamp_to_seconds,
    twist_from_msg,
)


MessageError = CodecError


def seconds_to_stamp(seconds: float) -> Time:
    sec = math.floor(seconds)
    return Time(sec=int(sec), nanosec=int(round((seconds - sec) * 1e9)) % 1_000_000_000)


def curve_to_msg(curve: Curve, curve_id: int, s: Sequence[float] | np.ndarray | None = None,
                 rate: Curve | None = None, clock: CurveClock | None = None
                 ) -> Float64MultiArray:
    """Float64MultiArray of a curve and, if given, its coefficients' rate (a moving curve),
    when it holds (core.formation.curve_codec.CurveClock) and the agents' parameters s (n,).
    """
    dims, data = encode_curve(curve, curve_id, s, rate, clock)
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                      for label, size, stride in dims]
    msg.data = data
    return msg


def pose_to_msg(x: float, y: float, theta: float, stamp_s: float, frame_id: str = 'arena',
                msg: PoseStamped | None = None) -> PoseStamped:
    """PoseStamped of a planar pose; `msg`: one to fill instead of a new one (a publisher's
    own, reused: publish() serialises it at once; 3.6 us against 9.3 us).
    """
    msg = PoseStamped() if msg is None else msg
    msg.header.stamp = seconds_to_stamp(stamp_s)
    msg.header.frame_id = frame_id
    msg.pose.position.x, msg.pose.position.y = float(x), float(y)
    _, _, msg.pose.orientation.z, msg.pose.orientation.w = quaternion_from_yaw(theta)
    return msg


def twist_to_msg(v: float, w: float) -> Twist:
    msg = Twist()
    msg.linear.x, msg.angular.z = float(v), float(w)
    return msg


STATE_FIELDS = ('e_x', 'e_y', 'curve_id', 'leader_age')
NO_NEWS = -1.0   # leader_age before any news of the leader (real ages are above -0.25 s)


def state_to_msg(state: State, frame_id: str = 'arena', msg: JointState | None = None
                 ) -> JointState:
    """JointState carrying a core.controller.agent.State; `msg`: one to fill, as pose_to_msg."""
    if msg is None:
        msg = JointState()
        msg.name = list(STATE_FIELDS)
    msg.header.stamp = seconds_to_stamp(state.stamp)
    msg.header.frame_id = frame_id
    leader = NO_NEWS if state.leader_age is None else float(state.leader_age)
    msg.position = [float(state.error[0]), float(state.error[1]), float(state.curve_id), leader]
    return msg


def state_from_msg(msg: JointState) -> tuple[float, float, int, float, float | None]:
    """(ex, ey, curve_id, stamp_s, leader_age_s or None); MessageError if malformed."""
    values = dict(zip(msg.name, msg.position, strict=False))
    missing = [f for f in STATE_FIELDS if f not in values]
    if missing:
        raise MessageError(f'formation state lacks {missing}')
    leader = values['leader_age']
    if not (math.isfinite(values['e_x']) and math.isfinite(values['e_y'])
            and math.isfinite(leader)):
        raise MessageError('formation state has NaN or infinite values')
    return (values['e_x'], values['e_y'], curve_id_from_float(values['curve_id']),
            stamp_to_seconds(msg.header.stamp), None if leader <= NO_NEWS else leader)


def estimate_to_msg(dhat: Sequence[float], stamp_s: float) -> Vector3Stamped:
    msg = Vector3Stamped()
    msg.header.stamp = seconds_to_stamp(stamp_s)
    msg.vector.x, msg.vector.y = float(dhat[0]), float(dhat[1])
    return msg


def tick_to_msg(tick: Tick, now_s: float) -> JointState:
    """JointState of one control tick at now_s: the command sent and the inputs it came from.

    names 'v' (m/s), 'w' (rad/s), 'pose_stamp' (s, NaN if none), 'x', 'y', 'theta' (m, rad:
    the pose the law used, predicted to now_s with predict_pose; NaN when stopped) and
    'stamp_<j>' (s) for each in-neighbour state used, in position.
    """
    msg = JointState()
    msg.header.stamp = seconds_to_stamp(now_s)
    pose_stamp = math.nan if tick.error_stamp is None else tick.error_stamp
    pose = (math.nan,) * 3 if tick.pose is None else tick.pose
    msg.name = (['v', 'w', 'pose_stamp', 'x', 'y', 'theta']
                + [f'stamp_{j}' for j, _ in tick.neighbour_stamps])
    msg.position = [float(tick.v), float(tick.w), float(pose_stamp)] + [float(v) for v in pose] + [
        math.nan if stamp is None else float(stamp) for _, stamp in tick.neighbour_stamps]
    return msg


def tick_from_msg(msg: JointState) -> dict[str, float]:
    """{name: value} of a control_tick message."""
    return dict(zip(msg.name, msg.position, strict=True))


# sensor_msgs/Image encodings this package reads, with their channel count.
IMAGE_CHANNELS = {'mono8': 1, '8UC1': 1, 'bgr8': 3, 'rgb8': 3, 'bgra8': 4, 'rgba8': 4}


def image_to_msg(image: np.ndarray, stamp_s: float, frame_id: str = 'camera') -> Image:
    """sensor_msgs/Image from a uint8 array: (h, w) -> mono8, (h, w, 3) -> bgr8 (OpenCV's)."""
    image = np.ascontiguousarray(image, dtype=np.uint8)
    msg = Image()
    msg.header.stamp = seconds_to_stamp(stamp_s)
    msg.header.frame_id = frame_id
    msg.height, msg.width = image.shape[:2]
    msg.encoding = 'mono8' if image.ndim == 2 else 'bgr8'
    msg.is_bigendian = 0
    msg.step = msg.width * (1 if image.ndim == 2 else image.shape[2])
    msg.data = image.tobytes()
    return msg


def gray_from_image_msg(msg: Image) -> np.ndarray:
    """(h, w) uint8 grey image from a mono8 / bgr8 / rgb8 / bgra8 / rgba8 Image.

    Raises MessageError on another encoding or a size that does not match the header.
    """
    channels = IMAGE_CHANNELS.get(msg.encoding)
    if channels is None:
        raise MessageError(f'image encoding {msg.encoding!r} not supported; one of '
                           f'{", ".join(IMAGE_CHANNELS)}')
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if msg.step < msg.width * channels or data.size < msg.step * msg.height:
        raise MessageError(f'image data ({data.size} bytes, step {msg.step}) does not hold '
                           f'{msg.height} x {msg.width} x {channels}')
    rows = data[:msg.step * msg.height].reshape(msg.height, msg.step)
    pixels = rows[:, :msg.width * channels].reshape(msg.height, msg.width, channels)
    if channels == 1:
        return np.ascontiguousarray(pixels[..., 0])
    import cv2
    code = {('bgr8', 3): cv2.COLOR_BGR2GRAY, ('rgb8', 3): cv2.COLOR_RGB2GRAY,
            ('bgra8', 4): cv2.COLOR_BGRA2GRAY, ('rgba8', 4): cv2.COLOR_RGBA2GRAY}
    return cv2.cvtColor(np.ascontiguousarray(pixels), code[(msg.encoding, channels)])


def robot_poses_to_msg(poses: np.ndarray, stamp_s: float, frame_id: str = 'arena'
                       ) -> JointState:
    """JointState of every robot's pose (n, 3) at stamp_s (the layout above)."""
    msg = JointState()
    msg.header.stamp = seconds_to_stamp(stamp_s)
    msg.header.frame_id = frame_id
    msg.position = np.asarray(poses, dtype=float).ravel().tolist()
    return msg


def robot_poses_from_msg(msg: JointState) -> tuple[np.ndarray, float]:
    """(poses (n, 3), stamp_s) from a /formation/robot_poses message; MessageError if its
    length is not a multiple of 3.
    """
    values = np.asarray(msg.position, dtype=float)
    if values.size % 3:
        raise MessageError(f'robot poses hold {values.size} values, not [x, y, theta] per robot')
    return values.reshape(-1, 3), stamp_to_seconds(msg.header.stamp)


def pose_array_to_msg(poses: dict[int, Sequence[float]], count: int, stamp_s: float,
                      frame_id: str = 'arena') -> PoseArray:
    """geometry_msgs/PoseArray of agents 1..count in order; an agent missing from `poses`
    ({agent: (x, y, theta)}) gets a NaN pose, so positions keep their meaning.
    """
    msg = PoseArray()
    msg.header.stamp = seconds_to_stamp(stamp_s)
    msg.header.frame_id = frame_id
    nan = float('nan')
    for agent in range(1, count + 1):
        x, y, th = poses.get(agent, (nan, nan, nan))
        pose = Pose()
        pose.position.x, pose.position.y = float(x), float(y)
        _, _, qz, qw = quaternion_from_yaw(th) if math.isfinite(th) else (0, 0, nan, nan)
        pose.orientation.z, pose.orientation.w = float(qz), float(qw)
        msg.poses.append(pose)
    return msg


def polygon_to_msg(points: np.ndarray, closed: bool, stamp_s: float,
                   frame_id: str = 'arena') -> PolygonStamped:
    """PolygonStamped of ordered curve points (k, 2) (m); a closed curve repeats its first
    point last, which is how the curve server tells it from an open one.
    """
    pts = np.asarray(points, dtype=float)
    if closed:
        pts = np.vstack([pts, pts[:1]])
    msg = PolygonStamped()
    msg.header.stamp = seconds_to_stamp(stamp_s)
    msg.header.frame_id = frame_id
    msg.polygon.points = [Point32(x=float(x), y=float(y)) for x, y in pts]
    return msg


def polygon_from_msg(msg: PolygonStamped) -> tuple[np.ndarray, bool]:
    """(points (k, 2), closed) of an observed curve: closed when the last point repeats the
    first (then dropped).
    """
    pts = np.array([[p.x, p.y] for p in msg.polygon.points], dtype=float).reshape(-1, 2)
    closed = len(pts) > 3 and bool(np.array_equal(pts[0], pts[-1]))
    return (pts[:-1] if closed else pts), closed


def estop_state_to_msg(holder: str, role: str, robot: str, engaged: bool, by: str,
                       since: float, robots: int = 0, holders: int = 0) -> DiagnosticStatus:
    """DiagnosticStatus of a node's e-stop state (core.controller.estop.EstopReport's fields):
    level
    WARN engaged, OK released.
    """
    return DiagnosticStatus(
        level=DiagnosticStatus.WARN if engaged else DiagnosticStatus.OK, name=holder,
        hardware_id=robot,
        message=(f'e-stop engaged by {by}' if engaged else
                 f'e-stop released by {by}' if by else 'e-stop released'),
        values=[KeyValue(key=key, value=value) for key, value
                in estop_fields(engaged, role, by, since, robots, holders).items()])

