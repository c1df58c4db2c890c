"""The commands a controller sent, as rows of a plain array (oldest first), and what they
did: which one acted when (each from its sending plus the command latency), their average
through the motors' lag over a motion, and the pose they carried the robot to. What
predict_pose and the observer read, in the nodes (commands_sent.CommandsSent holds the array)
and in the batch simulator's kernel alike: plain scalar math that numba compiles as it is.

A log is a (size, FIELDS) float array and the count of its rows in use. Times in s on the
controller's clock; poses in the arena frame (m, rad); commands in m/s and rad/s.
"""

import math

from curve_formation.core.base.shapes import FloatArray, Pose
from curve_formation.core.controller.inputs import shares_clock
from curve_formation.core.formation.dynamics import arc_step


# A row's columns: when sent; the command (v, w); the observer's reference (v, w) and what
# the safety filter shifted (v, w); 1 where the wheel limits cut it (observer.RAY_CLIPPED);
# 1 where driven (0: a stop, motors off, no drift); the observer's updates made before it.
AT, V, W, REF_V, REF_W, SHIFT_V, SHIFT_W, LIMITED, DRIVEN, ESTIMATE = range(10)
FIELDS = 10
# log_realised's result: found (False: the log does not reach back that far); the mean
# reference (v, w) and shift (v, w); limited if any was; driven if all were; the fewest
# observer updates any was sent after.
Realised = tuple[bool, float, float, float, float, bool, bool, int]


def make_room(rows: FloatArray, count: int) -> int:
    """Room for one more row after the first `count` of `rows` (oldest first): the oldest
    dropped when full. Returns the count before the new row.
    """
    if count < rows.shape[0]:
        return count
    rows[:count - 1] = rows[1:count]
    return count - 1


def log_append(log: FloatArray, count: int, at: float, v: float, w: float, ref_v: float,
               ref_w: float, shift_v: float, shift_w: float, limited: bool, driven: bool,
               estimate: int) -> int:
    """Append a command's row (the oldest dropped when full); returns the new count."""
    count = make_room(log, count)
    row = log[count]
    row[AT], row[V], row[W] = at, v, w
    row[REF_V], row[REF_W], row[SHIFT_V], row[SHIFT_W] = ref_v, ref_w, shift_v, shift_w
    row[LIMITED] = 1.0 if limited else 0.0
    row[DRIVEN] = 1.0 if driven else 0.0
    row[ESTIMATE] = estimate
    return count + 1


def log_acting(log: FloatArray, count: int, at: float, latency: float) -> int:
    """The row of the command acting on the robot at `at`: the last sent `latency` s or more
    before; -1 if none is known.
    """
    for k in range(count - 1, -1, -1):
        if log[k, AT] <= at - latency + 1e-9:
            return k
    return -1


def log_first_acting_after(log: FloatArray, count: int, updates: int, latency: float
                           ) -> float:
    """When the first command sent after the observer's `updates`-th update began to act
    (its sending plus the latency); NaN if none was sent yet.
    """
    for k in range(count):
        if log[k, ESTIMATE] >= updates:
            return log[k, AT] + latency
    return math.nan


def _lagged(lag: float, target: float, span: float, tau: float) -> float:
    """A first-order lag's state after `span` s towards `target` (tau s; 0: at it at once)."""
    if tau <= 0.0:
        return target
    return target + (lag - target) * math.exp(-span / tau)


def _lagged_mean(lag: float, target: float, span: float, tau: float) -> float:
    """The integral over `span` s of a first-order lag (tau s) from `lag` towards `target`."""
    if tau <= 0.0:
        return target * span
    return target * span + (lag - target) * tau * (1.0 - math.exp(-span / tau))


def log_realised(log: FloatArray, count: int, end: float, elapsed: float, latency: float,
                 tau: float, updates: int) -> Realised:
    """What the wheels did on average over the `elapsed` s up to `end`: the commands sent,
    each acting from its sending plus `latency`, through the motors' first-order lag `tau`
    (0: none), as Realised (the estimate at most `updates`).
    """
    begin = end - elapsed
    if count == 0 or log[0, AT] + latency > begin:
        return False, 0.0, 0.0, 0.0, 0.0, False, False, updates
    lags = [log[0, REF_V], log[0, REF_W], log[0, SHIFT_V], log[0, SHIFT_W]]   # the wheels'
    totals = [0.0, 0.0, 0.0, 0.0]
    limited, driven, estimate = False, True, updates
    for k in range(count):
        start = log[k, AT] + latency
        if start >= end:
            break
        stop = min(log[k + 1, AT] + latency, end) if k + 1 < count else end
        before = min(max(begin, start), stop)   # the part before the interval
        span = stop - before
        for c in range(4):
            lags[c] = _lagged(lags[c], log[k, REF_V + c], before - start, tau)
        if span <= 1e-9:   # none, or a sliver of rounding between clocks' sums
            continue
        for c in range(4):
            totals[c] += _lagged_mean(lags[c], log[k, REF_V + c], span, tau)
            lags[c] = _lagged(lags[c], log[k, REF_V + c], span, tau)
        limited = limited or log[k, LIMITED] != 0.0
        driven = driven and log[k, DRIVEN] != 0.0
        estimate = min(estimate, int(log[k, ESTIMATE]))
    return (True, totals[0] / elapsed, totals[1] / elapsed, totals[2] / elapsed,
            totals[3] / elapsed, limited, driven, estimate)


def driven_pose(x: float, y: float, theta: float, v: float, w: float, drift_v: float,
                drift_w: float, dt: float) -> Pose:
    """Pose after dt (s) under command (v, w), plus the drift while driven (m/s, rad/s)."""
    if dt <= 0.0:
        return x, y, theta
    if v != 0.0 or w != 0.0:
        v, w = v + drift_v, w + drift_w
    return arc_step(x, y, theta, v, w, dt)


def log_carried(log: FloatArray, count: int, x: float, y: float, theta: float, start: float,
                until: float, latency: float, drift_v: float, drift_w: float) -> Pose:
    """The pose taken at `start` carried to `until` by the commands acting since (each from
    its sending plus `latency`) and the drift while driven (m/s, rad/s).
    """
    v, w, at = 0.0, 0.0, start
    for k in range(count):
        acts = log[k, AT] + latency
        if acts > start:
            x, y, theta = driven_pose(x, y, theta, v, w, drift_v, drift_w, acts - at)
            at = acts
        v, w = log[k, V], log[k, W]
    return driven_pose(x, y, theta, v, w, drift_v, drift_w, until - at)


def log_predicted(log: FloatArray, count: int, x: float, y: float, theta: float,
                  stamp: float, received: float, now: float, latency: float, longest: float,
                  drift_v: float, drift_w: float) -> Pose:
    """The pose taken at `stamp` (received at `received`) carried to `now` + `latency`
    (log_carried). Its age is now - stamp where the pose's source and the controller share a
    clock (inputs.shares_clock within `longest`: AgentConfig.shared_clock); otherwise only
    the time the pose was held here (now - received) is made up for.
    """
    age = now - stamp
    if not shares_clock(age, longest):
        age = min(max(now - received, 0.0), longest)
    return log_carried(log, count, x, y, theta, now - age, now + latency, latency, drift_v,
                       drift_w)
