"""Unicycle kinematics with constant input disturbance.

x' = cos(theta) (v + d_v), y' = sin(theta) (v + d_v), theta' = w + d_w; arena frame, metres,
radians, seconds. Plain scalar math: the batch simulator compiles it with numba and the fake
robot node calls it as is.
"""

import math


def arc_step(x, y, theta, v, w, dt):
    """Exact pose after dt (s) at constant body velocities v (m/s) and w (rad/s)."""
    if abs(w * dt) < 1e-9:
        mid = theta + 0.5 * w * dt
        return x + v * dt * math.cos(mid), y + v * dt * math.sin(mid), theta + w * dt
    turned = theta + w * dt
    radius = v / w
    return (x + radius * (math.sin(turned) - math.sin(theta)),
            y - radius * (math.cos(turned) - math.cos(theta)), turned)
