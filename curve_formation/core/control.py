"""The paper's leader/follower law, disturbance estimator and wheel limits.

Frames and units: poses (x, y, theta) in the arena frame (metres, radians); the offset point
xb = (x + l cos theta, y + l sin theta) with offset l (metres, l != 0); commands u = (v, w) in the
robot frame (m/s, rad/s); the disturbance estimate dhat is in the same units as u.

The per-agent functions below use only scalar math so that the same source runs in the ROS
controller node (plain Python) and inside the batch simulator's compiled kernel (numba).
"""

from dataclasses import dataclass
import math

import numpy as np


@dataclass(frozen=True)
class Gains:
    """k1 (1/s) on the target error, k2 on the estimate, offset l (m) of the control point."""

    k1: float
    k2: float
    offset: float


@dataclass(frozen=True)
class WheelLimits:
    """Differential drive: wheel base (m), max wheel speed (m/s), optional max turn rate (rad/s).

    A limit of 0 or infinity means unlimited.
    """

    wheel_base: float = 0.0
    max_wheel_speed: float = math.inf
    max_angular_rate: float = math.inf


NO_LIMITS = WheelLimits()


def offset_point(x, y, theta, offset):
    """Offset control point xb (m) ahead of the axle centre by `offset` along the heading."""
    return x + offset * math.cos(theta), y + offset * math.sin(theta)


def agent_input(fx, fy, ex, ey, theta, dhat_v, dhat_w, k1, k2, offset):
    """One agent's command and estimator rate.

    Args:
        fx, fy: feedback term: e_i for the leader, sum_j a_ij (e_i - e_j) for a follower (m).
        ex, ey: own target error e_i = xb_i - G(s_i) xi (m), arena frame.
        theta: heading (rad).
        dhat_v, dhat_w: disturbance estimate.
    Returns:
        (v, w, ddhat_v, ddhat_w): u = R^-1 ub with ub = -k1 f - k2 R dhat, and the estimator
        rate dhat' = k2 R^T e.
    """
    c = math.cos(theta)
    s = math.sin(theta)
    v = -k1 * (c * fx + s * fy) - k2 * dhat_v
    w = -k1 * (-s * fx + c * fy) / offset - k2 * dhat_w
    return v, w, k2 * (c * ex + s * ey), k2 * offset * (-s * ex + c * ey)


def saturate(v, w, wheel_base, max_wheel_speed, max_angular_rate):
    """Scale (v, w) down so both wheel speeds and |w| are within limits, keeping curvature w/v.

    Wheel speeds are v -+ w * wheel_base / 2 (m/s). Returns the scaled (v, w).
    """
    scale = 1.0
    if max_wheel_speed > 0.0 and max_wheel_speed < math.inf:
        fastest = abs(v) + abs(w) * 0.5 * wheel_base
        if fastest > max_wheel_speed:
            scale = max_wheel_speed / fastest
    if max_angular_rate > 0.0 and max_angular_rate < math.inf:
        if abs(w) * scale > max_angular_rate:
            scale = max_angular_rate / abs(w)
    return v * scale, w * scale


def limit_acceleration(v, w, prev_v, prev_w, dt, max_linear_accel, max_angular_accel):
    """Clamp the change from the previous command to the acceleration limits over dt (s).

    Limits in m/s^2 and rad/s^2; 0 or infinity means unlimited. Returns (v, w).
    """
    if max_linear_accel > 0.0 and max_linear_accel < math.inf:
        step = max_linear_accel * dt
        v = min(max(v, prev_v - step), prev_v + step)
    if max_angular_accel > 0.0 and max_angular_accel < math.inf:
        step = max_angular_accel * dt
        w = min(max(w, prev_w - step), prev_w + step)
    return v, w


def inside_fence(x, y, fence):
    """True when (x, y) lies in fence = (xmin, ymin, xmax, ymax), or when fence is None."""
    return fence is None or (fence[0] <= x <= fence[2] and fence[1] <= y <= fence[3])


def leader_feedback(ex, ey):
    """The leader's feedback term: its own error (m)."""
    return ex, ey


def follower_feedback(ex, ey, neighbour_errors, weights):
    """A follower's feedback sum_j a_ij (e_i - e_j) from its in-neighbours' errors (k, 2)."""
    fx = 0.0
    fy = 0.0
    for j in range(len(weights)):
        fx += weights[j] * (ex - neighbour_errors[j][0])
        fy += weights[j] * (ey - neighbour_errors[j][1])
    return fx, fy


def wheel_speeds(v, w, wheel_base):
    """(right, left) wheel linear speeds (m/s) for body velocities (v, w)."""
    return v + 0.5 * wheel_base * w, v - 0.5 * wheel_base * w


def stacked_paper_input(poses, dhat, g_bar, xi, laplacian, leader, gains):
    """The paper's stacked law, with the pseudo-inverse, as a reference for tests.

    ub = -k1 (Lbar Gbar xi_e + Lambda_bar xb_e) - k2 R dhat with xi_e = Gbar^+ xb - xi.

    Args:
        poses: (n, 3) x, y, theta.  dhat: (n, 2).  g_bar: (2n, 2H).  xi: (2H,).
        laplacian: (n, n).  leader: 0-based index.  gains: Gains.
    Returns:
        ub (n, 2) in the arena frame.
    """
    n = len(poses)
    xb = poses[:, :2] + gains.offset * np.column_stack([np.cos(poses[:, 2]),
                                                        np.sin(poses[:, 2])])
    xb_e = xb.ravel() - g_bar @ xi
    xi_e = np.linalg.pinv(g_bar) @ xb.ravel() - xi
    lam = np.zeros((n, n))
    lam[leader, leader] = 1.0
    consensus = np.kron(laplacian, np.eye(2)) @ g_bar @ xi_e + np.kron(lam, np.eye(2)) @ xb_e
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    r_dhat = np.column_stack([c * dhat[:, 0] - gains.offset * s * dhat[:, 1],
                              s * dhat[:, 0] + gains.offset * c * dhat[:, 1]])
    return -gains.k1 * consensus.reshape(n, 2) - gains.k2 * r_dhat
