"""A differential drive's limits (WheelLimits) and how a command is kept within them.

Commands (v, w) in m/s and rad/s, robot frame; wheel speeds in m/s at the rim; the fence in
the arena frame (m). Plain scalar math: the batch simulator compiles it with numba.
"""

import math
from typing import NamedTuple

from curve_formation.core.base.shapes import Command
from curve_formation.core.controller.settings import default


class WheelLimits(NamedTuple):
    """Differential drive: wheel base (m), max wheel speed (m/s), optional max turn rate
    (rad/s) and acceleration limits (m/s^2, rad/s^2). 0 or infinity means unlimited.
    """

    wheel_base: float = default('limits.wheel_base')
    max_wheel_speed: float = default('limits.max_wheel_speed')
    max_angular_rate: float = default('limits.max_angular_rate')
    max_linear_accel: float = default('limits.max_linear_accel')
    max_angular_accel: float = default('limits.max_angular_accel')


NO_LIMITS = WheelLimits()


def timed_by(limits: WheelLimits) -> bool:
    """True when the wheel limits time a trip and can saturate a command (a wheel base and a
    finite wheel speed limit): driving.drive_direction needs them to choose between forwards
    and backwards, ray_growth to tell a saturated motion.
    """
    return limits.wheel_base > 0.0 and 0.0 < limits.max_wheel_speed < math.inf


def clipped(v: float, w: float, limits: WheelLimits, by: float = 1.0) -> bool:
    """True when the command (v, w) (m/s, rad/s) goes past the wheel limits by more than the
    factor `by` (1: the limits change it at all).
    """
    v, w = v / by, w / by
    sv, sw = saturate(v, w, limits.wheel_base, limits.max_wheel_speed, limits.max_angular_rate)
    return sv != v or sw != w


def saturate_drifting(v: float, w: float, drift_v: float, drift_w: float, wheel_base: float,
                      max_wheel_speed: float, max_angular_rate: float) -> Command:
    """The motion (v, w) (m/s, rad/s) whose command, the motion minus the drift (drift_v,
    drift_w), is scaled down into the limits (saturate): the curvature of the command kept.
    """
    cv, cw = saturate(v - drift_v, w - drift_w, wheel_base, max_wheel_speed, max_angular_rate)
    return cv + drift_v, cw + drift_w


# Share of the law's turn saturate_turning keeps (at least): the sampled heading asks for
# most of the heading error in one tick, which a command 2 ticks late would overshoot.
TURN_SHARE = 0.25


def saturate_turning(v: float, w: float, drift_v: float, drift_w: float, wheel_base: float,
                     max_wheel_speed: float, max_angular_rate: float) -> Command:
    """The motion (v, w) (m/s, rad/s) within the limits, turning first.

    The command is the motion minus the drift (drift_v, drift_w); the limits bound the
    command: |v_c| + |w_c| B / 2 <= max wheel speed and |w_c| <= max turn rate. A motion
    within them is returned as it is. Otherwise TURN_SHARE of the motion's turn (or what
    scaling down would keep, if more) is kept, its command at most the wheels' turn with no
    forward command, and the speed gets what the wheels have left: a robot far from facing
    its target turns in place (carried along only by drift_v) at the wheels' limit and then
    drives straight, the fastest way a differential drive with bounded wheel speeds has to a
    point (Balkcom and Mason, IJRR 2002), where scaling (v, w) down together (saturate) keeps
    the curvature and drives a wide arc. The share is of the motion's turn, not of the
    command's: a quarter of a command that also cancels a turn drift against the turn could
    leave no turn at all. A drift the wheels cannot cancel standing still: saturate.
    """
    fast = 0.0 < max_wheel_speed < math.inf
    turn = 0.0 < max_angular_rate < math.inf
    half = 0.5 * wheel_base
    cv, cw = v - drift_v, w - drift_w
    if ((not fast or abs(cv) + abs(cw) * half <= max_wheel_speed)
            and (not turn or abs(cw) <= max_angular_rate)):
        return v, w
    top = math.inf
    if fast:
        if abs(drift_v) >= max_wheel_speed or half <= 0.0:
            return saturate_drifting(v, w, drift_v, drift_w, wheel_base, max_wheel_speed,
                                     max_angular_rate)
        top = max_wheel_speed / half
    if turn:
        top = min(top, max_angular_rate)
    _, sw = saturate(cv, cw, wheel_base, max_wheel_speed, max_angular_rate)
    kept = TURN_SHARE * w   # of the motion's turn, not the command's (which cancels drift_w)
    if (sw + drift_w) * w > 0.0 and abs(sw + drift_w) > abs(kept):
        kept = sw + drift_w   # what scaling down would keep, if more
    cw = min(max(kept - drift_w, -top), top)
    if fast:
        room = max_wheel_speed - abs(cw) * half
        cv = min(max(cv, -room), room)
    return cv + drift_v, cw + drift_w


def saturate(v: float, w: float, wheel_base: float, max_wheel_speed: float,
             max_angular_rate: float) -> Command:
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


def limit_acceleration(v: float, w: float, prev_v: float, prev_w: float, dt: float,
                       max_linear_accel: float, max_angular_accel: float) -> Command:
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


def inside_fence(x: float, y: float,
                 fence: tuple[float, float, float, float] | None) -> bool:
    """True when (x, y) lies in fence = (xmin, ymin, xmax, ymax), or when fence is None."""
    return fence is None or (fence[0] <= x <= fence[2] and fence[1] <= y <= fence[3])
