"""Collision avoidance: a safety filter on each robot's command, from the poses near it.

Frames and units: poses in the arena frame (m, rad); commands (v, w) in the robot frame (m/s,
rad/s); the arena is [0, width] x [0, height] (m), no walls where width or height <= 0.

The formation law steers each robot's offset point b = (x + l cos th, y + l sin th), which
moves as a single integrator b' = m with m = R(th) (u + d) (paper-notes: R is invertible).
The filter works on m, as Robotarium's unicycle barrier certificates do; the barriers are on
the axle centres c, which move along the heading e at V = e^T m (docs/collision-avoidance.md
derives them), with D = 2 radius + margin and alpha in 1/s:

- every other robot j: h_ij = |c_i - c_j|^2 - D^2, and over the robot's own step in a tick
  2 T k V + T^2 V^2 >= -(alpha T / 2) h_ij, k = (c_i - c_j)^T e. Each robot takes half the
  responsibility (Wang, Ames, Egerstedt, 2017), so it needs only the other robots' poses,
  not their commands.
- each wall: h_w = distance from c to the wall - (radius + margin / 2), and
  V (n_w^T e) >= -alpha h_w (n_w pointing into the arena).
- both for every forward speed within `drift` (m/s) of V: a forward drift the command does
  not cancel (the robots' drift before the observer has learnt it).
- the wheel limits, |v| + |w| B / 2 <= max wheel speed and |w| <= max turn rate, written
  as half-planes of m through v, w = R^-1 m - d.

What is proved (docs/collision-avoidance.md): if at a control tick both robots of a pair
(or a robot and a wall) satisfy their half-planes and move straight for the period T with
alpha T <= 1, then h(k + 1) >= (1 - alpha T) h(k) up to 2 T^2 v_max^2 for a pair, so bodies
stay 2 radius + margin apart (less that residue) and margin / 2 off the walls. What is not
proved and is covered by the margin: the arc the centre draws within a tick instead of a
straight line, pose latency, and a disturbance estimate further from the truth than `drift`.

The filtered motion is the point of that polygon closest to the nominal motion (a QP in two
variables, solved exactly: the nominal if it is inside, else the projection onto one edge,
else a vertex). If the polygon is empty the robot is stopped: zero velocity keeps every h >= 0.

Deadlock: a robot whose law heads into a barrier would stop there (the filter takes away the
forward motion, and a unicycle cannot slide sideways). So before the law, shaped_feedback
turns the law's intended velocity into the closest one the barriers allow a point robot
(sliding along what blocks it), and a blocked robot gives way to the robots of higher
priority it heads at; an optional passing rule (`passing`) steers head-on meetings to the right.
Targets are also re-assigned among the robots while they travel (assignment.reassigned), so
paths that cross are swapped. That liveness is measured, not proved
(benchmarks/collision_avoidance.py).

Scalar loops only, so the same source runs compiled in the batch simulator (numba) and as plain
Python in the formation_controller node.
"""

import math
from typing import NamedTuple

import numpy as np

from curve_formation.core.base.shapes import FloatArray
from curve_formation.core.controller.settings import default


class Avoidance(NamedTuple):
    """The filter's settings (an experiment's `robots` and `avoidance` sections)."""

    on: bool
    radius: float = default('robots.radius')         # body radius (m)
    margin: float = default('avoidance.margin')      # kept between bodies, from walls (m)
    rate: float = default('avoidance.rate')          # barrier rate alpha (1/s); alpha T <= 1
    passing: float = default('avoidance.passing')    # passing rule (sideways per approach)
    passing_range: float = default('avoidance.passing_range')   # where it acts (m)
    width: float = 0.0        # arena (m); <= 0: no walls
    height: float = 0.0
    drift: float = default('avoidance.drift')   # forward drift (m/s) held against


AVOIDANCE_OFF = Avoidance(False)

