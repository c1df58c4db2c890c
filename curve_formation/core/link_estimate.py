"""How late a robot's commands act, measured from what was sent and how the robot moved.

Commands (v, w) sent at times tc and held until the next act L s later; the robot's poses are
measured at times tp (an overhead camera's stamps). Between two poses the robot's mean forward
speed and turn rate are measured (the displacement along the mean heading, and the heading's
change, over the interval) and compared with the commands' means over the same interval
shifted by a candidate L, plus a constant disturbance [d_v, d_w] acting while a command drives
the motors (fitted by least squares for each L). The latency is the L of least squared
residual; its spread over windows of a few seconds tells the jitter (and the estimate's own
noise). A robot whose commands hardly change tells nothing: then no latency is given.

Times in s (one clock for commands and poses), speeds in m/s and rad/s.
"""

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.shapes import FloatArray


LAGS = np.arange(-0.1, 0.6001, 0.0025)   # candidate latencies (s; below 0: the robot acts
# before the commands are dated, the recorder got them late)
WINDOW = 4.0   # s of poses per window for the spread
# Least variation of the commanded speed (m/s) and turn rate (rad/s, scaled by TURN_SCALE)
# across a window for its latency to count: a steady command has none to tell.
MIN_EXCITATION = 1e-3
TURN_SCALE = 0.04   # m: turn rates weigh as a point 4 cm from the axle moves


@dataclass(frozen=True)
class LinkEstimate:
    """latency (s, None if not observable), spread (s: std of the windows' latencies),
    windows (how many told a latency), residual (rms m/s of the fit at the latency).
    """

    latency: float | None
    spread: float | None
    windows: int
    residual: float | None


