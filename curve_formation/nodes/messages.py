"""Conversions between ROS messages and core values, at the nodes' edges.

Curve message (std_msgs/Float64MultiArray on /formation/curve): data = xi (2H values, the
paper's layout); layout.dim[0] = ('xi', 2H, 2H), dim[1] = ('basis=<fourier|polynomial>', H, 0),
dim[2] = ('curve_id=<k>', 0, 0).
Neighbour state (geometry_msgs/PointStamped on /robot_<i>/formation_state): point.x, point.y =
the robot's target error e_i (m, arena frame), point.z = the curve id it refers to; header.stamp
= stamp of the pose it was computed from.
"""

import math

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PointStamped, PoseStamped, Twist, Vector3Stamped
import numpy as np
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from curve_formation.core.curves import Curve, make_basis


class MessageError(ValueError):
    """A message that cannot be converted (malformed layout, NaN, ...)."""


def stamp_to_seconds(stamp):
    return stamp.sec + stamp.nanosec * 1e-9


def seconds_to_stamp(seconds):
    sec = math.floor(seconds)
    return Time(sec=int(sec), nanosec=int(round((seconds - sec) * 1e9)) % 1_000_000_000)


def curve_to_msg(curve, curve_id):
    basis = curve.basis
    size = basis.K if basis.kind == 'fourier' else basis.p
    msg = Float64MultiArray()
    msg.layout.dim = [
        MultiArrayDimension(label='xi', size=2 * basis.H, stride=2 * basis.H),
        MultiArrayDimension(label=f'basis={basis.kind}', size=int(size), stride=0),
        MultiArrayDimension(label=f'curve_id={int(curve_id)}', size=0, stride=0),
    ]
    msg.data = [float(v) for v in curve.xi]
    return msg


def curve_from_msg(msg):
    """(Curve, curve_id) from a curve message; MessageError if malformed."""
    labels = {d.label.split('=')[0]: d for d in msg.layout.dim}
    try:
        kind = labels['basis'].label.split('=', 1)[1]
        curve_id = int(labels['curve_id'].label.split('=', 1)[1])
        basis = make_basis(kind, labels['basis'].size)
    except (KeyError, IndexError, ValueError) as exc:
        raise MessageError(f'curve message layout not understood: {exc}') from None
    xi = np.array(msg.data, dtype=float)
    if len(xi) != 2 * basis.H:
        raise MessageError(f'curve message has {len(xi)} coefficients, {basis.describe()} '
                           f'needs {2 * basis.H}')
    if not np.all(np.isfinite(xi)):
        raise MessageError('curve message has NaN or infinite coefficients')
    return Curve(basis, xi), curve_id


def pose_from_msg(msg):
    """(x, y, theta, stamp_s) from a PoseStamped (planar: heading from the quaternion)."""
    q = msg.pose.orientation
    theta = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    return msg.pose.position.x, msg.pose.position.y, theta, stamp_to_seconds(msg.header.stamp)


def pose_to_msg(x, y, theta, stamp_s, frame_id='arena'):
    msg = PoseStamped()
    msg.header.stamp = seconds_to_stamp(stamp_s)
    msg.header.frame_id = frame_id
    msg.pose.position.x, msg.pose.position.y = float(x), float(y)
    msg.pose.orientation.z = math.sin(theta / 2.0)
    msg.pose.orientation.w = math.cos(theta / 2.0)
    return msg


def twist_to_msg(v, w):
    msg = Twist()
    msg.linear.x, msg.angular.z = float(v), float(w)
    return msg


def twist_from_msg(msg):
    return msg.linear.x, msg.angular.z


def state_to_msg(error, curve_id, stamp_s, frame_id='arena'):
    msg = PointStamped()
    msg.header.stamp = seconds_to_stamp(stamp_s)
    msg.header.frame_id = frame_id
    msg.point.x, msg.point.y, msg.point.z = float(error[0]), float(error[1]), float(curve_id)
    return msg


def state_from_msg(msg):
    """(ex, ey, curve_id, stamp_s) from a neighbour's state message."""
    return (msg.point.x, msg.point.y, int(round(msg.point.z)),
            stamp_to_seconds(msg.header.stamp))


def estimate_to_msg(dhat, stamp_s):
    msg = Vector3Stamped()
    msg.header.stamp = seconds_to_stamp(stamp_s)
    msg.vector.x, msg.vector.y = float(dhat[0]), float(dhat[1])
    return msg