# Filter outcome codes.
UNCHANGED, ADJUSTED, STOPPED = 0, 1, 2
# Shaped intent below this share of the intended speed: the robot is blocked (shaped_feedback).
BLOCKED = 0.2
# Feasibility tolerance (m/s) of the unit-normal half-planes.
TOLERANCE = 1e-12
# Half-planes besides the other robots': four walls, four wheel-speed and two turn-rate ones.
FIXED_CONSTRAINTS = 10


def with_latency(avoidance: Avoidance, period: float, latency: float) -> Avoidance:
    """The filter's settings for commands that act `latency` s after they are sent (period
    and latency in s): the barrier rate at most 1 / (period + latency). The proof's alpha T <= 1
    is for a command acting at once; late, a robot's own pose is carried over the latency but
    the others' are guessed from their last motion, and a pair holding each other at the
    barrier chatters (docs/collision-avoidance.md, "Commands that act late").
    """
    if latency <= 0.0 or avoidance.rate * (period + latency) <= 1.0:
        return avoidance
    return avoidance._replace(rate=1.0 / (period + latency))


def safe_command(v: float, w: float, x: float, y: float, theta: float, drift_v: float,
                 drift_w: float, others: FloatArray, me: int, offset: float, period: float,
                 avoidance: Avoidance, wheel_base: float, max_wheel_speed: float,
                 max_angular_rate: float) -> tuple[float, float, int]:
    """The command closest to (v, w) that keeps bodies apart and inside the arena.

    v, w: nominal command (m/s, rad/s), within the wheel limits. x, y, theta: own pose.
    drift_v, drift_w: the estimated disturbance acting on the robot (added to a non-zero
    command). others (n, 3): poses of the robots (own row `me` is skipped, NaN rows unknown).
    offset: l (m); period: the control period T (s; 0: continuous control). Returns (v, w,
    code) with code UNCHANGED, ADJUSTED or STOPPED.
    """
    if not avoidance.on:
        return v, w, UNCHANGED
    c = math.cos(theta)
    s = math.sin(theta)
    moving = v != 0.0 or w != 0.0   # a zero command means motors off: no drift either
    pv = v + drift_v if moving else 0.0
    pw = w + drift_w if moving else 0.0
    m0x = c * pv - offset * s * pw
    m0y = s * pv + offset * c * pw
    safe = 2.0 * avoidance.radius + avoidance.margin
    near = _near(others, me, x, y, safe, _reach(avoidance, max_wheel_speed, drift_v))
    planes = np.empty((near.shape[0] + FIXED_CONSTRAINTS, 3))
    count = 0
    for k in range(near.shape[0]):
        ux, uy, dist, gap = near[k, 0], near[k, 1], near[k, 2], near[k, 3]
        count = _pair_barrier(planes, count, c, s, dist * (ux * c + uy * s),
                              gap * (dist + safe), avoidance.rate, period, c * m0x + s * m0y,
                              avoidance.drift)
    low = avoidance.radius + 0.5 * avoidance.margin
    drift = avoidance.drift
    if avoidance.width > 0.0:
        count = _forward_barrier(planes, count, c, s, c, avoidance.rate * (x - low), drift)
        count = _forward_barrier(planes, count, c, s, -c,
                                 avoidance.rate * (avoidance.width - low - x), drift)
    if avoidance.height > 0.0:
        count = _forward_barrier(planes, count, c, s, s, avoidance.rate * (y - low), drift)
        count = _forward_barrier(planes, count, c, s, -s,
                                 avoidance.rate * (avoidance.height - low - y), drift)
    barriers = count
    count = _wheel_planes(planes, count, c, s, offset, wheel_base, max_wheel_speed,
                          max_angular_rate, drift_v, drift_w)
    if _inside(planes, count, m0x, m0y):
        return v, w, UNCHANGED
    found, mx, my = _closest(planes, count, m0x, m0y)
    if not found:
        # Already inside a barrier (h < 0: latency, a drift not yet estimated) and unable to
        # back off as fast as it asks: only forbid closing in further. Standing still or
        # turning satisfies that.
        for k in range(barriers):
            planes[k, 2] = max(planes[k, 2], 0.0)
        found, mx, my = _closest(planes, count, m0x, m0y)
    if not found:
        return 0.0, 0.0, STOPPED
    return (c * mx + s * my - drift_v, (-s * mx + c * my) / offset - drift_w, ADJUSTED)