def _measured_rates(tp: FloatArray, poses: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(forward speed, turn rate) over each interval between consecutive poses."""
    dt = np.diff(tp)
    turn = np.diff(np.unwrap(poses[:, 2]))
    heading = poses[:-1, 2] + 0.5 * turn
    step = np.diff(poses[:, :2], axis=0)
    forward = step[:, 0] * np.cos(heading) + step[:, 1] * np.sin(heading)
    # an arc's chord is shorter than its length by sinc(turn / 2)
    half = 0.5 * turn
    chord = np.where(np.abs(half) > 1e-9, np.sin(half) / np.where(half == 0, 1.0, half), 1.0)
    return forward / chord / dt, turn / dt


def _held_means(tc: FloatArray, values: FloatArray, starts: FloatArray, ends: FloatArray
                ) -> FloatArray:
    """Mean over [starts, ends] of the piecewise-constant signal values[k] from tc[k] (zero
    before the first command).
    """
    knots = np.concatenate([tc, [tc[-1] + 1e9]])
    integral = np.concatenate([[0.0], np.cumsum(values * np.diff(knots))])
    edges = np.concatenate([[tc[0] - 1e9], knots])
    area = np.concatenate([[0.0], integral])

    def cumulative(t):
        return np.interp(t, edges, area)

    return (cumulative(ends) - cumulative(starts)) / (ends - starts)


def _residuals(tc, commands, driven, tp, v_meas, w_meas, lags):
    """(len(lags),) sum of squared residuals of the fit at each lag, and the fit's count."""
    out = np.full(len(lags), np.inf)
    starts, ends = tp[:-1], tp[1:]
    for k, lag in enumerate(lags):
        v = _held_means(tc, commands[:, 0], starts - lag, ends - lag)
        w = _held_means(tc, commands[:, 1], starts - lag, ends - lag)
        on = _held_means(tc, driven, starts - lag, ends - lag)
        rv, rw = v_meas - v, (w_meas - w) * TURN_SCALE
        scale = float(on @ on)
        # the disturbance acting while driven: least squares in each channel
        dv = float(on @ rv) / scale if scale > 0 else 0.0
        dw = float(on @ rw) / scale if scale > 0 else 0.0
        out[k] = float(((rv - dv * on) ** 2).sum() + ((rw - dw * on) ** 2).sum())
    return out


def _best_lag(residuals: FloatArray, lags: FloatArray) -> float:
    """The lag of least residual, refined by a parabola through it and its neighbours."""
    k = int(np.argmin(residuals))
    if 0 < k < len(lags) - 1:
        a, b, c = residuals[k - 1:k + 2]
        curvature = a - 2 * b + c
        if curvature > 0:
            return float(lags[k] + 0.5 * (a - c) / curvature * (lags[1] - lags[0]))
    return float(lags[k])


def estimate_latency(command_times: ArrayLike, commands: ArrayLike, pose_times: ArrayLike,
                     poses: ArrayLike, lags: ArrayLike = LAGS, window: float = WINDOW
                     ) -> LinkEstimate:
    """The latency of one robot's commands (see the module): command_times (k,) and commands
    (k, 2) as sent; pose_times (m,) and poses (m, 3) as measured (x, y m; theta rad).
    """
    tc = np.asarray(command_times, float)
    cmd = np.asarray(commands, float).reshape(-1, 2)
    tp = np.asarray(pose_times, float)
    pose = np.asarray(poses, float).reshape(-1, 3)
    lags = np.asarray(lags, float)
    keep = np.isfinite(tp) & np.isfinite(pose).all(axis=1)
    tp, pose = tp[keep], pose[keep]
    order = np.argsort(tp, kind='stable')
    tp, pose = tp[order], pose[order]
    fresh = np.concatenate([[True], np.diff(tp) > 1e-6])
    tp, pose = tp[fresh], pose[fresh]
    if len(tc) < 2 or len(tp) < 3:
        return LinkEstimate(None, None, 0, None)
    driven = ((cmd[:, 0] != 0.0) | (cmd[:, 1] != 0.0)).astype(float)
    v_meas, w_meas = _measured_rates(tp, pose)
    # only intervals the commands cover at every candidate lag
    inside = (tp[:-1] - lags.max() >= tc[0]) & (tp[1:] <= tc[-1] + 1.0)
    lats = []
    for begin in np.arange(tp[0], tp[-1], window):
        sel = inside & (tp[:-1] >= begin) & (tp[1:] < begin + window)
        if sel.sum() < 5 or not _excited(tc, cmd, begin - lags.max(), begin + window):
            continue
        idx = np.flatnonzero(sel)
        res = _residuals(tc, cmd, driven, np.append(tp[idx], tp[idx[-1] + 1]),
                         v_meas[idx], w_meas[idx], lags)
        if _clear(res, len(idx)):
            lats.append(_best_lag(res, lags))
    if not lats:
        return LinkEstimate(None, None, 0, None)
    # the windows' median: a window whose disturbance changed (the fit holds it constant)
    # does not pull it, as it would a fit over the whole run
    latency = float(np.median(lats))
    idx = np.flatnonzero(inside)
    res = _residuals(tc, cmd, driven, np.append(tp[idx], tp[idx[-1] + 1]), v_meas[idx],
                     w_meas[idx], np.array([latency]))
    return LinkEstimate(latency, float(np.std(lats)), len(lats),
                        math.sqrt(float(res.min()) / max(len(idx), 1)))


def _clear(residuals: FloatArray, count: int) -> bool:
    """Whether the fit over `count` intervals tells one latency: its least residual below the
    typical one by more than the noise would make it vary (a standard deviation of a sum of
    count squared Gaussian residuals); a robot that stood still fits every lag alike.
    """
    typical, best = float(np.median(residuals)), float(residuals.min())
    return typical > 0.0 and typical - best > best * math.sqrt(2.0 / count)


def _excited(tc: FloatArray, cmd: FloatArray, begin: float, end: float) -> bool:
    """Whether the commands in force between begin and end (s) change enough to time."""
    sel = (tc >= begin) & (tc <= end)
    if sel.sum() < 2:
        return False
    v, w = cmd[sel, 0], cmd[sel, 1] * TURN_SCALE
    return bool(max(np.ptp(v), np.ptp(w)) >= MIN_EXCITATION)


# Online: candidate latencies on a coarser grid (refined by the parabola), how often (s) and
# over how much of the past (s) a controller estimates, how many estimates in a row must agree
# and within what (s) before one is taken.
ONLINE_LAGS = np.arange(0.0, 0.5001, 0.01)
ONLINE_EVERY = 1.0
ONLINE_SPAN = 6.0
AGREEING = 3
AGREEMENT = 0.02


class OnlineLatency:
    """A controller's running estimate of its command latency (estimate_latency over the last
    ONLINE_SPAN s, every ONLINE_EVERY s): a new value is taken only when AGREEING estimates in
    a row lie within AGREEMENT of each other (their median), so one that wanders is not.
    Times in s on the controller's clock.
    """

    def __init__(self, initial: float, rate_hz: float, pose_rate: float = 60.0) -> None:
        from collections import deque
        self.latency = initial
        self.commands: deque[tuple[float, float, float]] = deque(
            maxlen=int(rate_hz * (ONLINE_SPAN + 1.0)) + 2)
        self.poses: deque[tuple[float, float, float, float]] = deque(
            maxlen=int(pose_rate * ONLINE_SPAN) + 2)
        self.recent: deque[float] = deque(maxlen=AGREEING)
        self.next_at: float | None = None
        self.taken: list[tuple[float, float]] = []   # (when, latency) of each value taken

    def sent(self, at: float, v: float, w: float) -> None:
        self.commands.append((at, v, w))

    def seen(self, stamp: float, x: float, y: float, theta: float) -> None:
        if not self.poses or stamp > self.poses[-1][0]:
            self.poses.append((stamp, x, y, theta))

    def update(self, now: float) -> float:
        """The latency to use from `now` on (s): a new estimate every ONLINE_EVERY s."""
        if self.next_at is None:
            self.next_at = now + ONLINE_EVERY
        if now < self.next_at or len(self.commands) < 2 or len(self.poses) < 3:
            return self.latency
        self.next_at = now + ONLINE_EVERY
        sent = np.array(self.commands)
        seen = np.array(self.poses)
        found = estimate_latency(sent[:, 0], sent[:, 1:], seen[:, 0], seen[:, 1:],
                                 ONLINE_LAGS, ONLINE_SPAN)
        if found.latency is None:
            return self.latency
        self.recent.append(found.latency)
        if len(self.recent) == AGREEING and max(self.recent) - min(self.recent) <= AGREEMENT:
            latency = float(np.median(self.recent))
            if abs(latency - self.latency) > 1e-3:
                self.latency = latency
                self.taken.append((now, latency))
        return self.latency
