"""Unicycle kinematics with constant input disturbance.

x' = cos(theta) (v + d_v), y' = sin(theta) (v + d_v), theta' = w + d_w; arena frame, metres,
radians, seconds. Plain scalar math: the batch simulator compiles it with numba and the fake
robot node calls it as is.
"""

import math


def chord_ratio(half):
    """sin(h) / h: chord over arc length of an arc turning 2 h (rad); accurate as h -> 0."""
    return math.sin(half) / half if abs(half) > 1e-4 else 1.0 - half * half / 6.0


def arc_step(x, y, theta, v, w, dt):
    """Exact pose after dt (s) at constant body velocities v (m/s) and w (rad/s).

    The chord of the arc, v dt sin(h) / h with h = w dt / 2, points along the mid-period
    heading; this form stays accurate as w -> 0, where v / w times a sine difference does not.
    """
    half = 0.5 * w * dt
    chord = v * dt * chord_ratio(half)
    mid = theta + half
    return x + chord * math.cos(mid), y + chord * math.sin(mid), theta + w * dt