def shaped_feedback(fx: float, fy: float, x: float, y: float, others: FloatArray, me: int,
                    k1: float, speed: float, avoidance: Avoidance) -> tuple[float, float]:
    """The law's feedback f (m; the law steers along -k1 f) reshaped around robots and walls
    nearby, so that the law turns towards a way that is free instead of pushing into the
    safety filter (which would stop it there).

    The intended velocity d = -k1 f, scaled down to `speed` (m/s; the wheel limit) if faster,
    is replaced by the closest velocity that the barriers would allow a robot free to move in
    any direction (the same half-planes as safe_command's, with their true normals), so the
    robot slides along what blocks it. Where d heads within 45 degrees at a robot whose gap is
    below `passing_range`, `passing` times the part heading at it is first added to the right
    (passing rule: two robots meeting head-on both turn right and pass left side to left
    side; off with passing 0, the default). Nothing nearby: f is returned as it is.
    """
    if not avoidance.on:
        return fx, fy
    dx, dy = -k1 * fx, -k1 * fy
    size = math.hypot(dx, dy)
    scale = speed / size if 0.0 < speed < size else 1.0
    dx, dy = dx * scale, dy * scale
    safe = 2.0 * avoidance.radius + avoidance.margin
    reach = max(4.0 * math.hypot(dx, dy) / avoidance.rate, avoidance.passing_range)
    near = _near(others, me, x, y, safe, reach)
    planes = np.empty((near.shape[0] + 4, 3))
    count = 0
    gx, gy = dx, dy
    for k in range(near.shape[0]):
        ux, uy, dist, gap = near[k, 0], near[k, 1], near[k, 2], near[k, 3]
        approach = -(ux * dx + uy * dy)
        if gap < avoidance.passing_range and approach > abs(ux * dy - uy * dx):
            push = avoidance.passing * approach * (1.0 - max(gap, 0.0) / avoidance.passing_range)
            gx -= push * uy   # the right of the heading -u is (-uy, ux)
            gy += push * ux
        count = _plane(planes, count, -ux, -uy,
                       max(0.25 * avoidance.rate * gap * (dist + safe) / dist, 0.0))
    low = avoidance.radius + 0.5 * avoidance.margin
    if avoidance.width > 0.0:
        count = _plane(planes, count, -1.0, 0.0, max(avoidance.rate * (x - low), 0.0))
        count = _plane(planes, count, 1.0, 0.0,
                       max(avoidance.rate * (avoidance.width - low - x), 0.0))
    if avoidance.height > 0.0:
        count = _plane(planes, count, 0.0, -1.0, max(avoidance.rate * (y - low), 0.0))
        count = _plane(planes, count, 0.0, 1.0,
                       max(avoidance.rate * (avoidance.height - low - y), 0.0))
    if gx == dx and gy == dy and _inside(planes, count, dx, dy):
        return fx, fy
    found, gx, gy = _closest(planes, count, gx, gy)
    if not found:
        gx = gy = 0.0
    if math.hypot(gx, gy) < BLOCKED * math.hypot(dx, dy):
        # Blocked (robots around it block every way that leads on): give way to the robots
        # of lower index (higher priority) that it heads at, by backing away from them.
        yx, yy = _yield(dx, dy, x, y, others, me, safe, avoidance.passing_range)
        if yx != 0.0 or yy != 0.0:
            found, hx, hy = _closest(planes, count, gx + yx, gy + yy)
            if found:
                gx, gy = hx, hy
    return -gx / (k1 * scale), -gy / (k1 * scale)


