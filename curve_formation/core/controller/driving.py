"""Which way a robot drives to its target: forwards, steering the point l ahead of its axle
(the paper's), or backwards, steering the point l behind it (`controller.reverse`).

Frames and units as in core.controller.law: poses and targets in the arena frame (m, rad),
speeds in
m/s and rad/s. Scalar math only, so the node and the simulator's compiled kernel (numba) run
the same source.
"""

import math

from curve_formation.core.controller.gains import Law
from curve_formation.core.controller.limits import timed_by, WheelLimits


# drive_direction: no change of direction within this distance (m) of the target, where the
# bearing of the target says little, nor unless the other direction is estimated to arrive
# this much sooner (s).
REVERSE_LOCK = 0.05
REVERSE_HYSTERESIS = 1.0


def drive_direction(front: float, x: float, y: float, theta: float, tx: float, ty: float,
                    dhat_v: float, dhat_w: float, law: Law, limits: WheelLimits,
                    hysteresis: float = REVERSE_HYSTERESIS) -> float:
    """Which of its two offset points a robot steers to its target: +1, the configured one
    (l ahead of the axle for l > 0: driving forwards, the paper's), or -1, the one opposite
    (driving backwards).

    A differential drive reaches a point fastest by turning in place to face it, forwards or
    backwards, and driving straight (Balkcom and Mason, IJRR 2002): this estimates both
    times: the turn at both wheels' limit; the drive at what the wheel limit leaves once
    the turn drift estimated on the robot is cancelled (k2 dhat_w, rad/s), plus (forwards)
    or less (backwards) its forward drift (k2 dhat_v, m/s), at most the limit (no drift
    counts when the disturbance is added on the PC: the law cancels it before the limits).
    It changes `front` (the current choice) only when the other way is `hysteresis` (s)
    sooner and the target (tx, ty; m, arena frame) is at least REVERSE_LOCK from the axle
    (x, y): REVERSE_HYSTERESIS while the robot is on its way, 0 when a curve's first pose
    comes (nothing has been turned for the current choice yet). Without law.reverse, or
    without wheel limits to time the trips by, always +1.
    """
    if not law.reverse or not timed_by(limits):
        return 1.0
    speed = limits.max_wheel_speed
    dx = tx - x
    dy = ty - y
    distance = math.hypot(dx, dy)
    if distance < REVERSE_LOCK:
        return front
    c = math.cos(theta)
    s = math.sin(theta)
    # the way the configured point leads (+1: forwards), the target's bearing from it
    lead = 1.0 if law.offset > 0.0 else -1.0
    bearing = abs(math.atan2(lead * (-s * dx + c * dy), lead * (c * dx + s * dy)))
    turn_rate = 2.0 * speed / limits.wheel_base
    push = 0.0 if law.on_pc else lead * law.k2 * dhat_v
    drive = speed - (0.0 if law.on_pc else 0.5 * limits.wheel_base * abs(law.k2 * dhat_w))
    configured = bearing / turn_rate + distance / max(min(drive + push, speed), 0.1 * speed)
    opposite = ((math.pi - bearing) / turn_rate
                + distance / max(min(drive - push, speed), 0.1 * speed))
    if front > 0.0:
        return -1.0 if opposite < configured - hysteresis else 1.0
    return 1.0 if configured < opposite - hysteresis else -1.0


def steered_law(law: Law, front: float) -> Law:
    """The law steering the point `front` * offset ahead of the axle (drive_direction)."""
    return Law(law.code, law.k1, law.k2, front * law.offset, law.gamma_v, law.gamma_w,
               law.hold, law.period, law.observer_rate, law.on_pc, law.tail_radius,
               law.tail_gain, law.reverse, law.max_growth, law.order)
