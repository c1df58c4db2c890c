"""A controller's record of what it commanded and what its robot did, and the means the
online fits of its link and motors (core.controller.link_estimate, wheel_estimate) take over
it: the measured motion between poses, and a command signal held or through the motors' lag
over an interval.

Times in s on the controller's clock; poses in the arena frame (m, rad); commands in m/s and
rad/s.
"""

from collections import deque
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import ArrayLike

from curve_formation.core.base.shapes import FloatArray


def measured_rates(tp: FloatArray, poses: FloatArray) -> tuple[FloatArray, FloatArray]:
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


def held_means(tc: FloatArray, values: FloatArray, starts: FloatArray, ends: FloatArray
               ) -> FloatArray:
    """Mean over [starts, ends] (arrays of one shape) of the piecewise-constant signal
    values[k] from tc[k] (zero before the first command).
    """
    knots = np.concatenate([tc, [tc[-1] + 1e9]])
    integral = np.concatenate([[0.0], np.cumsum(values * np.diff(knots))])
    edges = np.concatenate([[tc[0] - 1e9], knots])
    area = np.concatenate([[0.0], integral])
    return (np.interp(ends, edges, area) - np.interp(starts, edges, area)) / (ends - starts)


def lag_knots(tc: FloatArray, values: FloatArray, tau: float) -> FloatArray:
    """The output y of a first-order lag of time constant tau (s, > 0), tau y' = u - y, at
    each command's start tc[k], driven by the piecewise-constant values[k] from tc[k] and
    from 0 before the first.
    """
    decay = np.exp(-np.diff(tc) / tau).tolist()
    u = values.tolist()
    knots = [0.0] * len(u)
    y = 0.0
    for k in range(1, len(u)):
        y = u[k - 1] + (y - u[k - 1]) * decay[k - 1]
        knots[k] = y
    return np.array(knots)


def lagged_means(tc: FloatArray, values: FloatArray, starts: FloatArray, ends: FloatArray,
                 tau: float, knots: FloatArray | None = None) -> FloatArray:
    """Mean over [starts, ends] of the piecewise-constant signal values[k] from tc[k] (zero
    before the first) through a first-order lag of time constant tau (s; the motors'; 0:
    none): tau y' = u - y, so the mean of y is the mean of u less tau (y(end) - y(start)) /
    (end - start). knots: lag_knots(tc, values, tau), where the caller has it already.
    """
    return LagMeans(tc, values, starts, ends).through(tau, knots)


CommandAt: TypeAlias = tuple[Any, Any, FloatArray, FloatArray]   # LagMeans._command_at


class LagMeans:
    """lagged_means of one signal over fixed intervals for any number of motor lags: what
    does not depend on the lag (the held means, the command in force at each end) is
    computed once.
    """

    def __init__(self, tc: FloatArray, values: FloatArray, starts: FloatArray,
                 ends: FloatArray) -> None:
        self.tc, self.values, self.span = tc, values, ends - starts
        self.held = held_means(tc, values, starts, ends)
        self.at = [self._command_at(t) for t in (starts, ends)]

    def _command_at(self, t: FloatArray) -> 'CommandAt':
        """(index, whether a command is in force, its value, s since it began) at t."""
        k = np.searchsorted(self.tc, t, side='right') - 1
        inside = k >= 0
        k = np.maximum(k, 0)
        return k, inside, self.values[k], np.maximum(t - self.tc[k], 0.0)

    def through(self, tau: float, knots: FloatArray | None = None) -> FloatArray:
        """The means through a lag of time constant tau (s; 0: the held means); knots as
        lagged_means takes them.
        """
        if tau <= 0.0:
            return self.held
        y0 = lag_knots(self.tc, self.values, tau) if knots is None else knots

        def lagged(at: 'CommandAt') -> FloatArray:
            k, inside, u, since = at
            return np.where(inside, u + (y0[k] - u) * np.exp(-since / tau), 0.0)

        return self.held - tau * (lagged(self.at[1]) - lagged(self.at[0])) / self.span


def driven_commands(cmd: FloatArray) -> FloatArray:
    """1.0 for each command (k, 2) that drives the motors, 0.0 for a stop."""
    return ((cmd[:, 0] != 0.0) | (cmd[:, 1] != 0.0)).astype(float)


def cleaned(command_times: ArrayLike, commands: ArrayLike, pose_times: ArrayLike,
            poses: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Arrays of commands and poses, the poses finite, in time order, one per stamp."""
    tc = np.asarray(command_times, float)
    cmd = np.asarray(commands, float).reshape(-1, 2)
    tp = np.asarray(pose_times, float)
    pose = np.asarray(poses, float).reshape(-1, 3)
    keep = np.isfinite(tp) & np.isfinite(pose).all(axis=1)
    tp, pose = tp[keep], pose[keep]
    order = np.argsort(tp, kind='stable')
    tp, pose = tp[order], pose[order]
    fresh = np.concatenate([[True], np.diff(tp) > 1e-6])
    return tc, cmd, tp[fresh], pose[fresh]


class MotionRecord:
    """A controller's recent commands (at, v, w; the last `commands` of them) and poses
    (taken, x, y, theta; the last `span` s, in time order), as its online fits read them.
    """

    def __init__(self, commands: int, span: float) -> None:
        self.span = span
        self.commands: deque[tuple[float, float, float]] = deque(maxlen=commands)
        self.poses: deque[tuple[float, float, float, float]] = deque()

    def sent(self, at: float, v: float, w: float) -> None:
        self.commands.append((at, v, w))

    def seen(self, taken: float, x: float, y: float, theta: float) -> None:
        if not self.poses or taken > self.poses[-1][0]:
            self.poses.append((taken, x, y, theta))
            while self.poses[0][0] < taken - self.span:
                self.poses.popleft()


class PeriodicFit:
    """A fit of a MotionRecord (`record`, which several fits may share) every `every` s
    (the first `every` s after its first update) once it holds `least` poses: update()
    calls fit(), which a subclass gives (the commands' times (k,) and (v, w) (k, 2), the
    poses' times (m,) and poses (m, 3), the latency and motors' lag it holds, s), and hands
    its result to took().
    """

    def __init__(self, record: MotionRecord, every: float, least: int) -> None:
        self.record = record
        self.every, self.least = every, least
        self.next_at: float | None = None

    def update(self, now: float, latency: float, motor_time_constant: float) -> None:
        """Fit again if `every` s have passed since the last fit."""
        if self.next_at is None:
            self.next_at = now + self.every
        commands, poses = self.record.commands, self.record.poses
        if now < self.next_at or len(commands) < 2 or len(poses) < self.least:
            return
        self.next_at = now + self.every
        sent, seen = np.array(commands), np.array(poses)
        self.took(now, self.fit(sent[:, 0], sent[:, 1:], seen[:, 0], seen[:, 1:], latency,
                                motor_time_constant))

    def fit(self, command_times: FloatArray, commands: FloatArray, pose_times: FloatArray,
            poses: FloatArray, latency: float, motor_time_constant: float) -> Any:
        raise NotImplementedError

    def took(self, now: float, found: Any) -> None:
        raise NotImplementedError