def _yield(dx: float, dy: float, x: float, y: float, others: FloatArray, me: int, safe: float,
           near: float) -> tuple[float, float]:
    """Backing-away velocity (m/s) from the higher-priority robots (lower index) within
    `near` of the safe distance that the intended velocity d heads at: |d| in all.
    """
    yx = yy = 0.0
    for j in range(min(me, others.shape[0])):
        if not (math.isfinite(others[j, 0]) and math.isfinite(others[j, 1])):
            continue
        ox = x - others[j, 0]
        oy = y - others[j, 1]
        dist = math.hypot(ox, oy)
        if dist == 0.0 or dist - safe >= near or ox * dx + oy * dy >= 0.0:
            continue
        yx += ox / dist
        yy += oy / dist
    size = math.hypot(yx, yy)
    if size == 0.0:
        return 0.0, 0.0
    speed = math.hypot(dx, dy) / size
    return yx * speed, yy * speed


def _pair_barrier(planes: FloatArray, count: int, c: float, s: float, k: float, h: float,
                  alpha: float, period: float, forward: float, drift: float) -> int:
    """Append the half-plane that keeps h = |c_i - c_j|^2 - D^2 (m^2) from falling faster
    than (alpha / 2) h per tick by this robot's own step, which moves its axle centre by
    T V along its heading e = (c, s) (V = e^T m, the forward speed, m/s; k = (c_i - c_j)^T e):

        2 T k V' + T^2 V'^2 >= -(alpha T / 2) h   for every V' within `drift` (m/s) of V,

    the forward drift the robot may have that the command does not cancel. The quadratic
    term is what lets a robot drive past another along a tangent (k = 0); the allowed V form
    one or two intervals, and the one kept is the one that holds the nominal forward speed,
    else the one that holds V = 0 (stopping). Continuous control (T = 0): the linear
    condition k V' >= -(alpha / 4) h.
    """
    if period <= 0.0:
        return _forward_barrier(planes, count, c, s, k, 0.25 * alpha * h, drift)
    gamma = alpha * period
    disc = k * k - 0.5 * gamma * h
    if disc <= 0.0:
        return count   # no forward speed brings it too close in one tick
    root = math.sqrt(disc)
    low = (-k - root) / period - drift    # V in (low, high) is forbidden
    high = (-k + root) / period + drift
    if forward >= high or (forward > low and high <= 0.0):
        return _plane(planes, count, -c, -s, -high)      # V >= high
    if forward <= low or low >= 0.0:
        return _plane(planes, count, c, s, low)          # V <= low
    # h < 0: V = 0 is forbidden too; the nearer side of the nominal
    if high - forward < forward - low:
        return _plane(planes, count, -c, -s, -high)
    return _plane(planes, count, c, s, low)


def _forward_barrier(planes: FloatArray, count: int, c: float, s: float, k: float, b: float,
                     drift: float) -> int:
    """Append k V' >= -b for every V' within `drift` (m/s) of V = e^T m, e = (c, s) the
    heading: the axle centre, which moves by V along e, may close in on what lies along -k e
    no faster than b (m^2/s) allows, whatever forward drift up to `drift` the command does
    not cancel; b < 0 asks it to back off.
    """
    if abs(k) < 1e-12:
        return count   # moving along the heading does not change this distance
    sign = 1.0 if k > 0.0 else -1.0
    return _plane(planes, count, -sign * c, -sign * s, b / abs(k) - drift)


def _near(others: FloatArray, me: int, x: float, y: float, safe: float, reach: float
          ) -> FloatArray:
    """(k, 4) [ux, uy, dist, gap] of the robots whose gap (distance - safe, m) is below
    `reach`: u the unit vector from each to (x, y), dist their distance (m). Skips row `me`,
    rows not finite and a robot at the very same point.
    """
    out = np.empty((others.shape[0], 4))
    count = 0
    for j in range(others.shape[0]):
        if j == me or not (math.isfinite(others[j, 0]) and math.isfinite(others[j, 1])):
            continue
        dx = x - others[j, 0]
        dy = y - others[j, 1]
        dist = math.hypot(dx, dy)
        if dist - safe >= reach or dist == 0.0:
            continue
        out[count, 0] = dx / dist
        out[count, 1] = dy / dist
        out[count, 2] = dist
        out[count, 3] = dist - safe
        count += 1
    return out[:count]


