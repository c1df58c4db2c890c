"""Which measurements a controller may believe: finite is not enough.

A pose 1e300 m away, one that jumps further than a robot can drive between two frames, or a
neighbour's error larger than the arena is not a measurement but a fault (a buggy script on
the domain, a tracker that swapped two markers); taken up, it would drive a robot at absurd
speeds and spread through the graph. Each check returns None for a plausible value, else why
not (one line). Units: m, s, m/s.
"""

import math


# Where no geofence bounds the arena: no lab arena is larger than this (m, |x| and |y|).
MAX_COORDINATE = 1.0e4
# How far beyond the geofence a measured pose may lie (m): outside the fence the controller
# stops its robot; further out still, the pose is not believed at all.
FENCE_SLACK = 1.0
# A pose may move at most JUMP_SPEED_FACTOR x the fastest wheel speed since the last one
# believed, plus JUMP_SLACK (tracker noise, a marker's sub-pixel jitter, a push).
JUMP_SPEED_FACTOR = 3.0
JUMP_SLACK = 0.02
# A planar orientation's quaternion must be unit within this.
QUATERNION_TOLERANCE = 0.01
# Commands where the experiment states no wheel limits are still bounded (m/s, rad/s).
DEFAULT_MAX_SPEED = 100.0
DEFAULT_MAX_TURN_RATE = 100.0

Box = tuple[float, float, float, float]


def plausible_box(geofence: Box | None) -> Box:
    """(xmin, ymin, xmax, ymax) (m) where a measured pose may lie: the geofence grown by
    FENCE_SLACK, or +-MAX_COORDINATE without one.
    """
    if geofence is None:
        return (-MAX_COORDINATE, -MAX_COORDINATE, MAX_COORDINATE, MAX_COORDINATE)
    x0, y0, x1, y1 = geofence
    return (x0 - FENCE_SLACK, y0 - FENCE_SLACK, x1 + FENCE_SLACK, y1 + FENCE_SLACK)


def position_problem(x: float, y: float, box: Box) -> str | None:
    """Why a position (m, arena frame) is not believable, or None."""
    if not (math.isfinite(x) and math.isfinite(y)):
        return 'not finite'
    if not (box[0] <= x <= box[2] and box[1] <= y <= box[3]):
        return (f'at ({x:.4g}, {y:.4g}) m, outside [{box[0]:g}, {box[2]:g}] x '
                f'[{box[1]:g}, {box[3]:g}] m')
    return None


def jump_problem(before: tuple[float, float, float], x: float, y: float, stamp: float,
                 top_speed: float) -> str | None:
    """Why a position at `stamp` (s) is not believable after the one believed before
    (x, y, stamp), for a robot whose wheels reach top_speed (m/s; inf: no check), or None.
    """
    if not math.isfinite(top_speed):
        return None
    x0, y0, t0 = before
    elapsed = abs(stamp - t0)
    moved = math.hypot(x - x0, y - y0)
    reach = JUMP_SPEED_FACTOR * top_speed * elapsed + JUMP_SLACK
    if moved > reach:
        return f'moved {moved:.3g} m in {elapsed:.3g} s (at most {reach:.3g} m believable)'
    return None


def error_problem(ex: float, ey: float, box: Box) -> str | None:
    """Why a neighbour's target error (m) is not believable (larger than the area where
    poses may lie), or None.
    """
    if not (math.isfinite(ex) and math.isfinite(ey)):
        return 'not finite'
    size = math.hypot(box[2] - box[0], box[3] - box[1])
    if math.hypot(ex, ey) > size:
        return f'error of {math.hypot(ex, ey):.4g} m, larger than the arena ({size:.4g} m)'
    return None


def quaternion_problem(x: float, y: float, z: float, w: float) -> str | None:
    """Why a quaternion is not a believable orientation (not unit), or None."""
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(norm) or abs(norm - 1.0) > QUATERNION_TOLERANCE:
        return f'quaternion of norm {norm:.4g}, not unit'
    return None


def bounded_command(v: float, w: float, max_speed: float = DEFAULT_MAX_SPEED,
                    max_turn_rate: float = DEFAULT_MAX_TURN_RATE) -> tuple[float, float]:
    """(v, w) scaled down together (keeping the curvature) to |v| <= max_speed (m/s) and
    |w| <= max_turn_rate (rad/s); what goes out where no wheel limits are configured.
    """
    scale = max(abs(v) / max_speed, abs(w) / max_turn_rate, 1.0)
    return v / scale, w / scale