def _reach(avoidance: Avoidance, max_wheel_speed: float, drift_v: float) -> float:
    """Gap (m) beyond which another robot's half-plane cannot cut the wheel-limited motions,
    nor the passing rule act: with the centre moving at most v_max, (alpha / 4) h <= |c_i -
    c_j| v_max needs a gap below 4 v_max / alpha. Infinite without wheel limits.
    """
    if not (max_wheel_speed > 0.0 and max_wheel_speed < math.inf):
        return math.inf
    return max(4.0 * (max_wheel_speed + abs(drift_v)) / avoidance.rate, avoidance.passing_range)


def _plane(planes: FloatArray, count: int, ax: float, ay: float, b: float) -> int:
    """Append the half-plane a^T m <= b (a a unit vector)."""
    planes[count, 0] = ax
    planes[count, 1] = ay
    planes[count, 2] = b
    return count + 1


def _wheel_planes(planes: FloatArray, count: int, c: float, s: float, offset: float,
                  wheel_base: float, max_wheel_speed: float, max_angular_rate: float,
                  drift_v: float, drift_w: float) -> int:
    """The wheel limits as half-planes of m: v = c mx + s my - dv, w = (-s mx + c my)/l - dw."""
    if max_wheel_speed > 0.0 and max_wheel_speed < math.inf:
        half = 0.5 * wheel_base
        for sv in (-1.0, 1.0):
            for sw in (-1.0, 1.0):
                ax = sv * c - sw * half * s / offset
                ay = sv * s + sw * half * c / offset
                norm = math.hypot(ax, ay)
                count = _plane(planes, count, ax / norm, ay / norm,
                               (max_wheel_speed + sv * drift_v + sw * half * drift_w) / norm)
    if max_angular_rate > 0.0 and max_angular_rate < math.inf:
        norm = 1.0 / abs(offset)
        for sw in (-1.0, 1.0):
            count = _plane(planes, count, -sw * s / offset / norm, sw * c / offset / norm,
                           (max_angular_rate + sw * drift_w) / norm)
    return count


def _inside(planes: FloatArray, count: int, mx: float, my: float) -> bool:
    for k in range(count):
        if planes[k, 0] * mx + planes[k, 1] * my > planes[k, 2] + TOLERANCE:
            return False
    return True


def _closest(planes: FloatArray, count: int, mx: float, my: float
             ) -> tuple[bool, float, float]:
    """(found, x, y): the point of the polygon {a_k^T m <= b_k} closest to (mx, my).

    Exact: the point itself if inside; else, for a half-plane it violates, its projection
    onto that edge if inside (then it is the closest point of that half-plane, so of the
    polygon); else the closest vertex on such an edge (at the optimum one of the two active
    half-planes is violated by (mx, my), by the optimality conditions): the candidates are
    tried nearest first, so only a few are checked against every half-plane.
    """
    if _inside(planes, count, mx, my):
        return True, mx, my
    candidates = np.empty((count * count, 3))
    found = 0
    for k in range(count):
        excess = planes[k, 0] * mx + planes[k, 1] * my - planes[k, 2]
        if excess <= TOLERANCE:
            continue
        px = mx - excess * planes[k, 0]
        py = my - excess * planes[k, 1]
        if _inside(planes, count, px, py):
            return True, px, py
        for j in range(count):
            det = planes[k, 0] * planes[j, 1] - planes[k, 1] * planes[j, 0]
            if j == k or abs(det) < 1e-12:
                continue
            vx = (planes[k, 2] * planes[j, 1] - planes[k, 1] * planes[j, 2]) / det
            vy = (planes[k, 0] * planes[j, 2] - planes[k, 2] * planes[j, 0]) / det
            candidates[found, 0] = (vx - mx) ** 2 + (vy - my) ** 2
            candidates[found, 1] = vx
            candidates[found, 2] = vy
            found += 1
    for q in np.argsort(candidates[:found, 0]):
        if _inside(planes, count, candidates[q, 1], candidates[q, 2]):
            return True, candidates[q, 1], candidates[q, 2]
    return False, 0.0, 0.0
